"""Stereo sources: KITTI raw drives, KITTI odometry sequences, plain folders of left/right pairs.

Every source lists its frames when it is opened (so a missing right image or a non-monotonic
frame number is reported before anything runs), checks its calibration (finite, plausible,
rectified: :func:`~lanegraph_io._calib.check_calibration`; the image size taken from the frames
when the calibration has none; left and right not swapped), reads images lazily one frame at a
time, and *yields* an :class:`~lanegraph.errors.InputError` for a frame it cannot read (truncated
file, size mismatch, an image above ``max_megapixels``) so that the executor can skip it and go on.
"""

from __future__ import annotations

import re
import struct
import warnings
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from pydantic import Field, model_validator

from lanegraph import NodeParams, Port, RunContext, node_type
from lanegraph.errors import InputError, UsageError
from lanegraph.frames import parse_frames as _parse_frames
from lanegraph.frames import select_frames, selection_text
from lanegraph.storage import digest
from lanegraph.threads import available_cpus, leave_signals_to_the_main_thread, lower_thread_priority
from lanegraph.types import Calibration

from ._calib import (
    YAML_NAMES,
    calibration_from_projections,
    check_calibration,
    projection,
    projection_names,
    read_calibration_yaml,
    read_key_rows,
)
from ._order import disparity_votes
from ._png import SIGNATURE as PNG_SIGNATURE
from ._png import decode_png

IMAGE_EXT = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")

STEREO_OUTPUTS = {
    "frame": Port("frame_id", "left image file stem"),
    "left": Port("image", "left rectified image (BGR uint8, or gray for grey cameras)"),
    "right": Port("image", "right rectified image"),
    "calib": Port("calibration", "rectified stereo calibration", rate="constant"),
    "stereo": Port(
        "stereo_calibration",
        "the calibration as read (for a rectified input, the rectified one), for image.rectify",
        rate="constant",
    ),
}


def parse_frames(text: str | None) -> slice | None:
    """``"A:B"``, ``"A:B:S"`` or ``"A"`` -> a slice over the frame list (None for empty);
    :func:`lanegraph.frames.parse_frames` with the reason prefixed by ``frames:``."""
    try:
        return _parse_frames(text)
    except ValueError as exc:
        raise ValueError(f"frames: {exc}") from None


def list_images(folder: Path) -> list[Path]:
    """The image files of ``folder`` by name; AppleDouble files (``._NAME``: the resource forks
    macOS leaves beside every file it copies to another file system) are not images."""
    return sorted(
        p
        for p in folder.iterdir()
        if p.suffix.lower() in IMAGE_EXT and not p.name.startswith("._") and p.is_file()
    )


#: ``image_size`` of an image whose header claims more pixels than PIL reads (about 179 Mpx)
TOO_LARGE = (-1, -1)


