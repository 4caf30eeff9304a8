"""The ``lanegraph`` command line.

Exit codes: 0 ok, 1 failure while running (or frames that failed), 2 invalid graph or usage, or an
input that is unusable before any frame runs (no images, no calibration, an empty frame selection).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import click
import yaml

from . import __version__
from .builtin import find_graph, graphs_dir
from .errors import GraphError, InputError, LanegraphError, Problem, UsageError
from .graph import Graph, graph_json_schema, load_graph
from .kernel_cache import first_run_notice
from .nodes import NodeType, RunContext
from .plugins import PluginManager, get_plugin_manager

REPO_GRAPHS = graphs_dir()  # the built-in graphs: lanegraph/graphs when installed, graphs/ in a checkout


def resolve_graph_path(name: str) -> Path:
    """A graph argument is a file path, or the name of a graph under ``graphs/`` (``paper``,
    ``ablations/slt``), looked up in the current folder and then among the built-in graphs; an
    unknown name is a :class:`GraphError` with the closest built-in name."""
    return find_graph(name)


def parse_frames(text: str | None) -> slice | None:
    """``A:B`` or ``A:B:S`` (Python slice semantics over the frame list) or a single index ``A``
    (:func:`lanegraph.frames.parse_frames`); a bad selection is a usage error naming ``--frames``."""
    from .frames import parse_frames as parse

    try:
        return parse(text)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--frames") from None


def _fail(exc: LanegraphError, exit_code: int | None = None) -> None:
    click.echo(f"error: {exc}", err=True)
    sys.exit(exc.exit_code if exit_code is None else exit_code)


def allowed_roots(graph_path: Path) -> list[Path]:
    """Where ``extends`` may point: the graph's own folder, the current folder, lanegraph's
    ``graphs/`` and the folders listed in ``LANEGRAPH_GRAPH_ROOTS`` (os.pathsep-separated)."""
    import os

    def resolved(p: Path, where: str, field: str | None = None) -> Path:
        try:
            return p.resolve()
        except (OSError, RuntimeError) as exc:  # a symbolic link loop
            raise GraphError(
                [
                    Problem(
                        f"cannot resolve {str(p)!r}: {exc} (a symbolic link loop?)", file=where, field=field
                    )
                ]
            ) from None

    roots = [
        resolved(graph_path, str(graph_path)).parent,
        resolved(Path.cwd(), "the current folder"),
        REPO_GRAPHS.resolve(),
    ]
    roots += [
        resolved(Path(p), "LANEGRAPH_GRAPH_ROOTS", p)
        for p in os.environ.get("LANEGRAPH_GRAPH_ROOTS", "").split(os.pathsep)
        if p
    ]
    return roots


def _plugins() -> PluginManager:
    """The installed plugins; each plugin that could not be loaded is a warning line on stderr
    (every command that loads plugins prints them, once)."""
    pm = get_plugin_manager()
    for err in pm.plugin_errors:
        click.echo(f"warning: {err}", err=True)
    return pm


def _load(graph: str, sets: tuple[str, ...] = (), pm: PluginManager | None = None) -> Graph:
    path = resolve_graph_path(graph)
    return load_graph(path, list(sets), pm or get_plugin_manager(), roots=allowed_roots(path))


def _scale_out_options(scope: str = ""):
    """The options ``run --dataset`` and ``ablate`` share: a Dask scheduler, chunks and their
    warm-up, the report at the end (``scope``: what they need, said before each help text)."""
    options = [
        click.option(
            "--scheduler",
            metavar="SPEC",
            help=f"{scope}run the sequences on a Dask cluster: local, local:N (N worker processes) "
            "or a scheduler address tcp://HOST:PORT",
        ),
        click.option(
            "--chunk-frames",
            type=int,
            metavar="K",
            help=f"{scope}split sequences into chunks of K frames run as separate tasks",
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
    ]

    def decorate(command):
        for option in reversed(options):
            command = option(command)
        return command

    return decorate


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="lanegraph")
def main() -> None:
    """lanegraph: stereo lane-marking detection as validated, plugin-based processing graphs."""


@main.command()
@click.argument("graph", default="paper")
@click.option(
    "--input",
    "input_path",
    type=click.Path(path_type=Path),
    help="input folder (KITTI raw drive, KITTI odometry sequence, folder of pairs); default: the built-in synthetic scene",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(path_type=Path),
    default=Path("out"),
    show_default=True,
    help="output folder (one run at a time: it is locked while a run writes it)",
)
@click.option(
    "--set", "sets", multiple=True, metavar="NODE.PARAM=VALUE", help="override a param (repeatable)"
)
@click.option(
    "--frames", help="frame selection A:B, A:B:S or A (indices into the input's frames; -1 is the last)"
)
@click.option("--quiet", is_flag=True, help="no progress bar")
@click.option(
    "--resume",
    is_flag=True,
    help="continue an interrupted run in OUT after its last frame done (same graph, params, input and --frames)",
)
@click.option(
    "--debug-dir",
    type=click.Path(path_type=Path),
    help="save every node's output of the chosen frames as pictures, and a mosaic",
)
@click.option("--debug-frames", help="frames for --debug-dir: ids or indices, comma-separated (default: all)")
@click.option(
    "--dataset",
    "dataset_path",
    type=click.Path(path_type=Path),
    help="a dataset file (YAML list of sequences) in place of --input: writes each sequence's run into OUT/<sequence>/",
)
@_scale_out_options("with --dataset: ")
def run(
    graph: str,
    input_path: Path | None,
    out_dir: Path,
    sets: tuple[str, ...],
    frames: str | None,
    quiet: bool,
    resume: bool,
    debug_dir: Path | None,
    debug_frames: str | None,
    dataset_path: Path | None,
    scheduler: str | None,
    chunk_frames: int | None,
    warmup: int,
    make_report: bool = False,
) -> None:
    """Run GRAPH (a file or a name under graphs/, default: paper): its sinks write into OUT (the
    lanes, overlays), with OUT/timings.json and OUT/run.json; with --dataset, every sequence into
    OUT/<sequence>/ (in this process, or on a Dask cluster with --scheduler)."""
    first_run_notice(quiet)  # the first run on a machine compiles the kernels: say so at once
    if dataset_path is not None:
        _run_dataset(
            graph,
            sets,
            dataset_path,
            out_dir,
            frames,
            quiet,
            scheduler,
            chunk_frames,
            warmup,
            input_path,
            resume,
            debug_dir,
            make_report,
        )
        return
    for flag, given in (
        ("--scheduler", scheduler),
        ("--chunk-frames", chunk_frames),
        ("--warmup", warmup or None),
    ):
        if given is not None:
            click.echo(f"error: {flag} runs the sequences of a --dataset: give --dataset FILE", err=True)
            sys.exit(2)
    from .paths import OutputLock, prepare_dir

    try:
        g = _load(graph, sets, _plugins())
    except GraphError as exc:
        _fail(exc)
    if input_path is not None and not input_path.exists():
        click.echo(f"error: --input {input_path}: no such file or folder", err=True)
        sys.exit(2)
    selection = parse_frames(frames)
    chosen = None
    if debug_frames is not None:
        chosen = {item.strip() for item in debug_frames.split(",") if item.strip()}
        if not chosen:
            _fail(
                UsageError(f"--debug-frames {debug_frames!r}: expected frame ids or indices, comma-separated")
            )
    locks: list[OutputLock] = []
    try:
        prepare_dir(out_dir, "--out")
        if debug_dir is not None:
            prepare_dir(debug_dir, "--debug-dir")
        locks.append(OutputLock(out_dir, "run").acquire())
    except UsageError as exc:
        for lk in locks:
            lk.release()
        _fail(exc)
    try:
        status = _run_locked(g, input_path, out_dir, selection, quiet, resume, debug_dir, chosen, make_report)
    finally:
        for lk in locks:
            lk.release()
    sys.exit(status)


def _run_locked(
    g: Graph,
    input_path: Path | None,
    out_dir: Path,
    selection: slice | None,
    quiet: bool,
    resume: bool,
    debug_dir: Path | None,
    debug_frames: set[str] | None,
    make_report: bool = False,
) -> int:
    """The body of ``lanegraph run`` once OUT is locked; returns the exit code."""
    from .executor import Executor

    ckpt, checkpoint = _checkpoint(out_dir, resume)
    ctx = RunContext(
        input_path=input_path,
        out_dir=out_dir,
        frames=selection,
        graph_file=g.file,
        extra={"resume": ckpt is not None},
        skip=ckpt.position if ckpt is not None else 0,
    )
    try:
        ex = Executor(g, ctx, checkpoint=checkpoint, resume=ckpt)
    except LanegraphError as exc:
        _fail(exc, 2)
    if ckpt is not None:
        if ckpt.complete:
            return _nothing_to_resume(ex, ckpt, out_dir)
        click.echo(
            f"resuming after frame {ckpt.last_frame} ({ckpt.position} frame(s) of the selection already done)",
            err=True,
        )
    recorder = None
    pm = get_plugin_manager()
    if debug_dir is not None:
        from .render import DebugRecorder

        recorder = DebugRecorder(debug_dir, debug_frames, pm)
        pm.register(recorder)
    try:
        result, code = _execute(ex, g, out_dir, input_path, quiet)
    finally:
        if recorder is not None:
            pm.unregister(recorder)
    if result is None:
        return code
    status = _report_run(ex, result, g, out_dir, input_path, recorder, debug_frames)
    if make_report and status != -1:
        try:
            dbg = (
                debug_dir if debug_dir is not None and debug_dir.is_dir() else None
            )  # none if no frame was chosen
            _write_report(
                out_dir, graph=g, input_path=input_path, frames=selection, debug_dir=dbg, quiet=quiet
            )
        except LanegraphError as exc:  # the run's own outputs are written: they stay
            click.echo(f"error: report: {exc}", err=True)
            status = 1
    return 1 if status == -1 else status


def _checkpoint(out_dir: Path, resume: bool) -> tuple[Any, Path]:
    """The checkpoint to resume (with ``--resume``, when OUT has one; validated) and where the run
    keeps its own; a checkpoint of an older lanegraph is never read."""
    from .resume import CHECKPOINT_NAME, LEGACY_NAME, load_checkpoint

    checkpoint = out_dir / CHECKPOINT_NAME
    legacy = out_dir / LEGACY_NAME
    try:
        if resume and legacy.is_file() and not checkpoint.is_file():
            raise UsageError(
                f"{legacy}: a checkpoint of an older lanegraph (a pickle, which could run code); it is never read; "
                "cannot resume (run without --resume to start over)"
            )
        legacy.unlink(missing_ok=True)
        if checkpoint.exists() and not checkpoint.is_file():
            raise UsageError(f"{checkpoint}: exists and is not a file (lanegraph keeps its checkpoint there)")
        if resume and checkpoint.is_file():
            return load_checkpoint(checkpoint), checkpoint
        if not resume:
            checkpoint.unlink(missing_ok=True)
    except LanegraphError as exc:
        _fail(exc)
    except OSError as exc:
        _fail(UsageError(f"{out_dir}: {exc.strerror or exc}"))
    return None, checkpoint


def _nothing_to_resume(ex: Any, ckpt: Any, out_dir: Path) -> int:
    """``--resume`` of a complete run: its input and outputs are checked, nothing runs."""
    try:  # the input and the outputs must still be those of the checkpoint
        ex.open()
    except LanegraphError as exc:
        _fail(exc, 2)
    finally:
        for inst in ex.instances.values():
            close = getattr(inst, "close", None)
            if close is not None:
                close()
    click.echo(
        f"nothing to resume: the run in {out_dir} is complete ({ckpt.frames_ok} frame(s) done, "
        f"{len(ckpt.failures)} failed); its outputs are left as they are",
        err=True,
    )
    return 1 if ckpt.failures else 0


def _execute(ex: Any, g: Graph, out_dir: Path, input_path: Path | None, quiet: bool) -> tuple[Any, int]:
    """Open and run the executor with a progress bar: ``(result, 0)``, or ``(None, exit code)``
    when it stopped (its partial record written: ``run.json`` says what it did and why it stopped)."""
    from tqdm import tqdm

    bar = None
    try:
        try:
            ex.open()
        except (
            InputError,
            UsageError,
        ) as exc:  # unusable input found before any frame ran: like a bad --input
            _fail(exc, 2)
        bar = tqdm(
            total=(len(ex) or None),
            unit="frame",
            disable=True if quiet else None,
            desc=g.name,
            file=sys.stderr,
        )

        def tick(index: int, frame: str | None) -> None:
            bar.update(1)
            bar.set_postfix_str(str(frame))

        return ex.run(on_frame=tick), 0
    except (LanegraphError, KeyboardInterrupt, OSError) as exc:
        if bar is not None:
            bar.close()
        if isinstance(exc, KeyboardInterrupt):
            err: LanegraphError = LanegraphError("interrupted (Ctrl-C); continue with --resume")
            code = 130
        elif isinstance(exc, OSError):
            err = LanegraphError(f"{str(exc.filename) + ': ' if exc.filename else ''}{exc.strerror or exc}")
            code = 1
        else:
            err, code = exc, exc.exit_code
        partial = getattr(ex, "result", None)
        if partial is not None:  # the run started: record what it did and why it stopped
            _write_run_files(out_dir, g, input_path, partial, stopped=err)
        click.echo(f"error: {err}", err=True)
        return None, code
    finally:
        if bar is not None:
            bar.close()


def _report_run(
    ex: Any,
    result: Any,
    g: Graph,
    out_dir: Path,
    input_path: Path | None,
    recorder: Any,
    debug_frames: set[str] | None,
) -> int:
    """Write the run's record and say what it did: 0, 1 (frames failed) or -1 (its record could
    not be written)."""
    status = 0
    written = _write_run_files(out_dir, g, input_path, result)
    if result.failures:
        click.echo(f"{len(result.failures)} frame(s) failed:", err=True)
        for f in result.failures:
            click.echo(
                f"  frame {f.frame} (#{f.index}): node '{f.node_id}' ({f.node_type}): {f.error}", err=True
            )
        status = 1
    for w in result.warnings():
        click.echo(f"warning: {w}", err=True)
    if recorder is not None and debug_frames is not None:
        missed = sorted(f for f in debug_frames if f not in recorder.matched)
        if missed:
            click.echo(
                f"warning: --debug-frames {', '.join(missed)} matched no frame of the run; nothing recorded for them",
                err=True,
            )
    if not written:
        return -1
    outputs = [str(p) for inst in ex.instances.values() for p in getattr(inst, "outputs", [])]
    total = result.timings_json().get("total", {})
    click.echo(
        f"{result.frames} frame(s) processed -> {', '.join([*outputs, str(out_dir / 'timings.json')])}"
        + (f" (median {total['median_ms']:.1f} ms/frame)" if total else "")
    )
    return status


def _run_dataset(
    graph,
    sets,
    dataset_path,
    out_dir,
    frames,
    quiet,
    scheduler,
    chunk_frames,
    warmup,
    input_path,
    resume,
    debug_dir,
    make_report,
) -> None:
    """``run GRAPH --dataset FILE``: every sequence into OUT/<sequence>/; exit 1 when a frame failed
    or a sequence stopped, 2 when no sequence could start."""
    from .batch import ResolvedGraph, describe_error, parse_scheduler, run_dataset
    from .dataset import load_dataset
    from .paths import OutputLock, prepare_dir

    for flag, given in (
        ("--input", input_path),
        ("--resume", resume or None),
        ("--debug-dir", debug_dir),
        ("--report", make_report or None),
    ):
        if given is not None:
            click.echo(
                f"error: {flag} is for a run on one input; --dataset names the inputs (give one or the other)",
                err=True,
            )
            sys.exit(2)
    _plugins()
    try:
        spec = parse_scheduler(scheduler)
        dataset = load_dataset(dataset_path)
        path = resolve_graph_path(graph)
        resolved = ResolvedGraph.load(path, sets, allowed_roots(path))
        prepare_dir(out_dir, "--out")
        lock = OutputLock(out_dir, "run").acquire()
    except GraphError as exc:
        _fail(exc)
    except LanegraphError as exc:  # a usage error
        _fail(exc, 2)
    try:
        summary = run_dataset(
            resolved, dataset, out_dir, parse_frames(frames), spec, chunk_frames, warmup, progress=not quiet
        )
    except GraphError as exc:
        _fail(exc)
    except LanegraphError as exc:  # a usage error, an unusable input found before any frame ran
        _fail(exc, 2)
    finally:
        lock.release()
    status = 0
    for s in summary:
        files = [str(out_dir / s["sequence"] / f) for f in s.get("results", {}).values()]
        line = f"{s['sequence']}: {s['frames']} frame(s) -> {', '.join(files) or out_dir / s['sequence']}"
        if s["error"] is not None and s["error"].get("before_any_frame"):
            line = f"{s['sequence']}: not run (see {out_dir / s['sequence']}/run.json)"
        if s["failures"]:
            line += f", {len(s['failures'])} frame(s) failed"
            status = 1
        click.echo(line)
        for f in s["failures"]:
            click.echo(
                f"  frame {f.frame} (#{f.index}): node '{f.node_id}' ({f.node_type}): {f.error}", err=True
            )
        if s["error"] is not None:
            click.echo(f"error: {describe_error(s['error'])}", err=True)
            status = 1
    if summary and all(s["error"] is not None and s["error"].get("before_any_frame") for s in summary):
        status = 2  # nothing ran at all: the inputs are unusable
    sys.exit(status)


def _write_run_files(
    out_dir: Path, g: Graph, input_path: Path | None, result: Any, stopped: LanegraphError | None = None
) -> bool:
    """``timings.json`` and ``run.json`` (frames done, failed frames, warnings, and the error that
    stopped the run); False (and the reason on stderr) when they cannot be written (a full disk)."""
    from .paths import write_text_atomic

    record: dict[str, Any] = {
        "graph": g.file,
        "input": str(input_path) if input_path else None,
        "status": "stopped" if stopped is not None else ("failed frames" if result.failures else "ok"),
        "frames_ok": result.frames,
        "resumed_frames": result.resumed_frames,
        "failures": [f.to_json() for f in result.failures],
        "warnings": result.warnings(),
        "results": result.results,
    }
    if stopped is not None:
        record["stopped"] = {
            "error": str(stopped),
            "node": getattr(stopped, "node_id", None),
            "frame": getattr(stopped, "frame", None),
        }
    try:
        write_text_atomic(out_dir / "timings.json", json.dumps(result.timings_json(), indent=2) + "\n")
        write_text_atomic(out_dir / "run.json", json.dumps(record, indent=2) + "\n")
    except OSError as exc:
        click.echo(
            f"error: cannot write {out_dir}/run.json and timings.json: {exc.strerror or exc}", err=True
        )
        return False
    return True


@main.command()
@click.argument("graph")
@click.option(
    "--set", "sets", multiple=True, metavar="NODE.PARAM=VALUE", help="override a param (repeatable)"
)
def validate(graph: str, sets: tuple[str, ...]) -> None:
    """Validate GRAPH (exit 2 with every problem listed when invalid)."""
    try:
        g = _load(graph, sets, _plugins())
    except GraphError as exc:
        _fail(exc)
    click.echo(f"{g.file}: ok ({len(g.nodes)} nodes, {sum(e.previous for e in g.edges)} feedback edge(s))")


def builtin_node_types(pm: PluginManager) -> dict[str, NodeType]:
    """The node types of ``pm`` provided by lanegraph's own plugins (its ``lanegraph.plugins`` entry points)."""
    from importlib import metadata

    from .plugins import BUILTIN_DISTRIBUTION, ENTRY_POINT_GROUP

    own = {
        ep.name
        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)
        if ep.dist is not None and ep.dist.name == BUILTIN_DISTRIBUTION
    }
    return {name: nt for name, nt in pm.node_types.items() if nt.plugin in own}


