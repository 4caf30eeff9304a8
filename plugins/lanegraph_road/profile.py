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

import math
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from lanegraph import NodeParams, Port, jit, node_type
from lanegraph.types import Calibration, RoadModel

from . import geometry
from ._line_fit import (  # noqa: F401 - the kernels' and tests' names in this module
    _line_fit,
    _line_refit_kernel,
    _ransac_line_kernel,
    _robust_fit,
    _robust_refit_np,
    _sample_pairs,
    _weighted_polyfit,
)
from ._plane import _fit_road_plane, _plane_fit_kernel, _plane_points, _plane_sums  # noqa: F401
from .vdisparity import (  # noqa: F401 - road.vdisparity's names, as they were here
    MAX_BINS,
    RoadInputError,
    VDisparityParams,
    _select,
    _select_kernel,
    bins_bounded,
    checked_disparity,
    compute_vdisparity,
    n_bins,
    road_vdisparity,
    select_and_count,
    select_pixels,
)

# --------------------------------------------------------------------------- kernels


@jit
def _dp_path_kernel(score, max_step, smoothness):
    """Best non-increasing-upwards path: ``path[v]`` is a bin per row, ``path[v] <= path[v+1] <=
    path[v] + max_step``; maximises ``sum score[v, path[v]] - smoothness * sum step**2``.
    Keeps one row of accumulated scores and the chosen step (uint8, ``max_step <= 255``) per cell.
    A row's best predecessors are found one step at a time over every bin (steps in increasing
    order, the first best kept: the smallest step on a tie), a loop over bins that the compiler
    vectorises."""
    H, D = score.shape
    prev = np.empty(D, np.float64)
    cur = np.empty(D, np.float64)
    best = np.empty(D, np.float64)
    arg = np.empty(D, np.uint8)
    back = np.empty((H, D), np.uint8)  # every row but the last is written below (no np.zeros: one
    # function less to compile)
    for k in range(D):
        prev[k] = score[H - 1, k]
    for v in range(H - 2, -1, -1):
        for k in range(D):
            best[k] = -1e300
            arg[k] = 0
        for step in range(min(max_step, D - 1) + 1):
            pen = smoothness * step * step
            for k in range(D - step):
                val = prev[k + step] - pen
                better = val > best[k]
                best[k] = val if better else best[k]
                arg[k] = step if better else arg[k]
        for k in range(D):
            cur[k] = score[v, k] + best[k]
            back[v, k] = arg[k]
        prev, cur = cur, prev
    path = np.empty(H, np.int32)
    k = 0
    top = -1e300
    for j in range(D):
        if prev[j] > top:
            top = prev[j]
            k = j
    path[0] = k
    for v in range(1, H):
        path[v] = path[v - 1] + back[v - 1, path[v - 1]]
    return path


@jit
def _row_runs(rows):
    """The runs of equal rows in a pixel list (:func:`_select_kernel`): ``starts`` (int64, the run
    ``q`` is ``starts[q]:starts[q + 1]``) and the number of runs."""
    N = rows.size
    starts = np.empty(N + 1, np.int64)
    nr = 0
    for i in range(N):
        if i == 0 or rows[i] != rows[i - 1]:
            starts[nr] = i
            nr += 1
    starts[nr] = N
    return starts, nr


#: disparities that are multiples of 1/256 (KITTI's PNGs; OpenCV's 1/16 pixels) below 2**23 are
#: refined as integers in 1/256 pixels
_FIXED = 256.0


@jit
def _fixed_point(d):
    """``(True, d * 256 as int32)`` when every disparity is a multiple of 1/256 below 2**23 pixels,
    else ``(False, empty)``. One pass (vectorised); the values are exactly ``dq / 256``."""
    ok = True
    for j in range(d.size):
        q = np.float64(d[j]) * _FIXED
        ok = ok & (q == math.floor(q)) & (abs(q) < 2.0**31)
    if not ok:
        return False, np.empty(0, np.int32)
    dq = np.empty(d.size, np.int32)
    for j in range(d.size):
        dq[j] = np.int32(np.float64(d[j]) * _FIXED)
    return True, dq