def image_size(path: Path) -> tuple[int, int] | None:
    """``(width, height)`` of an image file from its header (nothing decoded); :data:`TOO_LARGE`
    for a header beyond PIL's decompression-bomb limit; None when the header cannot be read (the
    decoder then reports the file)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(24)
    except OSError:
        return None
    if head[:8] == PNG_SIGNATURE and head[12:16] == b"IHDR":
        w, h = struct.unpack(">II", head[16:24])
        return int(w), int(h)
    try:
        from PIL import Image

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as im:
                return int(im.size[0]), int(im.size[1])
    except Exception as exc:  # noqa: BLE001 - UnidentifiedImageError, OSError: the decoder reports the file
        return TOO_LARGE if type(exc).__name__ == "DecompressionBombError" else None


def read_image(path: Path, frame: str, gray: bool = False, max_megapixels: float | None = None) -> np.ndarray:
    """Read one image; a missing, truncated or non-image file, or one above ``max_megapixels``
    (checked on the header, before decoding), raises a located InputError."""
    if not path.is_file():
        raise InputError("image file missing", path=str(path), frame=frame)
    if max_megapixels is not None:
        size = image_size(path)
        if size == TOO_LARGE:
            raise InputError(
                f"the image header claims more pixels than can be read safely, above the source's max_megapixels {max_megapixels:g}; refused",
                path=str(path),
                frame=frame,
            )
        if size is not None and size[0] * size[1] > max_megapixels * 1e6:
            raise InputError(
                f"image is {size[0]}x{size[1]} ({size[0] * size[1] / 1e6:.1f} Mpx), above the source's max_megapixels "
                f"{max_megapixels:g}; refused (raise max_megapixels to read it)",
                path=str(path),
                frame=frame,
            )
    img = None
    if path.suffix.lower() == ".png":  # the cameras' PNGs: OpenCV's pixels at less than half its CPU
        try:
            img = decode_png(path.read_bytes(), gray)
        except OSError:
            img = None  # OpenCV reports the file
    if img is None:
        try:
            img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_UNCHANGED)
        except cv2.error as exc:  # OpenCV's own limits (CV_IO_MAX_IMAGE_PIXELS) raise
            raise InputError(
                f"cannot decode image: {str(exc).strip().splitlines()[-1]}", path=str(path), frame=frame
            ) from None
    if img is None or img.size == 0:
        raise InputError("cannot decode image (truncated or not an image file)", path=str(path), frame=frame)
    if img.dtype != np.uint8:
        raise InputError(f"expected an 8-bit image, got {img.dtype}", path=str(path), frame=frame)
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    if img.ndim == 3 and img.shape[2] == 2:
        raise InputError("expected a grey or colour image, got 2 channels", path=str(path), frame=frame)
    return img


def pair_files(left_dir: Path, right_dir: Path) -> list[tuple[str, Path, Path]]:
    """(stem, left, right) for every left image; a left image without its right partner is an error."""
    if not left_dir.is_dir():
        raise InputError("image folder not found", path=str(left_dir))
    if not right_dir.is_dir():
        raise InputError("image folder of the right camera not found", path=str(right_dir))
    lefts = list_images(left_dir)
    if not lefts:
        raise InputError(
            f"no images in the folder (expected {', '.join(IMAGE_EXT[:3])} files)", path=str(left_dir)
        )
    rights = {p.stem: p for p in list_images(right_dir)}
    out = []
    for lp in lefts:
        rp = rights.get(lp.stem)
        if rp is None:
            raise InputError(
                f"left image {lp.name} has no right partner in {right_dir}", path=str(lp), frame=lp.stem
            )
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
            raise InputError(
                f"frame numbers not increasing: {n} after {prev} (duplicate frame?)",
                path=str(folder),
                frame=stem,
            )
        prev = n


def _read_ahead_field(
    description: str = "frames decoded ahead of the one the run asks for, on threads (as many as the CPUs free to "
    "the process less the one the nodes run on, at most two a frame; with 0, a pair's two images in "
    "parallel when 2 CPUs are free); -1 = auto: 2 when the process has 2 or more CPUs free to it "
    "(affinity mask, cgroup quota), else 0 with one image after the other",
):
    """``read_ahead`` of the pair sources, and of the stream sources (``_streams``, their own
    ``description``): one default and one range."""
    return Field(-1, ge=-1, le=16, description=description)


def _read_nice_field(
    description: str = "reading ahead, how many nice steps (Linux scheduling priority) the decoding threads run "
    "below the nodes: they then take the CPU the nodes leave idle instead of sharing it with the nodes' "
    "threads. It pays where the nodes' threads are the longest part of a frame (paper.yaml's SGBM bands "
    "on two CPUs: 10) and costs where the decoding is (half_res.yaml: 0). 0 = the nodes' priority; not "
    "on other systems than Linux, nor without reading ahead",
):
    """``read_nice`` of the pair sources, and of the stream sources (their own ``description``)."""
    return Field(0, ge=0, le=19, description=description)


class StereoSourceParams(NodeParams):
    """Params shared by the file-based stereo sources."""

    path: str = Field(
        "", description="input folder; empty: the --input path of the command line (give one, not both)"
    )
    frames: str = Field(
        "",
        pattern=r"^(-?\d*(:-?\d*){0,2})?$",
        description="frame selection 'A:B' or 'A:B:S' (indices); empty: all",
    )
    max_megapixels: float = Field(
        8.0,
        gt=0.0,
        le=150.0,
        description="an image larger than this, megapixels, is refused (that frame fails) before it is decoded",
    )
    min_baseline_m: float = Field(
        0.05,
        gt=0.0,
        le=1000.0,
        description="smallest plausible stereo baseline, metres; a calibration outside the range is refused",
    )
    max_baseline_m: float = Field(
        2.0, gt=0.0, le=1000.0, description="largest plausible stereo baseline, metres"
    )
    check_order: bool = Field(
        True,
        description="refuse an input whose first readable pair matches at negative disparities (left and right swapped)",
    )
    read_ahead: int = _read_ahead_field()
    read_nice: int = _read_nice_field()

    @model_validator(mode="after")
    def _baseline_range(self):
        if self.min_baseline_m >= self.max_baseline_m:
            raise ValueError(
                f"min_baseline_m ({self.min_baseline_m}) must be less than max_baseline_m ({self.max_baseline_m})"
            )
        return self


#: what every source of pairs implements (:mod:`lanegraph.lifecycle`)
PAIR_SOURCE_CAPABILITIES = ("constants", "identity", "frame_key", "len", "skip")


class _PairSource:
    """Common machinery: a list of (stem, left, right) pairs and a calibration."""

    skipped: int  # frames of a resumed run left out (context.skip)

    gray = False
    #: where the calibration was read from, and field -> key names for its messages (set by discover())
    calib_path: Path | None = None
    calib_names: dict[str, str] = {}

    def __init__(self, params: StereoSourceParams, context: RunContext):
        self.params = params
        given = str(context.input_path) if context.input_path else ""
        if params.path and given and _resolved(params.path) != _resolved(given):
            raise UsageError(
                f"node '{context.node_id or 'src'}' params.path {params.path!r} and --input {given!r} both name the input; give one"
            )
        root = params.path or given
        if not root:
            raise InputError("no input: give the source's 'path' param or --input")
        self.root = Path(root)
        if not self.root.exists():
            raise InputError("input folder not found", path=str(self.root))
        self.all_pairs, self.calib = self.discover()
        try:
            frames_param = parse_frames(params.frames)
        except ValueError as exc:  # a step of 0
            raise InputError(f"frame selection: {exc}", path=str(self.root)) from None
        selections = [(f"the source's frames param {params.frames!r}", frames_param)]
        if context.frames is not None:
            selections.append((f"--frames {selection_text(context.frames)}", context.frames))
        try:
            selected = select_frames(self.all_pairs, selections, str(self.root))
        except ValueError as exc:  # a step of 0
            raise InputError(f"frame selection: {exc}", path=str(self.root)) from None
        self.calib = self._checked_calibration(self.calib)
        if params.check_order:
            self._check_order(selected or self.all_pairs)
        # a resumed run leaves out the frames its checkpoint has done (the executor checks the count)
        self.skipped = min(max(int(context.skip), 0), len(selected))
        self.pairs = selected[self.skipped :]

    def discover(self) -> tuple[list[tuple[str, Path, Path]], Calibration]:  # pragma: no cover - abstract
        raise NotImplementedError

    def _checked_calibration(self, calib: Calibration) -> Calibration:
        """The calibration with the image size of the frames when it has none, checked for
        plausibility (refused before any frame, naming the file and key)."""
        first = next(
            (s for s in (image_size(lp) for _, lp, _ in self.all_pairs[:5]) if s not in (None, TOO_LARGE)),
            None,
        )
        if not (calib.width and calib.height):
            if first is not None:
                calib = replace(calib, width=first[0], height=first[1])
        elif first is not None and first != (calib.width, calib.height):
            key = self.calib_names.get("width", "image size")
            raise InputError(
                f"{key}: the calibration is for {calib.width}x{calib.height} images, the frames are {first[0]}x{first[1]} "
                f"({self.all_pairs[0][1].parent})",
                path=str(self.calib_path or self.root),
            )
        rng = (self.params.min_baseline_m, self.params.max_baseline_m)
        check_calibration(calib, self.calib_path or self.root, self.calib_names, rng)
        return calib

    def _check_order(self, pairs: list[tuple[str, Path, Path]]) -> None:
        for stem, lp, rp in pairs[:3]:
            try:
                left = read_image(lp, stem, True, self.params.max_megapixels)
                right = read_image(rp, stem, True, self.params.max_megapixels)
            except InputError:
                continue  # that frame reports itself when it is read
            if left.shape != right.shape:
                continue
            pos, neg = disparity_votes(left, right)
            if neg >= 200 and neg > 3 * pos:
                raise InputError(
                    f"left and right images look swapped: on frame {stem}, {neg} matched patches lie at a negative "
                    f"disparity and {pos} at a positive one (the left camera's image must be the left one); "
                    "set the source's check_order: false if this pair is right",
                    path=str(lp.parent),
                )
            return

    def constants(self) -> dict:
        from ._calibfiles import from_rectified

        where = str(self.calib_path or self.root)
        return {"calib": self.calib, "stereo": from_rectified(self.calib, where, self.calib_names)}

    def identity(self) -> str:
        """Digest of every input file the source reads (resolved path, size, mtime), its calibration
        included: a resumed run must read the same input."""
        parts = []
        for path in [p for pair in self.all_pairs for p in pair[1:]] + (
            [self.calib_path] if self.calib_path else []
        ):
            try:
                st = path.stat()
                parts.append((str(path.resolve()), st.st_size, st.st_mtime_ns))
            except OSError:
                parts.append((str(path), None, None))
        return digest(type(self).__name__, parts)

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

    def _pair(self, stem: str, lp: Path, rp: Path, left: np.ndarray, right: np.ndarray) -> dict:
        """The frame's outputs, its two images checked against each other and the calibration."""
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
        return {"frame": stem, "left": left, "right": right}

    def reading_plan(self) -> tuple[int, int]:
        """``(frames read ahead, decoding threads)``: ``read_ahead``, or for -1 two frames when the
        process has two or more CPUs free to it. Reading ahead, the decoders run while the nodes
        compute on the main thread, so they get the free CPUs less one (at least one, at most two a
        frame in flight): on two CPUs one thread decodes a pair's images one after the other
        (half_res.yaml 42-46 -> 47-50 frames/s end to end on drive 0001, paper.yaml the same).
        Without read-ahead a pair's two images are decoded in parallel where two CPUs are free (none:
        one image after the other in the caller's thread)."""
        cpus = available_cpus()
        ahead = self.params.read_ahead
        if ahead < 0:
            ahead = 2 if cpus >= 2 else 0
        if ahead > 0:  # the main thread computes meanwhile: the decoders get the other CPUs
            return ahead, max(1, min(cpus - 1, 2 * (ahead + 1)))
        return 0, min(cpus, 2) if cpus >= 2 else 0

    def __iter__(self):
        mpx = self.params.max_megapixels
        ahead, threads = self.reading_plan()
        if threads == 0:
            for stem, lp, rp in self.pairs:
                try:
                    left = read_image(lp, stem, self.gray, mpx)
                    right = read_image(rp, stem, self.gray, mpx)
                    item = self._pair(stem, lp, rp, left, right)
                except InputError as exc:
                    yield exc
                    continue
                yield item
            return
        nice = self.params.read_nice if ahead > 0 else 0
        pool = ThreadPoolExecutor(
            max_workers=threads,
            thread_name_prefix="lanegraph-read",
            initializer=_reader_thread,
            initargs=(nice,),
        )
        pending: deque = deque()
        pairs = iter(self.pairs)

        def submit() -> bool:
            for stem, lp, rp in pairs:
                fl = pool.submit(read_image, lp, stem, self.gray, mpx)
                pending.append((stem, lp, rp, fl, pool.submit(read_image, rp, stem, self.gray, mpx)))
                return True
            return False

        try:
            while True:
                # this frame and ``ahead`` more in flight; the next is submitted only when the
                # run asks for it (read_ahead 0: nothing decodes while the nodes compute)
                while len(pending) < ahead + 1 and submit():
                    pass
                if not pending:
                    return
                stem, lp, rp, fl, fr = pending.popleft()
                try:
                    item = self._pair(stem, lp, rp, fl.result(), fr.result())
                except InputError as exc:
                    yield exc
                    continue
                yield item
        finally:
            pool.shutdown(wait=False, cancel_futures=True)


