"""Calibration files of a user's own rig, read into a :class:`~lanegraph_io._stereo.StereoCalibration`.

- OpenCV ``FileStorage`` YAML or XML (``stereoCalibrate`` / ``stereoRectify``): ``K1`` (or ``M1``,
  ``cameraMatrix1``), ``D1``, ``K2``, ``D2``, ``R``, ``T`` (metres), optional ``R1``, ``R2``, ``P1``,
  ``P2`` and the image size (``image_width`` / ``image_height``, or ``imageSize``);
- ROS ``camera_info`` YAML, one file per camera (``camera_calibration``'s ``left.yaml``,
  ``right.yaml``): ``camera_matrix``, ``distortion_coefficients``, ``rectification_matrix``,
  ``projection_matrix``, ``image_width``, ``image_height``;
- lanegraph's ``calib.yaml`` (``f``, ``cx``, ``cy``, ``baseline``: a rectified rig) and KITTI's
  ``calib_cam_to_cam.txt`` / ``calib.txt`` (rectified projections).

Every file is refused above :data:`~lanegraph_io._calib.MAX_CALIB_BYTES`; every problem names the
file and the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from lanegraph.errors import InputError
from lanegraph.types import Calibration

from ._calib import (
    MAX_CALIB_BYTES,
    _UniqueKeyLoader,
    calibration_from_projections,
    projection,
    read_calibration_yaml,
    read_key_rows,
)
from ._stereo import StereoCalibration

#: OpenCV FileStorage key spellings (the first present is read) -> field
OPENCV_KEYS = {
    "K1": ("K1", "M1", "cameraMatrix1", "camera_matrix_1"),
    "D1": ("D1", "distCoeffs1", "dist_coeffs_1"),
    "K2": ("K2", "M2", "cameraMatrix2", "camera_matrix_2"),
    "D2": ("D2", "distCoeffs2", "dist_coeffs_2"),
    "R": ("R",),
    "T": ("T",),
    "R1": ("R1",),
    "R2": ("R2",),
    "P1": ("P1",),
    "P2": ("P2",),
}
_SHAPES = {
    "K1": (3, 3),
    "K2": (3, 3),
    "R": (3, 3),
    "R1": (3, 3),
    "R2": (3, 3),
    "T": (3,),
    "P1": (3, 4),
    "P2": (3, 4),
}
#: ROS distortion models lanegraph rectifies (OpenCV's model); ``equidistant`` (fisheye) is not one
ROS_MODELS = ("plumb_bob", "rational_polynomial", "")


def _read_text(path: Path) -> str:
    if not path.is_file():
        raise InputError("calibration file not found", path=str(path))
    size = path.stat().st_size
    if size > MAX_CALIB_BYTES:
        raise InputError(f"{size} bytes: not a calibration file (at most {MAX_CALIB_BYTES})", path=str(path))
    try:
        return path.read_text(errors="replace")
    except OSError as exc:
        raise InputError(f"cannot read the calibration file: {exc.strerror or exc}", path=str(path)) from None


def _matrix(value: Any, key: str, field: str, path: Path) -> np.ndarray:
    """``value`` as a float array of the shape ``field`` has (distortion: a vector of 4, 5, 8, 12 or 14)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"key {key!r}: expected numbers, got {str(value)[:60]}", path=str(path)) from None
    if field in ("D1", "D2"):
        arr = arr.reshape(-1)
        if arr.size not in (0, 4, 5, 8, 12, 14):
            raise InputError(
                f"key {key!r}: expected 4, 5, 8, 12 or 14 distortion coefficients (OpenCV's model), got {arr.size}",
                path=str(path),
            )
        return arr
    shape = _SHAPES[field]
    if arr.size != int(np.prod(shape)):
        want = "x".join(map(str, shape))
        raise InputError(f"key {key!r}: expected a {want} matrix, got {arr.size} numbers", path=str(path))
    arr = arr.reshape(shape)
    if not np.isfinite(arr).all():
        raise InputError(f"key {key!r}: must hold finite numbers", path=str(path))
    return arr


