"""Parabola fitting in a 40-pixel ROI around each Hough line: IRLS (the paper) or RANSAC.

The model is ``col = c0 + c1*t + c2*t**2`` with ``t = rows - 1 - row`` (BEV pixels above the bottom
row). IRLS: ordinary least squares, then weights from the residuals (Tukey biweight or Huber, scale
from the median absolute deviation), repeated. RANSAC: minimal samples of three points, the largest
consensus set within ``inlier_px``, then least squares on it.

A lane is reported only with enough support: ``min_inliers`` features spread over at least
``min_extent_m`` of road, and a plausible curvature; a frame with no painted markings reports none.

With the optional ``previous`` input (the previous frame's lanes, a feedback edge), a side the Hough
transform found no line on is fitted in the ROI around the previous lane there: only its offset and a
change of slope, the previous curvature kept, and only when the result still lies where an ego-lane
boundary can (``track_min_offset_m`` .. ``track_max_offset_m`` from the vehicle).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field

from lanegraph import NodeParams, Port, node_type
from lanegraph.types import BevGeometry, FeatureMap, Lane, Line

from ._parabola import (  # noqa: F401 - the fits, and the tests' names in this module
    _irls_kernel,
    _ransac_kernel,
    irls_fit,
    irls_fit_lstsq,
    ransac_fit,
    ransac_samples,
)


def _roi_points(features: FeatureMap, a: float, b: float, c: float, half_width: float):
    """The features with ``|col - x(row)| <= half_width`` around the centre curve
    ``x(row) = a + b (rows - row) + c (rows - 1 - row)^2`` (a Hough line: ``a = rho``,
    ``b = 1 / tan(theta)``, ``c = 0``; a lane ``col = c0 + c1 t + c2 t^2``: ``a = c0 - c1``, ``b = c1``,
    ``c = c2``), in the points' row-major order: ``(rows - 1 - row, col)`` as float64. From the map's
    points: no dense mask is built (a NaN curve keeps none)."""
    r, col = features.points()
    rows = features.shape[0]
    tr = rows - 1 - r
    x_line = a + (rows - r) * b + c * tr * tr
    keep = np.abs(col - x_line) <= half_width
    return tr[keep].astype(np.float64), col[keep].astype(np.float64)


def roi_points(features: FeatureMap, line: Line, width_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(t, col) of the features within ``width_px / 2`` of ``line`` (measured along the row)."""
    inv_tan = np.cos(line.theta) / max(np.sin(line.theta), 1e-6)
    return _roi_points(features, float(line.rho), float(inv_tan), 0.0, float(width_px / 2))


