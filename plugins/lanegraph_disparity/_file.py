"""``disparity.file``: precomputed disparity maps read from a folder.

The bridge to PSMNet or any other CNN: run the network offline, save one map per frame
as ``<frame>.png`` in KITTI format (uint16, disparity = value / 256, 0 = invalid) or as
``<frame>.npy`` (float HxW, pixels; values <= 0 or non-finite = invalid), and point
``dir`` at the folder.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from pydantic import Field

from lanegraph import InputError, NodeParams, Port, node_type


class FileParams(NodeParams):
    """Params of ``disparity.file``."""

    dir: str = Field(
        ...,
        min_length=1,
        description="folder holding one disparity map per frame, <frame>.png (KITTI 16-bit, value/256 pixels) "
        "or <frame>.npy (float, pixels); a relative path is relative to the working directory",
    )
    format: Literal["auto", "png", "npy"] = Field(
        "auto", description="file format to look for: 'png', 'npy', or 'auto' (png first, then npy)"
    )


def _expected_files(folder: Path, frame: str, fmt: str) -> list[Path]:
    exts = {"auto": (".png", ".npy"), "png": (".png",), "npy": (".npy",)}[fmt]
    return [folder / f"{frame}{ext}" for ext in exts]


def read_kitti_png(path: Path, frame: str | None = None) -> np.ndarray:
    """A KITTI-format disparity PNG as float32 pixels.

    Parameters
    ----------
    path : Path
        Single-channel uint16 PNG; pixel value ``v`` means disparity ``v / 256`` pixels,
        ``v == 0`` invalid.
    frame : str, optional
        Frame id, for error messages.

    Returns
    -------
    ndarray
        HxW float32 disparity in pixels, 0 where invalid.
    """
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise InputError(
            "cannot decode the file as a PNG image (truncated or not an image?)", path=str(path), frame=frame
        )
    if raw.ndim != 2:
        raise InputError(
            f"expected a single-channel 16-bit KITTI disparity PNG, got {raw.shape[2]} channels",
            path=str(path),
            frame=frame,
        )
    if raw.dtype != np.uint16:
        raise InputError(
            f"expected a 16-bit KITTI disparity PNG (value/256 pixels), got dtype {raw.dtype} "
            "(hint: save with cv2.imwrite(path, np.round(disp * 256).astype(np.uint16)))",
            path=str(path),
            frame=frame,
        )
    return raw.astype(np.float32) * np.float32(1.0 / 256.0)


def _check_png_size(path: Path, frame: str, shape: tuple[int, int]) -> None:
    """A PNG whose header size is not the left image's is refused before it is decoded (a header
    may claim gigapixels)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(24)
    except OSError as exc:
        raise InputError(
            f"cannot read the file: {exc.strerror or exc}", path=str(path), frame=frame
        ) from None
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        w, h = struct.unpack(">II", head[16:24])
        if (h, w) != shape:
            raise InputError(
                f"disparity map is {h}x{w} (rows x cols, from its PNG header) but the left image is {shape[0]}x{shape[1]}; "
                "expected the same size (hint: was it computed on a resized or cropped pair?)",
                path=str(path),
                frame=frame,
            )


def read_npy(path: Path, frame: str | None = None) -> np.ndarray:
    """A ``.npy`` disparity map (HxW or HxWx1 float, pixels) as float32, invalid -> 0."""
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is a user-facing input error
        raise InputError(
            f"cannot read the .npy file: {type(exc).__name__}: {exc}", path=str(path), frame=frame
        ) from exc
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.ndim != 2:
        raise InputError(
            f"expected an HxW disparity array, got shape {arr.shape}", path=str(path), frame=frame
        )
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InputError(
            f"expected a float disparity array (pixels), got dtype {arr.dtype}", path=str(path), frame=frame
        )
    d = arr.astype(np.float32)
    d[~np.isfinite(d) | (d <= 0)] = 0.0
    return d


@node_type(
    "disparity.file",
    inputs={
        "left": "image",
        "right": Port("image", doc="unused; accepted so the backends are interchangeable", optional=True),
        "frame": Port(
            "frame_id",
            doc="the left image's file stem: the map read is <dir>/<frame>.png|.npy",
            optional=True,
        ),
    },
    outputs={"disparity": "disparity"},
)
def file(
    params: FileParams, left: np.ndarray, right: np.ndarray | None = None, frame: str | None = None
) -> dict:
    """Disparity read from precomputed files (KITTI 16-bit PNG or .npy), e.g. from PSMNet.

    Parameters
    ----------
    params : FileParams
        The folder and format.
    left : ndarray
        The left image, HxW or HxWx3; only its size is used, to check the map.
    right : ndarray, optional
        Unused.
    frame : str
        The frame id (left image file stem); required although the port is optional.

    Returns
    -------
    dict
        ``disparity``: HxW float32 disparity in pixels, 0 where invalid.

    Raises
    ------
    InputError
        No frame id, a missing file, an undecodable file, a wrong dtype or channel
        count, or a size different from the left image's.
    """
    folder = Path(params.dir)
    if frame is None or str(frame) == "":
        raise InputError(
            f"disparity.file needs the 'frame' input (the left image's file stem) to find the map in {folder} "
            "(hint: connect it to the source's frame output)",
            path=str(folder),
        )
    frame = str(frame)
    candidates = _expected_files(folder, frame, params.format)
    path = next((p for p in candidates if p.is_file()), None)
    if path is None:
        why = "folder does not exist" if not folder.is_dir() else "no such file"
        raise InputError(
            f"no precomputed disparity: expected {' or '.join(str(p) for p in candidates)} ({why})",
            path=str(candidates[0]),
            frame=frame,
        )
    h, w = np.asarray(left).shape[:2]
    if path.suffix == ".png":
        _check_png_size(path, frame, (h, w))
    disp = read_kitti_png(path, frame) if path.suffix == ".png" else read_npy(path, frame)
    if disp.shape != (h, w):
        raise InputError(
            f"disparity map is {disp.shape[0]}x{disp.shape[1]} (rows x cols) but the left image is {h}x{w}; "
            "expected the same size (hint: was it computed on a resized or cropped pair?)",
            path=str(path),
            frame=frame,
        )
    return {"disparity": disp}
