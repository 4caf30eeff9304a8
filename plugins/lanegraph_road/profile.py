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
from pydantic import Field, model_validator
from scipy.linalg.lapack import dgesv

from lanegraph import InputError, NodeParams, Port, jit, node_type
from lanegraph.types import Calibration, RoadModel

from . import geometry

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
def _select_kernel(disp, step, band_k, b0, b1, b2, cx, cy, s, c, bin_size, max_disp, out_rows, out_d, vd):
    """The pixels of a profile pass, compacted, and their v-disparity, in one pass over the image.

    Selects the pixels with ``d > 0`` and, when ``band_k > 0``, within the band
    ``|d - (b0 + b1 u + b2 v)| <= band_k d`` of the road plane (disparity space; ``band_k`` is the
    band in metres over the camera height, eq. 4), whose roll-corrected row
    ``v' = cy + s (u - cx) + c (v - cy)``, rounded to the nearest row, lies in ``[0, H)``; only every
    ``step``-th column (from column 0) is looked at. Writes each one's row and disparity into
    ``out_rows`` / ``out_d`` in row-major order and counts it in ``vd[row, int(d / bin_size)]``
    (``H x n_bins`` float32, zeroed by the caller; ``n_bins`` may be 0: no counts) when
    ``d < max_disp`` and the bin exists. Returns the number of pixels selected.

    A NaN or an infinity is invalid, as 0 is (one more comparison on the pixels read anyway)."""
    H, W = disp.shape
    n_bins = vd.shape[1]
    n = 0
    for v in range(H):
        for u in range(0, W, step):
            d = disp[v, u]
            if not (d > 0.0 and d < math.inf):  # 0, negative, NaN, +-inf: invalid
                continue
            if band_k > 0.0 and abs(d - (b0 + b1 * u + b2 * v)) > band_k * d:
                continue
            r = int(math.floor(cy + s * (u - cx) + c * (v - cy) + 0.5))
            if r < 0 or r >= H:
                continue
            out_rows[n] = r
            out_d[n] = d
            n += 1
            if d < max_disp:
                k = int(d / bin_size)
                if k < n_bins:
                    vd[r, k] += 1.0  # exact: float32 counts up to 2**24
    return n


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


@jit
def _ransac_line_kernel(v, d, w, i, j, tol, min_slope):
    """Score the lines through the point pairs ``(i[k], j[k])`` (pairs with ``v[i] == v[j]`` or a slope
    ``<= min_slope`` (at least 0) are skipped): the weight ``w`` (>= 0) of the points within ``tol``.
    Returns ``(found, inliers of the first best line)``. Integer weights are summed as integers
    (exact)."""
    n = v.size
    best_score = -1.0
    best_a0 = 0.0
    best_a1 = 0.0
    found = False
    # the profile's weights are pixel counts: summed as integers, in any order and exactly, the
    # loop over the points vectorises (float sums keep their order: they do not)
    wi = np.empty(n, np.int64)
    integral = True
    for p in range(n):
        integral = integral and w[p] == math.floor(w[p]) and abs(w[p]) < 2.0**52
        wi[p] = int(w[p]) if integral else 0
    for k in range(i.size):
        vi = v[i[k]]
        vj = v[j[k]]
        if vi == vj:
            continue
        a1 = (d[i[k]] - d[j[k]]) / (vi - vj)
        if not (a1 > 0 and a1 > min_slope):
            continue
        a0 = d[i[k]] - a1 * vi
        if integral:
            si = 0
            for p in range(n):
                si += wi[p] if abs(d[p] - (a0 + a1 * v[p])) < tol else 0
            score = float(si)
            if score > best_score:
                best_score = score
                best_a0 = a0
                best_a1 = a1
                found = True
            continue
        # four interleaved sums without branches (one sum would make every addition wait for the
        # last): exact, so in any order, for integer weights (the pixel counts of the profile rows)
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        e = n - n % 4
        for p in range(0, e, 4):
            s0 += w[p] if abs(d[p] - (a0 + a1 * v[p])) < tol else 0.0
            s1 += w[p + 1] if abs(d[p + 1] - (a0 + a1 * v[p + 1])) < tol else 0.0
            s2 += w[p + 2] if abs(d[p + 2] - (a0 + a1 * v[p + 2])) < tol else 0.0
            s3 += w[p + 3] if abs(d[p + 3] - (a0 + a1 * v[p + 3])) < tol else 0.0
        for p in range(e, n):
            s0 += w[p] if abs(d[p] - (a0 + a1 * v[p])) < tol else 0.0
        score = (s0 + s1) + (s2 + s3)
        if score > best_score:
            best_score = score
            best_a0 = a0
            best_a1 = a1
            found = True
    inl = np.empty(n, np.bool_)
    for p in range(n):
        inl[p] = found and abs(d[p] - (best_a0 + best_a1 * v[p])) < tol
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
        for i in range(n):  # not inl[:] = new: its shape check's message took 3 s to compile
            inl[i] = new[i]
    return ok, a0, a1, inl