@jit
def _refine(rows, d, fixed, dq, starts, nr, centre, radius, total, count):
    """Per row ``v``, the sum ``total[v]`` and the count ``count[v]`` (float64, ``H``) of the selected
    pixels' disparities (:func:`_select_kernel`, in runs of one row: :func:`_row_runs`) within
    ``radius[v]`` of ``centre[v]``.

    With ``fixed`` (:func:`_fixed_point`) on the fixed-point disparities ``dq``: each pixel's
    disparity ``dq / 256`` is the float one exactly, and the sums of the ones within the radius are
    integers (exact in any order, so the loop over a run vectorises): the same totals and counts.
    Else on ``d``: a run of pixels of one row is summed in registers, in two interleaved accumulators
    (one floating-point sum would make every addition wait for the last); without branches (which
    pixel is in is unpredictable): adding 0.0 to a sum of positive disparities leaves it unchanged.
    One function for both (each was one more for numba to compile on the first run's path)."""
    H = centre.size
    for v in range(H):
        total[v] = 0.0
        count[v] = 0.0
    inv = 1.0 / _FIXED
    for q in range(nr):
        a = starts[q]
        b = starts[q + 1]
        r = rows[a]
        c = centre[r]
        rad = radius[r]
        if fixed:
            t = 0
            n = 0
            for j in range(a, b):
                x = dq[j]
                inside = abs(x * inv - c) <= rad
                t += x if inside else 0
                n += inside
            # t / 256 and the sums of such values are exact in float64 (far below 2**45): the
            # same totals as an integer sum per row divided once
            total[r] += t * inv
            count[r] += n
            continue
        t0 = 0.0
        t1 = 0.0
        n0 = 0
        n1 = 0
        e = a + ((b - a) // 2) * 2
        for j in range(a, e, 2):
            d0 = np.float64(d[j])
            d1 = np.float64(d[j + 1])
            in0 = abs(d0 - c) <= rad
            in1 = abs(d1 - c) <= rad
            t0 += d0 if in0 else 0.0
            t1 += d1 if in1 else 0.0
            n0 += in0
            n1 += in1
        if e < b:  # the run's last pixel, when its length is odd
            dj = np.float64(d[e])
            if abs(dj - c) <= rad:
                t0 += dj
                n0 += 1
        total[r] += t0 + t1
        count[r] += n0 + n1


@jit
def _row_refine_kernel(rows, d, centre, radius):
    """Per row, the sum and the count of the selected pixels' disparities (:func:`_select_kernel`)
    within ``radius[row]`` of ``centre[row]`` (in fixed point when the disparities allow it)."""
    starts, nr = _row_runs(rows)
    fixed, dq = _fixed_point(d)
    total = np.empty(centre.size, np.float64)
    count = np.empty(centre.size, np.float64)
    _refine(rows, d, fixed, dq, starts, nr, centre, radius, total, count)
    return total, count


@jit
def _profile_kernel(
    vd,
    columns,
    max_step,
    smoothness,
    bin_size,
    radius0,
    rows,
    d,
    height,
    plane_tol,
    min_tol,
    step,
    min_row_count,
    min_fit_disp,
):
    """Steps 2-3 of a pass up to the robust fit: DP path, row refinement, profile, fit rows.

    The rows above the first one with any support in the ``H x D`` v-disparity ``vd`` (the sky, or
    the rows the disparity was not computed for) add nothing: the DP (:func:`_dp_path_kernel`, score
    ``vd / columns``: support per column) runs from that row down and the path stays level above it;
    the bins above the largest one with support are left out too. A row's disparity is then the
    mean of its selected pixels (``rows``, ``d``: :func:`_select_kernel`) within ``radius0`` of the
    path's bin centre; with ``height > 0`` twice more within ``max(plane_tol * mean / height,
    min_tol)`` (metric, eq. 4) of the last mean (rows without pixels keep the bin centre).

    Returns ``(profile, fit_rows, fit_d, fit_w)``: the ``H`` row disparities (float32, -1 where the
    row has fewer than ``min_row_count`` full-resolution pixels: ``count * step``) and the rows whose
    disparity is ``>= min_fit_disp`` (a float32, compared in float32): row, disparity and pixel count
    (float64)."""
    H, D = vd.shape
    v0 = -1
    for v in range(H):  # a loop, not np.any(vd[v] != 0): an array expression compiles for seconds
        for k in range(D):
            if vd[v, k] != 0:
                v0 = v
                break
        if v0 >= 0:
            break
    v0 = max(v0, 0)
    last = -1
    for v in range(v0, H):
        for k in range(last + 1, D):
            if vd[v, k] != 0:
                last = k
    d_hi = last + 1 if last >= 0 else D
    score = np.empty((H - v0, d_hi), np.float64)
    for v in range(v0, H):
        for k in range(d_hi):
            score[v - v0, k] = np.float64(vd[v, k]) / columns
    sub = _dp_path_kernel(score, max_step, smoothness)
    centre = np.empty(H, np.float64)
    radius = np.empty(H, np.float64)
    for v in range(H):
        radius[v] = radius0
    for v in range(H):
        centre[v] = (np.float64(sub[max(v - v0, 0)]) + 0.5) * bin_size
    starts, nr = _row_runs(rows)  # the list is read three times in pass 2
    fixed, dq = _fixed_point(d)
    total = np.empty(H, np.float64)
    count = np.empty(H, np.float64)
    _refine(rows, d, fixed, dq, starts, nr, centre, radius, total, count)
    if height > 0.0:
        for _ in range(2):
            for v in range(H):
                if count[v] > 0:
                    centre[v] = total[v] / max(count[v], 1.0)
                radius[v] = max(plane_tol * centre[v] / height, min_tol)
            _refine(rows, d, fixed, dq, starts, nr, centre, radius, total, count)
    profile = np.empty(H, np.float32)
    use = np.empty(H, np.bool_)
    n = 0
    for v in range(H):
        profile[v] = -1.0
        use[v] = False
        if count[v] * step >= min_row_count:  # full-resolution pixels
            profile[v] = np.float32(total[v] / count[v])
            if profile[v] >= min_fit_disp:
                use[v] = True
                n += 1
    fit_rows = np.empty(n, np.float64)
    fit_d = np.empty(n, np.float64)
    fit_w = np.empty(n, np.float64)
    k = 0
    for v in range(H):
        if use[v]:
            fit_rows[k] = v
            fit_d[k] = profile[v]
            fit_w[k] = count[v]
            k += 1
    return profile, fit_rows, fit_d, fit_w


# --------------------------------------------------------------------------- road.profile


class ProfileParams(NodeParams):
    """Params of ``road.profile``."""

    max_disparity: float = Field(128.0, gt=0.0, le=1024.0, description="v-disparity range, pixels")
    bin_size: float = Field(
        1.0, ge=0.25, le=16.0, description="v-disparity bin width, pixels (>= 0.25; at most 1024 bins)"
    )
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
    ransac_iterations: int = Field(300, ge=1, le=10000, description="RANSAC samples (fixed seed)")
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

    @model_validator(mode="after")
    def _bins_bounded(self):
        return bins_bounded(self)


def _profile_pass(
    H: int,
    W: int,
    pixels,
    vd,
    params: ProfileParams,
    height: float | None = None,
    vd_columns: int | None = None,
    step: int | None = None,
    min_slope: float = 0.0,
):
    """DP + refinement + robust fit in (roll-corrected) rows over the pass's ``pixels`` (``(rows,
    disparities)`` from :func:`select_and_count`, every ``step``-th column, default ``column_step``)
    of an ``H x W`` disparity map; ``vd`` (C-contiguous float32) counts the pixels of ``vd_columns``
    columns (default: the sampled ones).

    With a ``height`` estimate (pass 2) the row disparities are refined once more, keeping only the
    disparities within ``plane_tolerance_m`` (metric, eq. 4) of the first mean, so that a kerb or
    a low object next to the road does not pull the far rows.

    Kernels: :func:`_profile_kernel` (DP, refinements, profile, fit rows) and
    :func:`_line_fit` (through :func:`_robust_fit`), whose lines rise by more than
    ``min_slope`` disparity per row: a flatter line is a camera higher than ``max_height_m``, the
    wall of trees or a hillside far beyond the road, not the road.

    Returns ``((line, coef), profile, inlier_rows)``, coefficients lowest power first; the first
    item is None when there is no fit.
    """
    step = int(step or params.column_step)
    profile, rows, dv, wv = _profile_kernel(
        vd,
        float(vd_columns or -(-W // step)),  # the score is the support per column
        int(params.max_step),
        float(params.smoothness),
        float(params.bin_size),
        float(max(params.refine_radius_px, 0.5 * params.bin_size)),
        pixels[0],
        pixels[1],
        float(height) if height is not None and height > 0 else 0.0,
        float(params.plane_tolerance_m),
        float(params.min_plane_tolerance_px),
        step,
        int(params.min_row_count),
        # compared with the float32 profile in float32, as NumPy compares a float32 array with a float
        np.float32(params.min_fit_disparity_px),
    )
    if rows.size < params.min_fit_rows:
        return None, profile, None
    line, inl = _robust_fit(
        rows, dv, wv, 1, params.fit_tolerance_px, params.ransac_iterations, None, min_slope=min_slope
    )
    if line is None or np.count_nonzero(inl) < params.min_fit_rows or not line[1] > 0:
        return None, profile, None
    coef = line
    if params.model == "quadratic":
        quad, _ = _robust_fit(rows, dv, wv, 2, params.fit_tolerance_px, 0, inl)
        if quad is not None:
            coef = quad
    return (line, coef), profile, rows[inl].astype(int)


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

    The disparity map is validated by :func:`checked_disparity`; its NaNs and infinities are
    invalid pixels to the kernels that read it.
    """
    disp = checked_disparity(disparity, "road.profile")
    H, W = disp.shape
    D = n_bins(params.max_disparity, params.bin_size)
    cx, cy = float(calib.cx), float(calib.cy)
    if vdisparity is not None:
        vd = np.ascontiguousarray(vdisparity, dtype=np.float32)
        if vd.shape != (H, D):
            raise RoadInputError(
                f"road.profile: vdisparity: expected shape {(H, D)} (rows of the disparity x ceil(max_disparity / bin_size)), "
                f"got {vd.shape} (hint: give road.vdisparity the same max_disparity and bin_size)"
            )
    # pass 1: every pixel in its own row (no roll: v' = v); counted unless a v-disparity is given
    s, c = geometry.roll_row_coeffs(0.0, calib)
    step1 = int(params.first_pass_column_step)
    bins = D if vdisparity is None else 0
    rows, d, counted = _select(disp, cx, cy, s, c, bins, params.bin_size, params.max_disparity, None, step1)
    if vdisparity is None:
        vd = counted

    # the road line rises by at least f B / (fy max_height_m) per row (eq. 3 at zero pitch)
    min_slope = float(calib.f * calib.baseline / (calib.f_y * params.max_height_m))
    fit, profile, inl = _profile_pass(
        H,
        W,
        (rows, d),
        vd,
        params,
        vd_columns=W if vdisparity is not None else None,
        step=step1,
        min_slope=min_slope,
    )
    if fit is None:
        return _invalid(profile), vd
    line = fit[0]
    roll = 0.0
    plane = np.array([line[0], 0.0, line[1]])
    _, h1 = geometry.pose_from_line(float(line[0]), float(line[1]), calib)
    if params.estimate_roll:
        b = _fit_road_plane(disp, line, h1, int(inl.min()), params)
        if b is not None:
            est = geometry.roll_from_plane(float(b[1]), float(b[2]), calib)
            if abs(est) <= math.radians(params.max_abs_roll_deg):
                roll, plane = est, b
    # pass 2: only the pixels within road_band_m of that plane, in roll-corrected rows
    band = (params.road_band_m / h1, *plane) if params.road_band_m > 0 else None
    s, c = geometry.roll_row_coeffs(roll, calib)
    rows, d, vd = select_and_count(
        disp, cx, cy, s, c, params.max_disparity, params.bin_size, band, params.column_step
    )
    fit, profile, inl = _profile_pass(H, W, (rows, d), vd, params, h1, min_slope=min_slope)
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
