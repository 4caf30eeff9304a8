"""``lanegraph run``: a graph on one input, or on every sequence of a dataset."""

from __future__ import annotations

from pathlib import Path

import click

from ..kernel_cache import compile_share, first_run_notice
from ._common import FOLDER, keeping_options, parse_frames, scale_out_options, session
from ._errors import handled


@click.command()
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
    type=FOLDER,
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
@click.option(
    "--dataset",
    "dataset_path",
    type=click.Path(path_type=Path),
    help="a dataset file (YAML list of sequences) in place of --input: writes each sequence's run into OUT/<sequence>/",
)
@scale_out_options()
@keeping_options
@handled()
def run(
    graph: str,
    input_path: Path | None,
    out_dir: Path,
    sets: tuple[str, ...],
    frames: str | None,
    resume: bool,
    debug_dir: Path | None,
    debug_frames: str | None,
    dataset_path: Path | None,
    scheduler: str | None,
    chunk_frames: int | None,
    warmup: int,
    make_report: bool = False,
    verbose: int = 0,
    quiet: int = 0,
    overwrite: bool = False,
    track: str | None = None,
) -> int:
    """Run GRAPH (a file or a name under graphs/, default: paper): its sinks write into OUT (the
    lanes, overlays), with OUT/timings.json and OUT/run.json; with --dataset, every sequence into
    OUT/<sequence>/. Runs go in this process, or on a Dask cluster with --scheduler, whole or in
    chunks (--chunk-frames)."""
    from ..service.session import refuse

    first_run_notice(bool(quiet))  # the first run on a machine compiles the kernels: say so at once
    s = session(quiet, verbose, overwrite, track)
    runner = s.runner(scheduler)
    graph_ = s.open_graph(graph, sets)
    options = {"frames": parse_frames(frames), "runner": runner, "chunk_frames": chunk_frames, "warmup": warmup,
               "resume": resume, "debug_dir": debug_dir, "debug_frames": debug_frames}  # fmt: skip
    if dataset_path is not None:
        from ..evaluation.dataset import load_dataset

        if input_path is not None:
            refuse("--input", "dataset")
        if make_report:
            refuse("--report", "dataset")
        dataset = load_dataset(dataset_path)
        compile_share()  # the first run on a machine: its part of the kernels, beside the helper's
        return s.run_dataset(graph_, dataset, out_dir, **options)
    compile_share()  # the first run on a machine: its part of the kernels, beside the helper's
    return s.run(graph_, input_path=input_path, out_dir=out_dir, make_report=make_report, **options)
