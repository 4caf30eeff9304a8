"""``lanegraph data kitti``: KITTI downloads laid out as lanegraph's sources read them, with the lane
ground truth this plugin ships (:mod:`lanegraph_data.kitti`)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from lanegraph.api import FOLDER, PATH
from lanegraph.errors import LanegraphError


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
    from .kitti import prepare_kitti

    try:
        summary = prepare_kitti(list(sources), out_dir, progress=None if quiet else _say)
    except LanegraphError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(exc.exit_code)
    for line in summary:
        click.echo(line)


def _say(text: str) -> None:
    click.echo(f"data: {text}", err=True)


__all__ = ["data_cmd"]
