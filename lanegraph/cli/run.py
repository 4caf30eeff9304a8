"""``lanegraph run``: a graph on one input, or on every sequence of a dataset."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..errors import UsageError
from ..kernels import compile_share, first_run_notice
from ._common import FOLDER, PATH, dataset_file, keeping_options, parse_frames, scale_out_options, session
from ._errors import handled


@click.command()
@click.argument("graph", default="paper")
@click.option(
    "--input",
    "input_path",
    type=PATH,
    help="input: a KITTI raw drive or odometry sequence, a folder of pairs, a ROS bag, a stereo video (docs/inputs.md); default: the built-in synthetic scene",
)
@click.option(
    "--calib",
    help="calibration file(s) of the input, comma-separated: OpenCV YAML/XML, ROS camera_info left.yaml,right.yaml, "
    "calib.yaml (docs/inputs.md); sets the source node's calib param",
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
    type=PATH,
    help="a dataset file (YAML list of sequences) in place of --input: writes each sequence's run into OUT/<sequence>/",
)
@scale_out_options()
@keeping_options
@handled()
def run(
    graph: str,
    input_path: Path | None,
    calib: str | None,
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
        if input_path is not None:
            refuse("--input", "dataset")
        if calib is not None:
            refuse("--calib", "dataset")
        if make_report:
            refuse("--report", "dataset")
        dataset = dataset_file(dataset_path)
        compile_share()  # the first run on a machine: its part of the kernels, beside the helper's
        return s.run_dataset(graph_, dataset, out_dir, **options)
    if calib is not None:
        graph_ = s.open_graph(graph, (*sets, *calib_sets(s.pm, graph_.raw, calib)))
    compile_share()  # the first run on a machine: its part of the kernels, beside the helper's
    status = s.run(graph_, input_path=input_path, out_dir=out_dir, make_report=make_report, **options)
    if not quiet:  # the result a person reads: the score against the ground truth, a picture to look at
        from ..evaluation.scoring import score_line

        line = score_line(out_dir)
        if line:
            click.echo(line)
        if not make_report:
            click.echo(f"pictures: `lanegraph report {out_dir}` writes {out_dir / 'report' / 'index.html'}")
    return status


def calib_sets(pm, raw: dict, calib: str) -> list[str]:
    """``--calib FILES`` as a ``--set NODE.calib=FILES`` for each source node whose params have a
    ``calib`` field (paths made absolute: the source reads them wherever it runs)."""
    files = [str(Path(p.strip()).resolve()) for p in calib.split(",") if p.strip()]
    nodes = [
        nid
        for nid, spec in (raw.get("nodes") or {}).items()
        if isinstance(spec, dict)
        and (nt := pm.get_node_type(str(spec.get("type")))) is not None
        and nt.source
        and "calib" in nt.params.model_fields
    ]
    if not files or not nodes:
        why = (
            "names no file"
            if not files
            else "the graph's source node takes no calibration file (no calib param)"
        )
        raise UsageError(f"--calib {calib!r}: {why}")
    return [f"{nid}.calib={json.dumps(','.join(files))}" for nid in nodes]
