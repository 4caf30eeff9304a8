"""``lanegraph report``: the HTML report of a run or an ablation. A command of the
``lanegraph.commands`` entry-point group, like a third party's."""

from __future__ import annotations

from pathlib import Path

import click

from lanegraph.api import FOLDER, PATH, handled, parse_frames, session


@click.command()
@click.argument("run_dir", type=PATH)
@click.option(
    "--gt",
    "gt_path",
    type=PATH,
    help="ground truth lanes_gt.jsonl (default: lanes_gt.jsonl in the input folder, when there is one)",
)
@click.option(
    "--dataset",
    "dataset_path",
    type=PATH,
    help="a dataset file: each sequence's input and ground truth (RUN_DIR/<sequence>/ run folders, or an ablation's runs)",
)
@click.option(
    "--input",
    "input_path",
    type=PATH,
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
@click.option("--debug-dir", type=FOLDER, help="the run's --debug-dir (default: one found inside RUN_DIR)")
@click.option("--out", "out_dir", type=FOLDER, help="report folder  [default: RUN_DIR/report]")
@click.option("--open", "open_browser", is_flag=True, help="open the report in the web browser")
@click.option("--quiet", is_flag=True, help="no progress messages")
@handled(input_exit=2)  # a folder, option or file that does not fit: 2; failing to write: 1
def report(run_dir, gt_path, dataset_path, input_path, frames, sets, debug_dir, out_dir, open_browser, quiet):
    """Write a self-contained HTML report of RUN_DIR, the output folder of `lanegraph run` or
    `lanegraph ablate`: every frame's lanes against the ground truth, every node's pictures of the
    frames recorded with --debug-dir, the graph with its times, the metrics; for an ablation its
    results table and two variants side by side. Opens from file://, fetches nothing."""
    summary = session(quiet, warn=False).report(
        run_dir, out_dir=out_dir, gt_path=gt_path, dataset_path=dataset_path, input_path=input_path,
        frames=parse_frames(frames), sets=sets, debug_dir=debug_dir,
    )  # fmt: skip
    if open_browser:
        open_in_browser(summary.index)


def open_in_browser(page: Path) -> bool:
    """Open ``page`` in the web browser (``report --open``); where this machine has none (a server,
    a container, no DISPLAY), say so and where the page is, instead of doing nothing."""
    import webbrowser

    try:
        opened = webbrowser.open(page.resolve().as_uri())
    except webbrowser.Error:
        opened = False
    if not opened:
        click.echo(
            f"report: no web browser found to open it (set BROWSER to one); open {page} in a browser",
            err=True,
        )
    return opened
