"""What the recorded-stream sources (``io.rosbag``, ``io.video``) share: the input path, the
calibration (given with ``calib`` / ``--calib``, or carried by the input), its checks against the
frames, rectification in the source (the maps computed once: :class:`~lanegraph_io._stereo.Rectifier`),
the frame selection and a resumed run's frames done, and reading ahead on a thread.

A subclass lists its frames when it is opened (``index()``: ids and whatever it needs to find
them again), says the frames' size (``frame_size()``), and reads the selected frames in order
(``read(frames)``: ``(id, left, right)`` or an :class:`~lanegraph.errors.InputError` per frame).
"""

from __future__ import annotations

import bisect
import queue
import threading
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field, model_validator

from lanegraph import NodeParams, Port, RunContext
from lanegraph.errors import InputError, UsageError
from lanegraph.frames import select_frames, selection_text
from lanegraph.runlog import get_logger
from lanegraph.storage import digest
from lanegraph.threads import available_cpus, leave_signals_to_the_main_thread, lower_thread_priority

from ._calibfiles import read_stereo_calibration
from ._order import disparity_votes
from ._sources import STEREO_OUTPUTS, _read_ahead_field, _read_nice_field, parse_frames
from ._stereo import Rectifier, StereoCalibration

log = get_logger("io")

#: what a recorded-stream source implements beyond reading frames (lanegraph.lifecycle)
STREAM_SOURCE_CAPABILITIES = ("constants", "identity", "frame_key", "len", "skip", "close")

STREAM_OUTPUTS = {
    **STEREO_OUTPUTS,
    "left": Port("image", "left image, rectified unless the source's rectify is false (BGR uint8, or gray)"),
    "right": Port("image", "right image, rectified unless the source's rectify is false"),
    "calib": Port(
        "calibration", "the rectified stereo calibration (of the rectified frames)", rate="constant"
    ),
    "stereo": Port(
        "stereo_calibration",
        "the calibration as read (unrectified: both cameras, their distortion and pose), for image.rectify",
        rate="constant",
    ),
}


def calib_field():
    return Field(
        "",
        max_length=4000,
        description="calibration file(s), comma-separated: an OpenCV FileStorage YAML/XML, two ROS camera_info "
        "YAMLs (left,right), a lanegraph calib.yaml or a KITTI calibration (docs/inputs.md); empty: the "
        "calibration the input carries (a bag's CameraInfo). --calib of lanegraph run sets it",
    )


def rectify_field():
    return Field(
        True,
        description="rectify unrectified frames in the source (the maps computed once); false: the frames come "
        "as recorded and the graph rectifies them (image.rectify fed by the source's stereo output)",
    )


class StreamParams(NodeParams):
    """Params shared by the recorded-stream sources."""

    path: str = Field(
        "",
        description="input file or folder; empty: the --input path of the command line (give one, not both)",
    )
    calib: str = calib_field()
    rectify: bool = rectify_field()
    frames: str = Field(
        "",
        pattern=r"^(-?\d*(:-?\d*){0,2})?$",
        description="frame selection 'A:B' or 'A:B:S' (indices into the paired frames); empty: all",
    )
    max_megapixels: float = Field(
        8.0,
        gt=0.0,
        le=150.0,
        description="a frame larger than this, megapixels, is refused before it is decoded",
    )
    min_baseline_m: float = Field(
        0.05, gt=0.0, le=1000.0, description="smallest plausible stereo baseline, metres"
    )
    max_baseline_m: float = Field(
        2.0, gt=0.0, le=1000.0, description="largest plausible stereo baseline, metres"
    )
    check_order: bool = Field(
        True,
        description="refuse an input whose first pair matches at negative disparities (left and right swapped)",
    )
    read_ahead: int = _read_ahead_field(
        "frames decoded (and rectified) ahead of the one the run asks for, on a thread; "
        "-1 = auto: 2 when the process has 2 or more CPUs free to it, else 0"
    )
    read_nice: int = _read_nice_field(
        "reading ahead, how many nice steps (Linux scheduling priority) the reading thread runs below "
        "the nodes (as the pair sources' read_nice: io.auto passes paper.yaml's 10 on); 0 = the nodes' priority"
    )

    @model_validator(mode="after")
    def _baseline_range(self):
        if self.min_baseline_m >= self.max_baseline_m:
            raise ValueError(
                f"min_baseline_m ({self.min_baseline_m}) must be less than max_baseline_m ({self.max_baseline_m})"
            )
        return self


