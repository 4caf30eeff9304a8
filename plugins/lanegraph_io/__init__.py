"""Sources and sinks: KITTI raw drives, KITTI odometry sequences, folders of pairs, ROS bags
(``io.rosbag``) and stereo videos (``io.video``), and ``io.auto``, which chooses among every
installed source by the input path; the lanes writer (``lanes.jsonl``, the run's result file of
kind ``lanes``), overlays and an MCAP file for Foxglove (``io.write_mcap``); calibration files
(KITTI, ``calib.yaml``, OpenCV FileStorage, ROS camera_info) and their rectification.

The bag, video and MCAP nodes need the ``io`` extra (``rosbags``, ``av``, ``mcap``,
``foxglove-sdk``); this package imports none of them until such a node opens.
"""

from __future__ import annotations

from pathlib import Path

from lanegraph import PortType, hookimpl

from ._auto import AutoSource, detect_source
from ._calib import MAX_CALIB_BYTES, read_calibration_yaml
from ._calibfiles import is_opencv_storage, read_stereo_calibration
from ._mcap_sink import WriteMcap
from ._rosbag import RosbagSource
from ._sinks import WriteLanes, WriteOverlay, draw_overlay, lane_record
from ._sources import FolderSource, KittiOdometrySource, KittiRawSource, parse_frames
from ._stereo import Rectifier, StereoCalibration
from ._video import VideoSource

__all__ = [
    "Rectifier",
    "StereoCalibration",
    "detect_source",
    "draw_overlay",
    "lane_record",
    "parse_frames",
    "read_calibration_yaml",
    "read_stereo_calibration",
]


def _check_stereo(value) -> str | None:
    return None if isinstance(value, StereoCalibration) else "expected a lanegraph_io.StereoCalibration"


@hookimpl
def lanegraph_node_types():
    return [
        AutoSource, KittiRawSource, KittiOdometrySource, FolderSource, RosbagSource, VideoSource,
        WriteLanes, WriteOverlay, WriteMcap,
    ]  # fmt: skip


@hookimpl
def lanegraph_port_types():
    return [
        PortType(
            "stereo_calibration",
            "a stereo rig's calibration as read, unrectified: both cameras, their distortion and pose "
            "(lanegraph_io.StereoCalibration)",
            check=_check_stereo,
        )
    ]


@hookimpl
def lanegraph_detect_source(path):
    return detect_source(path)


@hookimpl
def lanegraph_read_calibration(path):
    """A calibration file: ``calib.yaml`` (``f``, ``cx``, ``cy``, ``baseline``:
    :func:`read_calibration_yaml`), or an OpenCV FileStorage file (YAML, XML) with its image
    size, as the rectified calibration its rectification gives."""
    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml", ".xml"):
        return None
    if not p.is_file():
        return None
    with open(p, "rb") as fh:
        head = fh.read(MAX_CALIB_BYTES + 1).decode("utf-8", "replace")
    if is_opencv_storage(head):
        stereo = read_stereo_calibration([p])
        if not (stereo.width and stereo.height):
            return None
        return Rectifier(stereo.check(None)).calib
    if p.suffix.lower() == ".xml":
        return None
    return read_calibration_yaml(p)


@hookimpl
def lanegraph_kernels():
    """This plugin's kernel list, its kernels' machine code beside it (:mod:`lanegraph.kernels`)."""
    return Path(__file__).with_name("kernels.json")