def _md_cell(text: object) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _md_type(annotation: object) -> str:
    if isinstance(annotation, type):
        return annotation.__name__
    return str(annotation).replace("typing.", "").replace("NoneType", "None")


def _split_numpydoc(doc: str) -> tuple[str, str]:
    """A docstring's prose, and its numpydoc sections (from the first ``Header`` over a ``---`` line)."""
    lines = doc.strip().splitlines()
    for i in range(1, len(lines)):
        rule = lines[i].strip()
        if rule and set(rule) == {"-"} and lines[i - 1].strip():
            return "\n".join(lines[: i - 1]).strip(), "\n".join(lines[i - 1 :]).strip()
    return doc.strip(), ""


def nodes_markdown(types: dict[str, NodeType], title: str = "Node reference") -> str:
    """The node reference as Markdown: per node type its doc, ports with types and params with
    defaults, bounds and descriptions (``lanegraph nodes --markdown --builtin > docs/nodes.md``)."""
    from pydantic_core import PydanticUndefined

    out = [
        f"# {title}",
        "",
        "<!-- generated by `lanegraph nodes --markdown --builtin > docs/nodes.md`; do not edit by hand -->",
        "",
        "Every node type lanegraph ships, by family. Port types: [graph-format.md](graph-format.md);",
        "orientation and BEV conventions: [architecture.md](architecture.md).",
        "",
    ]
    families: dict[str, list[str]] = {}
    for name in types:
        families.setdefault(name.split(".")[0], []).append(name)
    for fam, names in families.items():
        out.append(f"- **{fam}**: " + ", ".join(f"[`{n}`](#{n.replace('.', '')})" for n in names))
    for name, nt in types.items():
        flags = [
            f
            for f, on in (
                ("source", nt.source),
                ("sink", nt.sink),
                ("stateful", nt.stateful and not nt.source),
            )
            if on
        ]
        out += [
            "",
            f"## {name}",
            "",
            f"Plugin `{nt.plugin}`" + (f"; {', '.join(flags)}" if flags else "") + ".",
            "",
        ]
        prose, sections = _split_numpydoc(nt.doc)
        if prose:
            out += [prose, ""]
        if sections:  # numpydoc "Parameters / -----" would render as headings
            out += ["```text", sections, "```", ""]
        for label, ports in (("Inputs", nt.inputs), ("Outputs", nt.outputs)):
            if not ports:
                out.append(f"{label}: none.")
                out.append("")
                continue
            out += [f"| {label.lower()[:-1]} | type | | description |", "|---|---|---|---|"]
            for pname, port in ports.items():
                notes = ", ".join(
                    n for n, on in (("optional", port.optional), ("constant", port.rate == "constant")) if on
                )
                out.append(f"| `{pname}` | `{port.type}` | {notes} | {_md_cell(port.doc)} |")
            out.append("")
        fields = nt.params.model_fields
        if not fields:
            out.append("Params: none.")
            continue
        out += ["| param | type | default | bounds | description |", "|---|---|---|---|---|"]
        for fname, f in fields.items():
            if f.is_required():
                default = "required"
            elif f.default is PydanticUndefined and f.default_factory is not None:
                default = f"`{f.default_factory()!r}`"
            else:
                default = f"`{f.default!r}`"
            bounds = []
            for m in f.metadata:
                for attr, sym in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<")):
                    if getattr(m, attr, None) is not None:
                        bounds.append(f"{sym} {getattr(m, attr)}")
            out.append(
                f"| `{fname}` | `{_md_type(f.annotation)}` | {_md_cell(default)} | {_md_cell(', '.join(bounds))} "
                f"| {_md_cell(f.description or '')} |"
            )
    return "\n".join(out) + "\n"


