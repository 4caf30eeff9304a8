"""``road.vdisparity`` and ``road.profile``: the v-disparity road profile and the camera pose.

Method (the paper's section on IPM, after Fan et al.'s road-surface papers):

1. v-disparity: a histogram of the disparities of each image row (``H x D``, bins of ``bin_size``
   pixels; invalid ``<= 0`` and ``>= max_disparity`` disparities are left out).
2. Dynamic programming: the best path through the accumulator, one disparity bin per row from the
   bottom row up, disparity non-increasing upwards by at most ``max_step`` bins per row, maximising
   the accumulated support minus ``smoothness * step**2`` (a convex step cost, so that an evenly
   slanted road line beats an obstacle's vertical segment followed by a jump).
3. Each row's disparity is refined to sub-bin accuracy (mean of the row's disparities within
   ``refine_radius_px`` of the path) and a line ``d = a0 + a1 v`` is fitted robustly (RANSAC over
   rows weighted by their support, then least squares on the inliers).
4. Roll: the road pixels (within ``roll_tolerance_px`` of the profile) are fitted with a plane
   ``d = b0 + b1 u + b2 v`` (re-selecting the pixels near the plane a few times);
   ``roll = atan(b1 fy / (b2 f))``. The disparity map is rotated by the roll about the principal
   point (each pixel is accumulated at its roll-corrected row ``v'``, see :mod:`.geometry`) and
   steps 1-3 are run again.
5. Pitch and height from the final line (see :mod:`.geometry`, eq. 3)::

       pitch = arctan((cy + a0/a1) / fy),   height = f B cos(pitch) / (fy a1).

Each pass first compacts its pixels into a list (row in the pass, disparity; every
``column_step``-th column, the first pass every ``first_pass_column_step``-th: a row's road
disparity stays an average over many pixels) and the v-disparity and the row refinements loop over that list; counts are
scaled back to full-resolution pixels. The roll plane samples every ``roll_subsample``-th row and
column. ``road.vdisparity`` counts every column.
"""

from __future__ import annotations

import functools
import math
from typing import Literal

import numpy as np
from pydantic import Field

from lanegraph import InputError, NodeParams, Port, node_type
from lanegraph._numba import jit
from lanegraph.types import Calibration, RoadModel

from . import geometry

# --------------------------------------------------------------------------- kernels


@jit
def _dp_path_kernel(score, max_step, smoothness):
    """Best non-increasing-upwards path: ``path[v]`` is a bin per row, ``path[v] <= path[v+1] <=
    path[v] + max_step``; maximises ``sum score[v, path[v]] - smoothness * sum step**2``.
    Keeps one row of accumulated scores and the chosen step (uint8, ``max_step <= 255``) per cell."""
    H, D = score.shape
    pen = np.empty(max_step + 1, np.float64)
    for step in range(max_step + 1):
        pen[step] = smoothness * step * step
    prev = np.empty(D, np.float64)
    cur = np.empty(D, np.float64)
    back = np.zeros((H, D), np.uint8)
    for k in range(D):
        prev[k] = score[H - 1, k]
    for v in range(H - 2, -1, -1):
        for k in range(D):
            best = -1e300
            arg = 0
            hi = min(D, k + max_step + 1)
            for j in range(k, hi):
                val = prev[j] - pen[j - k]
                if val > best:
                    best = val
                    arg = j - k
            cur[k] = score[v, k] + best
            back[v, k] = arg
        prev, cur = cur, prev
    path = np.zeros(H, np.int32)
    k = 0
    best = -1e300
    for j in range(D):
        if prev[j] > best:
            best = prev[j]
            k = j
    path[0] = k
    for v in range(1, H):
        path[v] = path[v - 1] + back[v - 1, path[v - 1]]
    return path