def _line_fit(v, d, w, i, j, tol, rounds, min_slope):
    """The robust line of a pass: RANSAC over the pairs ``(i, j)`` (:func:`_ransac_line_kernel`, slopes
    above ``min_slope``), then up to ``rounds`` least-squares rounds (:func:`_line_refit_kernel`).
    Returns ``(status, a0, a1, inliers)``: status 0 when RANSAC found no line or fewer than two
    inliers, 1 when the least squares failed (``inliers``: the last ones), 2 for a line. Two kernels
    called from Python (one kernel calling both compiled them twice over, on the first run's path)."""
    found, inl = _ransac_line_kernel(v, d, w, i, j, tol, min_slope)
    if not found or np.count_nonzero(inl) < 2:
        return 0, 0.0, 0.0, inl
    ok, a0, a1, inl = _line_refit_kernel(v, d, w, inl, tol, rounds)
    return (2 if ok else 1), a0, a1, inl


@jit
def _plane_points(disp, step, v_top, min_disp):
    """The candidates of :func:`_plane_fit_kernel`, compacted in row-major order: ``(us, vs, ds, m)``
    (float64 columns, rows and disparities; the first ``m`` are set)."""
    H, W = disp.shape
    cap = ((H + step - 1) // step) * ((W + step - 1) // step)
    us = np.empty(cap, np.float64)
    vs = np.empty(cap, np.float64)
    ds = np.empty(cap, np.float64)
    m = 0
    for v in range(0, H, step):
        if v < v_top:
            continue
        for u in range(0, W, step):
            dd = np.float64(disp[v, u])
            if not (dd > min_disp and dd < math.inf):  # NaN, +-inf: invalid
                continue
            us[m] = u
            vs[m] = v
            ds[m] = dd
            m += 1
    return us, vs, ds, m


@jit
def _plane_sums(us, vs, ds, m, first, b0, b1, b2, first_tol, plane_tol, height, min_tol, uc, vc, M, rhs):
    """One round of :func:`_plane_fit_kernel`: selects the candidates within the round's tolerance
    of the plane ``b``, writes the normal equations into ``M`` (3 x 3) and ``rhs``; returns the
    number selected."""
    n = 0
    su = 0.0
    sv = 0.0
    suu = 0.0
    suv = 0.0
    svv = 0.0
    sd = 0.0
    sud = 0.0
    svd = 0.0
    for p in range(m):
        fu = us[p]
        fv = vs[p]
        dd = ds[p]
        if first:
            tol = first_tol
        else:
            tol = max(plane_tol * dd / height, min_tol)
        if abs(dd - (b0 + b1 * fu + b2 * fv)) < tol:
            x = fu - uc
            y = fv - vc
            n += 1
            su += x
            sv += y
            suu += x * x
            suv += x * y
            svv += y * y
            sd += dd
            sud += x * dd
            svd += y * dd
    M[0, 0] = n
    M[0, 1] = su
    M[0, 2] = sv
    M[1, 0] = su
    M[1, 1] = suu
    M[1, 2] = suv
    M[2, 0] = sv
    M[2, 1] = suv
    M[2, 2] = svv
    rhs[0] = sd
    rhs[1] = sud
    rhs[2] = svd
    return n


def _plane_fit_kernel(
    disp, step, v_top, min_disp, b0, b1, b2, first_tol, plane_tol, height, min_tol, uc, vc, rounds
):
    """The roll plane ``d = b0 + b1 u + b2 v`` (disparity space), ``rounds`` selection and
    least-squares rounds over every ``step``-th row and column from row 0 and column 0.

    The candidates (``d > min_disp``, ``v >= v_top``) are compacted once, in row-major order
    (:func:`_plane_points`). A round (:func:`_plane_sums`) selects those with ``|d - (b0 + b1 u + b2
    v)| < tol`` (the plane of the previous round, the first round the one given), ``tol =
    first_tol`` in the first round, then ``max(plane_tol * d / height, min_tol)``; sums the
    least-squares normal equations of ``d = a + c1 (u - uc) + c2 (v - vc)`` (centred coordinates)
    and solves them with LAPACK's ``dgesv`` (SciPy's, the one numba's ``np.linalg.solve`` calls:
    the solve stays out of the kernels, whose first compilation it made 4 s longer):
    ``b = (a - c1 uc - c2 vc, c1, c2)``. Returns ``(ok, b0, b1, b2)``; not ok when a round selects
    fewer than 50 pixels, its system is singular or not finite, a coefficient is not finite, or
    the final ``b2 <= 0``."""
    us, vs, ds, m = _plane_points(disp, int(step), int(v_top), float(min_disp))
    M = np.empty((3, 3), np.float64)
    rhs = np.empty(3, np.float64)
    b0, b1, b2 = float(b0), float(b1), float(b2)
    args = (float(first_tol), float(plane_tol), float(height), float(min_tol), float(uc), float(vc))
    for it in range(int(rounds)):
        n = _plane_sums(us, vs, ds, m, it == 0, b0, b1, b2, *args, M, rhs)
        if n < 50 or not (np.isfinite(M).all() and np.isfinite(rhs).all()):
            return False, 0.0, 0.0, 0.0
        _, _, sol, info = dgesv(M, rhs)
        if info != 0:  # singular (every selected pixel on one row or column)
            return False, 0.0, 0.0, 0.0
        c0, c1, c2 = float(sol[0]), float(sol[1]), float(sol[2])
        b0 = c0 - c1 * uc - c2 * vc
        b1 = c1
        b2 = c2
        if not (math.isfinite(b0) and math.isfinite(b1) and math.isfinite(b2)):
            return False, 0.0, 0.0, 0.0
    if not b2 > 0:
        return False, 0.0, 0.0, 0.0
    return True, b0, b1, b2


# --------------------------------------------------------------------------- helpers


class RoadInputError(InputError, ValueError):
    """An input of a road node is not what its port promises: lanegraph's own :class:`InputError`
    (so the executor reports it like any bad input) that stays a ``ValueError`` for Python callers."""


def checked_disparity(disparity: np.ndarray, node: str) -> np.ndarray:
    """Validate a disparity map's shape and dtype; C-contiguous float32 (no copy when it is already).
    NaNs and infinities stay: every road kernel treats them as invalid pixels, as it does 0 (no
    pass over the map to look for them)."""
    disparity = np.asarray(disparity)
    if (
        disparity.ndim != 2
        or disparity.shape[0] < 1
        or disparity.shape[1] < 1
        or disparity.dtype.kind not in "biuf"
    ):
        raise RoadInputError(
            f"{node}: disparity: expected a non-empty HxW array of numbers, "
            f"got shape {disparity.shape} of dtype {disparity.dtype}"
        )
    return np.ascontiguousarray(disparity, dtype=np.float32)


#: the most v-disparity bins (max_disparity / bin_size) the params may ask for
MAX_BINS = 1024


def n_bins(max_disparity: float, bin_size: float) -> int:
    return max(1, int(math.ceil(max_disparity / bin_size)))


def _select(disp, cx, cy, s, c, bins, bin_size, max_disparity, band, step):
    """:func:`_select_kernel` into new arrays: ``(rows, disparities, vdisparity)``. Rows are int16
    (half the memory traffic of int32) unless the image has too many rows for it."""
    H, W = disp.shape
    cap = H * -(-W // step)
    rows = np.empty(cap, np.int16 if H < 32767 else np.int32)
    d = np.empty(cap, np.float32)
    vd = np.zeros((H, bins), np.float32)
    k, b0, b1, b2 = band if band is not None else (0.0, 0.0, 0.0, 0.0)
    n = _select_kernel(
        disp,
        int(step),
        float(k),
        float(b0),
        float(b1),
        float(b2),
        float(cx),
        float(cy),
        float(s),
        float(c),
        float(bin_size),
        float(max_disparity),
        rows,
        d,
        vd,
    )
    return rows[:n], d[:n], vd


def select_and_count(
    disp: np.ndarray,
    cx: float,
    cy: float,
    s: float,
    c: float,
    max_disparity: float,
    bin_size: float,
    band: tuple[float, float, float, float] | None = None,
    step: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels of a pass and their v-disparity in one pass over a validated map
    (:func:`_select_kernel`): ``(rows, disparities, H x D vdisparity)`` of the selected pixels of every
    ``step``-th column, in roll-corrected rows ``v' = cy + s (u - cx) + c (v - cy)`` (pixels);
    ``band = (band_k, b0, b1, b2)`` or None for every valid pixel."""
    return _select(disp, cx, cy, s, c, n_bins(max_disparity, bin_size), bin_size, max_disparity, band, step)


def select_pixels(
    disp: np.ndarray,
    cx: float,
    cy: float,
    s: float,
    c: float,
    band: tuple[float, float, float, float] | None = None,
    step: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`select_and_count` without the counts: ``(rows, disparities)``."""
    return _select(disp, cx, cy, s, c, 0, 1.0, 0.0, band, step)[:2]


def compute_vdisparity(
    disp: np.ndarray,
    max_disparity: float,
    bin_size: float,
    roll: float = 0.0,
    calib: Calibration | None = None,
) -> np.ndarray:
    """``H x D`` v-disparity of a validated disparity map, optionally in roll-corrected rows."""
    if roll != 0.0 and calib is None:
        raise ValueError("a roll needs the calibration (principal point)")
    s, c = geometry.roll_row_coeffs(roll, calib) if calib is not None else (0.0, 1.0)
    cx, cy = (calib.cx, calib.cy) if calib is not None else (0.0, 0.0)
    return select_and_count(disp, cx, cy, s, c, max_disparity, bin_size)[2]


# --------------------------------------------------------------------------- road.vdisparity


def bins_bounded(params):
    """``params`` (with ``max_disparity`` and ``bin_size``) when its v-disparity has at most
    :data:`MAX_BINS` bins (memory and time grow with them: 8x the default's 128); else ValueError."""
    if params.max_disparity / params.bin_size > MAX_BINS:
        raise ValueError(
            f"max_disparity / bin_size = {params.max_disparity / params.bin_size:.0f} disparity bins, "
            f"more than {MAX_BINS}; raise bin_size or lower max_disparity"
        )
    return params


class VDisparityParams(NodeParams):
    """Params of ``road.vdisparity``."""

    max_disparity: float = Field(
        128.0, gt=0.0, le=1024.0, description="disparities >= this are left out, pixels; D = ceil(max / bin)"
    )
    bin_size: float = Field(
        1.0, ge=0.25, le=16.0, description="width of a disparity bin, pixels (>= 0.25; at most 1024 bins)"
    )

    @model_validator(mode="after")
    def _bins_bounded(self):
        return bins_bounded(self)


@node_type(
    "road.vdisparity",
    inputs={"disparity": Port("disparity", "left disparity map")},
    outputs={"vdisparity": Port("vdisparity", "H x D count of disparities per row")},
)
def road_vdisparity(params: VDisparityParams, disparity: np.ndarray) -> dict:
    """The v-disparity image: per image row, a histogram of its valid disparities (H x D float32)."""
    disp = checked_disparity(disparity, "road.vdisparity")  # NaN, +-inf: invalid to the kernel
    return {"vdisparity": compute_vdisparity(disp, params.max_disparity, params.bin_size)}


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


def _robust_fit(
    v, d, w, deg, tol, iterations, init: np.ndarray | None, seed: int = 0, min_slope: float = 0.0
):
    """RANSAC (for the line: ``iterations`` pairs drawn by :func:`_sample_pairs`, slopes above
    ``min_slope``) then least squares with inlier re-selection (four rounds at most); with ``init``
    (inliers) only the least squares. The line: :func:`_line_fit`. Returns
    (coef, inliers), coef None when no fit (inliers None when RANSAC found none)."""
    v = np.ascontiguousarray(v, dtype=np.float64)
    d = np.ascontiguousarray(d, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    if init is None:
        if deg != 1:
            raise ValueError("RANSAC fits a line (deg 1) only; give the inliers of a line for deg > 1")
        if v.size < 2:
            return None, None
        i, j = _sample_pairs(v.size, int(iterations), int(seed))
        status, a0, a1, inl = _line_fit(v, d, w, i, j, float(tol), 4, float(min_slope))
        if status == 0:
            return None, None
        return (np.array([a0, a1]), inl) if status == 2 else (None, inl)
    if np.count_nonzero(init) < deg + 1:
        return None, None
    if deg == 1:
        ok, a0, a1, inl = _line_refit_kernel(
            v, d, w, np.ascontiguousarray(init, dtype=np.bool_), float(tol), 4
        )
        return (np.array([a0, a1]), inl) if ok else (None, inl)
    return _robust_refit_np(v, d, w, deg, tol, init)


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


def _fit_road_plane(disp, line, height: float, v_top: int, params: ProfileParams) -> np.ndarray | None:
    """The road plane ``d = b0 + b1 u + b2 v`` (disparity space) fitted over the pixels within
    ``roll_tolerance_px`` of the profile line, then re-fitted ``roll_iterations`` times over the
    pixels within ``plane_tolerance_m`` (metric, eq. 4) of the plane: every round in one call of
    :func:`_plane_fit_kernel` (normal equations in coordinates centred on the image centre, a
    3 x 3 solve). None when a round has fewer than 50 pixels or no plane, or the plane is not
    a road (``b2 <= 0``). ``height``: the camera height of the line (metres)."""
    H, W = disp.shape
    ok, b0, b1, b2 = _plane_fit_kernel(
        disp,
        int(params.roll_subsample),
        int(v_top),
        float(params.min_fit_disparity_px),
        float(line[0]),
        0.0,
        float(line[1]),
        float(params.roll_tolerance_px),
        float(params.plane_tolerance_m),
        float(height),
        float(params.min_plane_tolerance_px),
        0.5 * (W - 1),
        0.5 * (H - 1),
        int(params.roll_iterations),  # at least one (the param's bound): b is then a fit
    )
    return np.array([b0, b1, b2]) if ok else None


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
