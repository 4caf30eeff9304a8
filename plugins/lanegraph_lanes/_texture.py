"""The texture of the road beside a lane (the texture check of ``lanes.verify`` and the paint
check's darker side): per row, the lateral standard deviation or the (median) absolute difference of
neighbouring pixels across a side band; the small median the kernels share; the road's grey level
(:func:`road_level`)."""

from __future__ import annotations

import math

import numpy as np

from lanegraph import InputError, jit
from lanegraph.types import Lane

#: the texture measures, as the kernels number them
_MEASURES = {"std": 0, "diff": 1, "mdiff": 2}


@jit
def _small_median(buf, m, hist):
    """The median of ``buf[:m]`` (``m >= 1``; the mean of the two middle values when ``m`` is even,
    as ``np.median``). With a 256-bin ``hist`` (all zero; the values integers in 0..255) by counting,
    which leaves ``hist`` zero again; with an empty one by sorting ``buf[:m]`` in place."""
    k1 = (m - 1) // 2
    k2 = m // 2
    if hist.size > 0:
        first = hist.size  # the counts start at the smallest value: the bins below it are empty
        for i in range(m):
            b = int(buf[i])
            hist[b] += 1
            first = min(first, b)
        lo = -1
        cum = 0
        hi = 0
        for v in range(first, hist.size):
            cum += hist[v]
            if lo < 0 and cum > k1:
                lo = v
            if cum > k2:
                hi = v
                break
        for i in range(m):
            hist[int(buf[i])] = 0
        return 0.5 * (lo + hi)
    for i in range(1, m):  # insertion sort: a band is a few dozen values
        x = buf[i]
        j = i - 1
        while j >= 0 and buf[j] > x:
            buf[j + 1] = buf[j]
            j -= 1
        buf[j + 1] = x
    return 0.5 * (buf[k1] + buf[k2])


@jit
def _band_texture_kernel(img, r0, centre, gap_px, band_px, sign, mode, hist, out):
    """Per lane row ``r0 + i``: the texture of the side band, columns ``round(centre[i] + sign * k)``
    for ``k = gap_px .. band_px``, into ``out[i]``; NaN where the band leaves the image. ``mode``
    (:data:`_MEASURES`): 0, the population standard deviation of the band pixels; 1, the mean
    absolute difference of neighbouring band pixels; 2, their median absolute difference
    (``hist``: see :func:`_small_median`)."""
    rows, cols = img.shape
    n = band_px - gap_px + 1
    # int64 for an integer image (the differences summed as integers: exact, and no chain of
    # float additions), float64 for a float one
    zero = np.zeros(1, img.dtype)[0] + np.int64(0)
    vals = np.full(n, zero)
    diffs = np.full(max(n - 1, 1), zero)
    step = 1 if sign > 0 else -1
    for i in range(centre.size):
        r = r0 + i
        ce = centre[i]
        full = True
        if abs(ce - math.floor(ce) - 0.5) > 1e-9:
            # no half to round: round(ce + k) = round(ce) + k for every integer offset k, so the
            # band is a run of columns, checked against the image at its two ends only
            a = int(np.round(ce)) + step * gap_px
            b = a + step * (n - 1)
            lo = min(a, b)
            hi = max(a, b)
            if lo < 0 or hi >= cols:
                full = False
            elif mode == 1:
                # on the row slice, the terms in the band's order (|x - y| = |y - x|): the same sum
                row = img[r, lo : hi + 1]
                acc = zero
                if step > 0:
                    for j in range(n - 1):
                        acc += abs((row[j + 1] + zero) - row[j])
                else:
                    for j in range(n - 2, -1, -1):
                        acc += abs((row[j + 1] + zero) - row[j])
                out[i] = acc / (n - 1) if n > 1 else 0.0
                continue
            elif mode == 2:
                row = img[r, lo : hi + 1]  # the median does not depend on the order
                for j in range(n - 1):
                    diffs[j] = abs((row[j + 1] + zero) - row[j])
                out[i] = _small_median(diffs, n - 1, hist) if n > 1 else 0.0
                continue
            else:
                for j in range(n):
                    vals[j] = img[r, a + step * j]
        else:
            for j in range(n):
                c = int(np.round(ce + sign * (gap_px + j)))
                if c < 0 or c >= cols:
                    full = False
                    break
                vals[j] = img[r, c]
        if not full:
            out[i] = np.nan
            continue
        if mode == 1:
            acc = zero
            for j in range(n - 1):
                acc += abs(vals[j + 1] - vals[j])
            out[i] = acc / (n - 1) if n > 1 else 0.0
        elif mode == 2:
            for j in range(n - 1):
                diffs[j] = abs(vals[j + 1] - vals[j])
            out[i] = _small_median(diffs, n - 1, hist) if n > 1 else 0.0
        else:
            mean = 0.0
            for j in range(n):
                mean += vals[j]
            mean /= n
            acc = 0.0
            for j in range(n):
                acc += (vals[j] - mean) ** 2
            out[i] = math.sqrt(acc / n)


def _median_hist(img: np.ndarray) -> np.ndarray:
    """The counting buffer of :func:`_small_median`: 256 bins for a uint8 image (its differences are
    integers in 0..255), none (sorting) for any other."""
    return np.zeros(256 if img.dtype == np.uint8 else 0, np.int64)