def _reader_thread(nice: int) -> None:
    """A decoding thread: signals left to the main thread, and ``nice`` steps below the nodes'
    priority (``read_nice``: on two CPUs the disparity's two threads and a decoder otherwise share
    them while the nodes after it leave one idle)."""
    leave_signals_to_the_main_thread()
    lower_thread_priority(nice)


def _resolved(p: str) -> str:
    try:
        return str(Path(p).resolve())
    except (OSError, RuntimeError):
        return p


class KittiRawParams(StereoSourceParams):
    """Params of ``io.kitti_raw``."""

    camera: str = Field(
        "auto",
        pattern="^(auto|color|gray)$",
        description="colour pair image_02/03, grey pair image_00/01, or auto (colour first)",
    )


@node_type("io.kitti_raw", source=True, outputs=STEREO_OUTPUTS, implements=PAIR_SOURCE_CAPABILITIES)
class KittiRawSource(_PairSource):
    """A KITTI raw drive folder (``<date>/<date>_drive_NNNN_sync``), calibration in the date folder."""

    def __init__(self, params: KittiRawParams, context: RunContext):
        self.camera = params.camera
        super().__init__(params, context)

    def discover(self):
        cams = {
            "color": ("image_02", "image_03", "P_rect_02", "P_rect_03"),
            "gray": ("image_00", "image_01", "P_rect_00", "P_rect_01"),
        }
        order = ["color", "gray"] if self.camera == "auto" else [self.camera]
        chosen = next((c for c in order if (self.root / cams[c][0]).is_dir()), None)
        if chosen is None:
            want = " or ".join(f"{cams[c][0]}/data" for c in order)
            raise InputError(f"not a KITTI raw drive folder: expected {want}", path=str(self.root))
        self.gray = chosen == "gray"
        ld, rd, pl, pr = cams[chosen]
        calib_path = self.root.resolve().parent / "calib_cam_to_cam.txt"
        self.calib_path, self.calib_names = calib_path, projection_names(pl, pr)
        rows = read_key_rows(calib_path)
        pairs = pair_files(self.root / ld / "data", self.root / rd / "data")
        check_monotonic(pairs, self.root / ld / "data")
        calib = calibration_from_projections(
            projection(rows, pl, calib_path), projection(rows, pr, calib_path), calib_path, keys=(pl, pr)
        )
        size_key = "S_rect_" + pl[-2:]
        w, h = 0, 0
        if size_key in rows and rows[size_key][1]:
            line, vals = rows[size_key]
            if len(vals) != 2 or not all(
                np.isfinite(v) and v >= 1 and v == int(v) and v <= 100000 for v in vals
            ):
                raise InputError(
                    f"line {line}: row {size_key!r}: expected the image width and height in pixels (two integers >= 1), got {vals}",
                    path=str(calib_path),
                )
            w, h = (int(x) for x in vals)
            self.calib_names = {
                **self.calib_names,
                "width": f"row {size_key!r}",
                "height": f"row {size_key!r}",
            }
        return pairs, replace(calib, width=w, height=h)


