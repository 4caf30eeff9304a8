"""Calibration readers: KITTI raw ``calib_cam_to_cam.txt``, KITTI odometry ``calib.txt``, a small YAML."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from lanegraph.errors import InputError, did_you_mean
from lanegraph.types import BASELINE_RANGE_M, Calibration, calibration_problems

#: calibration files are small text files: larger ones are refused before they are read
MAX_CALIB_BYTES = 1_000_000
#: how far (metres, along any axis) a camera of a stereo rig may sit from the rig's reference
#: camera: a projection row whose translation is further is not a camera of the rig
MAX_CAMERA_OFFSET_M = 10.0
#: the keys of a calib.yaml
YAML_KEYS = ("f", "fy", "cx", "cy", "baseline", "width", "height")


def read_key_rows(path: Path) -> dict[str, tuple[int, list[float]]]:
    """``KEY: v1 v2 ...`` rows of a KITTI calibration file -> {key: (line number, numbers)}.

    Rows whose values are not numbers (``calib_time``) are kept with an empty list."""
    if not path.is_file():
        raise InputError("calibration file not found", path=str(path))
    rows: dict[str, tuple[int, list[float]]] = {}
    try:
        if path.stat().st_size > MAX_CALIB_BYTES:
            raise InputError(
                f"{path.stat().st_size} bytes: not a calibration file (at most {MAX_CALIB_BYTES})",
                path=str(path),
            )
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise InputError(f"cannot read the calibration file: {exc.strerror or exc}", path=str(path)) from None
    for k, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        if ":" not in line:
            raise InputError(f"line {k}: expected 'KEY: values', got {line[:60]!r}", path=str(path))
        key, _, rest = line.partition(":")
        key = key.strip()
        if key in rows:
            raise InputError(
                f"line {k}: row {key!r} appears twice (first at line {rows[key][0]}); which one holds?",
                path=str(path),
            )
        try:
            vals = [float(x) for x in rest.split()]
        except ValueError:
            vals = []
        rows[key] = (k, vals)
    return rows


def projection(rows: dict[str, tuple[int, list[float]]], key: str, path: Path) -> np.ndarray:
    """The 3x4 projection matrix of row ``key``; errors name the row and the line."""
    if key not in rows:
        raise InputError(
            f"row {key!r} missing (expected a 3x4 projection matrix, 12 numbers)", path=str(path)
        )
    line, vals = rows[key]
    if len(vals) != 12:
        text = path.read_text(errors="replace").splitlines()[line - 1].partition(":")[2].strip()
        what = f"{len(vals)} numbers" if vals or not text else f"non-numeric values {text[:60]!r}"
        raise InputError(
            f"line {line}: row {key!r} has {what}, expected 12 numbers (a 3x4 matrix)", path=str(path)
        )
    m = np.asarray(vals, dtype=np.float64).reshape(3, 4)
    if not np.isfinite(m).all():
        bad = next(v for v in vals if not np.isfinite(v))
        raise InputError(
            f"line {line}: row {key!r} holds a non-finite value ({bad}); expected 12 finite numbers",
            path=str(path),
        )
    return m


#: the entries of a projection matrix ``P = K [I | t]`` that a calibration field comes from
_P_ENTRY = {"f": "fx, P[0,0]", "fy": "fy, P[1,1]", "cx": "cx, P[0,2]", "cy": "cy, P[1,2]"}


def calibration_from_projections(
    p_left: np.ndarray,
    p_right: np.ndarray,
    path: Path,
    width: int = 0,
    height: int = 0,
    keys: tuple[str, str] = ("left", "right"),
) -> Calibration:
    """Rectified calibration from the two 3x4 projection matrices (``P = K [I | t]``) of rows
    ``keys``; a pair whose intrinsics differ is not rectified and is refused, naming both rows."""
    kl, kr = keys
    for key, p in ((kl, p_left), (kr, p_right)):  # P = K [I | t]: no skew, last row (0, 0, 1, tz)
        form = [(0, 1), (1, 0), (2, 0), (2, 1)]
        if (
            any(abs(float(p[i, j])) > 1e-6 * max(abs(float(p[0, 0])), 1.0) for i, j in form)
            or abs(float(p[2, 2]) - 1.0) > 1e-6
        ):
            raise InputError(
                f"row {key!r} is not a rectified projection matrix [[f, 0, cx, tx], [0, fy, cy, ty], [0, 0, 1, tz]]: "
                f"got {' '.join(f'{v:g}' for v in p.reshape(-1))}",
                path=str(path),
            )
    for name, (i, j) in (("fx", (0, 0)), ("fy", (1, 1)), ("cx", (0, 2)), ("cy", (1, 2))):
        a, b = float(p_left[i, j]), float(p_right[i, j])
        if abs(a - b) > 1e-4 * max(abs(a), 1.0):
            raise InputError(
                f"rows {kl!r} and {kr!r} are not a rectified pair: {name} (P[{i},{j}]) is {a:g} and {b:g} "
                "(a rectified pair has equal intrinsics)",
                path=str(path),
            )
    f = float(p_left[0, 0])
    if f <= 0:
        raise InputError(f"row {kl!r}: focal length (fx, P[0,0]) must be > 0, got {f}", path=str(path))
    baseline = (float(p_left[0, 3]) - float(p_right[0, 3])) / f
    if baseline <= 0:
        raise InputError(
            f"rows {kl!r}, {kr!r}: baseline (P[0,3] of {kl} minus P[0,3] of {kr}, over fx) must be > 0 "
            f"(the left camera left of the right one), got {baseline:.4f} m",
            path=str(path),
        )
    fy = float(p_left[1, 1])
    _check_translations(p_left, p_right, keys, path, baseline)
    return Calibration(
        f=f,
        cx=float(p_left[0, 2]),
        cy=float(p_left[1, 2]),
        baseline=baseline,
        width=width,
        height=height,
        fy=None if abs(fy - f) < 1e-9 else fy,
    )


def translation(p: np.ndarray) -> np.ndarray:
    """The translation ``t`` (metres, from the rig's reference camera) of ``P = K [I | t]``."""
    tz = float(p[2, 3])
    return np.array(
        [
            (float(p[0, 3]) - float(p[0, 2]) * tz) / float(p[0, 0]),
            (float(p[1, 3]) - float(p[1, 2]) * tz) / float(p[1, 1]),
            tz,
        ]
    )


def _check_translations(
    p_left: np.ndarray, p_right: np.ndarray, keys: tuple[str, str], path: Path, baseline: float
) -> None:
    """Refuse a projection row whose camera sits implausibly far from the rig's reference camera
    (more than :data:`MAX_CAMERA_OFFSET_M` along y or z: ``ty = -300`` m), and a pair whose right
    camera is not beside the left one (a rectified pair's cameras differ along x only: rows of
    the two images would not match)."""
    ts = {}
    for key, p in zip(keys, (p_left, p_right)):
        t = ts[key] = translation(p)
        # along x the cameras are a baseline apart: the baseline's own check names it (millimetres?)
        far = next((i for i in (1, 2) if abs(t[i]) > MAX_CAMERA_OFFSET_M), None)
        if far is not None:
            axis = "xyz"[far]
            raise InputError(
                f"implausible calibration: row {key!r}: the camera's translation t{axis} (from P[:,3] = K t) is "
                f"{t[far]:.4g} m, more than {MAX_CAMERA_OFFSET_M:g} m from the rig's reference camera",
                path=str(path),
            )
    d = ts[keys[0]] - ts[keys[1]]
    for i in (1, 2):
        if abs(d[i]) > max(0.1 * baseline, 0.01):
            axis = "xyz"[i]
            raise InputError(
                f"implausible calibration: rows {keys[0]!r}/{keys[1]!r}: the cameras are {abs(d[i]):.4g} m apart "
                f"along {axis} (t{axis} from P[:,3] = K t), a rectified pair's differ along x only "
                f"(baseline {baseline:.4g} m)",
                path=str(path),
            )


def check_calibration(
    calib: Calibration,
    path: Path | str,
    names: dict[str, str],
    baseline_range_m: tuple[float, float] = BASELINE_RANGE_M,
) -> None:
    """Refuse an implausible calibration (:func:`lanegraph.types.calibration_problems`) with an
    :class:`InputError` naming the file and, through ``names`` (field -> key in the file), the key."""
    problems = calibration_problems(calib, baseline_range_m)
    if problems:
        text = "; ".join(f"{names.get(field, field)}: {msg}" for field, msg in problems)
        raise InputError(f"implausible calibration: {text}", path=str(path))


def projection_names(kl: str, kr: str) -> dict[str, str]:
    """Field -> key text of a calibration read from projection rows ``kl`` (left), ``kr`` (right)."""
    names = {k: f"row {kl!r} ({v})" for k, v in _P_ENTRY.items()}
    names["baseline"] = f"rows {kl!r}/{kr!r} (baseline from P[0,3])"
    names["width"] = names["height"] = "image size"
    return names


class _UniqueKeyLoader(yaml.SafeLoader):
    """A safe YAML loader that refuses a key given twice (the last would win silently)."""


def _unique_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        if isinstance(key, (str, int, float, bool)) or key is None:
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    f"key {key!r} is given twice (first at line {seen[key] + 1}); which one holds?",
                    key_node.start_mark,
                )
            seen[key] = key_node.start_mark.line
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def read_calibration_yaml(path: str | Path) -> Calibration:
    """A small YAML calibration: ``f``, ``cx``, ``cy``, ``baseline`` (metres), optional ``fy``,
    ``width``, ``height``; a key given twice or another key is refused."""
    path = Path(path)
    if not path.is_file():
        raise InputError(
            "calibration file not found (expected calib.yaml with f, cx, cy, baseline)", path=str(path)
        )
    if path.stat().st_size > MAX_CALIB_BYTES:
        raise InputError(
            f"{path.stat().st_size} bytes: not a calibration file (at most {MAX_CALIB_BYTES})", path=str(path)
        )
    try:
        data = yaml.load(path.read_text(), Loader=_UniqueKeyLoader)  # noqa: S506 - a safe loader
    except yaml.MarkedYAMLError as exc:
        line = f"line {exc.problem_mark.line + 1}: " if exc.problem_mark is not None else ""
        raise InputError(f"{line}invalid YAML: {exc.problem or exc}", path=str(path)) from None
    except yaml.YAMLError as exc:
        raise InputError(f"invalid YAML: {exc}", path=str(path)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the calibration file: {exc}", path=str(path)) from None
    if not isinstance(data, dict):
        raise InputError("expected a mapping with f, cx, cy, baseline", path=str(path))
    unknown = [k for k in data if k not in YAML_KEYS]
    if unknown:
        hint = did_you_mean(unknown[0], YAML_KEYS, listing="known keys")
        raise InputError(f"unknown key {str(unknown[0])[:40]!r} ({hint})", path=str(path))
    missing = [k for k in ("f", "cx", "cy", "baseline") if k not in data]
    if missing:
        raise InputError(
            f"missing key(s) {missing} (expected f, cx, cy in pixels and baseline in metres)", path=str(path)
        )
    vals: dict[str, float] = {}
    for k in ("f", "cx", "cy", "baseline", "fy"):
        v = data.get(k)
        if k == "fy" and v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float, str)):
            raise InputError(f"key {k!r}: calibration values must be numbers, got {v!r}", path=str(path))
        try:
            vals[k] = float(v)
        except ValueError:
            raise InputError(
                f"key {k!r}: calibration values must be numbers, got {v!r}", path=str(path)
            ) from None
        if not np.isfinite(vals[k]):
            raise InputError(f"key {k!r}: must be a finite number, got {v!r}", path=str(path))
    size = {}
    for k in ("width", "height"):
        v = data.get(k, 0) or 0
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if isinstance(v, bool) or not isinstance(v, int) or v < 0 or v > 100000:
            raise InputError(
                f"key {k!r}: expected the image {k} in pixels (an integer 0..100000), got {v!r}",
                path=str(path),
            )
        size[k] = v
    if bool(size["width"]) != bool(size["height"]):
        raise InputError("keys 'width', 'height': give both or neither", path=str(path))
    if vals["f"] <= 0:
        raise InputError(f"key 'f': focal length must be > 0 pixels, got f={vals['f']}", path=str(path))
    if vals["baseline"] <= 0:
        raise InputError(f"key 'baseline': must be > 0 m, got baseline={vals['baseline']}", path=str(path))
    return Calibration(
        f=vals["f"], cx=vals["cx"], cy=vals["cy"], baseline=vals["baseline"], fy=vals.get("fy"), **size
    )


YAML_NAMES = {
    "f": "key 'f'",
    "fy": "key 'fy'",
    "cx": "key 'cx'",
    "cy": "key 'cy'",
    "baseline": "key 'baseline'",
    "width": "keys 'width'/'height'",
    "height": "keys 'width'/'height'",
}