@main.command()
@click.option("--json", "as_json", is_flag=True, help="machine-readable listing")
@click.option(
    "--markdown", "as_markdown", is_flag=True, help="the node reference as Markdown (docs/nodes.md)"
)
@click.option("--builtin", is_flag=True, help="only the node types of lanegraph's own plugins")
def nodes(as_json: bool, as_markdown: bool, builtin: bool) -> None:
    """List the installed node types with their ports and params, the port types, and the plugins
    that could not be loaded."""
    pm = _plugins() if as_markdown else get_plugin_manager()  # the listing and --json show them themselves
    types = builtin_node_types(pm) if builtin else pm.node_types
    if as_markdown:
        click.echo(nodes_markdown(types), nl=False)
        return
    if as_json:
        out = []
        for name, nt in types.items():
            out.append(
                {
                    "name": name,
                    "plugin": nt.plugin,
                    "doc": nt.doc,
                    "stateful": nt.stateful,
                    "source": nt.source,
                    "sink": nt.sink,
                    "inputs": {
                        p: {"type": x.type, "optional": x.optional, "rate": x.rate, "doc": x.doc}
                        for p, x in nt.inputs.items()
                    },
                    "outputs": {
                        p: {"type": x.type, "rate": x.rate, "doc": x.doc} for p, x in nt.outputs.items()
                    },
                    "params": nt.params.model_json_schema(),
                }
            )
        ports = [
            {"name": t.name, "description": t.description, "parent": t.parent} for t in pm.port_types.values()
        ]
        click.echo(
            json.dumps(
                {"node_types": out, "port_types": ports, "plugin_errors": [str(e) for e in pm.plugin_errors]},
                indent=2,
            )
        )
        return
    for name, nt in types.items():
        flags = ",".join(
            f
            for f, on in (
                ("source", nt.source),
                ("sink", nt.sink),
                ("stateful", nt.stateful and not nt.source),
            )
            if on
        )
        click.echo(f"{name}  [{nt.plugin}]{' (' + flags + ')' if flags else ''}")
        if nt.summary:
            click.echo(f"    {nt.summary}")
        ins = ", ".join(f"{p}: {x.type}{'?' if x.optional else ''}" for p, x in nt.inputs.items())
        outs = ", ".join(f"{p}: {x.type}" for p, x in nt.outputs.items())
        click.echo(f"    in({ins}) -> out({outs})")
        for fname, f in nt.params.model_fields.items():
            default = "(required)" if f.is_required() else f"= {f.default!r}"
            click.echo(f"    - {fname} {default}: {f.description or ''}")
    from .types import PORT_TYPES

    added = [t for t in pm.port_types.values() if t.name not in PORT_TYPES]
    if added:
        click.echo("port types added by plugins:")
        for t in added:
            click.echo(
                f"    {t.name}" + (f" (feeds {t.parent} ports)" if t.parent else "") + f": {t.description}"
            )
    if pm.plugin_errors:
        click.echo("plugins not loaded:")
        for err in pm.plugin_errors:
            click.echo(f"    warning: {err}")


