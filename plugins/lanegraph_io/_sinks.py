"""Sinks: the lanes writer (``lanes.jsonl``) and an overlay image writer.

Both write only inside ``--out`` (their path params are :data:`lanegraph.paths.OutputFile` /
:data:`~lanegraph.paths.OutputDir`, resolved with :func:`lanegraph.paths.inside`), and both own
their part of a resumed run: ``state()`` is what the executor's checkpoint records after every
frame, ``restore(state)`` puts the sink back there when ``--resume`` continues the run.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import Field

from lanegraph import NodeParams, Port, RunContext, node_type
from lanegraph.errors import InputError
from lanegraph.paths import OutputDir, OutputFile, create_new, inside, safe_name, write_bytes_atomic
from lanegraph.presentation.render import draw_lane_points
from lanegraph.types import Lane


def _out_dir(context: RunContext) -> Path:
    out = Path(context.out_dir) if context.out_dir else Path("out")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _where(context: RunContext, type_name: str, param: str) -> str:
    return f"node '{context.node_id or '?'}' ({type_name}) params.{param}"


def lane_record(frame: str, lanes: list[Lane] | None) -> dict:
    """The ``lanes.jsonl`` record of one frame."""
    return {"frame": str(frame), "lanes": [ln.to_json() for ln in (lanes or [])]}


class WriteLanesParams(NodeParams):
    """Params of ``io.write_lanes``."""

    filename: OutputFile = Field(
        "lanes.jsonl", description="output file, relative to --out (inside it: no absolute path, no '..')"
    )
    append: bool = Field(False, description="append to an existing file instead of starting a new one")
    fsync: bool = Field(False, description="fsync after every frame (slower, survives power loss)")


@node_type(
    "io.write_lanes",
    sink=True,
    inputs={"frame": Port("frame_id"), "lanes": Port("lanes", "lanes with image points", optional=True)},
    implements=("outputs", "result_files", "resume", "verify", "close"),
)
class WriteLanes:
    """Writes one JSON line per frame to OUT/lanes.jsonl as each frame finishes (one write, flushed)."""

    outputs: list[Path]  # the lanes file

    @staticmethod
    def result_files(params: WriteLanesParams) -> dict[str, str]:
        """The run's lanes (kind ``lanes``, what ``lanegraph eval``, ``ablate`` and ``report`` read)."""
        return {"lanes": params.filename}

    def __init__(self, params: WriteLanesParams, context: RunContext):
        self.path = inside(_out_dir(context), params.filename, _where(context, "io.write_lanes", "filename"))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.outputs = [self.path]
        self.fsync = params.fsync
        self._hash = hashlib.sha256()
        self._bytes = 0
        self._start = 0  # bytes of the file before this run's first line (append: true)
        self._frames = 0  # lines written: one per frame done
        self.fh: Any = None
        if context.extra.get("resume"):
            return  # restore() opens the file where the checkpoint left it
        if params.append and self.path.is_file():
            data = self.path.read_bytes()
            self._hash.update(data)
            self._bytes = self._start = len(data)
        # unbuffered: a record is one write() call, so an interrupted run never leaves half of one
        # in a buffer that closing the file would flush; a new file is created anew (never written
        # through a link planted at its name)
        self.fh = open(self.path, "ab", buffering=0) if params.append else create_new(self.path)  # noqa: SIM115 - closed by close()

    def __call__(self, frame: str, lanes: list[Lane] | None = None) -> dict:
        data = (json.dumps(lane_record(frame, lanes), separators=(",", ":")) + "\n").encode("utf-8")
        view = memoryview(data)
        while view:
            view = view[self.fh.write(view) :]
        self._hash.update(data)
        self._bytes += len(data)
        self._frames += 1
        if self.fsync:
            os.fsync(self.fh.fileno())
        return {}

    def state(self) -> dict[str, Any]:
        """How much of the file belongs to the frames done: its length and the SHA-256 of its
        bytes, where this run's lines start (``append``) and how many frames they are (the
        checkpoint checks ``frames`` against the frames done)."""
        return {
            "bytes": self._bytes,
            "sha256": self._hash.hexdigest(),
            "start": self._start,
            "frames": self._frames,
        }

    def restore(self, state: Any) -> None:
        """Continue the file of a checkpoint's ``state``: refused (InputError) when the state does
        not agree with itself, or the file is gone, shorter than recorded, changed, or does not
        hold one line per frame done; bytes after the recorded length (a frame written after the
        checkpoint, half a line of a killed run) are cut."""
        hint = "; cannot resume (run without --resume to start over)"

        def count(key: str) -> int | None:
            v = state.get(key) if isinstance(state, dict) else None
            return v if isinstance(v, int) and not isinstance(v, bool) and v >= 0 else None

        n, start, frames = count("bytes"), count("start"), count("frames")
        if n is None or start is None or frames is None or not isinstance(state.get("sha256"), str):
            raise InputError(
                f"the checkpoint holds no valid state of this writer (expected {{bytes, sha256, start, frames}}, got {str(state)[:80]}){hint}",
                path=str(self.path),
            )
        if start > n or (frames > 0) != (n > start) or frames > n - start:
            raise InputError(
                f"the checkpoint's state of this writer does not agree with itself ({frames} frame(s) in bytes {start}..{n}){hint}",
                path=str(self.path),
            )
        if not self.path.is_file():
            if n:
                raise InputError(
                    f"missing: the checkpoint recorded {n} bytes of frames done here (deleted or moved since?){hint}",
                    path=str(self.path),
                )
            self.path.write_bytes(b"")
        size = self.path.stat().st_size
        if size < n:
            raise InputError(
                f"has {size} bytes, the checkpoint recorded {n} (shortened since?){hint}", path=str(self.path)
            )
        h = hashlib.sha256()
        lines, last = 0, b"\n"
        with open(self.path, "rb") as fh:
            pos = 0
            while pos < n:
                chunk = fh.read(min(n - pos, 1 << 20))
                if not chunk:
                    break
                h.update(chunk)
                if pos + len(chunk) > start:
                    mine = chunk[max(start - pos, 0) :]
                    lines += mine.count(b"\n")
                    last = mine[-1:] or last
                pos += len(chunk)
        if h.hexdigest() != state["sha256"]:
            raise InputError(
                f"its first {n} bytes are not those the checkpoint recorded (changed since?){hint}",
                path=str(self.path),
            )
        if lines != frames or last != b"\n":
            raise InputError(
                f"bytes {start}..{n} hold {lines} whole line(s), the checkpoint recorded {frames} frame(s) done{hint}",
                path=str(self.path),
            )
        self.fh = open(self.path, "r+b", buffering=0)  # noqa: SIM115 - closed by close()
        self.fh.truncate(n)
        self.fh.seek(n)
        self._hash, self._bytes, self._start, self._frames = h, n, start, frames

    def verify(self) -> None:
        """After the last frame: the file at :attr:`path` must be the one this run wrote (the same
        file, of the length written); another run, or a person, replacing it is an error (the run
        exits 1 saying so)."""
        if self.fh is None:
            return
        mine = os.fstat(self.fh.fileno())
        try:
            there = os.stat(self.path, follow_symlinks=False)
        except OSError:
            there = None
        if there is None or (there.st_dev, there.st_ino) != (mine.st_dev, mine.st_ino):
            raise InputError(
                f"{'gone' if there is None else 'replaced'} during the run: the file there is not the one this run "
                f"wrote its {self._frames} line(s) to (another process wrote into the output folder?)",
                path=str(self.path),
            )
        if mine.st_size != self._bytes:
            raise InputError(
                f"changed during the run: {mine.st_size} bytes, this run wrote {self._bytes} "
                "(another process wrote into it?)",
                path=str(self.path),
            )

    def close(self) -> None:
        if self.fh is not None:
            self.fh.close()


