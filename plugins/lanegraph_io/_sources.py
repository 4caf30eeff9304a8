"""Stereo sources: KITTI raw drives, KITTI odometry sequences, plain folders of left/right pairs.

Every source lists its frames when it is opened (so a missing right image or a non-monotonic
frame number is reported before anything runs), reads images lazily one frame at a time, and
*yields* an :class:`~lanegraph.errors.InputError` for a frame it cannot read (truncated file,
size mismatch) so that the executor can skip it and go on.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from pydantic import Field

from lanegraph import NodeParams, Port, RunContext, node_type
from lanegraph.errors import InputError
from lanegraph.types import Calibration

from ._calib import calibration_from_projections, projection, read_calibration_yaml, read_key_rows

IMAGE_EXT = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")

STEREO_OUTPUTS = {
    "frame": Port("frame_id", "left image file stem"),
    "left": Port("image", "left rectified image (BGR uint8, or gray for grey cameras)"),
    "right": Port("image", "right rectified image"),
    "calib": Port("calibration", "rectified stereo calibration", rate="constant"),
}


def parse_frames(text: str | None) -> slice | None:
    """``"A:B"``, ``"A:B:S"`` or ``"A"`` -> a slice over the frame list (None for empty)."""
    if not text:
        return None
    try:
        parts = [int(x) if x.strip() else None for x in str(text).split(":")]
    except ValueError:
        raise ValueError(f"frames: expected 'A:B', 'A:B:S' or 'A' with integers, got {text!r}") from None
    if len(parts) == 1:
        return slice(parts[0], parts[0] + 1 if parts[0] is not None and parts[0] != -1 else None)
    if len(parts) > 3:
        raise ValueError(f"frames: expected 'A:B' or 'A:B:S', got {text!r}")
    return slice(*parts)


def _slice_text(s: slice) -> str:
    text = f"{'' if s.start is None else s.start}:{'' if s.stop is None else s.stop}"
    return text + (f":{s.step}" if s.step not in (None, 1) else "")


def list_images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXT and p.is_file())


def read_image(path: Path, frame: str, gray: bool = False) -> np.ndarray:
    """Read one image; a missing, truncated or non-image file raises a located InputError."""
    if not path.is_file():
        raise InputError("image file missing", path=str(path), frame=frame)
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise InputError("cannot decode image (truncated or not an image file)", path=str(path), frame=frame)
    if img.dtype != np.uint8:
        raise InputError(f"expected an 8-bit image, got {img.dtype}", path=str(path), frame=frame)
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


def pair_files(left_dir: Path, right_dir: Path) -> list[tuple[str, Path, Path]]:
    """(stem, left, right) for every left image; a left image without its right partner is an error."""
    if not left_dir.is_dir():
        raise InputError("image folder not found", path=str(left_dir))
    if not right_dir.is_dir():
        raise InputError("image folder of the right camera not found", path=str(right_dir))
    lefts = list_images(left_dir)
    if not lefts:
        raise InputError(f"no images in the folder (expected {', '.join(IMAGE_EXT[:3])} files)", path=str(left_dir))
    rights = {p.stem: p for p in list_images(right_dir)}
    out = []
    for lp in lefts:
        rp = rights.get(lp.stem)
        if rp is None:
            raise InputError(f"left image {lp.name} has no right partner in {right_dir}", path=str(lp), frame=lp.stem)
        out.append((lp.stem, lp, rp))
    return out


def check_monotonic(pairs: list[tuple[str, Path, Path]], folder: Path) -> None:
    """KITTI frame numbers must be increasing integers (duplicates or gaps in order are errors)."""
    prev = None
    for stem, _, _ in pairs:
        if not re.fullmatch(r"\d+", stem):
            raise InputError(f"frame file name {stem!r} is not a frame number", path=str(folder), frame=stem)
        n = int(stem)
        if prev is not None and n <= prev:
            raise InputError(f"frame numbers not increasing: {n} after {prev} (duplicate frame?)", path=str(folder), frame=stem)
        prev = n


class StereoSourceParams(NodeParams):
    """Params shared by the file-based stereo sources."""

    path: str = Field("", description="input folder; empty: the --input path of the command line")
    frames: str = Field("", pattern=r"^(-?\d*(:-?\d*){0,2})?$", description="frame selection 'A:B' or 'A:B:S' (indices); empty: all")


class _PairSource:
    """Common machinery: a list of (stem, left, right) pairs and a calibration."""

    gray = False

    def __init__(self, params: StereoSourceParams, context: RunContext):
        root = params.path or (str(context.input_path) if context.input_path else "")
        if not root:
            raise InputError("no input: give the source's 'path' param or --input")
        self.root = Path(root)
        if not self.root.exists():
            raise InputError("input folder not found", path=str(self.root))
        self.pairs, self.calib = self.discover()
        n = len(self.pairs)
        try:
            self.pairs = self.pairs[parse_frames(params.frames) or slice(None)]
            if context.frames is not None:
                self.pairs = self.pairs[context.frames]
        except ValueError as exc:  # a step of 0
            raise InputError(f"frame selection: {exc}", path=str(self.root)) from None
        if n and not self.pairs and not context.extra.get("resume"):  # a resumed, finished run has none left
            chosen = [f"the source's frames param {params.frames!r}"] if params.frames else []
            if context.frames is not None:
                chosen.append(f"--frames {_slice_text(context.frames)}")
            raise InputError(
                f"{' and '.join(chosen) or 'the frame selection'} select(s) no frame: the input has {n} frame(s), "
                f"indices 0..{n - 1}",
                path=str(self.root),
            )

    def discover(self) -> tuple[list[tuple[str, Path, Path]], Calibration]:  # pragma: no cover - abstract
        raise NotImplementedError

    def constants(self) -> dict:
        return {"calib": self.calib}

    def frame_key(self, frame: str) -> str | None:
        """Identity of a frame's input files (resolved path, size, mtime), for result caches."""
        pair = next((p for p in self.pairs if p[0] == frame), None)
        if pair is None:
            return None
        parts = []
        for path in pair[1:]:
            try:
                st = path.stat()
            except OSError:
                return None
            parts.append(f"{path.resolve()}:{st.st_size}:{st.st_mtime_ns}")
        return "|".join(parts)

    def __len__(self) -> int:
        return len(self.pairs)

    def __iter__(self):
        for stem, lp, rp in self.pairs:
            try:
                left = read_image(lp, stem, self.gray)
                right = read_image(rp, stem, self.gray)
                if left.shape[:2] != right.shape[:2]:
                    raise InputError(
                        f"left/right size mismatch: left {left.shape[1]}x{left.shape[0]}, right {right.shape[1]}x{right.shape[0]}",
                        path=str(rp),
                        frame=stem,
                    )
                if self.calib.width and (left.shape[1], left.shape[0]) != (self.calib.width, self.calib.height):
                    raise InputError(
                        f"image is {left.shape[1]}x{left.shape[0]}, the calibration expects {self.calib.width}x{self.calib.height}",
                        path=str(lp),
                        frame=stem,
                    )
            except InputError as exc:
                yield exc
                continue
            yield {"frame": stem, "left": left, "right": right}


