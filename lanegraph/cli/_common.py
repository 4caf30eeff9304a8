"""What the commands share: the run service they call, options and their parsing."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import UsageError
from ..service import Session


class FolderPath(click.Path):
    """``click.Path`` for a folder option: an empty value (``--out ""``, which would have meant the
    current folder) is refused, naming the option."""

    def __init__(self) -> None:
        super().__init__(path_type=Path)

    def convert(self, value, param, ctx):  # noqa: ANN001, D102 - click's signature
        if isinstance(value, str) and not value.strip():
            self.fail(f"expected a folder, got {value!r} (for the current folder, give '.')", param, ctx)
        return super().convert(value, param, ctx)


#: the type of ``--out`` and ``--debug-dir``
FOLDER = FolderPath()
#: the type of a file or folder option
PATH = click.Path(path_type=Path)


def session(
    quiet: int = 0, verbose: int = 0, overwrite: bool = False, track: str | None = None, warn: bool = True
) -> Session:
    """The run service for a command; the plugins that could not be loaded said as warnings
    (``warn``: the commands that load plugins for their own use say so).

    What the command says on stderr goes through :mod:`logging` (:func:`lanegraph.runlog.say`):
    on the console at the level of ``-v`` / ``-q`` and into a run's ``run.log``. ``track``:
    ``--track NAME[:URI]`` (a usage error for a tracker no plugin provides)."""
    from ..runlog import configure_console, say
    from ..tracking import Tracking, parse_track

    undo = configure_console(verbose, quiet)
    ctx = click.get_current_context(silent=True)
    if ctx is not None:
        ctx.call_on_close(undo)
    s = Session(out=click.echo, err=say, progress=not quiet, overwrite=overwrite, verbose=verbose)
    if warn:
        s.warn_plugins()
    if track is not None:
        s.tracking = Tracking(parse_track(track, s.pm))
    return s


def stacked(*options):
    """One decorator applying click ``options`` in the order given (the first is listed first)."""

    def decorate(command):
        for option in reversed(options):
            command = option(command)
        return command

    return decorate


def keeping_options(command):
    """The options of the commands that write a result folder (``run``, ``ablate``): ``-v`` /
    ``-q``, ``--overwrite`` and ``--track``."""
    return stacked(
        click.option("-v", "--verbose", count=True, help="say more (details on stderr and in OUT/run.log)"),
        click.option(
            "-q",
            "--quiet",
            count=True,
            help="no progress bar (-qq: warnings and errors only, -qqq: errors only)",
        ),
        click.option(
            "--overwrite",
            is_flag=True,
            help="OUT holds another run's results: remove what lanegraph wrote there (its results, run files, "
            "debug pictures, report, runs/) and run; nothing else is touched",
        ),
        click.option(
            "--track",
            metavar="mlflow[:URI]",
            help="send the runs to an experiment tracker: mlflow (a local store), mlflow:http://HOST:PORT, "
            'mlflow:file:///DIR (pip install "lanegraph[mlflow]"; docs/tracking.md)',
        ),
    )(command)


def dataset_cache_options(command):
    """The options of the commands that run a graph over a dataset's sequences and share the
    result cache (``ablate``, ``tune``): ``--frames`` (for every sequence that does not choose its
    own), ``--no-cache``, ``--cache-dir`` and ``--cache-max-gb``."""
    return stacked(
        click.option(
            "--frames", help="frame selection A:B or A:B:S (for every sequence that does not choose its own)"
        ),
        click.option(
            "--no-cache",
            is_flag=True,
            help="recompute everything (no shared results, no reuse of unchanged runs)",
        ),
        click.option(
            "--cache-dir", type=PATH, help="result cache folder (default: ~/.cache/lanegraph/results)"
        ),
        click.option(
            "--cache-max-gb",
            type=float,
            default=2.0,
            show_default=True,
            help="size bound of the result cache, GiB",
        ),
    )(command)


def parse_frames(text: str | None) -> slice | None:
    """``A:B`` or ``A:B:S`` (Python slice semantics over the frame list) or a single index ``A``
    (:func:`lanegraph.frames.parse_frames`); a bad selection is a usage error naming ``--frames``."""
    from ..frames import parse_frames as parse

    try:
        return parse(text)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--frames") from None


def scale_out_options(scope: str = ""):
    """The options ``run`` and ``ablate`` share: resuming, debug pictures, a Dask scheduler, chunks
    and their warm-up, the report at the end (``scope``: what they need, said before each help text)."""
    return stacked(
        click.option(
            "--resume",
            is_flag=True,
            help="continue what an interrupted command left in OUT: one run after its last frame done (same graph, "
            "params, input and --frames); a batch's runs not yet finished",
        ),
        click.option(
            "--debug-dir",
            type=FOLDER,
            help="save every node's output of the chosen frames as pictures, and a mosaic (a batch's in "
            "DIR/[<variant>/]<sequence>/)",
        ),
        click.option(
            "--debug-frames", help="frames for --debug-dir: ids or indices, comma-separated (default: all)"
        ),
        click.option(
            "--scheduler",
            metavar="SPEC",
            help=f"{scope}run the runs (or their chunks) on a Dask cluster: local, local:N (N worker processes) "
            "or a scheduler address tcp://HOST:PORT",
        ),
        click.option(
            "--chunk-frames",
            type=int,
            metavar="K",
            help=f"{scope}split each run into chunks of K frames run as separate tasks",
        ),
        click.option(
            "--warmup",
            type=int,
            default=0,
            show_default=True,
            metavar="W",
            help="with --chunk-frames: run W frames before each chunk and discard their outputs",
        ),
        click.option(
            "--report",
            "make_report",
            is_flag=True,
            help="write OUT/report/index.html at the end (see `lanegraph report`)",
        ),
    )


def dataset_file(path: Path):
    """The dataset file ``path`` loaded; one that cannot be used (not there, malformed, a sequence
    named ``../x``) is an input refused before any frame: exit 2."""
    from ..errors import InputError, NotStarted
    from ..evaluation.dataset import load_dataset

    try:
        return load_dataset(path)
    except InputError as exc:
        raise NotStarted(exc) from exc


def dataset_option(dataset_path: Path | None, input_path: Path | None, gt_path: Path | None):
    """The dataset of ``--dataset``, or the one sequence of ``--input`` / ``--gt``."""
    from ..evaluation.dataset import single_sequence

    if dataset_path is not None:
        if input_path is not None or gt_path is not None:
            raise UsageError(
                "--dataset lists the inputs and ground truths: give it instead of --input/--gt, not with them"
            )
        return dataset_file(dataset_path)
    if input_path is not None and not input_path.exists():
        raise UsageError(f"--input {input_path}: no such file or folder")
    if gt_path is not None and not gt_path.is_file():
        raise UsageError(f"--gt {gt_path}: no such file")
    return single_sequence(input_path, gt_path)
