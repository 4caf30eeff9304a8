"""The order statistics of the lane kernels (lanegraph_lanes._select) against their NumPy twins."""

from __future__ import annotations

import math

import numpy as np
import pytest
from lanegraph_lanes._select import kth_smallest, median_inplace, percentile_inplace


def _samples():
    rng = np.random.default_rng(7)
    for n in (1, 2, 3, 4, 5, 10, 11, 64, 257):
        yield rng.normal(size=n)  # distinct values
        yield rng.integers(0, 4, size=n).astype(np.float64)  # many ties
        yield np.where(rng.random(n) < 0.8, 1.0, rng.random(n))  # mostly one value (a profile's 1.0)
        yield np.full(n, 2.5)  # one value only
        yield np.sort(rng.normal(size=n))  # sorted, and reversed: quickselect's bad cases
        yield np.sort(rng.normal(size=n))[::-1].copy()


def percentile_twin(a: np.ndarray, q: float) -> float:
    """numba's np.percentile: the values at rank 1 + (n - 1) q / 100 and the next, interpolated."""
    s = np.sort(a)
    if len(s) == 1:
        return float(s[0])
    rank = 1 + (len(s) - 1) * (q / 100.0)
    f = math.floor(rank)
    m = rank - f
    upper = s[min(f, len(s) - 1)]
    return float(s[f - 1] * (1 - m) + upper * m)


def test_kth_smallest_is_the_sorted_value_and_partitions():
    for a in _samples():
        for k in sorted({0, len(a) // 2, len(a) - 1}):
            work = a.copy()
            assert kth_smallest(work, len(a), k) == np.sort(a)[k]
            assert (work[:k] <= work[k]).all() and (work[k + 1 :] >= work[k]).all()
            assert sorted(work) == sorted(a)  # a permutation


def test_kth_smallest_ends_on_a_nan():
    """A NaN (which no kernel passes) makes the result undefined but never loops for ever."""
    for a in ([np.nan] * 5, [1.0, np.nan, 0.0, np.nan, 3.0], [np.nan, 2.0, 1.0]):
        for k in range(len(a)):
            kth_smallest(np.array(a), len(a), k)


def test_median_is_numpys():
    for a in _samples():
        work = a.copy()
        assert median_inplace(work, len(a)) == np.median(a)  # exactly: the same two values, (a + b) / 2
    assert math.isnan(median_inplace(np.empty(0), 0))


@pytest.mark.parametrize("q", [10.0, 50.0, 90.0, 99.5])
def test_percentile_is_numbas_formula_and_numpys_value(q):
    for a in _samples():
        got = percentile_inplace(a.copy(), len(a), q)
        assert got == percentile_twin(a, q)
        assert got == pytest.approx(np.percentile(a, q), rel=1e-12, abs=1e-12)
    assert math.isnan(percentile_inplace(np.array([1.0, np.nan, 2.0]), 3, 90.0))
    assert math.isnan(percentile_inplace(np.array([np.inf]), 1, 90.0))