def lane_roi_points(features: FeatureMap, lane: Lane, width_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(t, col) of the features within ``width_px / 2`` of a lane's parabola (along the row)."""
    c0, c1, c2 = (float(v) for v in lane.coeffs)
    return _roi_points(features, c0 - c1, c1, c2, float(width_px / 2))


class FitParams(NodeParams):
    """Params shared by ``fit.irls`` and ``fit.ransac``."""

    roi_width: float = Field(
        40.0, gt=1.0, le=1000.0, description="ROI thickness around each Hough line, BEV pixels"
    )
    degree: int = Field(2, ge=1, le=3, description="polynomial degree (2: parabola)")
    min_inliers: int = Field(
        80, ge=3, le=1000000, description="a lane needs at least this many supporting features"
    )
    min_extent_m: float = Field(
        4.0, ge=0.0, le=500.0, description="supporting features must span at least this much road, metres"
    )
    max_curvature: float = Field(
        0.02,
        gt=0.0,
        le=1.0,
        description="largest plausible curvature, 1/metres; above it the fit falls back to a line",
    )
    extend_to_bottom: bool = Field(
        True, description="report the lane down to the nearest BEV row (markings continue towards the car)"
    )
    track_min_score: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="with `previous` lanes: a side with no Hough line is fitted around the previous lane there when it scored at least this",
    )
    track_min_offset_m: float = Field(
        0.6,
        ge=0.0,
        le=20.0,
        description="a lane fitted around a previous one must cross the bottom row at least this far from the vehicle (as hough.min_offset_m), metres",
    )
    track_max_offset_m: float = Field(
        3.2,
        gt=0.0,
        le=50.0,
        description="a lane fitted around a previous one must cross the bottom row at most this far from the vehicle (as hough.max_offset_m), metres",
    )
    track_lane_change: bool = Field(
        True,
        description="a lane fitted around a previous one may also lie nearer than track_min_offset_m (the line being crossed "
        "in a lane change), and then the other side's up to track_max_lane_width_m from it (as hough.lane_change)",
    )
    track_max_lane_width_m: float = Field(
        4.6,
        gt=0.0,
        le=20.0,
        description="lane change: widest plausible lane (as hough.max_lane_width_m), metres",
    )
    near_fit_m: float | None = Field(
        None,
        gt=0.0,
        le=1000.0,
        description="a line seen continuously nearer than this (its features on near_fit_coverage of those BEV rows: a "
        "solid line) is fitted there only, metres: a parabola is a constant curvature, a road's changes (a clothoid "
        "entering a bend), and the near part is what the image shows largest. A dashed line's few near dashes "
        "would bend the parabola: it is fitted over the whole BEV. null: always the whole BEV (the paper)",
    )
    near_fit_coverage: float = Field(
        0.7,
        gt=0.0,
        le=1.0,
        description="near_fit_m: the fraction of the near BEV rows the ROI's features must cover (unitless)",
    )
    residuals: Literal["bev", "image"] = Field(
        "bev",
        description="'image': residuals measured as the image shows them (times the image pixels per BEV pixel at "
        "the point's distance, z_min / z): near features, where a BEV pixel spans many image pixels, weigh more; "
        "'bev': plain BEV pixels (the paper)",
    )
    distance_weight: float = Field(
        1.0,
        ge=0.0,
        le=4.0,
        description="'image' residuals: each feature also weighs (z_min / z) to this power (unitless; 0: the image's "
        "pixels across only; 2: every image row equally, as the lane metric counts them, which lets the nearest "
        "dash alone bend a parabola: 1 is the compromise)",
    )


class IrlsParams(FitParams):
    """Params of ``fit.irls``."""

    iterations: int = Field(10, ge=1, le=100, description="reweighting iterations")
    loss: Literal["tukey", "huber"] = Field("tukey", description="robust weight function")
    tolerance_px: float = Field(
        0.01,
        gt=0.0,
        le=10.0,
        description="converged when no fitted point moves by more than this between iterations, BEV pixels",
    )


class RansacParams(FitParams):
    """Params of ``fit.ransac``."""

    iterations: int = Field(200, ge=1, le=2000, description="random minimal samples")
    inlier_px: float = Field(3.0, gt=0.0, le=100.0, description="inlier distance, BEV pixels")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="random seed (runs are deterministic)")


