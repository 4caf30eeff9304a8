"""The topics of a ROS bag, and which of them ``io.rosbag`` would read::

    python -m lanegraph_io.topics recording.mcap

Lists every topic with its message type and count, then the left and right image topics that
``io.rosbag`` finds from the bag's ``CameraInfo`` (or the reason it cannot, and what to give it).
Needs the ``io`` extra (``rosbags``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lanegraph.errors import InputError

from ._rosbag import CAMERA_INFO, COMPRESSED, IMAGE, RosbagParams, RosbagSource


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lanegraph_io.topics", description=__doc__.splitlines()[0])
    ap.add_argument("bag", type=Path, help="a .bag, .mcap or .db3 file, or a ROS 2 bag folder")
    args = ap.parse_args(argv)
    src = RosbagSource.__new__(RosbagSource)
    src.root, src.p = args.bag, RosbagParams()
    try:
        reader = src._open()
    except InputError as exc:
        print(f"error: {exc}")
        return 1
    kinds = {IMAGE: "image", COMPRESSED: "compressed image", CAMERA_INFO: "camera info"}
    try:
        for c in sorted(reader.connections, key=lambda c: c.topic):
            print(f"{c.topic:40s} {c.msgtype:32s} {c.msgcount:6d} messages  {kinds.get(c.msgtype, '')}")
        images = sorted({c.topic for c in reader.connections if c.msgtype in (IMAGE, COMPRESSED)})
        infos = sorted({c.topic for c in reader.connections if c.msgtype == CAMERA_INFO})
        try:
            left, right = src._find_topics(reader, images, infos)
        except InputError as exc:
            print(f"io.rosbag finds no pair: {exc}")
            return 1
    finally:
        reader.close()
    print(f"io.rosbag reads: left {left}, right {right} (give others with left_topic / right_topic)")
    return 0


if __name__ == "__main__":  # pragma: no cover - the command line
    raise SystemExit(main())
