"""``lanegraph tune``: cross-validated parameter search over a dataset's sequences (the entry point
``tune = "lanegraph_tune.cli:tune"`` of the ``lanegraph.commands`` group)."""

from __future__ import annotations

from pathlib import Path

import click

from lanegraph.api import FOLDER, PATH, dataset_cache_options, handled, keeping_options, parse_frames, session
from lanegraph.kernels import compile_share, first_run_notice


@click.command()
@click.argument("graph", type=PATH)
@click.option(
    "--dataset",
    "dataset_path",
    type=PATH,
    required=True,
    help="a dataset file (sequences with ground truth; a sequence's `group` is left out as a whole)",
)
@click.option(
    "--space",
    "space_path",
    type=PATH,
    required=True,
    help="a space file: node_id.param -> {low, high[, log, step, type]} or {choices: [...]} (docs/tune.md)",
)
@click.option("--out", "out_dir", type=FOLDER, default=Path("out/tune"), show_default=True)
@click.option(
    "--trials",
    type=int,
    default=20,
    show_default=True,
    help="trials per study (grid: at most the grid's size)",
)
@click.option(
    "--sampler",
    type=click.Choice(["random", "grid", "qmc", "tpe"]),
    default="random",
    show_default=True,
    help="random, grid, qmc: one shared set of trials serves every fold; tpe: a study per fold",
)
@click.option(
    "--pruner",
    type=click.Choice(["none", "median"]),
    default="none",
    show_default=True,
    help="with --sampler tpe: stop a trial whose score after a training sequence is below the median",
)
@click.option(
    "--grid-points", type=int, default=5, show_default=True, help="--sampler grid: values per float range"
)
@click.option("--seed", type=int, default=0, show_default=True, help="the samplers' seed")
@click.option(
    "--name",
    "graph_name",
    metavar="NAME",
    help="the name of the tuned graph in OUT/tuned.yaml (default: GRAPH's name and _tuned)",
)
@dataset_cache_options
@click.option(
    "--scheduler", metavar="SPEC", help="run the trials on a Dask cluster: local, local:N or tcp://HOST:PORT"
)
@keeping_options
@handled()
def tune(
    graph, dataset_path, space_path, out_dir, trials, sampler, pruner, grid_points, seed, graph_name, frames,
    no_cache, cache_dir, cache_max_gb, scheduler, verbose=0, quiet=0, overwrite=False, track=None,
):  # fmt: skip
    """Choose GRAPH's params in the --space over the --dataset, cross-validated: each fold leaves one
    sequence (or group) out, chooses on the others and scores the one left out. Writes into OUT the
    left-out and tuned-on scores per sequence (results.md, results.csv), each fold's choice
    (folds.json), every trial (trials.csv), the params chosen on all sequences as a graph that extends
    GRAPH (tuned.yaml, named by --name; its description names the search and its left-out figure)
    and a report (report/index.html). The same command resumes an interrupted search (the study is
    kept in OUT/study.journal)."""
    from lanegraph.api import load_dataset

    from .command import TuneOptions
    from .command import tune as run_tune

    first_run_notice(bool(quiet))
    s = session(quiet, verbose, overwrite, track)
    dataset = load_dataset(dataset_path)
    options = TuneOptions(
        trials=trials, sampler=sampler, pruner=pruner, seed=seed, frames=parse_frames(frames),
        grid_points=grid_points, cache_dir=cache_dir, cache_max_gb=cache_max_gb, no_cache=no_cache,
        scheduler=scheduler, name=graph_name, dataset_file=dataset_path,
    )  # fmt: skip
    compile_share()
    return run_tune(s, graph, dataset, space_path, out_dir, options)
