"""``io.auto``: the source node type that reads an input path, chosen among every installed source
(through the plugins' ``lanegraph_detect_source``), and lanegraph_io's own detection."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, ValidationInfo, field_validator

from lanegraph import NodeParams, RunContext, node_type

from ._sources import STEREO_OUTPUTS, _read_ahead_field, _read_nice_field
from ._streams import calib_field, rectify_field

#: file name endings of the bags io.rosbag reads (ROS 1, ROS 2 MCAP, ROS 2 sqlite3)
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
#: file name endings of the videos io.video reads
VIDEO_SUFFIXES = (".mp4", ".mkv", ".avi", ".mov", ".webm", ".m4v")
#: the sources that read a calibration file (``calib`` / ``--calib``); the others carry their own
TAKES_CALIB = ("io.folder", "io.rosbag", "io.video")


def video_pair(folder: Path) -> tuple[Path, Path] | None:
    """``left.<ext>`` and ``right.<ext>`` video files of ``folder`` (two cameras), or None."""
    found = {}
    for side in ("left", "right"):
        hits = [folder / f"{side}{ext}" for ext in VIDEO_SUFFIXES if (folder / f"{side}{ext}").is_file()]
        if len(hits) != 1:
            return None
        found[side] = hits[0]
    return found["left"], found["right"]


def detect_source(path: Path) -> str | None:
    """The source node type that reads ``path``, or None."""
    p = Path(path)
    if p.is_file():
        suffix = p.suffix.lower()
        if suffix in BAG_SUFFIXES:
            return "io.rosbag"
        if suffix in VIDEO_SUFFIXES:
            return "io.video"
        return None
    if not p.is_dir():
        return None
    if (p / "metadata.yaml").is_file() and (any(p.glob("*.mcap")) or any(p.glob("*.db3"))):
        return "io.rosbag"
    if video_pair(p) is not None:
        return "io.video"
    if ((p / "image_02").is_dir() or (p / "image_00").is_dir()) and (
        p.resolve().parent / "calib_cam_to_cam.txt"
    ).is_file():
        return "io.kitti_raw"
    if (p / "calib.txt").is_file() and ((p / "image_0").is_dir() or (p / "image_2").is_dir()):
        return "io.kitti_odometry"
    if (p / "left").is_dir() and (p / "right").is_dir():
        return "io.folder"
    return None


class AutoParams(NodeParams):
    """Params of ``io.auto``. A field it shares with the source it chooses (``read_ahead``,
    ``read_nice``, ``calib``, ``rectify``, a bag's topics) is passed on to that source when the
    graph (or ``--set``, ``--calib``) sets it; the synthetic scene has none."""

    default: str = Field(
        "io.synthetic",
        description="source node type used when no --input is given (an installed source type)",
    )
    read_ahead: int = _read_ahead_field()
    read_nice: int = _read_nice_field()
    calib: str = calib_field()
    rectify: bool = rectify_field()
    left_topic: str = Field(
        "", max_length=500, description="a bag's left image topic (io.rosbag); empty: found from CameraInfo"
    )
    right_topic: str = Field(
        "", max_length=500, description="a bag's right image topic (io.rosbag); empty: found from CameraInfo"
    )

    @field_validator("default")
    @classmethod
    def _a_source(cls, v: str, info: ValidationInfo) -> str:
        types = (info.context or {}).get("node_types")
        if types is None:  # validated outside a graph: nothing to look the name up in
            return v
        nt = types.get(v)
        if nt is None or not nt.source or v == "io.auto":
            sources = sorted(n for n, t in types.items() if t.source and n != "io.auto")
            what = "is not an installed node type" if nt is None else "is not a source node type"
            raise ValueError(f"{v!r} {what}; expected one of {', '.join(sources)}")
        return v


@node_type("io.auto", source=True, outputs=STEREO_OUTPUTS, implements=("select_source",))
class AutoSource:
    """Chooses the source from the --input path (KITTI raw, KITTI odometry, a folder of pairs, a ROS
    bag, a stereo video, or any installed source whose plugin recognises it); the built-in
    synthetic scene when there is none. The executor runs the chosen source in its place. An
    unrectified input (a bag or video with a calibration that has distortion or a rotation) is
    rectified by its source, and says so, unless ``rectify`` is false (then the graph must place
    ``image.rectify``: graphs/paper_rectify.yaml)."""

    @staticmethod
    def select_source(params: AutoParams, input_path: Path | None, detect) -> str:
        """The source node type for ``input_path``: ``params.default`` without an input, else the
        one a plugin's ``lanegraph_detect_source`` names (``detect``); ValueError when none does."""
        if input_path is None:
            return params.default
        name = detect(input_path)
        if name is None:
            raise ValueError(
                f"no installed source node type recognises the input {str(input_path)!r} (expected a KITTI raw "
                "drive folder, a KITTI odometry sequence, a folder of left/right pairs, a ROS bag (.bag, .mcap, "
                "a ROS 2 bag folder) or a video (.mp4, .mkv, ...; a folder of left.mp4 and right.mp4))"
            )
        if params.calib and name not in TAKES_CALIB:
            raise ValueError(
                f"calib / --calib {params.calib!r}: the input {str(input_path)!r} is read by {name}, which "
                "carries its own calibration (a calibration file is for a folder of pairs, a bag or a video)"
            )
        return name

    def __init__(self, params: AutoParams, context: RunContext):  # pragma: no cover - replaced before a run
        raise RuntimeError(
            "io.auto stands for the source it selects (select_source) and is never instantiated"
        )