def calib_paths(text: str) -> list[Path]:
    return [Path(p.strip()) for p in text.split(",") if p.strip()]


class StreamSource:
    """The machinery of a recorded-stream source (see the module's text)."""

    gray = False
    skipped: int  # frames of a resumed run left out (context.skip)

    def __init__(self, params: StreamParams, context: RunContext):
        self.params = params
        given = str(context.input_path) if context.input_path else ""
        if params.path and given and Path(params.path).resolve() != Path(given).resolve():
            raise UsageError(
                f"node '{context.node_id or 'src'}' params.path {params.path!r} and --input {given!r} both name the input; give one"
            )
        root = params.path or given
        if not root:
            raise InputError("no input: give the source's 'path' param or --input")
        self.root = Path(root)
        if not self.root.exists():
            raise InputError("input not found", path=str(self.root))
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.calib_files = calib_paths(params.calib)
        try:
            self._prepare(params, context)
        except BaseException:
            self.close()  # the reader a failed open took
            raise

    def _prepare(self, params: StreamParams, context: RunContext) -> None:
        ids = self.index()
        try:
            frames_param = parse_frames(params.frames)
        except ValueError as exc:
            raise InputError(f"frame selection: {exc}", path=str(self.root)) from None
        selections = [(f"the source's frames param {params.frames!r}", frames_param)]
        if context.frames is not None:
            selections.append((f"--frames {selection_text(context.frames)}", context.frames))
        selected = select_frames(list(range(len(ids))), selections, where=str(self.root))
        self.all_ids = ids
        self.stereo = self._calibration()
        rng = (params.min_baseline_m, params.max_baseline_m)
        self.rectifier = Rectifier(self.stereo, rng)
        self.calib = self.rectifier.calib
        if not self.rectifier.identity and params.rectify:
            c = self.calib
            log.info(
                "%s: the frames are not rectified: the source rectifies them (rectified f %.1f px, baseline %.3f m)",
                self.root, c.f, c.baseline,
            )  # fmt: skip
        elif not self.rectifier.identity:
            log.info(
                "%s: the frames are not rectified and the source's rectify is false: the graph must rectify them "
                "(image.rectify fed by the source's stereo output)",
                self.root,
            )
        # a resumed run leaves out the frames its checkpoint has done (the executor checks the count)
        self.skipped = min(max(int(context.skip), 0), len(selected))
        self.selected = selected[self.skipped :]
        if params.check_order and self.selected:
            self._check_order(self.selected[0])

    # -- what a subclass provides -------------------------------------------------------------
    def index(self) -> list[str]:  # pragma: no cover - abstract
        """The frame ids of the whole input, in order (the input's checks done)."""
        raise NotImplementedError

    def frame_size(self) -> tuple[int, int]:  # pragma: no cover - abstract
        """``(width, height)`` of one camera's frames."""
        raise NotImplementedError

    def input_calibration(self) -> StereoCalibration | None:
        """The calibration the input carries (None: none)."""
        return None

    def read(self, frames: list[int]):  # pragma: no cover - abstract
        """``(id, left, right)`` (or an InputError) for each of ``frames`` (indices), in order."""
        raise NotImplementedError

    def input_files(self) -> list[Path]:
        return [self.root]

    # -- the shared part ----------------------------------------------------------------------
    def _calibration(self) -> StereoCalibration:
        size = self.frame_size()
        if self.calib_files:
            stereo = read_stereo_calibration(self.calib_files)
        else:
            stereo = self.input_calibration()
            if stereo is None:
                raise InputError(
                    "no calibration: the input carries none; give the calibration file(s) with --calib "
                    "(OpenCV YAML/XML, ROS camera_info left.yaml,right.yaml, calib.yaml: docs/inputs.md)",
                    path=str(self.root),
                )
        return stereo.check(size, (self.params.min_baseline_m, self.params.max_baseline_m))

    def _check_order(self, first: int) -> None:
        for item in self.read([first]):
            if isinstance(item, InputError):
                return  # that frame reports itself when it is read
            frame, left, right = item
            left, right = self.rectifier(left, right)
            pos, neg = disparity_votes(left, right)
            if neg >= 200 and neg > 3 * pos:
                raise InputError(
                    f"left and right images look swapped: on frame {frame}, {neg} matched patches lie at a negative "
                    f"disparity and {pos} at a positive one; set the source's check_order: false if this pair is right",
                    path=str(self.root),
                )

    def constants(self) -> dict:
        return {"calib": self.calib, "stereo": self.stereo}

    def identity(self) -> str:
        """Digest of the input and calibration files (resolved path, size, mtime): a resumed run
        must read the same input."""
        parts = []
        for path in [*self.input_files(), *self.calib_files]:
            try:
                st = path.stat()
                parts.append((str(path.resolve()), st.st_size, st.st_mtime_ns))
            except OSError:
                parts.append((str(path), None, None))
        return digest(type(self).__name__, parts, self.params.rectify)

    def frame_key(self, frame: str) -> str | None:
        """A frame's content key for result caches: the input's identity and the frame id."""
        return f"{self.identity()}:{frame}"

    def __len__(self) -> int:
        return len(self.selected)

    def _item(self, item: Any) -> dict | InputError:
        if isinstance(item, InputError):
            return item
        frame, left, right = item
        if left.shape[:2] != right.shape[:2]:
            return InputError(
                f"left/right size mismatch: left {left.shape[1]}x{left.shape[0]}, right {right.shape[1]}x{right.shape[0]}",
                path=str(self.root),
                frame=frame,
            )
        if (left.shape[1], left.shape[0]) != (self.stereo.width, self.stereo.height):
            return InputError(
                f"frame is {left.shape[1]}x{left.shape[0]}, the calibration expects {self.stereo.width}x{self.stereo.height}",
                path=str(self.root),
                frame=frame,
            )
        if self.params.rectify:
            left, right = self.rectifier(left, right)
        return {"frame": frame, "left": left, "right": right}

    def _ahead(self) -> int:
        ahead = self.params.read_ahead
        return (2 if available_cpus() >= 2 else 0) if ahead < 0 else ahead

    def __iter__(self):
        ahead = self._ahead()
        if ahead == 0:
            for item in self.read(self.selected):
                yield self._item(item)
            return
        q: queue.Queue = queue.Queue(maxsize=ahead)
        done = object()
        stop = self._stop = threading.Event()

        def put(value: Any) -> bool:
            """Hand ``value`` to the run's thread; False when the run stopped asking."""
            while not stop.is_set():
                try:
                    q.put(value, timeout=0.1)
                    return True
                except queue.Full:
                    continue
            return False

        def work() -> None:
            leave_signals_to_the_main_thread()
            lower_thread_priority(self.params.read_nice)
            try:
                for item in self.read(self.selected):
                    if not put(self._item(item)):
                        return
            except BaseException as exc:  # noqa: BLE001 - handed to the run's thread
                put(exc)
            put(done)

        self._thread = threading.Thread(target=work, name="lanegraph-read", daemon=True)
        self._thread.start()
        try:
            while True:
                item = q.get()
                if item is done:
                    return
                if isinstance(item, BaseException) and not isinstance(item, InputError):
                    raise item
                yield item
        finally:
            stop.set()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None


def match_stamps(lefts: list[int], rights: list[int], tol: float) -> list[tuple[int, int]]:
    """``(left index, right index)`` pairs: each left stamp (increasing) with the nearest right stamp
    (increasing) not taken yet, when they are at most ``tol`` apart (the same unit)."""
    used: set[int] = set()
    pairs = []
    for i, s in enumerate(lefts):
        j = bisect.bisect_left(rights, s)
        # the nearest free stamp on each side, looking no further than the tolerance
        below = next((k for k in range(j - 1, -1, -1) if k not in used or s - rights[k] > tol), None)
        above = next((k for k in range(j, len(rights)) if k not in used or rights[k] - s > tol), None)
        best = min(
            (k for k in (below, above) if k is not None), key=lambda k: abs(rights[k] - s), default=None
        )
        if best is not None and abs(rights[best] - s) <= tol:
            used.add(best)
            pairs.append((i, best))
    return pairs


def to_bgr_or_gray(img: np.ndarray) -> np.ndarray:
    """An 8-bit image as the sources give it: BGR, or 2-D grey."""
    if img.ndim == 3 and img.shape[2] == 1:
        return img[:, :, 0]
    return img