@main.command()
def schema() -> None:
    """Print the JSON Schema of the graph format, with every installed node type's params."""
    click.echo(json.dumps(graph_json_schema(_plugins()), indent=2))


@main.command()
@click.argument("graph")
@click.option(
    "--format", "fmt", type=click.Choice(["yaml", "dot", "mermaid"]), default="yaml", show_default=True
)
@click.option("--set", "sets", multiple=True, metavar="NODE.PARAM=VALUE")
def show(graph: str, fmt: str, sets: tuple[str, ...]) -> None:
    """Print the resolved graph (after extends and overrides) as YAML, Graphviz dot or Mermaid."""
    try:
        g = _load(graph, sets, _plugins())
    except GraphError as exc:
        _fail(exc)
    if fmt == "yaml":
        click.echo(yaml.safe_dump(g.resolved_dict(), sort_keys=False), nl=False)
    elif fmt == "dot":
        q = _dot_quote
        lines = [f"digraph {q(g.name)} {{", "  rankdir=TB;", "  node [shape=box, fontname=Helvetica];"]
        for nid in g.order:
            lines.append(f"  {q(nid)} [label={q(nid + chr(10) + g.nodes[nid].type.name)}];")
        for e in g.edges:
            style = (
                f", style=dashed, constraint=false, label={q(e.src_port + ' (prev)')}"
                if e.previous
                else f", label={q(e.src_port)}"
            )
            lines.append(f"  {q(e.src_node)} -> {q(e.dst_node)} [headlabel={q(e.dst_port)}{style}];")
        lines.append("}")
        click.echo("\n".join(lines))
    else:
        ids = {
            nid: f"n_{nid.replace('-', '_')}_{k}" for k, nid in enumerate(g.order)
        }  # never a keyword (end, graph)
        lines = ["flowchart TD"]
        for nid in g.order:
            lines.append(f'  {ids[nid]}["{_mermaid_text(nid)}<br/>{_mermaid_text(g.nodes[nid].type.name)}"]')
        for e in g.edges:
            arrow = "-.->" if e.previous else "-->"
            label = f"{e.src_port}→{e.dst_port}" + (" (prev)" if e.previous else "")
            lines.append(f'  {ids[e.src_node]} {arrow}|"{_mermaid_text(label)}"| {ids[e.dst_node]}')
        click.echo("\n".join(lines))