def _fit_roi(
    t: np.ndarray,
    y: np.ndarray,
    side: str,
    rows: int,
    res: float,
    p: FitParams,
    fitter,
    extra: dict | None = None,
    shape: tuple[float, float] | None = None,
) -> Lane | None:
    """A lane fitted to the ROI points ``(t, y)``, or None without enough support: ``min_inliers``
    inliers spanning ``min_extent_m``, and a plausible curvature (else a straight refit).

    With ``shape = (c1, c2)`` (a previous lane's slope and curvature) only the lane's offset and a
    change of slope are fitted, to ``y - c1 t - c2 t^2``: a dashed line seen over part of the ROI
    cannot bend the parabola away from the lane it continues."""
    if t.size < max(p.min_inliers, p.degree + 1):  # a fit of degree d needs d + 1 points
        return None
    if shape is not None:
        b1, b2 = shape
        coef, w = fitter(t, y - b1 * t - b2 * t * t, 1)
        coef = np.array([coef[0], coef[1] + b1, b2])
    else:
        coef, w = fitter(t, y, p.degree)
    inl = w > 0.5
    if inl.sum() < p.min_inliers:
        return None
    extent = (t[inl].max() - t[inl].min()) * res
    if extent < p.min_extent_m:
        return None
    # curvature of x(z) = c0 + c1 t + c2 t^2 in metres: 2 c2 / res
    if shape is None and p.degree >= 2 and abs(2 * coef[2] / res) > p.max_curvature:
        coef, w = fitter(t, y, 1)
        inl = w > 0.5
        if inl.sum() < p.min_inliers:  # the straight fallback lost the support
            return None
    c = np.zeros(3)
    c[: min(3, coef.size)] = coef[:3]
    t_hi = int(t[inl].max())
    t_lo = 0 if p.extend_to_bottom else int(t[inl].min())
    score = float(min(1.0, inl.sum() / max(1.0, (t_hi - t_lo + 1) * 2.0)))
    return Lane(
        coeffs=(float(c[0]), float(c[1]), float(c[2])),
        bev_rows=(rows - 1 - t_hi, rows - 1 - t_lo),
        side=side,
        score=score,
        extra={"support": int(inl.sum()), "extent_m": round(float(extent), 2), **(extra or {})},
    )


def _plausible_tracked(lateral: float, others: list[float], p: FitParams) -> bool:
    """Whether a lane fitted around a previous one, crossing the bottom row ``lateral`` metres from
    the vehicle, is still a plausible ego-lane boundary beside this frame's lanes at ``others``:
    ``track_min_offset_m .. track_max_offset_m`` away, like a Hough line; with
    ``track_lane_change`` also nearer (the line being crossed continues a previous lane by
    construction), or farther when another lane is being crossed, up to a lane's width from it."""
    if p.track_min_offset_m <= abs(lateral) <= p.track_max_offset_m:
        return True
    if not p.track_lane_change:
        return False
    if abs(lateral) < p.track_min_offset_m:
        return True
    return any(
        abs(o) < p.track_min_offset_m and o * lateral < 0 and abs(lateral - o) <= p.track_max_lane_width_m
        for o in others
    )


def _near_fit(t: np.ndarray, y: np.ndarray, t_near: float, coverage: float) -> tuple[np.ndarray, np.ndarray]:
    """The ROI points ``(t, y)`` to fit: those below BEV row height ``t_near`` when they cover at
    least ``coverage`` of those rows (a line seen continuously there), else all of them. ``t`` in
    the row-major order :func:`_roi_points` gives (a row's points together): the rows covered are
    counted where ``t`` changes (``np.unique``'s count, without its sort)."""
    if not t.size or not math.isfinite(t_near) or t.max() < t_near:
        return t, y
    keep = t < t_near
    near = t[keep]
    covered = np.count_nonzero(near[1:] != near[:-1]) + 1 if near.size else 0
    if covered < coverage * t_near:
        return t, y
    return near, y[keep]


