"""The newcomer's commands: ``lanegraph graphs`` (the built-in graph and dataset files) and
``lanegraph data kitti`` (a KITTI download laid out as lanegraph's sources read it, with the lane
ground truth that ships with lanegraph). ``lanegraph.cli`` registers them."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import click

from ..builtin import describe, graph_names, graphs_dir
from ..errors import LanegraphError
from ._common import FOLDER, PATH


@click.command(name="graphs")
@click.option("--paths", is_flag=True, help="print each file's path instead of its description")
def graphs_cmd(paths: bool) -> None:
    """List the built-in graphs and dataset files: each NAME works wherever a graph file is expected
    (`lanegraph run NAME`, `lanegraph ablate paper ablations/slt`, `extends: NAME.yaml`)."""
    root = graphs_dir()
    for title, kind in (("graphs", "graphs"), ("dataset files", "datasets")):
        names = graph_names(kind)
        click.echo(f"{title} ({root}):" if not paths else f"# {title}")
        width = max((len(n) for n in names), default=0)
        for name in names:
            file = root / f"{name}.yaml"
            if paths:
                click.echo(f"  {file}")
                continue
            lead = f"  {name:<{width}}  "
            text = textwrap.fill(describe(file), 108, initial_indent=lead, subsequent_indent=" " * len(lead))
            click.echo(text.rstrip() or lead.rstrip())


@click.group(name="data")
def data_cmd() -> None:
    """Turn downloaded datasets into folders lanegraph reads (with the lane ground truth it ships)."""


@data_cmd.command(name="kitti")
@click.argument("sources", nargs=-1, required=True, type=PATH)
@click.option("--out", "out_dir", type=FOLDER, required=True, help="the folder to lay the data out in")
@click.option("--quiet", is_flag=True, help="no progress messages")
def kitti_cmd(sources: tuple[Path, ...], out_dir: Path, quiet: bool) -> None:
    """Lay out KITTI downloads as lanegraph's sources read them, in OUT.

    SOURCES: a raw drive's *_sync.zip with its date's *_calib.zip, and/or the odometry
    data_odometry_gray.zip with data_odometry_calib.zip; zip files or the folders they unpack to.
    Writes the lane ground truth lanegraph ships for the frames it has (lanes_gt.jsonl beside the
    frames) and OUT/kitti.yaml, a dataset file of the sequences laid out."""
    from ..data.kitti import prepare_kitti

    try:
        summary = prepare_kitti(list(sources), out_dir, progress=None if quiet else _say)
    except LanegraphError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(exc.exit_code)
    for line in summary:
        click.echo(line)


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


def _say(text: str) -> None:
    click.echo(f"data: {text}", err=True)


__all__ = ["data_cmd", "graphs_cmd"]
