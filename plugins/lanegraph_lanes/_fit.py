"""Parabola fitting in a 40-pixel ROI around each Hough line: IRLS (the paper) or RANSAC.

The model is ``col = c0 + c1*t + c2*t**2`` with ``t = rows - 1 - row`` (BEV pixels above the bottom
row). IRLS: ordinary least squares, then weights from the residuals (Tukey biweight or Huber, scale
from the median absolute deviation), repeated. RANSAC: minimal samples of three points, the largest
consensus set within ``inlier_px``, then least squares on it.

A lane is reported only with enough support: ``min_inliers`` features spread over at least
``min_extent_m`` of road, and a plausible curvature; a frame with no painted markings reports none.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

from lanegraph import NodeParams, Port, node_type
from lanegraph.types import BevGeometry, FeatureMap, Lane, Line


def roi_points(features: FeatureMap, line: Line, width_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(t, col) of the features within ``width_px / 2`` of ``line`` (measured along the row)."""
    rows = features.mask.shape[0]
    r, c = np.nonzero(features.mask)
    inv_tan = np.cos(line.theta) / max(np.sin(line.theta), 1e-6)
    x_line = line.rho + (rows - r) * inv_tan
    keep = np.abs(c - x_line) <= width_px / 2
    return (rows - 1 - r[keep]).astype(np.float64), c[keep].astype(np.float64)


def _design(t: np.ndarray, degree: int) -> np.ndarray:
    return np.vander(t, degree + 1, increasing=True)


