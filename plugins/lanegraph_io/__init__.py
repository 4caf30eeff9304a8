"""Sources and sinks: KITTI raw drives, KITTI odometry sequences, folders of pairs; lanes and overlays."""

from __future__ import annotations

from lanegraph import hookimpl

from ._calib import read_calibration_yaml
from ._sinks import WriteLanes, WriteOverlay, draw_overlay, lane_record
from ._sources import FolderSource, KittiOdometrySource, KittiRawSource, detect_source, parse_frames

__all__ = ["detect_source", "draw_overlay", "lane_record", "parse_frames", "read_calibration_yaml"]


@hookimpl
def lanegraph_node_types():
    return [KittiRawSource, KittiOdometrySource, FolderSource, WriteLanes, WriteOverlay]


@hookimpl
def lanegraph_detect_source(path):
    return detect_source(path)