def _grey_bev(image: np.ndarray) -> np.ndarray:
    """The grey BEV image, C-contiguous (no copy when it is); an InputError for anything but Hb x Wb."""
    img = np.ascontiguousarray(image)
    if img.ndim != 2:
        raise InputError(f"lanes.verify: image: expected an Hb x Wb grey BEV image, got shape {img.shape}")
    return img


def _lane_rows_in(image: np.ndarray, lane: Lane) -> tuple[np.ndarray, int, int]:
    """The grey BEV image (:func:`_grey_bev`) and the lane's first and last rows clipped to it
    (``r1 < r0``: none)."""
    img = _grey_bev(image)
    return img, max(int(lane.bev_rows[0]), 0), min(int(lane.bev_rows[1]), img.shape[0] - 1)


def band_textures(
    image: np.ndarray, lane: Lane, gap_px: int, band_px: int, measure: str = "std"
) -> tuple[np.ndarray, np.ndarray]:
    """Per lane row, the lateral texture of the (left, right) side band (NaN where a band leaves
    the image): ``measure="std"``, the intensity's standard deviation across the band; ``"diff"``,
    the mean absolute difference of neighbouring pixels across the band, which a smooth shadow
    edge or illumination gradient barely changes while gravel or grass raise it; ``"mdiff"``, their
    median absolute difference, which a few sharp edges in the band (a kerb's face, a hatching's
    bars, a shadow's border) do not change either: only a surface rough across most of the band
    raises it."""
    img, r0, r1 = _lane_rows_in(image, lane)
    t = img.shape[0] - 1 - np.arange(r0, r1 + 1, dtype=np.float64)
    c0, c1, c2 = lane.coeffs
    centre = c0 + c1 * t + c2 * t * t
    out = []
    for sign in (-1, 1):
        tex = np.empty(centre.size, np.float64)
        _band_texture_kernel(
            img,
            r0,
            centre,
            int(gap_px),
            int(band_px),
            float(sign),
            _MEASURES[measure],
            _median_hist(img),
            tex,
        )
        out.append(tex)
    return out[0], out[1]


@jit
def _side_texture_kernel(img, r0, r1, c0, c1, c2, gap_px, band_px, mode, hist, quantile):
    """:func:`side_texture` in one call: the per-row textures of both side bands of the lane
    ``col = c0 + c1 t + c2 t^2`` (``t = rows - 1 - row``) over the rows ``r0 .. r1`` (as
    :func:`_band_texture_kernel`), then the ``quantile`` of each side's rows that stay inside the
    image (0 when none does). Returns ``(left, right)``."""
    rows = img.shape[0]
    n = r1 - r0 + 1 if r1 >= r0 else 0
    centre = np.empty(n, np.float64)
    for i in range(n):
        t = rows - 1 - (r0 + i)
        centre[i] = c0 + c1 * t + c2 * t * t
    tex = np.empty(n, np.float64)
    res = np.zeros(2, np.float64)
    for k in range(2):
        _band_texture_kernel(img, r0, centre, gap_px, band_px, -1.0 if k == 0 else 1.0, mode, hist, tex)
        m = 0
        for i in range(n):
            if not np.isnan(tex[i]):
                tex[m] = tex[i]
                m += 1
        if m > 0:
            res[k] = np.quantile(tex[:m], quantile)
    return res[0], res[1]


def side_texture(
    image: np.ndarray, lane: Lane, gap_px: int, band_px: int, measure: str = "std", quantile: float = 0.5
) -> tuple[float, float]:
    """The ``quantile`` (0.5: the median) over the lane's rows of the lateral texture in the (left,
    right) side bands (rows where a band leaves the image do not count; 0 when none is left): see
    :func:`band_textures`, whose per-row values this takes (one kernel call for both sides)."""
    img, r0, r1 = _lane_rows_in(image, lane)
    c0, c1, c2 = (float(c) for c in lane.coeffs)
    left, right = _side_texture_kernel(
        img,
        r0,
        r1,
        c0,
        c1,
        c2,
        int(gap_px),
        int(band_px),
        _MEASURES[measure],
        _median_hist(img),
        float(quantile),
    )
    return float(left), float(right)


#: road_level() samples every n-th row and column
_LEVEL_STEP = 4


def road_level(image: np.ndarray, mask: np.ndarray | None, quantile: float) -> float | None:
    """The ``quantile`` of the grey levels of the road in a BEV image: the pixels on ``mask`` (the BEV
    road mask), or without one every pixel inside the image (> 0), sampled on every 4th row and
    column (an 800 x 400 BEV: about 8 000 road pixels, 0.06 ms). None with fewer than 200 such
    pixels (no road to take a level from)."""
    img = np.asarray(image)
    sample = img[::_LEVEL_STEP, ::_LEVEL_STEP]
    if mask is None:
        sel = sample > 0
    else:
        if np.shape(mask) != img.shape:
            raise InputError(
                f"lanes.verify: mask: expected the BEV image's shape {img.shape}, got {np.shape(mask)}"
            )
        sel = np.asarray(mask, dtype=bool)[::_LEVEL_STEP, ::_LEVEL_STEP]
    values = sample[sel]
    if values.size < 200:
        return None
    if values.dtype == np.uint8:  # a histogram: no sort
        cum = np.cumsum(np.bincount(values, minlength=256))
        return float(np.searchsorted(cum, quantile * values.size))
    return float(np.quantile(values, quantile))
