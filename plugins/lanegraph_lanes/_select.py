"""Order statistics inside the lane kernels: the median and a percentile of a work buffer.

The same values as numba's ``np.median`` and ``np.percentile`` (linear interpolation between the
closest ranks, numba's formula), from a short quickselect of our own: numba's implementations
are generic and took about 5 s of the first run's compilation (the median 2.7 s in ``fit.irls``,
the percentile 3.5 s in ``lanes.verify``), this one a fraction of a second. The buffers hold finite
numbers (a NaN makes the percentile NaN; the kernels never pass one to the median).
"""

from __future__ import annotations

import math

from lanegraph import jit


@jit
def kth_smallest(a, n, k):
    """The ``k``-th smallest (0-based, ``0 <= k < n``) of ``a[:n]``, by quickselect in place: on
    return ``a[k]`` is it, ``a[:k]`` holds values ``<=`` it and ``a[k + 1:n]`` values ``>=`` it."""
    lo = 0
    hi = n - 1
    while hi > lo + 1:
        mid = (lo + hi) >> 1
        t = a[mid]
        a[mid] = a[lo + 1]
        a[lo + 1] = t
        if a[lo] > a[hi]:  # median of three: a[lo] <= a[lo + 1] <= a[hi], the scans' sentinels
            t = a[lo]
            a[lo] = a[hi]
            a[hi] = t
        if a[lo + 1] > a[hi]:
            t = a[lo + 1]
            a[lo + 1] = a[hi]
            a[hi] = t
        if a[lo] > a[lo + 1]:
            t = a[lo]
            a[lo] = a[lo + 1]
            a[lo + 1] = t
        x = a[lo + 1]
        i = lo + 1
        j = hi
        while True:
            i += 1
            while i < hi and a[i] < x:
                i += 1
            j -= 1
            while j > lo and a[j] > x:
                j -= 1
            if j < i:
                break
            t = a[i]
            a[i] = a[j]
            a[j] = t
        a[lo + 1] = a[j]
        a[j] = x
        if j >= k:
            hi = j - 1
        if j <= k:
            lo = i
    if hi == lo + 1 and a[hi] < a[lo]:
        t = a[lo]
        a[lo] = a[hi]
        a[hi] = t
    return a[k]


@jit
def median_inplace(a, n):
    """``np.median(a[:n])`` (the mean of the two middle values when ``n`` is even; NaN when ``n`` is
    0), reordering ``a[:n]``."""
    if n == 0:
        return math.nan
    half = n >> 1
    if n & 1:
        return kth_smallest(a, n, half)
    lower = kth_smallest(a, n, half - 1)  # and the next one: the least of a[half:n] (>= lower)
    upper = a[half]
    for i in range(half + 1, n):
        upper = upper if upper <= a[i] else a[i]
    return (lower + upper) / 2


@jit
def percentile_inplace(a, n, q):
    """``np.percentile(a[:n], q)`` as numba computes it, for ``0 < q < 100`` and ``n >= 1``: rank
    ``1 + (n - 1) q / 100``, the values at its floor and the next rank interpolated linearly
    (``lower (1 - m) + upper m``); NaN when ``a[:n]`` holds a NaN. Reorders ``a[:n]``."""
    for i in range(n):
        if math.isnan(a[i]):
            return math.nan
    if n == 1:
        return a[0] + 0.0 if math.isfinite(a[0]) else math.nan
    rank = 1 + (n - 1) * (q / 100.0)
    f = math.floor(rank)
    m = rank - f
    k = int(f - 1)  # k + 1 < n: the value at rank k and the next one, the least of a[k + 1:n]
    lower = kth_smallest(a, n, k)
    upper = a[k + 1]
    for i in range(k + 2, n):
        upper = upper if upper <= a[i] else a[i]
    return lower * (1 - m) + upper * m
