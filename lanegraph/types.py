"""Port types and the value types that travel along graph edges.

Ports are typed so that a whole graph can be checked before any frame runs.
A port type is a short name (``"disparity"``, ``"bev_image"`` ...). A value of
a *sub*-type may feed a port of its parent type (a ``gray`` image may feed an
``image`` port); ``any`` accepts everything.

Every port type, lanegraph's own included, is registered through the ``lanegraph_port_types``
hook (a :class:`PortType` with a parent for compatibility, its picture and its check; lanegraph's
own: :mod:`lanegraph.port_types`), and
:attr:`lanegraph.plugins.PluginManager.port_types` holds them all.

Coordinates: arrays are indexed ``(row, col)``; points are ``(x, y)`` pixels.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class PortType:
    """A port type: its ``name`` (a lower-case identifier), what a value of it is, and the
    ``parent`` type whose ports it may feed (``None``: only ports of its own type and ``any``)."""

    name: str
    description: str
    parent: str | None = None
    #: ``render(value, context) -> BGR uint8 image or None``: its picture (``--debug-dir``, the report)
    render: Callable[[Any, Mapping[str, Any]], Any] | None = field(default=None, compare=False, repr=False)
    #: ``check(value) -> str or None``: what is wrong with a value of this type
    check: Callable[[Any], str | None] | None = field(default=None, compare=False, repr=False)
    #: the class of the values ``encode`` / ``decode`` store (a port whose values are lists of
    #: them, such as ``lanes``, names the element class); None: its values are plain data
    #: (numbers, strings, arrays, lists, tuples, dicts), stored as they are (:mod:`lanegraph.storage`)
    stores: type | None = field(default=None, compare=False, repr=False)
    #: ``encode(value) -> data`` (JSON scalars, lists, tuples, dicts, numeric NumPy arrays, or values
    #: other port types store): how the result cache and a checkpoint keep a value of ``stores``
    encode: Callable[[Any], Any] | None = field(default=None, compare=False, repr=False)
    #: ``decode(data) -> value``: the inverse of ``encode``; raises on data it would not have written
    decode: Callable[[Any], Any] | None = field(default=None, compare=False, repr=False)


def port_compatible(produced: str, expected: str, types: Mapping[str, PortType]) -> bool:
    """Whether a value of port type ``produced`` may feed a port of type ``expected``: the same
    type, one of its ancestors through ``parent`` (in ``types``: a plugin manager's ``port_types``), or
    ``any`` on either side."""
    if expected == "any" or produced == "any":
        return True
    t: str | None = produced
    seen: set[str] = set()
    while t is not None and t not in seen:
        if t == expected:
            return True
        seen.add(t)
        pt = types.get(t)
        t = pt.parent if pt is not None else None
    return False


@dataclass(frozen=True)
class Calibration:
    """Rectified stereo calibration of the left camera.

    Attributes
    ----------
    f : float
        Focal length in pixels (fx; rectified images have fx == fy).
    cx, cy : float
        Principal point in pixels.
    baseline : float
        Distance between the two optical centres, metres (> 0).
    width, height : int
        Image size in pixels (0 when unknown).
    fy : float or None
        Vertical focal length if different from ``f``.
    """

    f: float
    cx: float
    cy: float
    baseline: float
    width: int = 0
    height: int = 0
    fy: float | None = None

    @property
    def f_y(self) -> float:
        return self.fy if self.fy is not None else self.f

    def scaled(self, s: float) -> Calibration:
        """Calibration for the image resized by factor ``s``."""
        return Calibration(
            f=self.f * s,
            cx=(self.cx + 0.5) * s - 0.5,
            cy=(self.cy + 0.5) * s - 0.5,
            baseline=self.baseline,
            width=int(round(self.width * s)),
            height=int(round(self.height * s)),
            fy=None if self.fy is None else self.fy * s,
        )


#: the baseline range a calibration is checked against unless the user says otherwise, metres
BASELINE_RANGE_M = (0.05, 2.0)


def calibration_problems(
    calib: Calibration, baseline_range_m: tuple[float, float] = BASELINE_RANGE_M
) -> list[tuple[str, str]]:
    """What is implausible in a rectified calibration: ``[(field, message), ...]``, empty when none.

    Checked: every value finite; ``f`` (and ``fy``) > 0, ``fy`` within 4x of ``f``; the baseline
    inside ``baseline_range_m`` (a baseline 1000 times too large is named as millimetres); with a
    known image size, the principal point inside the image and ``f`` between 0.05 and 50 image
    widths. A source reports them with its own file and key names.
    """
    out: list[tuple[str, str]] = []
    vals = {"f": calib.f, "cx": calib.cx, "cy": calib.cy, "baseline": calib.baseline}
    if calib.fy is not None:
        vals["fy"] = calib.fy
    bad = [k for k, v in vals.items() if not np.isfinite(v)]
    for k in bad:
        out.append((k, f"must be a finite number, got {vals[k]}"))
    for k in ("f", "fy"):
        if k in vals and k not in bad and vals[k] <= 0:
            out.append((k, f"focal length must be > 0 pixels, got {vals[k]}"))
    if "fy" in vals and not bad and calib.f > 0 and calib.fy > 0 and not (0.25 <= calib.fy / calib.f <= 4.0):
        out.append(("fy", f"vertical focal length {calib.fy} is not within 4x of f = {calib.f}"))
    lo, hi = baseline_range_m
    b = calib.baseline
    if "baseline" not in bad and not (lo <= b <= hi):
        msg = f"baseline {b} m is outside the plausible {lo}-{hi} m"
        if lo <= b / 1000.0 <= hi:
            msg += f" (millimetres? the baseline is in metres: {b / 1000.0:g})"
        elif b <= 0:
            msg = f"baseline must be > 0 m (the left camera left of the right one), got {b:.4g} m"
        out.append(("baseline", msg + "; a source's min_baseline_m / max_baseline_m widen the range"))
    if calib.width < 0 or calib.height < 0:
        out.append(("width", f"image size must not be negative, got {calib.width}x{calib.height}"))
    elif calib.width and calib.height and not bad:
        if not (0 <= calib.cx < calib.width):
            out.append(
                ("cx", f"principal point x {calib.cx} lies outside the {calib.width}x{calib.height} image")
            )
        if not (0 <= calib.cy < calib.height):
            out.append(
                ("cy", f"principal point y {calib.cy} lies outside the {calib.width}x{calib.height} image")
            )
        if calib.f > 0 and not (0.05 * calib.width <= calib.f <= 50 * calib.width):
            out.append(
                (
                    "f",
                    f"focal length {calib.f} px is implausible for a {calib.width} px wide image (expected 0.05 to 50 widths)",
                )
            )
    return out


@dataclass
class RoadModel:
    """Road profile in the v-disparity domain and the camera pose it implies.

    ``d(v) = a0 + a1*v + a2*v**2`` (disparity in pixels at image row ``v``), valid
    for rows ``v >= v_min``. Angles in radians, height in metres.
    ``profile`` holds the DP path: one disparity per row (``-1`` where none).
    """

    a0: float
    a1: float
    a2: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    height: float = 0.0
    v_min: int = 0
    valid: bool = True
    profile: np.ndarray | None = None

    def disparity_at(self, v: np.ndarray | float) -> np.ndarray | float:
        v = np.asarray(v, dtype=np.float64)
        return self.a0 + self.a1 * v + self.a2 * v * v


@dataclass
class BevGeometry:
    """A metric bird's-eye-view grid on the road plane and its link to the image.

    The BEV image has ``rows x cols`` pixels; column ``c`` is lateral ``x`` (metres,
    right positive), row ``r`` is distance ``z`` (metres ahead; row 0 is the far end
    ``z_max``, the bottom row is ``z_min``). ``H_img_from_bev`` is the 3x3
    homography mapping BEV pixel ``(c, r, 1)`` to left-image pixel ``(x, y, 1)``.
    """

    x_min: float
    x_max: float
    z_min: float
    z_max: float
    resolution: float
    H_img_from_bev: np.ndarray

    @property
    def cols(self) -> int:
        return int(round((self.x_max - self.x_min) / self.resolution))

    @property
    def rows(self) -> int:
        return int(round((self.z_max - self.z_min) / self.resolution))

    @property
    def vehicle_col(self) -> float:
        """The (fractional) BEV column of the camera's centre line, x = 0."""
        return -self.x_min / self.resolution - 0.5

    def lateral_m(self, col: float) -> float:
        """How far right of the vehicle BEV column ``col`` lies, metres (negative: left)."""
        return (col - self.vehicle_col) * self.resolution

    def bev_to_metric(self, c: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """BEV pixel (col, row) -> metric (x, z) on the road plane."""
        x = self.x_min + (np.asarray(c, float) + 0.5) * self.resolution
        z = self.z_max - (np.asarray(r, float) + 0.5) * self.resolution
        return x, z

    def metric_to_bev(self, x: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = (np.asarray(x, float) - self.x_min) / self.resolution - 0.5
        r = (self.z_max - np.asarray(z, float)) / self.resolution - 0.5
        return c, r

    def bev_to_image(self, c: np.ndarray, r: np.ndarray) -> np.ndarray:
        """BEV pixels (col, row) -> left-image pixels, an N x 2 array of (x, y)."""
        pts = np.stack([np.asarray(c, float), np.asarray(r, float), np.ones(np.size(c))])
        q = self.H_img_from_bev @ pts.reshape(3, -1)
        return (q[:2] / q[2]).T


@dataclass(init=False)
class FeatureMap:
    """Lane feature points in the BEV.

    ``mask``: Hb x Wb bool, True on a feature. ``orientation``: Hb x Wb float32, the
    feature's direction in radians in ``[0, pi)`` measured from the BEV's +x axis
    (image columns) towards -y (up the BEV); NaN-free, ``-1`` where unknown (SLT);
    ``None`` when no feature has an orientation.

    Two ways to build one, both giving the same map (equal masks and orientations):

    - dense, ``FeatureMap(mask, orientation)``: the feature points are found in the mask on
      first use of :meth:`points`;
    - sparse, :meth:`FeatureMap.from_points`: the points and their orientations; ``mask`` and
      ``orientation`` are materialised on first read (``-1`` off the points), so nodes that
      only need :meth:`points` and :meth:`point_orientations` never make a dense pass.

    A map is shared by every node that reads it: treat it as immutable.
    """

    # no class-level defaults: a sparse map materialises these two on first read (__getattr__)
    mask: np.ndarray
    orientation: np.ndarray | None

    def __init__(self, mask: np.ndarray, orientation: np.ndarray | None = None):
        self.mask = mask
        self.orientation = orientation
        self._points: tuple[np.ndarray, np.ndarray] | None = None
        self._values: np.ndarray | None = None  # orientations at the points, once gathered

    @classmethod
    def from_points(
        cls,
        shape: tuple[int, int],
        rows: np.ndarray,
        cols: np.ndarray,
        orientation_values: np.ndarray | None = None,
        *,
        mask: np.ndarray | None = None,
        orientation: np.ndarray | None = None,
    ) -> FeatureMap:
        """A map of the ``shape`` (Hb, Wb) with features at BEV pixels ``(rows[i], cols[i])``.

        ``rows``, ``cols``: integer arrays of N in-bounds, distinct pixels in row-major order (as
        ``np.nonzero`` gives them; :meth:`points` returns them as int64). ``orientation_values``:
        N radians (``-1`` where unknown), or ``None`` for a map without orientation (SLT).
        ``mask``, ``orientation``: the same map in dense form when the producer has it already
        (not checked against the points); otherwise built from the points on first read. The
        arrays are kept, not copied.
        """
        rows = np.asarray(rows).astype(np.int64, copy=False)
        cols = np.asarray(cols).astype(np.int64, copy=False)
        shape = (int(shape[0]), int(shape[1]))
        if rows.ndim != 1 or rows.shape != cols.shape:
            raise ValueError(
                f"FeatureMap.from_points: rows and cols: expected two 1-D arrays of one length, got shapes {rows.shape} and {cols.shape}"
            )
        values = None
        if orientation_values is not None:
            values = np.asarray(orientation_values)
            if values.shape != rows.shape:
                raise ValueError(
                    f"FeatureMap.from_points: orientation_values: expected shape {rows.shape} (one per point), got {values.shape}"
                )
        fm = cls.__new__(cls)
        # mask and orientation stay unset until read (__getattr__ builds them) unless given
        fm.__dict__.update(_shape=shape, _points=(rows, cols), _values=values)
        if mask is not None:
            fm.__dict__["mask"] = mask
        if orientation is not None and values is not None:
            fm.__dict__["orientation"] = orientation
        return fm

    def select(self, keep: np.ndarray) -> FeatureMap:
        """The map of the features whose entry in ``keep`` (bool, one per :meth:`points`) is True,
        sparse (see :meth:`from_points`); of a dense map's orientations only the kept are read."""
        r, c = self.points()
        values = self.__dict__.get("_values")
        if values is not None:
            values = values[keep]
        elif "_shape" not in self.__dict__ and self.orientation is not None:  # dense, not gathered yet
            o = np.asarray(self.orientation)
            rk, ck = r[keep], c[keep]
            values = o.reshape(-1).take(rk * o.shape[1] + ck) if o.flags.c_contiguous else o[rk, ck]
            return FeatureMap.from_points(self.shape, rk, ck, values)
        return FeatureMap.from_points(self.shape, r[keep], c[keep], values)

    def __getattr__(self, name: str) -> Any:
        # called only for attributes not set: ``mask`` / ``orientation`` of a sparse map
        d = self.__dict__
        if name not in ("mask", "orientation") or "_shape" not in d:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        rows, cols = d["_points"]
        shape = d["_shape"]
        flat = rows * shape[1] + cols
        if name == "mask":
            m = np.zeros(shape, bool)
            m.reshape(-1)[flat] = True
            d["mask"] = m
            return m
        values = d["_values"]
        o = None
        if values is not None:
            o = np.full(shape, -1, values.dtype if values.dtype.kind == "f" else np.float32)
            o.reshape(-1)[flat] = values
        d["orientation"] = o
        return o

    @property
    def shape(self) -> tuple[int, int]:
        """``(Hb, Wb)``, BEV pixels (without materialising the mask of a sparse map)."""
        s = self.__dict__.get("_shape")
        return s if s is not None else tuple(np.shape(self.mask))

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """``(rows, cols)`` of the features (int64, row-major order, as ``np.nonzero(mask)``),
        computed once per map and shared by the nodes that read it: treat the map as immutable."""
        if self._points is None:
            m = np.asarray(self.mask)
            if m.ndim != 2:
                raise ValueError(f"FeatureMap.mask: expected an Hb x Wb array, got shape {m.shape}")
            # flatnonzero + divmod: several times faster than a 2-D np.nonzero
            r, c = np.divmod(np.flatnonzero(m), max(m.shape[1], 1))
            self._points = (r, c)
        return self._points

    def point_orientations(self) -> np.ndarray | None:
        """The orientations (radians, ``-1`` where unknown) at :meth:`points`, in their order, in
        the orientation map's dtype; ``None`` for a map without orientation. Computed once."""
        if self._values is None and "_shape" not in self.__dict__:  # dense: gather once
            if self.orientation is None:
                return None
            r, c = self.points()
            self._values = np.asarray(self.orientation)[r, c]
        return self._values


@dataclass
class Line:
    """A straight line in the BEV: it crosses the bottom row at column ``rho`` with
    direction ``theta`` (radians, from +x towards up; pi/2 is vertical)."""

    rho: float
    theta: float
    votes: float = 0.0
    side: str = ""  # "left" | "right" | ""


@dataclass
class Lane:
    """A fitted lane marking.

    ``coeffs``: the BEV model ``col = c0 + c1*t + c2*t**2`` with ``t = rows - 1 - row``
    (BEV pixels from the bottom row). ``bev_rows``: the (first, last) BEV rows it
    covers. ``points``: N x 2 left-image pixels (x, y), filled by the projection
    step. ``side``: "left" or "right" of the vehicle. ``score``: support in [0, 1].
    """

    coeffs: tuple[float, float, float]
    bev_rows: tuple[int, int]
    side: str
    score: float
    points: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        # tolist(): Python floats straight away (rounded exactly as before, 40 % faster)
        pts = (
            []
            if self.points is None
            else [[round(x, 1), round(y, 1)] for x, y in np.asarray(self.points, dtype=np.float64).tolist()]
        )
        out: dict[str, Any] = {"points": pts, "side": self.side, "score": round(float(self.score), 4)}
        out["bev_coeffs"] = [float(c) for c in self.coeffs]
        out.update(self.extra)
        return out