def read_opencv(path: Path) -> StereoCalibration:
    """An OpenCV ``FileStorage`` file (YAML with ``%YAML:1.0`` or XML ``<opencv_storage>``)."""
    _read_text(path)
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        msg = str(exc).strip().splitlines()[-1]
        raise InputError(f"not a readable OpenCV FileStorage file: {msg}", path=str(path)) from None
    try:
        if not fs.isOpened():
            raise InputError("not a readable OpenCV FileStorage file", path=str(path))
        vals: dict[str, Any] = {}
        names: dict[str, str] = {}
        for field, spellings in OPENCV_KEYS.items():
            key = next((k for k in spellings if not fs.getNode(k).empty()), None)
            names[field] = f"key {(key or spellings[0])!r}"
            if key is None:
                continue
            node = fs.getNode(key)
            mat = node.mat()
            if mat is None:  # a plain sequence of numbers
                mat = [node.at(i).real() for i in range(node.size())] if node.isSeq() else None
            if mat is None:
                raise InputError(
                    f"key {key!r}: expected a matrix (!!opencv-matrix) or numbers", path=str(path)
                )
            vals[field] = _matrix(mat, key, field, path)
        size = _opencv_size(fs, path, names)
    finally:
        fs.release()
    missing = [OPENCV_KEYS[f][0] for f in ("K1", "D1", "K2", "D2") if f not in vals]
    if missing:
        raise InputError(
            f"missing key(s) {missing}: expected K1, D1, K2, D2 (or M1, M2) and R, T from stereoCalibrate",
            path=str(path),
        )
    if ("P1" in vals) != ("P2" in vals):
        raise InputError("keys 'P1', 'P2': give both rectified projections or neither", path=str(path))
    if "T" in vals and "R" not in vals:
        raise InputError("key 'R' missing: T without R (the right camera's rotation)", path=str(path))
    names["width"] = names["height"] = size[2]
    return StereoCalibration(
        **{f: vals.get(f) for f in OPENCV_KEYS}, width=size[0], height=size[1], path=str(path), names=names
    )


def _opencv_size(fs: Any, path: Path, names: dict[str, str]) -> tuple[int, int, str]:
    """``(width, height, key text)`` of a FileStorage (0, 0 when it gives no size)."""
    w, h = fs.getNode("image_width"), fs.getNode("image_height")
    if not w.empty() or not h.empty():
        vals, key = (
            [w.real() if not w.empty() else 0, h.real() if not h.empty() else 0],
            "keys 'image_width'/'image_height'",
        )
    else:
        key_name = next((k for k in ("imageSize", "image_size", "size") if not fs.getNode(k).empty()), None)
        if key_name is None:
            return 0, 0, "image size"
        node = fs.getNode(key_name)
        mat = node.mat()
        vals = (
            list(np.asarray(mat).reshape(-1))
            if mat is not None
            else [node.at(i).real() for i in range(node.size())]
        )
        key = f"key {key_name!r}"
    if len(vals) != 2 or not all(np.isfinite(v) and 1 <= v <= 100000 and v == int(v) for v in vals):
        raise InputError(f"{key}: expected the image width and height in pixels, got {vals}", path=str(path))
    return int(vals[0]), int(vals[1]), key


def _ros_matrix(data: dict, key: str, field: str, path: Path) -> np.ndarray | None:
    entry = data.get(key)
    if entry is None:
        return None
    if not isinstance(entry, dict) or "data" not in entry:
        raise InputError(f"key {key!r}: expected {{rows, cols, data: [...]}}", path=str(path))
    return _matrix(entry["data"], key, field, path)


def read_camera_info(path: Path) -> dict[str, Any]:
    """One camera of a ROS ``camera_info`` YAML: ``{K, D, R, P, width, height}``."""
    text = _read_text(path)
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a safe loader
    except yaml.YAMLError as exc:
        raise InputError(f"invalid YAML: {str(exc).splitlines()[0]}", path=str(path)) from None
    if not isinstance(data, dict) or "camera_matrix" not in data:
        raise InputError(
            "not a ROS camera_info file: expected camera_matrix, distortion_coefficients, "
            "rectification_matrix, projection_matrix",
            path=str(path),
        )
    model = str(data.get("distortion_model") or "")
    if model not in ROS_MODELS:
        raise InputError(
            f"key 'distortion_model': {model!r} is not rectified by lanegraph (expected plumb_bob or rational_polynomial)",
            path=str(path),
        )
    cam = {
        "K": _ros_matrix(data, "camera_matrix", "K1", path),
        "D": _ros_matrix(data, "distortion_coefficients", "D1", path),
        "R": _ros_matrix(data, "rectification_matrix", "R1", path),
        "P": _ros_matrix(data, "projection_matrix", "P1", path),
    }
    if cam["D"] is None:
        cam["D"] = np.zeros(0)
    if cam["P"] is None:
        raise InputError(
            "key 'projection_matrix' missing: a stereo pair's camera_info gives the rectified projection",
            path=str(path),
        )
    size = []
    for key in ("image_width", "image_height"):
        v = data.get(key, 0)
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 100000:
            raise InputError(f"key {key!r}: expected an integer number of pixels, got {v!r}", path=str(path))
        size.append(v)
    cam["width"], cam["height"] = size
    return cam


