"""Calibration readers: KITTI raw ``calib_cam_to_cam.txt``, KITTI odometry ``calib.txt``, a small YAML."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from lanegraph.errors import InputError
from lanegraph.types import Calibration


def read_key_rows(path: Path) -> dict[str, tuple[int, list[float]]]:
    """``KEY: v1 v2 ...`` rows of a KITTI calibration file -> {key: (line number, numbers)}.

    Rows whose values are not numbers (``calib_time``) are kept with an empty list."""
    if not path.is_file():
        raise InputError("calibration file not found", path=str(path))
    rows: dict[str, tuple[int, list[float]]] = {}
    for k, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        if not line.strip():
            continue
        if ":" not in line:
            raise InputError(f"line {k}: expected 'KEY: values', got {line[:60]!r}", path=str(path))
        key, _, rest = line.partition(":")
        try:
            vals = [float(x) for x in rest.split()]
        except ValueError:
            vals = []
        rows[key.strip()] = (k, vals)
    return rows


def projection(rows: dict[str, tuple[int, list[float]]], key: str, path: Path) -> np.ndarray:
    """The 3x4 projection matrix of row ``key``; errors name the row and the line."""
    if key not in rows:
        raise InputError(f"row {key!r} missing (expected a 3x4 projection matrix, 12 numbers)", path=str(path))
    line, vals = rows[key]
    if len(vals) != 12:
        text = path.read_text(errors="replace").splitlines()[line - 1].partition(":")[2].strip()
        what = f"{len(vals)} numbers" if vals or not text else f"non-numeric values {text[:60]!r}"
        raise InputError(f"line {line}: row {key!r} has {what}, expected 12 numbers (a 3x4 matrix)", path=str(path))
    return np.asarray(vals, dtype=np.float64).reshape(3, 4)


def calibration_from_projections(p_left: np.ndarray, p_right: np.ndarray, path: Path, width: int = 0, height: int = 0) -> Calibration:
    """Rectified calibration from the two 3x4 projection matrices (``P = K [I | t]``)."""
    f = float(p_left[0, 0])
    if f <= 0:
        raise InputError(f"focal length must be > 0, got {f}", path=str(path))
    baseline = (float(p_left[0, 3]) - float(p_right[0, 3])) / f
    if baseline <= 0:
        raise InputError(f"baseline must be > 0 (left camera left of the right one), got {baseline:.4f} m", path=str(path))
    fy = float(p_left[1, 1])
    return Calibration(f=f, cx=float(p_left[0, 2]), cy=float(p_left[1, 2]), baseline=baseline, width=width, height=height,
                       fy=None if abs(fy - f) < 1e-9 else fy)


def read_calibration_yaml(path: str | Path) -> Calibration:
    """A small YAML calibration: ``f``, ``cx``, ``cy``, ``baseline`` (metres), optional ``fy``,
    ``width``, ``height``."""
    path = Path(path)
    if not path.is_file():
        raise InputError("calibration file not found (expected calib.yaml with f, cx, cy, baseline)", path=str(path))
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(f"invalid YAML: {exc}", path=str(path)) from None
    if not isinstance(data, dict):
        raise InputError("expected a mapping with f, cx, cy, baseline", path=str(path))
    missing = [k for k in ("f", "cx", "cy", "baseline") if k not in data]
    if missing:
        raise InputError(f"missing key(s) {missing} (expected f, cx, cy in pixels and baseline in metres)", path=str(path))
    try:
        vals = {k: float(data[k]) for k in ("f", "cx", "cy", "baseline")}
        fy = float(data["fy"]) if data.get("fy") is not None else None
        w, h = int(data.get("width", 0) or 0), int(data.get("height", 0) or 0)
    except (TypeError, ValueError) as exc:
        raise InputError(f"calibration values must be numbers: {exc}", path=str(path)) from None
    if vals["f"] <= 0 or vals["baseline"] <= 0:
        raise InputError(f"f and baseline must be > 0, got f={vals['f']}, baseline={vals['baseline']}", path=str(path))
    return Calibration(**vals, fy=fy, width=w, height=h)
