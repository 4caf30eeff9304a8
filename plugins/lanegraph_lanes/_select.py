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
    return ``a[k]`` is it, ``a[:k]`` holds values ``<=`` it and ``a[k + 1:n]`` values ``>=`` it.

    Each level partitions without a branch per element (every element swapped with the boundary,
    the boundary moved by the comparison's outcome: over unordered values a branch on it was
    mispredicted half the time, most of a selection's cost), in two passes around the pivot (the
    median of three): below it, then equal to it (ties end a level). A NaN ends the search (its
    result is then undefined, never an endless loop)."""
    lo = 0
    hi = n - 1
    while lo < hi:
        x = a[lo]
        y = a[(lo + hi) >> 1]
        z = a[hi]
        pivot = max(min(x, y), min(max(x, y), z))
        store = lo
        for i in range(lo, hi + 1):
            v = a[i]
            a[i] = a[store]
            a[store] = v
            store += v < pivot
        if k < store:
            hi = store - 1
            continue
        top = store
        for i in range(store, hi + 1):
            v = a[i]
            a[i] = a[top]
            a[top] = v
            top += v <= pivot
        if k < top or top == lo:  # a[store:top] are the pivot; top == lo: a NaN pivot
            break
        lo = top
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