def stereo_from_cameras(left: dict, right: dict, where: str, names: dict[str, str]) -> StereoCalibration:
    """A rig from two ROS cameras (``camera_info`` files or messages): ``K``, ``D``, ``R``, ``P``."""
    if (left["width"], left["height"]) != (right["width"], right["height"]):
        raise InputError(
            f"the left camera's images are {left['width']}x{left['height']}, the right's "
            f"{right['width']}x{right['height']} (expected one size)",
            path=where,
        )
    if abs(float(left["P"][0, 3])) > 1e-9 and abs(float(right["P"][0, 3])) < 1e-9:
        raise InputError(
            "the first camera's projection has the baseline term P[0,3] and the second's none: "
            "left and right swapped? (give the left camera first)",
            path=where,
        )
    return StereoCalibration(
        K1=left["K"], D1=left["D"], K2=right["K"], D2=right["D"], R1=left["R"], R2=right["R"],
        P1=left["P"], P2=right["P"], width=left["width"], height=left["height"], path=where, names=names,
    )  # fmt: skip


def from_rectified(calib: Calibration, where: str, names: dict[str, str]) -> StereoCalibration:
    """A rectified :class:`Calibration` as a rig that needs no rectification."""
    k = np.array([[calib.f, 0, calib.cx], [0, calib.f_y, calib.cy], [0, 0, 1]], np.float64)
    p1 = np.hstack([k, np.zeros((3, 1))])
    p2 = p1.copy()
    p2[0, 3] = -calib.f * calib.baseline
    return StereoCalibration(
        K1=k, D1=np.zeros(0), K2=k.copy(), D2=np.zeros(0), P1=p1, P2=p2,
        width=calib.width, height=calib.height, path=where, names=names,
    )  # fmt: skip


def is_opencv_storage(text: str) -> bool:
    """Whether a calibration file's text is OpenCV FileStorage (``%YAML:1.0`` or OpenCV 5's
    ``%YAML 1.2`` with ``!!opencv-matrix`` entries, or XML ``<opencv_storage>``)."""
    head = text.lstrip()[:200]
    return (
        head.startswith("%YAML:1")
        or "<opencv_storage>" in head
        or (head.startswith("%YAML") and "!!opencv-" in text)
    )


def read_stereo_calibration(paths: list[Path]) -> StereoCalibration:
    """The rig of ``paths``: one file (OpenCV FileStorage, lanegraph ``calib.yaml``, KITTI) or two
    ROS ``camera_info`` files (left, right)."""
    paths = [Path(p) for p in paths]
    if len(paths) == 2:
        left, right = (read_camera_info(p) for p in paths)
        names = {
            "P1": f"{paths[0].name}: projection_matrix",
            "P2": f"{paths[1].name}: projection_matrix",
            "K1": f"{paths[0].name}: camera_matrix",
            "K2": f"{paths[1].name}: camera_matrix",
            "width": f"{paths[0].name}: image_width/image_height",
        }
        return stereo_from_cameras(left, right, f"{paths[0]},{paths[1]}", names)
    if len(paths) != 1:
        raise InputError(
            f"calibration: expected one file (OpenCV, calib.yaml, KITTI) or two ROS camera_info files "
            f"(left,right), got {len(paths)}"
        )
    path = paths[0]
    text = _read_text(path)
    if is_opencv_storage(text):
        return read_opencv(path)
    if path.suffix.lower() == ".txt":
        rows = read_key_rows(path)
        keys = next(
            ((a, b) for a, b in (("P_rect_02", "P_rect_03"), ("P2", "P3"), ("P0", "P1")) if a in rows), None
        )
        if keys is None:
            raise InputError(
                "not a KITTI calibration: expected rows P_rect_02/P_rect_03 or P2/P3", path=str(path)
            )
        calib = calibration_from_projections(
            projection(rows, keys[0], path), projection(rows, keys[1], path), path, keys=keys
        )
        return from_rectified(calib, str(path), {"width": "image size", "T": f"rows {keys}"})
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        data = None
    if isinstance(data, dict) and "camera_matrix" in data:
        raise InputError(
            "a ROS camera_info file describes one camera: give both, left first (--calib left.yaml,right.yaml)",
            path=str(path),
        )
    if isinstance(data, dict) and any(k in data for k in OPENCV_KEYS):
        return read_opencv(path)
    calib = read_calibration_yaml(path)
    return from_rectified(
        calib,
        str(path),
        {"width": "keys 'width'/'height'", "T": "key 'baseline'", "K1": "key 'f'", "K2": "key 'f'"},
    )