@jit
def _select_kernel(disp, step, band_k, b0, b1, b2, cx, cy, s, c, out_rows, out_d):
    """The pixels of a profile pass, compacted: those with ``d > 0`` and, when ``band_k > 0``, within
    the band ``|d - (b0 + b1 u + b2 v)| <= band_k d`` of the road plane (disparity space; ``band_k`` is
    the band in metres over the camera height, eq. 4), whose roll-corrected row
    ``v' = cy + s (u - cx) + c (v - cy)``, rounded to the nearest row, lies in ``[0, H)``. Writes each
    one's row and disparity into ``out_rows`` / ``out_d`` in row-major order; returns their number.
    Only every ``step``-th column (from column 0) is looked at. The v-disparity and the row
    refinements then loop over this list, not over the image."""
    H, W = disp.shape
    n = 0
    for v in range(H):
        for u in range(0, W, step):
            d = disp[v, u]
            if not d > 0.0:
                continue
            if band_k > 0.0 and abs(d - (b0 + b1 * u + b2 * v)) > band_k * d:
                continue
            r = int(math.floor(cy + s * (u - cx) + c * (v - cy) + 0.5))
            if r < 0 or r >= H:
                continue
            out_rows[n] = r
            out_d[n] = d
            n += 1
    return n


def select_pixels(
    disp: np.ndarray,
    cx: float,
    cy: float,
    s: float,
    c: float,
    band: tuple[float, float, float, float] | None = None,
    step: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_select_kernel` into new arrays: ``(rows, disparities)`` of the selected pixels of
    every ``step``-th column; ``band = (band_k, b0, b1, b2)`` or None for every valid pixel. Rows are int16 (half the memory
    traffic of int32) unless the image has too many rows for it."""
    cap = disp.shape[0] * -(-disp.shape[1] // step)
    rows = np.empty(cap, np.int16 if disp.shape[0] < 32767 else np.int32)
    d = np.empty(cap, np.float32)
    k, b0, b1, b2 = band if band is not None else (0.0, 0.0, 0.0, 0.0)
    n = _select_kernel(disp, int(step), float(k), float(b0), float(b1), float(b2), float(cx), float(cy), float(s), float(c), rows, d)
    return rows[:n], d[:n]


@jit
def _vdisparity_kernel(rows, d, H, n_bins, bin_size, max_disp):
    """The ``H x n_bins`` v-disparity of selected pixels (:func:`_select_kernel`): count per (row,
    bin) those with ``d < max_disp``. The bins are computed in a first loop; the counts go to four
    interleaved partial histograms (neighbouring pixels mostly hit the same cell: one histogram
    would make every increment wait for the previous one), added at the end."""
    n = rows.size
    k = np.empty(n, np.int32)
    for i in range(n):
        di = d[i]
        # bin n_bins collects the left-out disparities (>= max_disp or beyond the last bin)
        k[i] = min(int(di / bin_size), n_bins) if di < max_disp else n_bins
    part = np.zeros((4, H, n_bins + 1), np.int32)
    for i in range(n):
        part[i & 3, rows[i], k[i]] += 1
    out = np.empty((H, n_bins), np.float32)
    for r in range(H):
        for j in range(n_bins):
            out[r, j] = part[0, r, j] + part[1, r, j] + part[2, r, j] + part[3, r, j]
    return out


@jit
def _row_refine_kernel(rows, d, centre, radius):
    """Per row, the sum and the count of the selected pixels' disparities (:func:`_select_kernel`)
    within ``radius[row]`` of ``centre[row]``."""
    H = centre.size
    N = rows.size
    total = np.zeros(H, np.float64)
    count = np.zeros(H, np.float64)
    # a run of pixels of one row (they come in image-row order) is summed in registers, in two
    # interleaved accumulators (one floating-point sum would make every addition wait for the last)
    i = 0
    while i < N:
        r = rows[i]
        c = centre[r]
        rad = radius[r]
        t0 = 0.0
        t1 = 0.0
        n0 = 0
        n1 = 0
        j = i
        while j + 1 < N and rows[j] == r and rows[j + 1] == r:
            d0 = d[j]
            d1 = d[j + 1]
            if abs(d0 - c) <= rad:
                t0 += d0
                n0 += 1
            if abs(d1 - c) <= rad:
                t1 += d1
                n1 += 1
            j += 2
        if j < N and rows[j] == r:  # the run's last pixel, when its length is odd
            dj = d[j]
            if abs(dj - c) <= rad:
                t0 += dj
                n0 += 1
            j += 1
        total[r] += t0 + t1
        count[r] += n0 + n1
        i = j
    return total, count


@jit
def _plane_sums_kernel(disp, step, v_top, min_disp, b0, b1, b2, fixed_tol, plane_tol, height, min_tol, uc, vc):
    """One selection round of the roll plane over every ``step``-th row and column from row 0 and
    column 0: the pixels with ``d > min_disp``, ``v >= v_top`` and ``|d - (b0 + b1 u + b2 v)| < tol``,
    ``tol = fixed_tol`` when it is > 0 else ``max(plane_tol * d / height, min_tol)``. Returns the sums
    of the least-squares normal equations of ``d = a + b1 (u - uc) + b2 (v - vc)``: ``(n, S)`` with
    ``S = [Su, Sv, Suu, Suv, Svv, Sd, Sud, Svd]`` over the centred ``u - uc``, ``v - vc``."""
    H, W = disp.shape
    n = 0
    su = 0.0
    sv = 0.0
    suu = 0.0
    suv = 0.0
    svv = 0.0
    sd = 0.0
    sud = 0.0
    svd = 0.0
    for v in range(0, H, step):
        if v < v_top:
            continue
        fv = float(v)
        for u in range(0, W, step):
            d = float(disp[v, u])
            if not d > min_disp:
                continue
            fu = float(u)
            if fixed_tol > 0.0:
                tol = fixed_tol
            else:
                tol = plane_tol * d / height
                if tol < min_tol:
                    tol = min_tol
            if abs(d - (b0 + b1 * fu + b2 * fv)) < tol:
                x = fu - uc
                y = fv - vc
                n += 1
                su += x
                sv += y
                suu += x * x
                suv += x * y
                svv += y * y
                sd += d
                sud += x * d
                svd += y * d
    out = np.empty(8, np.float64)
    out[0] = su
    out[1] = sv
    out[2] = suu
    out[3] = suv
    out[4] = svv
    out[5] = sd
    out[6] = sud
    out[7] = svd
    return n, out


@jit
def _ransac_line_kernel(v, d, w, i, j, tol):
    """Score the lines through the point pairs ``(i[k], j[k])`` (pairs with ``v[i] == v[j]`` or a slope
    ``<= 0`` are skipped): the weight ``w`` of the points within ``tol``. Returns ``(found, inliers
    of the first best line)``."""
    n = v.size
    best_score = -1.0
    best_a0 = 0.0
    best_a1 = 0.0
    found = False
    for k in range(i.size):
        vi = v[i[k]]
        vj = v[j[k]]
        if vi == vj:
            continue
        a1 = (d[i[k]] - d[j[k]]) / (vi - vj)
        if not a1 > 0:
            continue
        a0 = d[i[k]] - a1 * vi
        score = 0.0
        for p in range(n):
            if abs(d[p] - (a0 + a1 * v[p])) < tol:
                score += w[p]
        if score > best_score:
            best_score = score
            best_a0 = a0
            best_a1 = a1
            found = True
    inl = np.zeros(n, np.bool_)
    if found:
        for p in range(n):
            inl[p] = abs(d[p] - (best_a0 + best_a1 * v[p])) < tol
    return found, inl


@jit
def _line_refit_kernel(v, d, w, inl, tol, rounds):
    """Weighted least-squares line ``d = a0 + a1 v`` over the inliers ``inl``, then the points within
    ``tol`` of it become the inliers, repeated up to ``rounds`` times (until the inliers repeat or
    fewer than two remain). The line in closed form about the weighted mean. Returns ``(ok, a0, a1,
    inliers)``: ok False when no line could be fitted (then ``inliers`` are the last ones)."""
    n = v.size
    inl = inl.copy()
    new = np.empty(n, np.bool_)
    ok = False
    a0 = 0.0
    a1 = 0.0
    for _ in range(rounds):
        sw = 0.0
        swv = 0.0
        swd = 0.0
        k = 0
        for i in range(n):
            if inl[i] and w[i] > 0.0:
                sw += w[i]
                swv += w[i] * v[i]
                swd += w[i] * d[i]
                k += 1
        if k < 2:
            break
        mv = swv / sw
        md = swd / sw
        var = 0.0
        cov = 0.0
        for i in range(n):
            if inl[i]:
                dv = v[i] - mv
                var += w[i] * dv * dv
                cov += w[i] * dv * (d[i] - md)
        if not var > 0.0:
            break
        b1 = cov / var
        b0 = md - b1 * mv
        if not (math.isfinite(b0) and math.isfinite(b1)):
            break
        a0 = b0
        a1 = b1
        ok = True
        m = 0
        same = True
        for i in range(n):
            new[i] = abs(d[i] - (a0 + a1 * v[i])) < tol
            m += new[i]
            same = same and new[i] == inl[i]
        if m < 2 or same:
            break
        inl[:] = new
    return ok, a0, a1, inl


# --------------------------------------------------------------------------- helpers


class RoadInputError(InputError, ValueError):
    """An input of a road node is not what its port promises: lanegraph's own :class:`InputError`
    (so the executor reports it like any bad input) that stays a ``ValueError`` for Python callers."""


def as_disparity(disparity: np.ndarray, node: str = "road") -> np.ndarray:
    """Validate a disparity map and return it as C-contiguous float32 with non-finite values set to 0."""
    disparity = np.asarray(disparity)
    if disparity.ndim != 2 or disparity.shape[0] < 1 or disparity.shape[1] < 1 or disparity.dtype.kind not in "biuf":
        raise RoadInputError(
            f"{node}: disparity: expected a non-empty HxW array of numbers, "
            f"got shape {disparity.shape} of dtype {disparity.dtype}"
        )
    d = np.ascontiguousarray(disparity, dtype=np.float32)
    if not np.isfinite(d).all():
        d = np.where(np.isfinite(d), d, 0.0).astype(np.float32)
    return d


def n_bins(max_disparity: float, bin_size: float) -> int:
    return max(1, int(math.ceil(max_disparity / bin_size)))


def compute_vdisparity(
    disp: np.ndarray, max_disparity: float, bin_size: float, roll: float = 0.0, calib: Calibration | None = None
) -> np.ndarray:
    """``H x D`` v-disparity of a validated disparity map, optionally in roll-corrected rows."""
    if roll != 0.0 and calib is None:
        raise ValueError("a roll needs the calibration (principal point)")
    s, c = geometry.roll_row_coeffs(roll, calib) if calib is not None else (0.0, 1.0)
    cx, cy = (calib.cx, calib.cy) if calib is not None else (0.0, 0.0)
    rows, d = select_pixels(disp, cx, cy, s, c)
    return _vdisparity_kernel(rows, d, disp.shape[0], n_bins(max_disparity, bin_size), float(bin_size), float(max_disparity))


# --------------------------------------------------------------------------- road.vdisparity


class VDisparityParams(NodeParams):
    """Params of ``road.vdisparity``."""

    max_disparity: float = Field(
        128.0, gt=0.0, le=1024.0, description="disparities >= this are left out, pixels; D = ceil(max / bin)"
    )
    bin_size: float = Field(1.0, gt=0.0, le=16.0, description="width of a disparity bin, pixels")


@node_type(
    "road.vdisparity",
    inputs={"disparity": Port("disparity", "left disparity map")},
    outputs={"vdisparity": Port("vdisparity", "H x D count of disparities per row")},
)
def road_vdisparity(params: VDisparityParams, disparity: np.ndarray) -> dict:
    """The v-disparity image: per image row, a histogram of its valid disparities (H x D float32)."""
    disp = as_disparity(disparity, "road.vdisparity")
    return {"vdisparity": compute_vdisparity(disp, params.max_disparity, params.bin_size)}


# --------------------------------------------------------------------------- road.profile


class ProfileParams(NodeParams):
    """Params of ``road.profile``."""

    max_disparity: float = Field(128.0, gt=0.0, le=1024.0, description="v-disparity range, pixels")
    bin_size: float = Field(1.0, gt=0.0, le=16.0, description="v-disparity bin width, pixels")
    smoothness: float = Field(
        0.02,
        ge=0.0,
        le=100.0,
        description="DP cost of a step of k bins between rows: smoothness * k**2, in units of a full "
        "image row of support (the score is the count divided by the image width)",
    )
    max_step: int = Field(3, ge=1, le=64, description="largest disparity decrease between rows, bins")
    refine_radius_px: float = Field(
        1.0,
        gt=0.0,
        le=16.0,
        description="sub-bin refinement: a row's disparities within this of the path, pixels",
    )
    model: Literal["linear", "quadratic"] = Field(
        "linear", description="road profile d(v): linear (flat road) or quadratic; pose always from the line"
    )
    fit_tolerance_px: float = Field(1.0, gt=0.0, le=16.0, description="RANSAC inlier tolerance, pixels")
    ransac_iterations: int = Field(300, ge=1, le=100000, description="RANSAC samples (fixed seed)")
    column_step: int = Field(
        4,
        ge=1,
        le=16,
        description="the profile passes look at every n-th column (a row's mean road disparity is an "
        "average over a hundred or more pixels at 4 on KITTI; the pose moves by < 0.005 deg and < 0.1 cm "
        "from 2 to 4 on the synthetic scenes); counts are scaled back to full-resolution pixels",
    )
    first_pass_column_step: int = Field(
        8,
        ge=1,
        le=16,
        description="the first pass (which only seeds the road plane, the roll and the road band of the "
        "second) looks at every n-th column",
    )
    min_row_count: int = Field(
        10, ge=1, le=100000, description="rows with fewer path pixels are left out of the fit, pixels"
    )
    min_fit_disparity_px: float = Field(
        3.0, ge=0.0, le=1024.0, description="rows whose path disparity is below this are left out, pixels"
    )
    min_fit_rows: int = Field(10, ge=2, le=100000, description="fewer inlier rows make the model invalid")
    estimate_roll: bool = Field(
        True, description="estimate the roll and redo the profile in roll-corrected rows"
    )
    roll_tolerance_px: float = Field(
        1.0,
        gt=0.0,
        le=16.0,
        description="road pixels for the roll plane: within this of the profile/plane, pixels",
    )
    road_band_m: float = Field(
        1.0,
        ge=0.0,
        le=100.0,
        description="pass 2 keeps only pixels within this height of the pass-1 road plane, metres; 0 = off",
    )
    plane_tolerance_m: float = Field(
        0.05,
        gt=0.0,
        le=10.0,
        description="pass 2 row refinement and roll-plane re-selection keep disparities within this height "
        "of the road, metres",
    )
    min_plane_tolerance_px: float = Field(
        0.25, gt=0.0, le=16.0, description="floor of the metric tolerance above (far-away noise), pixels"
    )
    roll_iterations: int = Field(3, ge=1, le=20, description="plane fit / pixel re-selection rounds")
    roll_subsample: int = Field(
        4, ge=1, le=16, description="use every n-th row and column for the roll plane"
    )
    max_abs_roll_deg: float = Field(
        10.0, gt=0.0, le=45.0, description="a larger roll estimate is discarded (roll 0 is used), degrees"
    )
    min_height_m: float = Field(
        0.2, gt=0.0, le=100.0, description="a smaller height estimate is invalid, metres"
    )
    max_height_m: float = Field(
        6.0, gt=0.0, le=100.0, description="a larger height estimate is invalid, metres"
    )


@functools.lru_cache(maxsize=512)
def _sample_pairs(n: int, iterations: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The RANSAC pairs ``(i, j)`` among ``n`` points: a generator seeded with ``seed`` draws them,
    so a frame's samples do not depend on earlier frames. Cached by ``n`` (a frame's profile has
    a few hundred rows, so the same few counts recur): seeding a generator and drawing took 0.08 ms
    per fit. Read-only: shared by every call with the same arguments."""
    rng = np.random.default_rng(seed)
    i = rng.integers(0, n, iterations)
    j = rng.integers(0, n, iterations)
    i.flags.writeable = False
    j.flags.writeable = False
    return i, j


def _ransac_line(
    v: np.ndarray, d: np.ndarray, w: np.ndarray, tol: float, iterations: int, seed: int = 0
) -> np.ndarray | None:
    """Robust line ``d = a0 + a1 v`` (a1 > 0) over weighted points: inlier mask, or None."""
    n = v.size
    if n < 2:
        return None
    i, j = _sample_pairs(n, int(iterations), int(seed))
    found, inl = _ransac_line_kernel(
        np.ascontiguousarray(v, dtype=np.float64),
        np.ascontiguousarray(d, dtype=np.float64),
        np.ascontiguousarray(w, dtype=np.float64),
        i,
        j,
        float(tol),
    )
    return inl if found else None


def _weighted_polyfit(v: np.ndarray, d: np.ndarray, w: np.ndarray, deg: int) -> np.ndarray | None:
    """Weighted least squares, coefficients lowest power first (a line in closed form, about the
    weighted mean: no SVD for two unknowns)."""
    if np.count_nonzero(w > 0) < deg + 1:
        return None
    if deg == 1:
        sw = w.sum()
        mv = (w * v).sum() / sw
        md = (w * d).sum() / sw
        dv = v - mv
        var = (w * dv * dv).sum()
        if not var > 0:
            return None
        a1 = (w * dv * (d - md)).sum() / var
        coef = np.array([md - a1 * mv, a1])
        return coef if np.all(np.isfinite(coef)) else None
    A = np.stack([v**k for k in range(deg + 1)], axis=1)
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(A * sw[:, None], d * sw, rcond=None)
    return coef if np.all(np.isfinite(coef)) else None


def _robust_fit(v, d, w, deg, tol, iterations, init: np.ndarray | None):
    """RANSAC (for the line) then least squares with inlier re-selection (four rounds at most).
    Returns (coef, inliers)."""
    inl = init if init is not None else _ransac_line(v, d, w, tol, iterations)
    if inl is None or np.count_nonzero(inl) < deg + 1:
        return None, None
    if deg == 1:
        ok, a0, a1, inl = _line_refit_kernel(
            np.ascontiguousarray(v, dtype=np.float64), np.ascontiguousarray(d, dtype=np.float64),
            np.ascontiguousarray(w, dtype=np.float64), np.ascontiguousarray(inl, dtype=np.bool_), float(tol), 4,
        )
        return (np.array([a0, a1]), inl) if ok else (None, inl)
    return _robust_refit_np(v, d, w, deg, tol, inl)


def _robust_refit_np(v, d, w, deg, tol, inl):
    """The least-squares rounds of :func:`_robust_fit` in NumPy (any degree; the reference of
    :func:`_line_refit_kernel`)."""
    coef = None
    for _ in range(4):
        c = _weighted_polyfit(v[inl], d[inl], w[inl], deg)
        if c is None:
            break
        coef = c
        new = np.abs(d - np.polynomial.polynomial.polyval(v, coef)) < tol
        if np.count_nonzero(new) < deg + 1 or np.array_equal(new, inl):
            break
        inl = new
    return coef, inl


def _profile_pass(
    H: int, W: int, pixels, vd, params: ProfileParams, height: float | None = None, vd_columns: int | None = None, step: int | None = None
):
    """DP + refinement + robust fit in (roll-corrected) rows over the pass's ``pixels`` (``(rows,
    disparities)`` from :func:`select_pixels`, every ``step``-th column, default ``column_step``) of
    an ``H x W`` disparity map; ``vd`` counts the pixels of ``vd_columns`` columns (default: the
    sampled ones).

    With a ``height`` estimate (pass 2) the row disparities are refined once more, keeping only the
    disparities within ``plane_tolerance_m`` (metric, eq. 4) of the first mean, so that a kerb or
    a low object next to the road does not pull the far rows.

    Returns ``((line, coef), profile, inlier_rows)``, coefficients lowest power first; the first
    item is None when there is no fit.
    """
    step = int(step or params.column_step)
    # the rows above the first one with any support (the sky, or the rows the disparity was not
    # computed for) add nothing: the DP runs from that row down and the path stays level above it
    # (and the bins above the largest disparity seen hold no support either: left out)
    vd = np.asarray(vd)
    supported = np.flatnonzero(vd.any(axis=1))
    v0 = int(supported[0]) if supported.size else 0
    bins = np.flatnonzero(vd[v0:].any(axis=0))
    d_hi = int(bins[-1]) + 1 if bins.size else vd.shape[1]
    score = vd[v0:, :d_hi].astype(np.float64) / float(vd_columns or -(-W // step))  # support per column
    path = np.empty(H, np.int32)
    path[v0:] = _dp_path_kernel(score, int(params.max_step), float(params.smoothness))
    path[:v0] = path[v0]
    centre = (path.astype(np.float64) + 0.5) * params.bin_size
    radius = np.full(H, max(params.refine_radius_px, 0.5 * params.bin_size))
    total, count = _row_refine_kernel(*pixels, centre, radius)
    if height is not None and height > 0:
        for _ in range(2):
            ok = count > 0
            centre = np.where(ok, total / np.maximum(count, 1.0), centre)
            radius = np.maximum(params.plane_tolerance_m * centre / height, params.min_plane_tolerance_px)
            total, count = _row_refine_kernel(*pixels, centre, radius)
    profile = np.full(H, -1.0, np.float32)
    have = count * step >= params.min_row_count  # full-resolution pixels
    profile[have] = (total[have] / count[have]).astype(np.float32)
    use = have & (profile >= params.min_fit_disparity_px)
    rows = np.flatnonzero(use).astype(np.float64)
    if rows.size < params.min_fit_rows:
        return None, profile, None
    dv, wv = profile[use].astype(np.float64), count[use]
    line, inl = _robust_fit(rows, dv, wv, 1, params.fit_tolerance_px, params.ransac_iterations, None)
    if line is None or np.count_nonzero(inl) < params.min_fit_rows or not line[1] > 0:
        return None, profile, None
    coef = line
    if params.model == "quadratic":
        quad, _ = _robust_fit(rows, dv, wv, 2, params.fit_tolerance_px, 0, inl)
        if quad is not None:
            coef = quad
    return (line, coef), profile, rows[inl].astype(int)


def _fit_road_plane(disp, line, v_top: int, params: ProfileParams, calib: Calibration) -> np.ndarray | None:
    """The road plane ``d = b0 + b1 u + b2 v`` (disparity space) fitted over the pixels within
    ``roll_tolerance_px`` of the profile line, then re-fitted ``roll_iterations`` times over the
    pixels within ``plane_tolerance_m`` (metric, eq. 4) of the plane.

    Each round is one pass of :func:`_plane_sums_kernel` (selection and least-squares normal
    equations together, in coordinates centred on the image centre) and a 3 x 3 solve."""
    H, W = disp.shape
    st = int(params.roll_subsample)
    uc, vc = 0.5 * (W - 1), 0.5 * (H - 1)
    _, h1 = geometry.pose_from_line(float(line[0]), float(line[1]), calib)
    b = np.array([float(line[0]), 0.0, float(line[1])])
    fixed = float(params.roll_tolerance_px)  # the first round: within this of the profile line
    for _ in range(params.roll_iterations):  # at least one (the param's bound): b is then a fit
        n, S = _plane_sums_kernel(
            disp, st, int(v_top), float(params.min_fit_disparity_px), float(b[0]), float(b[1]), float(b[2]),
            fixed, float(params.plane_tolerance_m), float(h1), float(params.min_plane_tolerance_px), uc, vc,
        )
        if n < 50:
            return None
        su, sv, suu, suv, svv, sd, sud, svd = S
        M = np.array([[n, su, sv], [su, suu, suv], [sv, suv, svv]], np.float64)
        try:  # a direct solve: lstsq's SVD took 0.05 ms per round
            a, b1, b2 = np.linalg.solve(M, np.array([sd, sud, svd]))
        except np.linalg.LinAlgError:  # every selected pixel on one row or column: no plane
            return None
        b = np.array([a - b1 * uc - b2 * vc, b1, b2])
        if not np.all(np.isfinite(b)):
            return None
        fixed = 0.0  # later rounds: the metric tolerance around the plane
    if not b[2] > 0:
        return None
    return b


def _invalid(profile: np.ndarray | None, roll: float = 0.0) -> RoadModel:
    return RoadModel(
        a0=0.0, a1=0.0, a2=0.0, roll=roll, pitch=0.0, height=0.0, v_min=0, valid=False, profile=profile
    )


def estimate_road(
    params: ProfileParams, disparity: np.ndarray, calib: Calibration, vdisparity: np.ndarray | None = None
) -> tuple[RoadModel, np.ndarray]:
    """The work of ``road.profile``: ``(road model, v-disparity used in the final pass)``.

    Pass 1 runs on the whole v-disparity (or the one given). Its line gives a first road plane
    (with the roll when ``estimate_roll``); pass 2 accumulates, in roll-corrected rows, only the
    pixels within ``road_band_m`` of that plane, so that walls, trees and the upper part of
    vehicles no longer compete with the far road in the DP.
    """
    disp = as_disparity(disparity, "road.profile")
    H, W = disp.shape
    D = n_bins(params.max_disparity, params.bin_size)
    cx, cy = float(calib.cx), float(calib.cy)
    # pass 1: every pixel in its own row (no roll: v' = v)
    s, c = geometry.roll_row_coeffs(0.0, calib)
    step1 = int(params.first_pass_column_step)
    pixels = select_pixels(disp, cx, cy, s, c, step=step1)
    if vdisparity is not None:
        vd = np.asarray(vdisparity, dtype=np.float32)
        if vd.shape != (H, D):
            raise RoadInputError(
                f"road.profile: vdisparity: expected shape {(H, D)} (rows of the disparity x ceil(max_disparity / bin_size)), "
                f"got {vd.shape} (hint: give road.vdisparity the same max_disparity and bin_size)"
            )
    else:
        vd = _vdisparity_kernel(*pixels, H, D, float(params.bin_size), float(params.max_disparity))

    fit, profile, inl = _profile_pass(H, W, pixels, vd, params, vd_columns=W if vdisparity is not None else None, step=step1)
    if fit is None:
        return _invalid(profile), vd
    line = fit[0]
    roll = 0.0
    plane = np.array([line[0], 0.0, line[1]])
    if params.estimate_roll:
        b = _fit_road_plane(disp, line, int(inl.min()), params, calib)
        if b is not None:
            est = geometry.roll_from_plane(float(b[1]), float(b[2]), calib)
            if abs(est) <= math.radians(params.max_abs_roll_deg):
                roll, plane = est, b
    _, h1 = geometry.pose_from_line(float(line[0]), float(line[1]), calib)
    # pass 2: only the pixels within road_band_m of that plane, in roll-corrected rows
    band = (params.road_band_m / h1, *plane) if params.road_band_m > 0 else None
    s, c = geometry.roll_row_coeffs(roll, calib)
    pixels = select_pixels(disp, cx, cy, s, c, band, step=params.column_step)
    vd = _vdisparity_kernel(*pixels, H, D, float(params.bin_size), float(params.max_disparity))
    fit, profile, inl = _profile_pass(H, W, pixels, vd, params, h1)
    if fit is None:
        return _invalid(profile, roll), vd
    line, coef = fit
    pitch, height = geometry.pose_from_line(float(line[0]), float(line[1]), calib)
    valid = params.min_height_m <= height <= params.max_height_m and math.isfinite(pitch)
    road = RoadModel(
        a0=float(coef[0]),
        a1=float(coef[1]),
        a2=float(coef[2]) if coef.size > 2 else 0.0,
        roll=float(roll),
        pitch=float(pitch),
        height=float(height),
        v_min=int(inl.min()),
        valid=bool(valid),
        profile=profile,
    )
    return road, vd


@node_type(
    "road.profile",
    inputs={
        "disparity": Port("disparity", "left disparity map"),
        "calib": Port("calibration", "stereo calibration", rate="constant"),
        "vdisparity": Port(
            "vdisparity", "a precomputed v-disparity (same max_disparity / bin_size)", optional=True
        ),
    },
    outputs={
        "road": Port("road_model", "road profile and camera pitch, roll, height"),
        "vdisparity": Port("vdisparity", "the v-disparity of the final pass (roll-corrected rows)"),
    },
)
def road_profile(params: ProfileParams, disparity: np.ndarray, calib: Calibration, vdisparity=None) -> dict:
    """Road profile by dynamic programming on the v-disparity, roll from the road plane, then pitch
    and camera height from the roll-corrected profile (``RoadModel.valid`` False when no road)."""
    road, vd = estimate_road(params, disparity, calib, vdisparity)
    return {"road": road, "vdisparity": vd}
