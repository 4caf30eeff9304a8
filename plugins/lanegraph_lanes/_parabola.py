"""The two robust parabola fits of ``fit.irls`` and ``fit.ransac`` (:mod:`._fit`): points in,
coefficients of ``col = c0 + c1*t + c2*t**2`` out.

IRLS (:func:`irls_fit`): ordinary least squares, then weights from the residuals (Tukey biweight or
Huber, scale from the median absolute deviation), repeated, in a numba kernel
(:func:`_irls_kernel`; :func:`irls_fit_lstsq` is its NumPy reference). RANSAC
(:func:`ransac_fit`): minimal samples of three points (:func:`ransac_samples`), the largest
consensus set within the inlier distance, then least squares on it (:func:`_ransac_kernel`).
"""

from __future__ import annotations

import math

import numpy as np

from lanegraph import jit

from ._select import median_inplace


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