def _dot_quote(text: str) -> str:
    """A Graphviz quoted string: backslashes and quotes escaped, line breaks as \\n."""
    body = str(text).replace("\\", "\\\\").replace('"', '\\"').replace("\r", "").replace("\n", "\\n")
    return f'"{body}"'


def _mermaid_text(text: str) -> str:
    """Text inside a Mermaid quoted label: quotes and angle brackets as entities."""
    return (
        str(text)
        .replace("&", "#amp;")
        .replace('"', "#quot;")
        .replace("<", "#lt;")
        .replace(">", "#gt;")
        .replace("\n", " ")
    )


@main.command()
@click.argument("base", type=click.Path(path_type=Path))
@click.argument("variants", nargs=-1, type=click.Path(path_type=Path))
@click.option(
    "--input",
    "input_path",
    type=click.Path(path_type=Path),
    help="input folder; default: the built-in synthetic scene",
)
@click.option(
    "--gt", "gt_path", type=click.Path(path_type=Path), help="ground truth lanes_gt.jsonl to evaluate against"
)
@click.option(
    "--dataset",
    "dataset_path",
    type=click.Path(path_type=Path),
    help="a dataset file (YAML list of sequences, each an input and a ground truth) in place of --input/--gt",
)
@click.option(
    "--sweep",
    "sweeps",
    multiple=True,
    metavar="NODE.PARAM=V1,V2,...",
    help="also run BASE once per value (repeatable)",
)
@click.option(
    "--out", "out_dir", type=click.Path(path_type=Path), default=Path("out/ablation"), show_default=True
)
@click.option(
    "--frames", help="frame selection A:B or A:B:S (for every sequence that does not choose its own)"
)
@click.option(
    "--no-cache", is_flag=True, help="recompute everything (no shared results, no reuse of unchanged runs)"
)
@click.option(
    "--cache-dir",
    type=click.Path(path_type=Path),
    help="result cache folder (default: ~/.cache/lanegraph/results)",
)
@click.option(
    "--cache-max-gb", type=float, default=2.0, show_default=True, help="size bound of the result cache, GiB"
)
@click.option("--quiet", is_flag=True, help="no progress bars")
@_scale_out_options()
def ablate(
    base,
    variants,
    input_path,
    gt_path,
    dataset_path,
    sweeps,
    out_dir,
    frames,
    no_cache,
    cache_dir,
    cache_max_gb,
    quiet,
    scheduler,
    chunk_frames,
    warmup,
    make_report=False,
):
    """Run BASE and every VARIANT (and every --sweep point) over the same input or dataset, evaluate
    each and write OUT/results.csv (per sequence and pooled), OUT/results.md and plots; runs go to
    OUT/runs/<variant>/<sequence>/; work shared between variants is computed once. A run that
    fails gets its row with the error and the others go on (exit 1)."""
    first_run_notice(quiet)
    from .batch import parse_scheduler

    pm = _plugins()
    try:
        spec = parse_scheduler(scheduler)
    except LanegraphError as exc:
        _fail(exc, 2)
    runs = _ablation_variants(base, variants, sweeps)
    try:
        dataset = _dataset_option(dataset_path, input_path, gt_path)
    except LanegraphError as exc:
        _fail(exc, 2)
    for r in runs:  # validate everything before running anything
        try:
            _load(str(r.graph), tuple(r.sets), pm)
        except GraphError as exc:
            _fail(exc)
    selection = parse_frames(frames)
    lock, cache = _ablation_out(out_dir, no_cache, cache_dir, cache_max_gb)
    t0 = time.perf_counter()
    options = {"progress": not quiet, "scheduler": spec, "chunk_frames": chunk_frames, "warmup": warmup}
    rows = _run_ablation(lock, runs, dataset, out_dir, selection, cache, options)
    _ablation_end(rows, out_dir, cache, time.perf_counter() - t0)
    if make_report:
        try:  # the base variant's source reads the left images; its graph is drawn
            _write_report(
                out_dir,
                dataset=dataset,
                frames=selection,
                graph=_load(str(runs[0].graph), tuple(runs[0].sets), pm),
                quiet=quiet,
            )
        except LanegraphError as exc:  # the ablation's own outputs are written: they stay
            _fail(exc, 1)
    _ablation_failures(rows)