def _wls(A: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
    return coef


def irls_fit(t: np.ndarray, y: np.ndarray, degree: int = 2, iterations: int = 10, loss: str = "tukey", c: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Robust polynomial fit by iteratively reweighted least squares.

    Returns (coefficients, lowest order first; final weights in [0, 1]).
    """
    A = _design(t, degree)
    w = np.ones_like(y)
    coef = _wls(A, y, w)
    k = c if c is not None else (4.685 if loss == "tukey" else 1.345)
    for _ in range(iterations):
        res = y - A @ coef
        scale = 1.4826 * np.median(np.abs(res - np.median(res)))
        scale = max(scale, 0.5)  # BEV pixels: never trust sub-half-pixel residual scales
        u = res / (k * scale)
        if loss == "tukey":
            w = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
        else:
            au = np.abs(u)
            w = np.where(au <= 1, 1.0, 1.0 / np.maximum(au, 1e-12))
        if w.sum() < degree + 1:
            break
        new = _wls(A, y, w)
        if np.allclose(new, coef, atol=1e-6):
            coef = new
            break
        coef = new
    return coef, w


def ransac_fit(t: np.ndarray, y: np.ndarray, degree: int = 2, iterations: int = 200, inlier_px: float = 3.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC polynomial fit; returns (coefficients, inlier weights 0/1)."""
    rng = np.random.default_rng(seed)
    n = t.size
    A = _design(t, degree)
    best_in = np.zeros(n, bool)
    m = degree + 1
    for _ in range(iterations):
        idx = rng.choice(n, m, replace=False)
        if np.unique(t[idx]).size < m:
            continue
        try:
            coef = np.linalg.solve(A[idx], y[idx])
        except np.linalg.LinAlgError:
            continue
        inl = np.abs(A @ coef - y) <= inlier_px
        if inl.sum() > best_in.sum():
            best_in = inl
    if best_in.sum() < m:
        best_in = np.ones(n, bool)
    coef, *_ = np.linalg.lstsq(A[best_in], y[best_in], rcond=None)
    inl = np.abs(A @ coef - y) <= inlier_px
    if inl.sum() >= m:
        coef, *_ = np.linalg.lstsq(A[inl], y[inl], rcond=None)
    return coef, inl.astype(np.float64)


class FitParams(NodeParams):
    """Params shared by ``fit.irls`` and ``fit.ransac``."""

    roi_width: float = Field(40.0, gt=1.0, le=1000.0, description="ROI thickness around each Hough line, BEV pixels")
    degree: int = Field(2, ge=1, le=3, description="polynomial degree (2: parabola)")
    min_inliers: int = Field(80, ge=3, le=1000000, description="a lane needs at least this many supporting features")
    min_extent_m: float = Field(4.0, ge=0.0, le=500.0, description="supporting features must span at least this much road, metres")
    max_curvature: float = Field(0.02, gt=0.0, le=1.0, description="largest plausible curvature, 1/metres; above it the fit falls back to a line")
    extend_to_bottom: bool = Field(True, description="report the lane down to the nearest BEV row (markings continue towards the car)")


class IrlsParams(FitParams):
    """Params of ``fit.irls``."""

    iterations: int = Field(10, ge=1, le=100, description="reweighting iterations")
    loss: Literal["tukey", "huber"] = Field("tukey", description="robust weight function")


class RansacParams(FitParams):
    """Params of ``fit.ransac``."""

    iterations: int = Field(200, ge=1, le=100000, description="random minimal samples")
    inlier_px: float = Field(3.0, gt=0.0, le=100.0, description="inlier distance, BEV pixels")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="random seed (runs are deterministic)")


def _fit_lanes(features: FeatureMap, lines: list[Line], geometry: BevGeometry, p: FitParams, fitter) -> list[Lane]:
    rows = features.mask.shape[0]
    res = geometry.resolution
    lanes = []
    for line in lines or []:
        t, y = roi_points(features, line, p.roi_width)
        if t.size < max(p.min_inliers, p.degree + 1):  # a fit of degree d needs d + 1 points
            continue
        coef, w = fitter(t, y, p.degree)
        inl = w > 0.5
        if inl.sum() < p.min_inliers:
            continue
        extent = (t[inl].max() - t[inl].min()) * res
        if extent < p.min_extent_m:
            continue
        # curvature of x(z) = c0 + c1 t + c2 t^2 in metres: 2 c2 / res
        if p.degree >= 2 and abs(2 * coef[2] / res) > p.max_curvature:
            coef, w = fitter(t, y, 1)
            inl = w > 0.5
            if inl.sum() < p.min_inliers:  # the straight fallback lost the support
                continue
        c = np.zeros(3)
        c[: min(3, coef.size)] = coef[:3]
        t_hi = int(t[inl].max())
        t_lo = 0 if p.extend_to_bottom else int(t[inl].min())
        score = float(min(1.0, inl.sum() / max(1.0, (t_hi - t_lo + 1) * 2.0)))
        lanes.append(
            Lane(
                coeffs=(float(c[0]), float(c[1]), float(c[2])),
                bev_rows=(rows - 1 - t_hi, rows - 1 - t_lo),
                side=line.side,
                score=score,
                extra={"support": int(inl.sum()), "extent_m": round(float(extent), 2)},
            )
        )
    return lanes


_FIT_INPUTS = {"features": "features", "lines": "lines", "geometry": Port("bev_geometry")}


@node_type("fit.irls", inputs=_FIT_INPUTS, outputs={"lanes": "lanes"})
def fit_irls(params: IrlsParams, features: FeatureMap, lines: list[Line], geometry: BevGeometry) -> dict:
    """Parabola through the features of a 40 px ROI around each line, by robust IRLS (Tukey or Huber)."""

    def fitter(t, y, degree):
        return irls_fit(t, y, degree, params.iterations, params.loss)

    return {"lanes": _fit_lanes(features, lines, geometry, params, fitter)}


@node_type("fit.ransac", inputs=_FIT_INPUTS, outputs={"lanes": "lanes"})
def fit_ransac(params: RansacParams, features: FeatureMap, lines: list[Line], geometry: BevGeometry) -> dict:
    """Parabola through the features of a 40 px ROI around each line, by RANSAC plus a least-squares refit."""

    def fitter(t, y, degree):
        return ransac_fit(t, y, degree, params.iterations, params.inlier_px, params.seed)
    return {"lanes": _fit_lanes(features, lines, geometry, params, fitter)}
