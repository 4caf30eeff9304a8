"""``lanegraph ablate``: variants of a graph over the same input or dataset, evaluated side by side."""

from __future__ import annotations

from pathlib import Path

import click

from ..kernels import compile_share, first_run_notice
from ._common import (
    FOLDER,
    PATH,
    dataset_cache_options,
    dataset_option,
    keeping_options,
    parse_frames,
    scale_out_options,
    session,
)
from ._errors import handled


@click.command()
@click.argument("base", type=PATH)
@click.argument("variants", nargs=-1, type=PATH)
@click.option("--input", "input_path", type=PATH, help="input folder; default: the built-in synthetic scene")
@click.option("--gt", "gt_path", type=PATH, help="ground truth lanes_gt.jsonl to evaluate against")
@click.option(
    "--dataset",
    "dataset_path",
    type=PATH,
    help="a dataset file (YAML list of sequences, each an input and a ground truth) in place of --input/--gt",
)
@click.option(
    "--sweep",
    "sweeps",
    multiple=True,
    metavar="NODE.PARAM=V1,V2,...",
    help="also run BASE once per value (repeatable)",
)
@click.option("--out", "out_dir", type=FOLDER, default=Path("out/ablation"), show_default=True)
@dataset_cache_options
@scale_out_options()
@keeping_options
@handled()
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
    resume,
    debug_dir,
    debug_frames,
    scheduler,
    chunk_frames,
    warmup,
    make_report=False,
    verbose=0,
    quiet=0,
    overwrite=False,
    track=None,
):
    """Run BASE and every VARIANT (and every --sweep point) over the same input or dataset, evaluate
    each and write OUT/results.csv (per sequence and pooled), OUT/results.md and plots; runs go to
    OUT/runs/<variant>/<sequence>/; work shared between variants is computed once. A run that
    fails gets its row with the error and the others go on (exit 1)."""
    from ..service.ablation import ablation_variants

    first_run_notice(bool(quiet))  # the first run on a machine compiles the kernels: say so at once
    s = session(quiet, verbose, overwrite, track)
    runner = s.runner(scheduler)
    runs = ablation_variants(base, variants, sweeps)
    dataset = dataset_option(dataset_path, input_path, gt_path)
    compile_share()  # the first run on a machine: its part of the kernels, beside the helper's
    return s.ablate(
        runs, dataset, out_dir, frames=parse_frames(frames), cache_dir=cache_dir, cache_max_gb=cache_max_gb,
        no_cache=no_cache, runner=runner, chunk_frames=chunk_frames, warmup=warmup, make_report=make_report,
        resume=resume, debug_dir=debug_dir, debug_frames=debug_frames,
    )  # fmt: skip