def _run_ablation(
    lock: Any,
    runs: list[Any],
    dataset: Any,
    out_dir: Path,
    selection: slice | None,
    cache: Any,
    options: dict[str, Any],
) -> list[dict[str, Any]]:
    """:func:`lanegraph.ablate.run_ablation` with OUT locked; its errors located, exit 2 for an
    input or usage found unusable before any run, 130 on Ctrl-C (the finished runs stay)."""
    from .ablate import run_ablation

    try:
        return run_ablation(runs, dataset, out_dir, selection, cache, **options)
    except (
        InputError,
        UsageError,
    ) as exc:  # a ground truth, input or usage unusable before any run: like `run`, exit 2
        _fail(exc, 2)
    except LanegraphError as exc:
        _fail(exc)
    except KeyboardInterrupt:
        click.echo(
            f"error: interrupted (Ctrl-C); the finished runs are in {out_dir}/runs and results.md", err=True
        )
        sys.exit(130)
    except OSError as exc:
        _fail(LanegraphError(f"{str(exc.filename) + ': ' if exc.filename else ''}{exc.strerror or exc}"), 1)
    finally:
        lock.release()
    raise AssertionError("unreachable")  # pragma: no cover - _fail exits


def _ablation_end(rows: list[dict[str, Any]], out_dir: Path, cache: Any, seconds: float) -> None:
    """Print the results table and where it went; exit 2 when no run could start at all."""
    runs_rows = [r for r in rows if r.get("sequence") != "all"]
    failed = [r for r in runs_rows if r.get("error")]
    if failed and all(r.get("before_any_frame") for r in failed) and len(failed) == len(runs_rows):
        for r in failed:  # nothing ran at all: the input is unusable (exit 2, as `run` says)
            click.echo(f"error: {r['variant']} / {r['sequence']}: {r['error']}", err=True)
        sys.exit(2)
    click.echo((out_dir / "results.md").read_text())
    hits = f", cache {cache.hits} hits / {cache.misses} misses" if cache is not None else ", no cache"
    click.echo(
        f"{len(rows)} row(s) in {seconds:.1f} s{hits} -> {out_dir}/results.md, results.csv, accuracy.png, accuracy_vs_ms.png"
    )


def _ablation_failures(rows: list[dict[str, Any]]) -> None:
    """The runs that failed and the frames that failed in the others: exit 1 when there are any."""
    runs_rows = [r for r in rows if r.get("sequence") != "all"]
    failed = [r for r in runs_rows if r.get("error")]
    if failed or any(r.get("failed_frames") for r in runs_rows):
        for r in failed:
            click.echo(f"error: run {r['variant']} / {r['sequence']} failed: {r['error']}", err=True)
        n_frames = sum(int(r.get("failed_frames") or 0) for r in runs_rows if not r.get("error"))
        if n_frames:
            click.echo(
                f"{n_frames} frame(s) failed in runs that went on (on_error skip); see results.md", err=True
            )
        sys.exit(1)


def _ablation_variants(base: Path, variants: tuple[Path, ...], sweeps: tuple[str, ...]) -> list[Any]:
    """BASE, each VARIANT (named by its file; by folder/file where two files share a name) and a
    variant of BASE per ``--sweep`` value."""
    from .ablate import Variant, expand_sweeps

    try:
        paths = [resolve_graph_path(str(p)) for p in (base, *variants)]
    except GraphError as exc:
        _fail(exc)
    runs = [Variant(p.stem, p) for p in paths]
    names = [r.name for r in runs]
    for r in runs:  # disambiguate equal file names
        if names.count(r.name) > 1:
            r.name = f"{r.graph.parent.name}/{r.name}"
    try:
        runs += expand_sweeps(paths[0], list(sweeps))
    except ValueError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
    return runs


def _ablation_out(
    out_dir: Path, no_cache: bool, cache_dir: Path | None, cache_max_gb: float
) -> tuple[Any, Any]:
    """OUT checked and locked, and the result cache (None with ``--no-cache``)."""
    import math

    from .cache import ResultCache
    from .paths import OutputLock, prepare_dir

    if not (math.isfinite(cache_max_gb) and cache_max_gb > 0):
        _fail(UsageError(f"--cache-max-gb: expected a size in GiB > 0, got {cache_max_gb}"))
    try:
        if cache_dir is not None and not no_cache:
            prepare_dir(cache_dir, "--cache-dir")
        prepare_dir(out_dir, "--out")
        lock = OutputLock(out_dir, "ablate").acquire()
    except UsageError as exc:
        _fail(exc)
    try:
        cache = None if no_cache else ResultCache(cache_dir, int(cache_max_gb * 1024**3))
    except OSError as exc:
        lock.release()
        _fail(UsageError(f"--cache-dir: cannot use the result cache: {exc.strerror or exc}"))
    return lock, cache


