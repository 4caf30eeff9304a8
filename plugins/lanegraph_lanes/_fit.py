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

from lanegraph import NodeParams, Port, jit, node_type
from lanegraph.types import BevGeometry, FeatureMap, Lane, Line

from ._select import median_inplace


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


def _design(t: np.ndarray, degree: int) -> np.ndarray:
    return np.vander(t, degree + 1, increasing=True)


def _wls(A: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
    return coef


@jit
def _solve_augmented(M, tiny, out):
    """Solve the ``m x m`` system whose augmented ``m x (m + 1)`` matrix is ``M`` (overwritten) into
    ``out``: Gaussian elimination with partial pivoting. False (``out`` unchanged) when a pivot is not
    above ``tiny`` (singular)."""
    m = M.shape[0]
    for col in range(m):
        piv = col
        for r in range(col + 1, m):
            if abs(M[r, col]) > abs(M[piv, col]):
                piv = r
        if not abs(M[piv, col]) > tiny:
            return False
        if piv != col:
            for c in range(m + 1):
                tmp = M[col, c]
                M[col, c] = M[piv, c]
                M[piv, c] = tmp
        for r in range(col + 1, m):
            f = M[r, col] / M[col, col]
            for c in range(col, m + 1):
                M[r, c] -= f * M[col, c]
    for r in range(m - 1, -1, -1):
        acc = M[r, m]
        for c in range(r + 1, m):
            acc -= M[r, c] * out[c]
        out[r] = acc / M[r, r]
    return True


@jit
def _normal_equations(x, w, y, m, M):
    """The weighted normal equations of the polynomial of ``m <= 4`` coefficients in ``x`` into the
    augmented ``m x (m + 1)`` matrix ``M``: ``M[r, c] = sum w x^(r + c)``, ``M[r, m] = sum w x^r y``.
    The power sums are accumulated in scalars (one pass; adding into ``M`` itself would chain every
    point's update through memory)."""
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = 0.0
    t0 = t1 = t2 = t3 = 0.0
    for i in range(x.size):
        wi = w[i]
        if wi == 0.0:
            continue
        xi = x[i]
        p1 = wi * xi
        p2 = p1 * xi
        p3 = p2 * xi
        s0 += wi
        s1 += p1
        s2 += p2
        s3 += p3
        s4 += p3 * xi
        s5 += p3 * xi * xi
        s6 += p3 * xi * xi * xi
        yi = y[i]
        t0 += wi * yi
        t1 += p1 * yi
        t2 += p2 * yi
        t3 += p3 * yi
    S = (s0, s1, s2, s3, s4, s5, s6)
    T = (t0, t1, t2, t3)
    for r in range(m):
        for c in range(m):
            M[r, c] = S[r + c]
        M[r, m] = T[r]


@jit
def _poly(a, x):
    """``sum a[j] x^j`` by Horner's rule."""
    p = 0.0
    for j in range(a.size - 1, -1, -1):
        p = p * x + a[j]
    return p


@jit
def _coeffs4(a):
    """The coefficients of ``a`` (at most 4) as four scalars, zero-padded, for :func:`_poly4`."""
    m = a.size
    return (a[0] if m > 0 else 0.0, a[1] if m > 1 else 0.0, a[2] if m > 2 else 0.0, a[3] if m > 3 else 0.0)


@jit
def _poly4(c, x):
    """:func:`_poly` with the coefficients ``c`` of :func:`_coeffs4` (scalars): Horner's rule from the
    zero-padded terms gives the same value as from ``a``'s own highest term, and a loop over points
    that calls it vectorises."""
    c0, c1, c2, c3 = c
    p = 0.0
    p = p * x + c3
    p = p * x + c2
    p = p * x + c1
    return p * x + c0


@jit
def _irls_kernel(t, y, degree, iterations, tukey, k, tol_px, scale_of, prior):
    """:func:`irls_fit` by weighted normal equations in the scaled abscissa ``x = (t - mid) / half``
    (``x`` in [-1, 1]: well conditioned, unlike powers of ``t`` itself); ``degree <= 3``. Returns
    ``(ok, coef, w)``, coefficients in ``t``, lowest power first, ``w`` the robust weights;
    ``ok`` False when a system is singular (the caller then uses the NumPy least-squares path).
    Converged when no point's fitted value moves by more than ``tol_px``. ``scale_of`` (one per
    point, or empty: all 1) scales each residual before the robust weights and the sums of squares,
    ``prior`` (one per point, or empty: all 1) weighs each point's square: the system's weights are
    the robust weights times ``scale_of**2 * prior``."""
    n = t.size
    m = degree + 1
    lo = t[0]
    hi = t[0]
    for i in range(1, n):  # t.min(), t.max() (loops: their generic code took a second to compile)
        if t[i] < lo:
            lo = t[i]
        if t[i] > hi:
            hi = t[i]
    mid = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    if half <= 0.0:
        half = 1.0
    # every array is np.empty(n, np.float64) or np.empty((r, c), np.float64) (the dtype named: the same
    # np.empty as the other kernels') and filled by a loop, powers are products and
    # the polynomial is written out (no np.zeros, np.ones, copy, ** or small helper kernels): each of
    # those is one more function for numba to compile, and this kernel's compilation is on the first
    # run's path (the same values: products of at most three factors are ``**``'s own)
    x = np.empty(n, np.float64)
    for i in range(n):
        x[i] = (t[i] - mid) / half
    # x^j = sum_i C(j, i) t^i (-mid)^(j - i) / half^j: T[i, j] maps x-coefficients to t-coefficients
    pm = np.empty(m, np.float64)  # (-mid)**e
    ph = np.empty(m, np.float64)  # half**e
    pm[0] = 1.0
    ph[0] = 1.0
    for e in range(1, m):
        pm[e] = pm[e - 1] * -mid
        ph[e] = ph[e - 1] * half
    T = np.empty((m, m), np.float64)
    for i in range(m):
        for j in range(m):
            T[i, j] = 0.0
    for j in range(m):
        binom = 1.0
        for i in range(j + 1):
            T[i, j] = binom * pm[j - i] / ph[j]
            binom = binom * (j - i) / (i + 1)
    ks = np.empty(n, np.float64)
    pw = np.empty(n, np.float64)  # the fixed part of the system's weights
    w = np.empty(n, np.float64)  # the robust weights
    sw = np.empty(n, np.float64)  # the system's weights
    for i in range(n):
        ks[i] = scale_of[i] if scale_of.size == n else 1.0
        pw[i] = ks[i] * ks[i] * (prior[i] if prior.size == n else 1.0)
        w[i] = 1.0
        sw[i] = pw[i]
    coef = np.empty(m, np.float64)
    a = np.empty(m, np.float64)
    for j in range(m):
        coef[j] = 0.0
        a[j] = 0.0
    res = np.empty(n, np.float64)
    dev = np.empty(n, np.float64)
    M = np.empty((m, m + 1), np.float64)
    for it in range(iterations + 1):
        if it > 0:
            c0 = a[0]  # _poly4(_coeffs4(a), x), written out
            c1 = a[1] if m > 1 else 0.0
            c2 = a[2] if m > 2 else 0.0
            c3 = a[3] if m > 3 else 0.0
            for i in range(n):
                xi = x[i]
                p = 0.0
                p = p * xi + c3
                p = p * xi + c2
                p = p * xi + c1
                p = p * xi + c0
                res[i] = (y[i] - p) * ks[i]
            for i in range(n):
                dev[i] = res[i]
            med = median_inplace(dev, n)  # np.median's value (lanegraph_lanes._select)
            for i in range(n):
                dev[i] = abs(res[i] - med)
            scale = 1.4826 * median_inplace(dev, n)
            scale = max(scale, 0.5)  # BEV pixels: never trust sub-half-pixel residual scales
            inv = 1.0 / (k * scale)
            if tukey:
                for i in range(n):
                    u = res[i] * inv
                    q = 1.0 - u * u
                    w[i] = q * q if abs(u) < 1.0 else 0.0
            else:
                for i in range(n):
                    au = abs(res[i] * inv)
                    w[i] = 1.0 if au <= 1.0 else 1.0 / max(au, 1e-12)
            wsum = 0.0  # apart from the weights: a sum in order does not vectorise
            for i in range(n):
                wsum += w[i]
            if wsum < degree + 1:
                break
            for i in range(n):
                sw[i] = w[i] * pw[i]
        _normal_equations(x, sw, y, m, M)
        new_a = np.empty(m, np.float64)
        new = np.empty(m, np.float64)
        for i in range(m):
            new_a[i] = 0.0
            new[i] = 0.0
        if not _solve_augmented(M, 1e-12 * max(1.0, abs(M[0, 0])), new_a):
            return False, coef, w
        for i in range(m):
            for j in range(m):
                new[i] += T[i, j] * new_a[j]
        finite = True
        for i in range(m):
            finite = finite and math.isfinite(new[i])
        if not finite:
            return False, coef, w
        if it > 0:
            step = np.empty(m, np.float64)
            for i in range(m):
                step[i] = new_a[i] - a[i]
            c0 = step[0]  # _poly4(_coeffs4(step), x), written out
            c1 = step[1] if m > 1 else 0.0
            c2 = step[2] if m > 2 else 0.0
            c3 = step[3] if m > 3 else 0.0
            moved = 0.0
            for i in range(n):
                xi = x[i]
                p = 0.0
                p = p * xi + c3
                p = p * xi + c2
                p = p * xi + c1
                p = p * xi + c0
                moved = max(moved, abs(p))
            a = new_a
            coef = new
            if moved <= tol_px:
                break
        else:
            a = new_a
            coef = new
    return True, coef, w


def irls_fit_lstsq(
    t: np.ndarray,
    y: np.ndarray,
    degree: int = 2,
    iterations: int = 10,
    loss: str = "tukey",
    c: float | None = None,
    tol_px: float = 0.01,
    scale_of: np.ndarray | None = None,
    prior: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`irls_fit` with ``np.linalg.lstsq`` solves (the reference; used when a normal-equation
    system of the kernel is singular)."""
    A = _design(t, degree)
    ks = (
        np.ones_like(y)
        if scale_of is None or np.size(scale_of) != np.size(y)
        else np.asarray(scale_of, dtype=np.float64)
    )
    pw = (
        ks
        * ks
        * (1.0 if prior is None or np.size(prior) != np.size(y) else np.asarray(prior, dtype=np.float64))
    )
    w = np.ones_like(y)
    coef = _wls(A, y, pw)
    k = c if c is not None else (4.685 if loss == "tukey" else 1.345)
    for _ in range(iterations):
        res = (y - A @ coef) * ks
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
        new = _wls(A, y, w * pw)
        moved = np.abs(A @ (new - coef)).max()
        coef = new
        if moved <= tol_px:
            break
    return coef, w


def irls_fit(
    t: np.ndarray,
    y: np.ndarray,
    degree: int = 2,
    iterations: int = 10,
    loss: str = "tukey",
    c: float | None = None,
    tol_px: float = 0.01,
    scale_of: np.ndarray | None = None,
    prior: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Robust polynomial fit by iteratively reweighted least squares, until no fitted value moves
    by more than ``tol_px`` (or ``iterations`` reweightings).

    ``scale_of`` (one positive factor per point, optional) measures each residual in other units
    before the robust weights and the sum of squares; ``prior`` (optional) weighs each point's
    square. With the image pixels per BEV pixel at each point's distance as ``scale_of`` and the
    image rows per BEV row as ``prior``, the fit minimises the lateral error as the image shows it,
    row by image row (near points count more), instead of the error in the BEV.

    Returns (coefficients, lowest order first; final robust weights in [0, 1]).
    """
    t = np.ascontiguousarray(t, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    ks = np.empty(0) if scale_of is None else np.ascontiguousarray(scale_of, dtype=np.float64)
    pr = np.empty(0) if prior is None else np.ascontiguousarray(prior, dtype=np.float64)
    k = c if c is not None else (4.685 if loss == "tukey" else 1.345)
    if t.size >= degree + 1 and degree <= 3:  # the kernel's power sums stop at x^6
        ok, coef, w = _irls_kernel(
            t, y, int(degree), int(iterations), loss == "tukey", float(k), float(tol_px), ks, pr
        )
        if ok:
            return coef, w
    return irls_fit_lstsq(t, y, degree, iterations, loss, c, tol_px, scale_of, prior)


@jit
def _ransac_kernel(t, y, samples, tol):
    """The consensus of every minimal sample (rows of ``samples``: ``m = degree + 1`` point indices):
    the polynomial through the sample (a Vandermonde system in the scaled abscissa
    ``(t - mid) / half``) and the number of points within their own ``tol`` (one per point) of it.
    Samples with repeated abscissae or a singular system are skipped. Returns the inlier mask of the
    first sample with the most inliers (all False when none was usable)."""
    n = t.size
    n_samples, m = samples.shape
    inl = np.zeros(n, np.bool_)
    if n == 0:
        return inl
    lo = t.min()
    hi = t.max()
    mid = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo) if hi > lo else 1.0
    x = np.empty(n)  # the scaled abscissae, once (not again for every sample)
    for i in range(n):
        x[i] = (t[i] - mid) / half
    M = np.empty((m, m + 1))
    a = np.zeros(m)
    best_a = np.zeros(m)
    best = -1
    for k in range(n_samples):
        distinct = True
        for i in range(m):
            for j in range(i):
                if t[samples[k, i]] == t[samples[k, j]]:
                    distinct = False
        if not distinct:
            continue
        for i in range(m):
            xs = x[samples[k, i]]
            p = 1.0
            for j in range(m):
                M[i, j] = p
                p *= xs
            M[i, m] = y[samples[k, i]]
        if not _solve_augmented(M, 1e-12, a):
            continue
        count = 0
        if m <= 4:  # scalar coefficients: the count vectorises
            ca = _coeffs4(a)
            for i in range(n):
                count += abs(_poly4(ca, x[i]) - y[i]) <= tol[i]
        else:
            for i in range(n):
                count += abs(_poly(a, x[i]) - y[i]) <= tol[i]
        if count > best:
            best = count
            best_a[:] = a
    if best < 0:
        return inl
    for i in range(n):
        inl[i] = abs(_poly(best_a, x[i]) - y[i]) <= tol[i]
    return inl


def ransac_samples(n: int, m: int, iterations: int, seed: int = 0) -> np.ndarray:
    """``iterations`` minimal samples of ``m`` distinct indices below ``n`` (deterministic for a seed):
    drawn with replacement, the rows with a repeated index redrawn."""
    rng = np.random.default_rng(seed)
    samples = rng.integers(0, max(n, 1), (iterations, m))
    if m > 1 and n >= m:
        for _ in range(100):
            srt = np.sort(samples, axis=1)
            bad = (srt[:, 1:] == srt[:, :-1]).any(axis=1)
            if not bad.any():
                break
            samples[bad] = rng.integers(0, n, (int(bad.sum()), m))
    return samples


def ransac_fit(
    t: np.ndarray,
    y: np.ndarray,
    degree: int = 2,
    iterations: int = 200,
    inlier_px: float = 3.0,
    seed: int = 0,
    scale_of: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC polynomial fit; returns (coefficients, inlier weights 0/1). The minimal samples are
    scored by :func:`_ransac_kernel`; then least squares on the best consensus set, re-selected once.
    ``scale_of`` (optional, one per point) measures the residuals in other units, as
    :func:`irls_fit`'s: a point is an inlier within ``inlier_px`` of those, and the least squares
    weigh each point's square by ``scale_of**2``."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    n = t.size
    m = degree + 1
    ks = np.ones(n) if scale_of is None else np.asarray(scale_of, dtype=np.float64)
    tol = np.ascontiguousarray(inlier_px / ks)
    A = _design(t, degree)
    best_in = (
        _ransac_kernel(t, y, ransac_samples(n, m, iterations, seed), tol) if n >= m else np.zeros(n, bool)
    )
    if best_in.sum() < m:
        best_in = np.ones(n, bool)
    coef, *_ = np.linalg.lstsq(A[best_in] * ks[best_in, None], y[best_in] * ks[best_in], rcond=None)
    inl = np.abs(A @ coef - y) <= tol
    if inl.sum() >= m:
        coef, *_ = np.linalg.lstsq(A[inl] * ks[inl, None], y[inl] * ks[inl], rcond=None)
    return coef, inl.astype(np.float64)


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