class KittiRawParams(StereoSourceParams):
    """Params of ``io.kitti_raw``."""

    camera: str = Field("auto", pattern="^(auto|color|gray)$", description="colour pair image_02/03, grey pair image_00/01, or auto (colour first)")


@node_type("io.kitti_raw", source=True, outputs=STEREO_OUTPUTS)
class KittiRawSource(_PairSource):
    """A KITTI raw drive folder (``<date>/<date>_drive_NNNN_sync``), calibration in the date folder."""

    def __init__(self, params: KittiRawParams, context: RunContext):
        self.camera = params.camera
        super().__init__(params, context)

    def discover(self):
        cams = {"color": ("image_02", "image_03", "P_rect_02", "P_rect_03"), "gray": ("image_00", "image_01", "P_rect_00", "P_rect_01")}
        order = ["color", "gray"] if self.camera == "auto" else [self.camera]
        chosen = next((c for c in order if (self.root / cams[c][0]).is_dir()), None)
        if chosen is None:
            want = " or ".join(f"{cams[c][0]}/data" for c in order)
            raise InputError(f"not a KITTI raw drive folder: expected {want}", path=str(self.root))
        self.gray = chosen == "gray"
        ld, rd, pl, pr = cams[chosen]
        calib_path = self.root.resolve().parent / "calib_cam_to_cam.txt"
        rows = read_key_rows(calib_path)
        pairs = pair_files(self.root / ld / "data", self.root / rd / "data")
        check_monotonic(pairs, self.root / ld / "data")
        calib = calibration_from_projections(projection(rows, pl, calib_path), projection(rows, pr, calib_path), calib_path)
        size_key = "S_rect_" + pl[-2:]
        if size_key in rows and len(rows[size_key][1]) == 2:
            w, h = (int(round(x)) for x in rows[size_key][1])
        else:
            w, h = 0, 0
        return pairs, replace(calib, width=w, height=h)


