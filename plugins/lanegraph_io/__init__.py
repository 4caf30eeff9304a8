"""Sources and sinks: KITTI raw drives, KITTI odometry sequences, folders of pairs and ``io.auto``,
which chooses among every installed source by the input path; the lanes writer (``lanes.jsonl``,
the run's result file of kind ``lanes``) and overlays; calibration files."""

from __future__ import annotations

from pathlib import Path

from lanegraph import hookimpl

from ._calib import read_calibration_yaml
from ._sinks import WriteLanes, WriteOverlay, draw_overlay, lane_record
from ._sources import (
    AutoSource,
    FolderSource,
    KittiOdometrySource,
    KittiRawSource,
    detect_source,
    parse_frames,
)

__all__ = ["detect_source", "draw_overlay", "lane_record", "parse_frames", "read_calibration_yaml"]


@hookimpl
def lanegraph_node_types():
    return [AutoSource, KittiRawSource, KittiOdometrySource, FolderSource, WriteLanes, WriteOverlay]


@hookimpl
def lanegraph_detect_source(path):
    return detect_source(path)


@hookimpl
def lanegraph_read_calibration(path):
    """A calibration YAML (``f``, ``cx``, ``cy``, ``baseline``: :func:`read_calibration_yaml`)."""
    if Path(path).suffix.lower() in (".yaml", ".yml"):
        return read_calibration_yaml(Path(path))
    return None


@hookimpl
def lanegraph_kernels():
    """This plugin's kernel list, its LLVM bitcode beside it (:mod:`lanegraph.kernels`)."""
    return Path(__file__).with_name("kernels.json")
