"""How high the road beside a lane stands above the fitted road plane, from the disparity: a kerb is
a step of 10-15 cm between the two sides of its edge, paint lies flat on the road."""

from __future__ import annotations

import math

import numpy as np

from lanegraph.types import BevGeometry, Calibration, Lane, RoadModel


def plane_fits(disparity: np.ndarray, road: RoadModel, calib: Calibration) -> bool:
    """Whether heights above ``road``'s plane can be read from ``disparity``: a valid road model with
    a camera height, and a map of the calibration's size (a reduced disparity: the road model is
    not its)."""
    if not road.valid or not road.height > 0:
        return False
    h, w = np.shape(disparity)
    return not ((calib.width and w != calib.width) or (calib.height and h != calib.height))


def heights_at(
    geometry: BevGeometry,
    disparity: np.ndarray,
    road: RoadModel,
    calib: Calibration,
    rows: np.ndarray,
    cols: np.ndarray,
) -> np.ndarray:
    """The height above the fitted road plane (metres, ``h (d - d_road) / d``, ``road.mask``'s eq. 4)
    of what the image shows at the BEV pixels ``(rows, cols)``; NaN without a disparity there or
    outside the image."""
    out = np.full(rows.shape, np.nan)
    if rows.size == 0:
        return out
    xy = geometry.bev_to_image(cols.astype(np.float64), rows.astype(np.float64))
    h, w = disparity.shape
    ok = np.isfinite(xy).all(axis=1)
    u = np.zeros(rows.shape, np.int64)
    v = np.zeros(rows.shape, np.int64)
    u[ok] = np.rint(xy[ok, 0]).astype(np.int64)
    v[ok] = np.rint(xy[ok, 1]).astype(np.int64)
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    d = np.zeros(rows.shape)
    d[ok] = disparity[v[ok], u[ok]]
    ok &= (d > 0) & np.isfinite(d)
    s, c = math.sin(road.roll) * calib.f_y / calib.f, math.cos(road.roll)
    vr = calib.cy + s * (u[ok] - calib.cx) + c * (v[ok] - calib.cy)
    out[ok] = road.height * (d[ok] - road.disparity_at(vr)) / d[ok]
    return out


def median_height(heights: np.ndarray) -> float:
    """The median of the known ``heights`` (:func:`heights_at`); NaN where fewer than 5 are known."""
    known = heights[~np.isnan(heights)]
    return float(np.median(known)) if known.size >= 5 else math.nan


def lane_heights(
    lane: Lane,
    geometry: BevGeometry,
    disparity: np.ndarray,
    road: RoadModel,
    calib: Calibration,
    max_distance_m: float,
    near_m: float = 0.3,
    far_m: float = 0.8,
    step: int = 4,
) -> tuple[float, float, float]:
    """The median height above the fitted road plane (metres; eq. 4 of ``road.mask``,
    ``h (d - d_road) / d``) of the road ``near_m .. far_m`` left of ``lane``, on the lane itself
    (+-5 cm) and right of it, sampled on every ``step``-th of its rows nearer than
    ``max_distance_m``; NaN where fewer than 5 samples have a disparity."""
    nan = (math.nan, math.nan, math.nan)
    if not plane_fits(disparity, road, calib):
        return nan
    res = float(geometry.resolution)
    rows = geometry.rows
    near = int(math.floor(geometry.metric_to_bev(0.0, max_distance_m)[1]))
    r = np.arange(max(int(lane.bev_rows[0]), near, 0), min(int(lane.bev_rows[1]), rows - 1) + 1, step)
    if r.size == 0:
        return nan
    t = rows - 1 - r.astype(np.float64)
    col = lane.coeffs[0] + lane.coeffs[1] * t + lane.coeffs[2] * t * t
    offsets = {
        "left": -np.arange(near_m, far_m + 1e-9, res) / res,
        "line": np.array([-1.0, 0.0, 1.0]),
        "right": np.arange(near_m, far_m + 1e-9, res) / res,
    }
    out = []
    for key in ("left", "line", "right"):
        cc = (col[:, None] + offsets[key][None, :]).ravel()
        rr = np.repeat(r, offsets[key].size).astype(np.float64)
        out.append(median_height(heights_at(geometry, disparity, road, calib, rr, cc)))
    return out[0], out[1], out[2]


def _measurable(disparity, road, calib) -> bool:
    return disparity is not None and road is not None and calib is not None


def dark_side_stepped(
    p,
    lane: Lane,
    geometry: BevGeometry,
    disparity: np.ndarray | None,
    road: RoadModel | None,
    calib: Calibration | None,
) -> bool:
    """``lanes.verify``'s flatness rule for a much darker side (``p``: its params): whether the road's
    height above the fitted plane steps across ``lane`` by more than ``max_dark_side_step_m`` (and,
    with ``max_kerb_step_m``, by no more than a kerb: an obstacle's side beside a line is no step of
    the road) (:func:`lane_heights`, both sides measured; False without a disparity, a road and a
    calibration, or when a side has no disparity)."""
    if p.max_dark_side_step_m is None or not _measurable(disparity, road, calib):
        return False
    left, _, right = lane_heights(lane, geometry, np.asarray(disparity), road, calib, p.max_distance_m)
    step = abs(left - right)
    if p.max_kerb_step_m is not None and step > p.max_kerb_step_m:
        return False  # higher than a kerb: an obstacle's side beside the line (a parked car), not a kerb
    return step > p.max_dark_side_step_m  # NaN: False


def step_across(
    lane: Lane,
    geometry: BevGeometry,
    disparity: np.ndarray,
    road: RoadModel,
    calib: Calibration,
    max_distance_m: float,
) -> tuple[float, float]:
    """``(step, beyond)``: how much the road's median height above the fitted plane differs 0.3-0.8 m
    left and right of ``lane`` (:func:`lane_heights`), and how high the higher side stands 0.8-1.2 m
    out above the lower side's 0.3-0.8 m (a kerb's top, a pavement, stays at the kerb's height; a
    parked car's body or a wall rises higher); metres, NaN where a side has no disparity."""
    disparity = np.asarray(disparity)
    left, _, right = lane_heights(lane, geometry, disparity, road, calib, max_distance_m)
    step = abs(left - right)
    if not step >= 0.0:  # NaN
        return math.nan, math.nan
    far_left, _, far_right = lane_heights(
        lane, geometry, disparity, road, calib, max_distance_m, near_m=0.8, far_m=1.2
    )
    beyond = far_right if right > left else far_left
    return step, beyond - min(left, right)


def kerb_across(
    p,
    lane: Lane,
    geometry: BevGeometry,
    disparity: np.ndarray | None,
    road: RoadModel | None,
    calib: Calibration | None,
) -> bool:
    """``lanes.verify``'s flatness rule for every lane (``p``: its params): whether the road steps
    across ``lane`` by more than ``max_step_m`` (paint lies on the road plane; a kerb is a step of
    10-15 cm) while the higher side stays no higher than ``obstacle_height_m`` 0.8-1.2 m out (a kerb's
    top and the pavement behind it; a parked car or a wall beside a line rises higher, and the line
    is kept) (:func:`step_across`; False with ``max_step_m`` None, without a disparity, a road and a
    calibration, or when a side has no disparity)."""
    if p.max_step_m is None or not _measurable(disparity, road, calib):
        return False
    step, beyond = step_across(lane, geometry, disparity, road, calib, p.max_distance_m)
    return step > p.max_step_m and not beyond > p.obstacle_height_m  # a NaN step: False