def _dataset_option(dataset_path: Path | None, input_path: Path | None, gt_path: Path | None):
    """The dataset of ``--dataset``, or the one sequence of ``--input`` / ``--gt``."""
    from .dataset import load_dataset, single_sequence

    if dataset_path is not None:
        if input_path is not None or gt_path is not None:
            raise UsageError(
                "--dataset lists the inputs and ground truths: give it instead of --input/--gt, not with them"
            )
        return load_dataset(dataset_path)
    if input_path is not None and not input_path.exists():
        raise UsageError(f"--input {input_path}: no such file or folder")
    if gt_path is not None and not gt_path.is_file():
        raise UsageError(f"--gt {gt_path}: no such file")
    return single_sequence(input_path, gt_path)


def _scene_pose(scene: Path) -> tuple[float, float]:
    """``(pitch in radians, camera height in metres)`` of a synthetic sequence's ``scene.json``."""
    import math

    try:
        info = json.loads(scene.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read the scene description: {exc}", path=str(scene)) from None
    if not isinstance(info, dict):
        raise InputError("expected a JSON object with height and pitch_rad (or pitch_deg)", path=str(scene))
    pitch = info.get(
        "pitch_rad", math.radians(info["pitch_deg"]) if _is_number(info.get("pitch_deg")) else 0.0
    )
    height = info.get("height")
    for key, v in (("pitch_rad", pitch), ("height", height)):
        if not _is_number(v) or not math.isfinite(v):
            raise InputError(f"key {key!r}: expected a finite number, got {v!r}", path=str(scene))
    if height <= 0:
        raise InputError(f"key 'height': the camera height must be > 0 m, got {height}", path=str(scene))
    return float(pitch), float(height)


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


@main.command(name="eval")
@click.argument("pred", type=click.Path(path_type=Path))
@click.argument("gt", type=click.Path(path_type=Path), required=False)
@click.option(
    "--dataset",
    "dataset_path",
    type=click.Path(path_type=Path),
    help="a dataset file: PRED is then a folder with a run folder PRED/<sequence>/ per sequence (as `run --dataset` writes)",
)
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
@click.option(
    "--metrics",
    default="readme,culane,tusimple",
    show_default=True,
    help="readme, culane, tusimple, lateral (comma-separated)",
)
@click.option(
    "--scene",
    type=click.Path(path_type=Path),
    help="scene.json of a synthetic sequence (pitch, height) for the lateral error",
)
@click.option(
    "--calib",
    type=click.Path(path_type=Path),
    help="the calibration for the lateral error: a calibration file, or an input folder (default: the folder of --scene)",
)
def eval_cmd(
    pred: Path,
    gt: Path | None,
    dataset_path: Path | None,
    as_json: bool,
    metrics: str,
    scene: Path | None,
    calib: Path | None,
) -> None:
    """Evaluate PRED (a run's lanes file, or its run folder) against GT lanes_gt.jsonl: the lane
    metric of the data README, plus
    CULane-style F1, TuSimple-style accuracy and, for synthetic scenes, the lateral error in cm.
    With --dataset, every sequence of the dataset and all of them pooled."""
    wanted = {m.strip() for m in metrics.split(",") if m.strip()}
    unknown = wanted - {"readme", "culane", "tusimple", "lateral"}
    if unknown:
        click.echo(
            f"error: --metrics: unknown metric(s) {sorted(unknown)}; expected readme, culane, tusimple, lateral",
            err=True,
        )
        sys.exit(2)
    if scene is not None:
        wanted.add("lateral")
    if dataset_path is not None:
        if gt is not None:
            click.echo(
                "error: --dataset names every sequence's ground truth: give PRED (a folder) and --dataset, not GT",
                err=True,
            )
            sys.exit(2)
        _eval_dataset(pred, dataset_path, as_json)
        return
    if gt is None:
        click.echo(
            "error: missing GT (a lanes_gt.jsonl), or --dataset FILE with PRED a folder of <sequence>/ run folders",
            err=True,
        )
        sys.exit(2)
    try:
        res = _eval_one(pred, gt, wanted, scene, calib)
    except LanegraphError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
    if as_json:
        click.echo(json.dumps(res))
        return
    _print_eval(res)


def _eval_one(
    pred: Path, gt: Path, wanted: set[str], scene: Path | None, calib: Path | None
) -> dict[str, Any]:
    from .metrics import evaluate, read_ground_truth, read_predictions
    from .metrics_extra import culane_metrics, lateral_error_cm, tusimple_metrics

    if pred.is_dir():  # a run folder: the lanes its sinks recorded
        pred = _run_lanes(pred)
    pred_recs, gt_recs = read_predictions(pred), read_ground_truth(gt)
    pred_frames, gt_frames = {str(r["frame"]) for r in pred_recs}, {str(r["frame"]) for r in gt_recs}
    if pred_frames and gt_frames and not pred_frames & gt_frames:
        raise InputError(
            f"no frame of {pred} is in {gt} (e.g. {sorted(pred_frames)[0]!r} against {sorted(gt_frames)[0]!r}): "
            "predictions and ground truth of different sequences?",
            path=str(pred),
        )
    res = evaluate(pred_recs, gt_recs)
    res.pop("per_frame")
    if "culane" in wanted:
        res["culane"] = culane_metrics(pred_recs, gt_recs)
    if "tusimple" in wanted:
        res["tusimple"] = tusimple_metrics(pred_recs, gt_recs)
    if "lateral" in wanted:
        if scene is None:
            raise UsageError(
                "--metrics lateral needs --scene scene.json (and --calib, default: the calibration of the input folder holding it)"
            )
        from .sources import read_calibration

        cal = read_calibration(_plugins(), calib or Path(scene).parent)
        pitch, height = _scene_pose(Path(scene))
        res["lateral_error_cm"] = lateral_error_cm(pred_recs, gt_recs, cal, pitch, height)
    return res


def _run_lanes(folder: Path, what: str = "") -> Path:
    """The lanes file of run folder ``folder`` (the one its run.json records; :mod:`lanegraph.results`)."""
    from .results import LANES, describe, find_result

    lanes = find_result(folder, LANES, get_plugin_manager())
    if lanes is None:
        raise UsageError(
            f"{folder}: no predictions{' for ' + what if what else ''} (expected {describe(folder, LANES)})"
        )
    return lanes


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def _print_eval(res: dict[str, Any]) -> None:
    click.echo(f"frames:          {res['frames']}")
    click.echo(f"detection ratio: {_pct(res['detection_ratio'])}")
    click.echo(f"precision:       {_pct(res['precision'])}")
    click.echo(f"ego recall:      {_pct(res['ego_recall'])}")
    dx = res["mean_abs_dx_px"]
    click.echo(f"mean |dx|:       {'n/a' if dx is None else f'{dx:.2f} px'}")
    if "culane" in res:
        c = res["culane"]
        click.echo(
            f"CULane F1:       {_pct(c['f1'])} (precision {_pct(c['precision'])}, recall {_pct(c['recall'])}; TP {c['tp']} FP {c['fp']} FN {c['fn']})"
        )
    if "tusimple" in res:
        t = res["tusimple"]
        click.echo(f"TuSimple:        accuracy {_pct(t['accuracy'])}, FP {_pct(t['fp'])}, FN {_pct(t['fn'])}")
    if "lateral_error_cm" in res:
        lat = ", ".join(
            f"{k} m: {'n/a' if v is None else f'{v:.1f} cm'}" for k, v in res["lateral_error_cm"].items()
        )
        click.echo(f"lateral error:   {lat}")
    if res["failed_frames"]:
        click.echo(f"failed frames ({len(res['failed_frames'])}):")
        for f in res["failed_frames"]:
            click.echo(f"  {f['frame']}: {'; '.join(f['reasons'])}")


def _eval_dataset(pred_dir: Path, dataset_path: Path, as_json: bool) -> None:
    """``eval PRED --dataset FILE``: each sequence's figures and the pooled ones (the README metric)."""
    from .dataset import POOLED, load_dataset, read_gt
    from .metrics import read_predictions

    try:
        ds = load_dataset(dataset_path)
        if not pred_dir.is_dir():
            raise UsageError(
                f"{pred_dir}: expected a folder with a run folder <sequence>/ for each sequence of {dataset_path}"
            )
        pairs = []
        for seq in ds:
            gt = read_gt(seq, seq.frames)
            if gt is None:
                continue
            lanes = _run_lanes(pred_dir / seq.name, f"sequence {seq.name!r} of {dataset_path}")
            pairs.append((seq.name, read_predictions(lanes), gt))
        if not pairs:
            raise UsageError(f"{dataset_path}: no sequence has a ground truth ('gt') to evaluate against")
    except LanegraphError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
    from .dataset import evaluate_sequences

    res = evaluate_sequences(pairs)
    if as_json:
        click.echo(json.dumps({"dataset": ds.name, "sequences": res}))
        return
    click.echo("| sequence | frames | detection ratio | precision | ego recall | mean abs dx (px) |")
    click.echo("|---|---|---|---|---|---|")
    for name, r in res.items():
        dx = r["mean_abs_dx_px"]
        label = f"**{name}** (pooled)" if name == POOLED else name
        click.echo(
            f"| {label} | {r['frames']} | {_pct(r['detection_ratio'])} | {_pct(r['precision'])} | "
            f"{_pct(r['ego_recall'])} | {'n/a' if dx is None else f'{dx:.2f}'} |"
        )
    failed = res[POOLED]["failed_frames"]
    if failed:
        click.echo(f"failed frames ({len(failed)}):")
        for f in failed:
            click.echo(f"  {f['frame']}: {'; '.join(f['reasons'])}")


@main.command()
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option(
    "--gt",
    "gt_path",
    type=click.Path(path_type=Path),
    help="ground truth lanes_gt.jsonl (default: lanes_gt.jsonl in the input folder, when there is one)",
)
@click.option(
    "--dataset",
    "dataset_path",
    type=click.Path(path_type=Path),
    help="a dataset file: each sequence's input and ground truth (RUN_DIR/<sequence>/ run folders, or an ablation's runs)",
)
@click.option(
    "--input",
    "input_path",
    type=click.Path(path_type=Path),
    help="the input folder, where run.json names none or it moved (an ablation over one --input)",
)
@click.option(
    "--frames", help="the frame selection A:B or A:B:S the run was made with (the ground truth is cut alike)"
)
@click.option(
    "--set",
    "sets",
    multiple=True,
    metavar="NODE.PARAM=VALUE",
    help="the --set overrides the run was made with (its source node reads the left images)",
)
@click.option(
    "--debug-dir",
    type=click.Path(path_type=Path),
    help="the run's --debug-dir (default: one found inside RUN_DIR)",
)
@click.option(
    "--out", "out_dir", type=click.Path(path_type=Path), help="report folder  [default: RUN_DIR/report]"
)
@click.option("--open", "open_browser", is_flag=True, help="open the report in the web browser")
@click.option("--quiet", is_flag=True, help="no progress messages")
def report(run_dir, gt_path, dataset_path, input_path, frames, sets, debug_dir, out_dir, open_browser, quiet):
    """Write a self-contained HTML report of RUN_DIR, the output folder of `lanegraph run` or
    `lanegraph ablate`: every frame's lanes against the ground truth, every node's pictures of the
    frames recorded with --debug-dir, the graph with its times, the metrics; for an ablation its
    results table and two variants side by side. Opens from file://, fetches nothing."""
    try:
        summary = _write_report(
            run_dir, out_dir=out_dir, gt_path=gt_path, dataset_path=dataset_path, input_path=input_path,
            frames=parse_frames(frames), sets=sets, debug_dir=debug_dir, quiet=quiet,
        )  # fmt: skip
    except LanegraphError as exc:  # a folder, option or file that does not fit: 2; failing to write: 1
        _fail(exc, 2 if isinstance(exc, (UsageError, InputError, GraphError)) else 1)
    if open_browser:
        from .cli_start import open_in_browser

        open_in_browser(summary.index)


def _write_report(
    run_dir: Path,
    *,
    dataset=None,
    dataset_path: Path | None = None,
    gt_path: Path | None = None,
    quiet: bool = False,
    **kwargs: Any,
):
    """`lanegraph report` and the --report of run and ablate: write the report and print its
    summary line (how many frames, failed ones, its size)."""
    from .dataset import load_dataset
    from .report import write_report

    if dataset_path is not None:
        dataset = load_dataset(dataset_path)
    if gt_path is not None and not gt_path.is_file():
        raise UsageError(f"--gt {gt_path}: no such file")
    summary = write_report(run_dir, dataset=dataset, gt=gt_path, progress=not quiet, **kwargs)
    click.echo(summary.line())
    return summary


from .cli_start import data_cmd, graphs_cmd  # noqa: E402 - the newcomer's commands (issue 32)

main.add_command(graphs_cmd)
main.add_command(data_cmd)

if __name__ == "__main__":  # pragma: no cover
    main()