def _fit_lanes(
    features: FeatureMap,
    lines: list[Line],
    geometry: BevGeometry,
    p: FitParams,
    fitter,
    previous: list[Lane] | None = None,
) -> list[Lane]:
    rows = features.shape[0]
    res = geometry.resolution
    lanes = []
    t_near = math.inf if p.near_fit_m is None else (p.near_fit_m - geometry.z_min) / res
    for line in lines or []:
        t, y = _near_fit(*roi_points(features, line, p.roi_width), t_near, p.near_fit_coverage)
        lane = _fit_roi(t, y, line.side, rows, res, p, fitter)
        if lane is not None:
            lanes.append(lane)
    # a side the Hough transform found nothing on (a dashed line on a sharp curve spreads its
    # votes): the ROI follows the previous frame's lane on that side instead
    found = {ln.side for ln in lanes}
    n_hough = len(lanes)
    for prev in previous or []:
        if prev.side in found or prev.side not in ("left", "right") or prev.score < p.track_min_score:
            continue
        t, y = _near_fit(*lane_roi_points(features, prev, p.roi_width), t_near, p.near_fit_coverage)
        lane = _fit_roi(
            t,
            y,
            prev.side,
            rows,
            res,
            p,
            fitter,
            {"tracked": True},
            shape=(float(prev.coeffs[1]), float(prev.coeffs[2])),
        )
        if lane is None:
            continue
        # the side is where the lane is now (after a lane change the previous left line is right),
        # and it must still be a plausible ego-lane boundary, like a Hough line: else a lock on a
        # line the vehicle has moved away from would keep itself alive through the temporal mask
        lateral = geometry.lateral_m(lane.coeffs[0])
        side = "left" if lateral < 0 else "right"
        if side in found or not _plausible_tracked(
            lateral, [geometry.lateral_m(ln.coeffs[0]) for ln in lanes], p
        ):
            continue
        # the line being crossed, which the Hough transform found this frame on the other side
        # (it moves from one side to the other): not a second lane
        if abs(lateral) < p.track_min_offset_m and any(
            abs(lane.coeffs[0] - ln.coeffs[0]) <= 0.5 * p.roi_width for ln in lanes
        ):
            continue
        lanes.append(Lane(lane.coeffs, lane.bev_rows, side, lane.score, lane.points, lane.extra))
        found.add(side)
    if len(lanes) > n_hough:  # left to right, as the Hough lines come
        lanes.sort(key=lambda ln: ln.coeffs[0])
    return lanes


def _residual_scale(
    t: np.ndarray, geometry: BevGeometry, p: FitParams
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The fitters' ``scale_of`` and ``prior`` for the ROI points at ``t`` (BEV rows above the bottom
    one): ``residuals: bev``, none; ``image``: the image pixels a BEV pixel spans across at the
    point's distance, ``f res / z``, relative to the nearest row's (``z_min / z``: the units
    cancel), and that to the power ``distance_weight`` as the prior."""
    if p.residuals == "bev":
        return None, None
    z_near = max(geometry.z_min, geometry.resolution)
    k = z_near / (geometry.z_min + (np.asarray(t, dtype=np.float64) + 0.5) * geometry.resolution)
    return k, (k**p.distance_weight if p.distance_weight else None)


_FIT_INPUTS = {
    "features": "features",
    "lines": "lines",
    "geometry": Port("bev_geometry"),
    "previous": Port(
        "lanes",
        "the previous frame's lanes (a feedback edge): a side with no line is fitted around its lane",
        optional=True,
    ),
}


@node_type("fit.irls", inputs=_FIT_INPUTS, outputs={"lanes": "lanes"})
def fit_irls(
    params: IrlsParams,
    features: FeatureMap,
    lines: list[Line],
    geometry: BevGeometry,
    previous: list[Lane] | None = None,
) -> dict:
    """Parabola through the features of a 40 px ROI around each line, by robust IRLS (Tukey or Huber)."""

    def fitter(t, y, degree):
        k, prior = _residual_scale(t, geometry, params)
        return irls_fit(
            t, y, degree, params.iterations, params.loss, tol_px=params.tolerance_px, scale_of=k, prior=prior
        )

    return {"lanes": _fit_lanes(features, lines, geometry, params, fitter, previous)}


@node_type("fit.ransac", inputs=_FIT_INPUTS, outputs={"lanes": "lanes"})
def fit_ransac(
    params: RansacParams,
    features: FeatureMap,
    lines: list[Line],
    geometry: BevGeometry,
    previous: list[Lane] | None = None,
) -> dict:
    """Parabola through the features of a 40 px ROI around each line, by RANSAC plus a least-squares refit."""

    def fitter(t, y, degree):
        k, prior = _residual_scale(t, geometry, params)
        if prior is not None:
            k = k * np.sqrt(prior)  # the weight of each square: k^2 prior
        return ransac_fit(t, y, degree, params.iterations, params.inlier_px, params.seed, scale_of=k)

    return {"lanes": _fit_lanes(features, lines, geometry, params, fitter, previous)}
