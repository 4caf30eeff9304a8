"""Sinks: the lanes writer (``lanes.jsonl``) and an overlay image writer."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
from pydantic import Field

from lanegraph import NodeParams, Port, RunContext, node_type
from lanegraph.render import draw_lane_points
from lanegraph.types import Lane


def _out_dir(context: RunContext) -> Path:
    out = Path(context.out_dir) if context.out_dir else Path("out")
    out.mkdir(parents=True, exist_ok=True)
    return out


def lane_record(frame: str, lanes: list[Lane] | None) -> dict:
    """The ``lanes.jsonl`` record of one frame."""
    return {"frame": str(frame), "lanes": [ln.to_json() for ln in (lanes or [])]}


class WriteLanesParams(NodeParams):
    """Params of ``io.write_lanes``."""

    filename: str = Field("lanes.jsonl", min_length=1, description="output file, relative to --out")
    append: bool = Field(False, description="append to an existing file (resumed runs) instead of starting a new one")
    fsync: bool = Field(False, description="fsync after every frame (slower, survives power loss)")


@node_type(
    "io.write_lanes",
    sink=True,
    inputs={"frame": Port("frame_id"), "lanes": Port("lanes", "lanes with image points", optional=True)},
)
class WriteLanes:
    """Writes one JSON line per frame to OUT/lanes.jsonl as each frame finishes (one write, flushed)."""

    def __init__(self, params: WriteLanesParams, context: RunContext):
        self.path = _out_dir(context) / params.filename
        self.fsync = params.fsync
        append = params.append or bool(context.extra.get("resume"))
        self.fh = self.path.open("a" if append else "w", encoding="utf-8")

    def __call__(self, frame: str, lanes: list[Lane] | None = None) -> dict:
        line = json.dumps(lane_record(frame, lanes), separators=(",", ":")) + "\n"
        self.fh.write(line)  # one write of a whole line: the file never ends in half a record
        self.fh.flush()
        if self.fsync:
            os.fsync(self.fh.fileno())
        return {}

    def close(self) -> None:
        self.fh.close()


class OverlayParams(NodeParams):
    """Params of ``io.write_overlay``."""

    subdir: str = Field("overlay", min_length=1, description="output folder, relative to --out")
    every: int = Field(1, ge=1, le=100000, description="write every N-th frame")
    thickness: int = Field(3, ge=1, le=20, description="lane line thickness, pixels")


SIDE_COLOURS = {"left": (60, 220, 60), "right": (255, 140, 40), "": (0, 220, 255)}


def draw_overlay(image: np.ndarray, lanes: list[Lane] | None, mask: np.ndarray | None = None, label: str = "", thickness: int = 3) -> np.ndarray:
    """The left image with the road mask tinted and the lanes drawn (BGR uint8)."""
    img = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    img = img.copy()
    if mask is not None and mask.shape[:2] == img.shape[:2]:
        tint = img.copy()
        tint[mask.astype(bool)] = (0.5 * tint[mask.astype(bool)] + np.array([0, 90, 0])).astype(np.uint8)
        img = tint
    draw_lane_points(img, lanes or [], SIDE_COLOURS, thickness)
    if label:
        cv2.putText(img, label, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2, cv2.LINE_AA)
    return img


@node_type(
    "io.write_overlay",
    sink=True,
    inputs={
        "frame": Port("frame_id"),
        "image": Port("image", "the left image"),
        "lanes": Port("lanes", "lanes with image points", optional=True),
        "mask": Port("mask", "road mask to tint", optional=True),
    },
)
class WriteOverlay:
    """Writes OUT/overlay/<frame>.png: the left image with the road mask and the lanes drawn."""

    def __init__(self, params: OverlayParams, context: RunContext):
        self.dir = _out_dir(context) / params.subdir
        self.dir.mkdir(parents=True, exist_ok=True)
        self.p = params
        self.count = 0

    def __call__(self, frame: str, image: np.ndarray, lanes: list[Lane] | None = None, mask: np.ndarray | None = None) -> dict:
        if self.count % self.p.every == 0:
            out = draw_overlay(image, lanes, mask, f"{frame}  lanes: {len(lanes or [])}", self.p.thickness)
            tmp = self.dir / f".{frame}.tmp.png"
            cv2.imwrite(str(tmp), out)
            os.replace(tmp, self.dir / f"{frame}.png")
        self.count += 1
        return {}