class KittiOdometryParams(StereoSourceParams):
    """Params of ``io.kitti_odometry``."""

    camera: str = Field(
        "auto",
        pattern="^(auto|color|gray)$",
        description="grey pair image_0/1 (P0, P1), colour pair image_2/3 (P2, P3), or auto (colour first)",
    )


@node_type("io.kitti_odometry", source=True, outputs=STEREO_OUTPUTS, implements=PAIR_SOURCE_CAPABILITIES)
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
            raise InputError(
                "not a KITTI odometry sequence: expected image_0/image_1 or image_2/image_3",
                path=str(self.root),
            )
        self.gray = chosen == "gray"
        ld, rd, pl, pr = cams[chosen]
        calib_path = self.root / "calib.txt"
        self.calib_path, self.calib_names = calib_path, projection_names(pl, pr)
        rows = read_key_rows(calib_path)
        pairs = pair_files(self.root / ld, self.root / rd)
        check_monotonic(pairs, self.root / ld)
        return pairs, calibration_from_projections(
            projection(rows, pl, calib_path), projection(rows, pr, calib_path), calib_path, keys=(pl, pr)
        )


class FolderParams(StereoSourceParams):
    """Params of ``io.folder``."""

    calib: str = Field(
        "calib.yaml",
        min_length=1,
        description="calibration YAML (f, cx, cy, baseline), relative to the folder",
    )


@node_type("io.folder", source=True, outputs=STEREO_OUTPUTS, implements=PAIR_SOURCE_CAPABILITIES)
class FolderSource(_PairSource):
    """A plain folder of rectified pairs: ``left/*.png`` + ``right/*.png`` (same stems) and ``calib.yaml``."""

    def __init__(self, params: FolderParams, context: RunContext):
        self.calib_name = params.calib
        super().__init__(params, context)

    def discover(self):
        self.calib_path, self.calib_names = self.root / self.calib_name, YAML_NAMES
        calib = read_calibration_yaml(self.calib_path)
        return pair_files(self.root / "left", self.root / "right"), calib
