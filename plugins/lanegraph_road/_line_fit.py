"""The robust line fit of the road profile (:mod:`.profile`, step 3): RANSAC over the profile's rows
weighted by their support, then least squares on the inliers, in numba kernels
(:func:`_line_fit`), with the NumPy reference of its least-squares rounds
(:func:`_robust_refit_np`) for the other degrees.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from lanegraph import jit


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