class KittiOdometryParams(StereoSourceParams):
    """Params of ``io.kitti_odometry``."""

    camera: str = Field("auto", pattern="^(auto|color|gray)$", description="grey pair image_0/1 (P0, P1), colour pair image_2/3 (P2, P3), or auto (colour first)")


@node_type("io.kitti_odometry", source=True, outputs=STEREO_OUTPUTS)
class KittiOdometrySource(_PairSource):
    """A KITTI odometry sequence folder (``image_0``/``image_1`` or ``image_2``/``image_3``, ``calib.txt``)."""

    def __init__(self, params: KittiOdometryParams, context: RunContext):
        self.camera = params.camera
        super().__init__(params, context)

    def discover(self):
        cams = {"color": ("image_2", "image_3", "P2", "P3"), "gray": ("image_0", "image_1", "P0", "P1")}
        order = ["color", "gray"] if self.camera == "auto" else [self.camera]
        chosen = next((c for c in order if (self.root / cams[c][0]).is_dir()), None)
        if chosen is None:
            raise InputError("not a KITTI odometry sequence: expected image_0/image_1 or image_2/image_3", path=str(self.root))
        self.gray = chosen == "gray"
        ld, rd, pl, pr = cams[chosen]
        calib_path = self.root / "calib.txt"
        rows = read_key_rows(calib_path)
        pairs = pair_files(self.root / ld, self.root / rd)
        check_monotonic(pairs, self.root / ld)
        return pairs, calibration_from_projections(projection(rows, pl, calib_path), projection(rows, pr, calib_path), calib_path)


class FolderParams(StereoSourceParams):
    """Params of ``io.folder``."""

    calib: str = Field("calib.yaml", description="calibration YAML (f, cx, cy, baseline), relative to the folder")


@node_type("io.folder", source=True, outputs=STEREO_OUTPUTS)
class FolderSource(_PairSource):
    """A plain folder of rectified pairs: ``left/*.png`` + ``right/*.png`` (same stems) and ``calib.yaml``."""

    def __init__(self, params: FolderParams, context: RunContext):
        self.calib_name = params.calib
        super().__init__(params, context)

    def discover(self):
        calib = read_calibration_yaml(self.root / self.calib_name)
        return pair_files(self.root / "left", self.root / "right"), calib


def detect_source(path: Path) -> str | None:
    """The source node type that reads ``path``, or None."""
    p = Path(path)
    if not p.is_dir():
        return None
    if ((p / "image_02").is_dir() or (p / "image_00").is_dir()) and (p.resolve().parent / "calib_cam_to_cam.txt").is_file():
        return "io.kitti_raw"
    if (p / "calib.txt").is_file() and ((p / "image_0").is_dir() or (p / "image_2").is_dir()):
        return "io.kitti_odometry"
    if (p / "left").is_dir() and (p / "right").is_dir():
        return "io.folder"
    return None