class OverlayParams(NodeParams):
    """Params of ``io.write_overlay``."""

    subdir: OutputDir = Field(
        "overlay", description="output folder, relative to --out (inside it: no absolute path, no '..')"
    )
    every: int = Field(1, ge=1, le=100000, description="write every N-th frame")
    thickness: int = Field(3, ge=1, le=20, description="lane line thickness, pixels")


SIDE_COLOURS = {"left": (60, 220, 60), "right": (255, 140, 40), "": (0, 220, 255)}


def draw_overlay(
    image: np.ndarray,
    lanes: list[Lane] | None,
    mask: np.ndarray | None = None,
    label: str = "",
    thickness: int = 3,
) -> np.ndarray:
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
    implements=("outputs", "resume"),
)
class WriteOverlay:
    """Writes OUT/overlay/<frame>.png: the left image with the road mask and the lanes drawn."""

    outputs: list[Path]  # the overlay folder

    def __init__(self, params: OverlayParams, context: RunContext):
        self.dir = inside(_out_dir(context), params.subdir, _where(context, "io.write_overlay", "subdir"))
        self.dir.mkdir(parents=True, exist_ok=True)
        self.outputs = [self.dir]
        self.p = params
        self.count = 0

    def __call__(
        self, frame: str, image: np.ndarray, lanes: list[Lane] | None = None, mask: np.ndarray | None = None
    ) -> dict:
        if self.count % self.p.every == 0:
            out = draw_overlay(image, lanes, mask, f"{frame}  lanes: {len(lanes or [])}", self.p.thickness)
            name = safe_name(frame)  # a frame id is free text: never '..' or a separator in a file name
            ok, png = cv2.imencode(".png", out)
            if not ok:
                raise ValueError(f"cannot encode the overlay of frame {frame} as PNG")
            write_bytes_atomic(self.dir / f"{name}.png", png.tobytes())
        self.count += 1
        return {}

    def state(self) -> dict[str, Any]:
        """Frames seen so far (``every`` counts them; the checkpoint checks them against the
        frames done)."""
        return {"frames": self.count}

    def restore(self, state: Any) -> None:
        count = state.get("frames") if isinstance(state, dict) else None
        if not isinstance(count, int) or isinstance(count, bool) or count < 0:
            raise InputError(
                f"the checkpoint holds no valid state of this writer (expected {{frames}}, got {str(state)[:80]})",
                path=str(self.dir),
            )
        self.count = count
