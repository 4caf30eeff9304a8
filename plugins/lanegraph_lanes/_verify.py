"""``lanes.verify``: keep only lanes that look like paint on a road.

Deviation from the paper (documented in graphs/paper.yaml): on real roads a kerb's lit edge, the
border of the asphalt against a darker verge, a light concrete gutter or a rail passes SLT/ESLT and
the Hough transform like a painted line. What tells paint apart is its own cross profile, which
carries from one road to the next (the paint check, ``paint_check``, :func:`paint_cues`): on the
lane's rows nearer than ``max_distance_m`` (where the BEV resolves paint), each row's strip across
the lane (``paint_band_m`` each side; its centre moved to the brightest pixel within ``align_m`` of
the fitted lane) is divided by the level of its brighter side band (the median from ``paint_gap_m``
to ``paint_band_m``), so that every measure is relative and an exposure or a shadow changes none of
them. A row is *painted* when its centre stands ``min_row_contrast`` above that level. A lane is
paint when

- it has ``min_painted_rows`` painted rows;
- their median contrast reaches ``min_paint_contrast`` (or most of them are clipped at the image's
  largest grey level: an overexposed frame shows paint darker than it is): paint is bright against
  the road on both sides, while a kerb's lit edge or the road's border against a darker verge barely stands above
  the brighter side (on KITTI drive 0001 the kerb beside the tram tracks measures 0.16-0.33, its
  painted lines 0.39-1.0, the highway's lines 0.65-1.6);
- their median profile (offset by offset over the painted rows: sun patches that cross a minority
  of the rows do not widen it as they widen the mean) is at least ``min_width_m`` wide at half its height (the narrowest marking is
  10 cm; a kerb's lit edge measures 5-7 cm) and at most ``max_foot_width_m`` wide at a quarter of
  its height (paint is at most 30 cm wide with sharp edges; a light concrete gutter between the
  asphalt and a paved strip measures 46-85 cm there, painted lines 16-27 cm);
- road lies on both sides: a side darker than ``min_side_ratio`` of the other (the gravel beside a
  kerb measures 0.47-0.58 on KITTI drive 0001, painted lines 0.85-1.0) must be smooth, at most
  ``max_dark_side_texture`` (the texture check's measure, below): a shadow cast along a line darkens
  one side as much as gravel does (0.6-0.7 in the synthetic heavy shadows) but leaves it smooth
  (texture 3-8, gravel 15-17).

The texture check of earlier versions (``max_texture``: the roughness of the surface beside a line,
gravel or grass against asphalt) is kept as an option, off by default: grass beside a highway's edge
line measures as rough as the gravel beside a tram line's kerb, so texture cannot tell them apart.
It measures, per row, the median absolute difference of neighbouring pixels across a side band
(``measure``: or their mean, or the lateral standard deviation) from ``gap_px`` to ``band_px``, the
``row_quantile`` of the rows, in the grey levels of a road whose level is ``reference_level``
(``brightness: relative``).

A pedestrian crossing's bars (0.4-0.6 m wide, about 1 m apart, 3-4 m long along the road) are
parallel-bordered ridges too, on smooth asphalt, and a bar with the road's noise features below it
makes a lane on a street without lines. What tells them apart is their neighbours: averaged over
the lane's painted rows (:func:`neighbour_bars`), a bar has further bars within
``crossing_band_px`` that repeat its spacing (the nearest one on each side about as far, or on one
side a second one twice as far: :func:`crossing_pattern`). A lane line has none, or neighbours at
unrelated distances (a kerb on one side and an arrow on the other); a second line of a double line
lies nearer than ``crossing_min_offset_px``, another lane farther than ``crossing_band_px``, and a
pavement beyond a kerb is one wide bright region, not a bar. ``crossing_check`` drops such lanes.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from lanegraph import jit, node_type
from lanegraph.types import BevGeometry, Calibration, Lane, RoadModel

from ._heights import dark_side_stepped, kerb_across
from ._select import kth_smallest, percentile_inplace
from ._texture import (  # noqa: F401  (re-exported: the texture check's functions)
    _MEASURES,
    _band_texture_kernel,
    _grey_bev,
    _lane_rows_in,
    _median_hist,
    _side_texture_kernel,
    _small_median,
    band_textures,
    road_level,
    side_texture,
)
from ._verify_params import VerifyParams, verify_inputs


@jit
def _paint_rows_kernel(
    img,
    r0,
    r1,
    c0,
    c1,
    c2,
    band_px,
    gap_px,
    align_px,
    min_row_contrast,
    sat_level,
    hist,
    row,
    start,
    inv_level,
    measures,
):
    """The painted rows of the lane ``col = c0 + c1 t + c2 t^2`` (``t = rows - 1 - row``) over the rows
    ``r0 .. r1``, for :func:`paint_cues`. Per row: the lane's column rounded, moved to the brightest
    pixel within ``align_px`` (a fit is a pixel or two off the paint); the strip of columns
    ``-band_px .. band_px`` around it, skipped when it leaves the image or holds a 0 (outside the
    camera's view; in a float image also a NaN); the side levels ``L``, ``R``: the medians of the columns ``-band_px ..
    -gap_px`` and ``gap_px .. band_px`` (``hist``: see :func:`_small_median`). A row is painted when
    its centre is ``min_row_contrast`` (relative) brighter than the brighter side: for the ``k``-th
    painted row, ``row[k]``, ``start[k]`` (its strip's first column) and ``inv_level[k]`` (1 / the
    brighter side's level: the strip times it is the row's profile) and ``measures[k]`` = (centre /
    brighter side - 1, darker side / brighter side) are written (only the rows of the median
    profile are divided, after). Returns ``(strips inside the image, painted rows,
    painted rows whose centre is at ``sat_level`` or above: saturated)``."""
    rows, cols = img.shape
    w = 2 * band_px + 1
    ns = band_px - gap_px + 1
    side = np.empty(ns, np.float64)
    counting = hist.size > 0  # a uint8 image: a zero is its least value
    inside = 0
    painted = 0
    saturated = 0
    for r in range(max(r0, 0), min(r1, rows - 1) + 1):
        t = rows - 1 - r
        ce = int(np.rint(c0 + c1 * t + c2 * t * t))
        if ce - band_px - align_px < 0 or ce + band_px + align_px >= cols:
            continue
        # the loops read the row as a 1-D array: they vectorise, as loops over img[r, j] do not
        line = img[r]
        best = ce - align_px  # the first brightest, from the left
        for c in range(ce - align_px + 1, ce + align_px + 1):
            if line[c] > line[best]:
                best = c
        a = best - band_px
        dark = False
        if counting:
            least = line[a]
            for j in range(a + 1, a + w):
                least = min(least, line[j])
            dark = least == 0
        else:
            zeros = 0
            for j in range(a, a + w):
                zeros += line[j] == 0 or line[j] != line[j]  # a 0, or a NaN
            dark = zeros > 0
        if dark:
            continue
        inside += 1
        for j in range(ns):
            side[j] = line[a + j]
        left = _small_median(side, ns, hist)
        centre = line[best]
        if left > 0.0 and centre >= 0 and centre / left - 1.0 < min_row_contrast:
            # not painted against the left side: nor against the brighter of the two (a quotient
            # by a larger level is no larger), so the right side's median is not needed
            continue
        for j in range(ns):
            side[j] = line[best + gap_px + j]
        right = _small_median(side, ns, hist)
        hi = max(left, right)
        if hi <= 0.0:
            continue
        c_rel = centre / hi - 1.0
        if c_rel < min_row_contrast:
            continue
        inv = 1.0 / hi
        row[painted] = r
        start[painted] = a
        inv_level[painted] = inv
        measures[painted, 0] = c_rel
        measures[painted, 1] = min(left, right) * inv
        painted += 1
        if centre >= sat_level:
            saturated += 1
    return inside, painted, saturated


@jit
def _column_medians(strips, n, out):
    """The median of each column of ``strips[:n]`` (``n >= 1``; no NaN) into ``out``, as
    ``np.median(strips[:n], axis=0)`` (the mean of the two middle values when ``n`` is even), by
    selection."""
    buf = np.empty(n, np.float64)
    k1 = (n - 1) // 2
    k2 = n // 2
    for j in range(strips.shape[1]):
        for i in range(n):
            buf[i] = strips[i, j]
        hi = kth_smallest(buf, n, k2)
        lo = hi
        if k1 != k2:  # the largest below the k2-th: after the selection, all of buf[:k2] is <= it
            lo = buf[0]
            for i in range(1, k2):
                lo = max(lo, buf[i])
        out[j] = 0.5 * (lo + hi)


def _crossing_width(profile: np.ndarray, centre: int, level: float) -> float:
    """Width (pixels, sub-pixel) of the run of ``profile`` at or above ``level`` around ``centre``
    (linear interpolation at both ends; a run reaching the profile's end ends there)."""
    n = profile.size
    a = centre
    while a > 0 and profile[a - 1] >= level:
        a -= 1
    b = centre
    while b < n - 1 and profile[b + 1] >= level:
        b += 1
    left = (
        a - (profile[a] - level) / (profile[a] - profile[a - 1])
        if a > 0 and profile[a] > profile[a - 1]
        else float(a)
    )
    right = (
        b + (profile[b] - level) / (profile[b] - profile[b + 1])
        if b < n - 1 and profile[b] > profile[b + 1]
        else float(b)
    )
    return float(right - left)


@dataclass(frozen=True)
class PaintCues:
    """What :func:`paint_cues` measures of a lane (see the module docstring). Widths in metres;
    ``contrast`` and ``side_ratio`` relative (unitless); NaN where fewer than ``min_rows`` painted
    rows were found."""

    rows: int  # strips inside the image, within max_distance_m
    painted: int  # painted rows among them
    saturated: int  # painted rows whose centre is at the image's largest grey level (clipped)
    contrast: float  # median over the painted rows of centre / brighter side - 1
    side_ratio: float  # median over the painted rows of darker side / brighter side
    width_m: float  # full width at half the median profile's height
    foot_width_m: float  # full width at a quarter of its height


@functools.cache
def _saturation(dtype: np.dtype) -> float:
    """The largest grey level of an image of ``dtype`` (an integer type's largest; inf for a float)."""
    return float(np.iinfo(dtype).max) if dtype.kind in "ui" else math.inf


def painted_rows(
    img: np.ndarray,
    lane: Lane,
    geometry: BevGeometry,
    max_distance_m: float,
    band_m: float,
    gap_m: float,
    align_m: float,
    min_row_contrast: float,
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int, int]:
    """The painted rows of ``lane`` in the grey BEV ``img`` nearer than ``max_distance_m`` (found by
    :func:`_paint_rows_kernel`), which :func:`paint_cues` and ``_paint.paint_features`` measure:
    ``(inside, row, start, inv_level, measures, saturated, band, gap)``, the arrays (per painted row)
    cut to the painted rows; ``band`` and ``gap`` in pixels."""
    res = float(geometry.resolution)
    near = int(math.floor(geometry.metric_to_bev(0.0, max_distance_m)[1]))
    r0, r1 = max(int(lane.bev_rows[0]), 0, near), min(int(lane.bev_rows[1]), img.shape[0] - 1)
    band = max(int(round(band_m / res)), 2)
    gap = min(max(int(round(gap_m / res)), 1), band - 1)
    align = max(int(round(align_m / res)), 0)
    n = max(r1 - r0 + 1, 0)
    # per painted row: its BEV row, its strip's first column, 1 / its level, (contrast, side ratio)
    out = (np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n), np.empty((n, 2)))
    levels = (float(min_row_contrast), _saturation(img.dtype), _median_hist(img))
    coeffs = (float(c) for c in lane.coeffs)
    inside, painted, saturated = _paint_rows_kernel(img, r0, r1, *coeffs, band, gap, align, *levels, *out)
    p = int(painted)
    return (int(inside), *(a[:p] for a in out), int(saturated), band, gap)


def paint_cues(
    image: np.ndarray,
    lane: Lane,
    geometry: BevGeometry,
    *,
    max_distance_m: float = 25.0,
    band_m: float = 1.5,
    gap_m: float = 0.25,
    align_m: float = 0.1,
    min_row_contrast: float = 0.15,
    min_rows: int = 10,
) -> PaintCues:
    """The cross profile of ``lane`` in the grey BEV ``image``, on its rows nearer than
    ``max_distance_m``: its painted rows (:func:`_paint_rows_kernel`: the centre ``min_row_contrast``
    brighter than the brighter side band, ``gap_m .. band_m`` away), their median contrast and side
    ratio, and the widths of their median profile (each row divided by its brighter side's level;
    the median over the rows, offset by offset, of 64 to 127 of them spread evenly: a sun patch
    that a minority of the rows cross, a metre or more across, does not widen it as it widens
    their mean) at half and a quarter of its height above its base (the brighter of the profile's
    two side levels). The rows by :func:`painted_rows`."""
    img = _grey_bev(image)
    res = float(geometry.resolution)
    inside, row, start, inv_level, measures, saturated, band, gap = painted_rows(
        img, lane, geometry, max_distance_m, band_m, gap_m, align_m, min_row_contrast
    )
    painted = row.size
    nan = float("nan")
    if painted < max(min_rows, 1):
        return PaintCues(int(inside), int(painted), int(saturated), nan, nan, nan, nan)
    # the median profile over every k-th painted row, 64 to 127 of them: as good a median for a
    # width, at the cost of a mean (a median over all 300-400 near rows cost 0.1-0.2 ms a lane);
    # only those rows' strips are read and divided by their level
    k = slice(0, painted, max(1, painted // 64))
    strips = img[row[k, None], start[k, None] + np.arange(2 * band + 1)] * inv_level[k, None]
    profile = np.empty(2 * band + 1)
    _column_medians(strips, strips.shape[0], profile)
    # the other medians as columns too (np.median's values, the rows hold no NaN): the two side
    # bands' levels of the profile, the painted rows' contrast and side ratio
    levels = np.empty(2)
    _column_medians(
        np.stack((profile[: band - gap + 1], profile[band + gap :]), axis=1), band - gap + 1, levels
    )
    base = max(float(levels[0]), float(levels[1]))
    height = profile[band] - base
    meds = np.empty(2)
    _column_medians(measures, painted, meds)
    c_med, r_med = float(meds[0]), float(meds[1])
    if height <= 0.0:
        return PaintCues(int(inside), int(painted), int(saturated), c_med, r_med, nan, nan)
    return PaintCues(
        int(inside),
        int(painted),
        int(saturated),
        c_med,
        r_med,
        _crossing_width(profile, band, base + 0.5 * height) * res,
        _crossing_width(profile, band, base + 0.25 * height) * res,
    )


@jit
def _bar_profile_kernel(img, r0, r1, c0, c1, c2, band_px, min_contrast):
    """The mean lateral profile of the lane ``col = c0 + c1 t + c2 t^2`` (``t = rows - 1 - row``)
    over its painted rows, for :func:`neighbour_bars`: every 2nd row of ``r0 .. r1`` whose strip
    (columns ``round(col) - band_px .. round(col) + band_px``) is inside the image, less the
    strip's darkest pixel (the road level: a per-row constant, which the profile's top-hat does
    not see); painted rows have a centre (+-1 px) above it by ``min_contrast`` and by half the
    90th percentile of that over the rows. Returns ``(profile, painted rows)``; a zero profile and
    0 with fewer than 10 rows. Two passes over the rows (the contrasts, then the painted rows'
    sums) instead of keeping the strip."""
    rows, cols = img.shape
    w = 2 * band_px + 1
    nmax = (r1 - r0) // 2 + 1 if r1 >= r0 else 0
    start = np.empty(nmax, np.int64)
    rr = np.empty(nmax, np.int64)
    base = np.empty(nmax, np.float64)
    contrast = np.empty(nmax, np.float64)
    m = 0
    for r in range(r0, r1 + 1, 2):
        t = rows - 1 - r
        ce = int(np.rint(c0 + c1 * t + c2 * t * t))
        if ce - band_px < 0 or ce + band_px >= cols:
            continue
        a = ce - band_px
        strip = img[r, a : a + w]  # a 1-D slice: the loops over it vectorise
        least = strip[0]  # in the image's own type (exact, and it vectorises), then as a float
        for j in range(1, w):
            least = min(least, strip[j])
        b = least + 0.0
        c = max(strip[band_px - 1], strip[band_px], strip[band_px + 1]) - b
        start[m] = a
        rr[m] = r
        base[m] = b
        contrast[m] = c
        m += 1
    profile = np.empty(w, np.float64)  # np.zeros(w) as a loop: numba compiles no np.zeros (first run)
    for i in range(w):
        profile[i] = 0.0
    if m < 10:
        return profile, 0
    work = np.empty(m, np.float64)
    for i in range(m):
        work[i] = contrast[i]
    thr = max(min_contrast, 0.5 * percentile_inplace(work, work.size, 90.0))  # np.percentile's value
    n = 0
    for i in range(m):
        if contrast[i] >= thr:
            n += 1
            strip = img[rr[i], start[i] : start[i] + w]
            b = base[i]
            for j in range(w):
                profile[j] += strip[j] - b
    if n > 0:
        for j in range(w):
            profile[j] = profile[j] / n
    return profile, n


@jit
def _bar_offsets_kernel(profile, band_px, min_offset_px, max_bar_px, min_contrast):
    """The offsets (middles, right positive) of the bars of a lane's mean lateral ``profile``
    (offsets ``-band_px .. band_px``, as :func:`_bar_profile_kernel` returns it), as
    :func:`neighbour_bars` describes: the white top-hat of width ``L = max_bar_px + 1`` (the
    profile less its opening: the minimum over each window of ``L`` offsets, the profile's ends
    repeated beyond it, then the maximum of those minima over the windows holding each offset),
    then the runs of offsets from ``min_offset_px`` out on each side whose top-hat reaches a third
    of the lane's own (centre +-1) and ``min_contrast / 2``: right side first, outwards, then the
    left side from its outer end."""
    n = profile.size
    L = max_bar_px + 1
    eroded = np.empty(
        n + L - 1, np.float64
    )  # eroded[e]: the minimum over offsets e - L + 1 .. e (ends repeated)
    for e in range(n + L - 1):
        lo = e - (L - 1)
        v = profile[min(max(lo, 0), n - 1)]
        for q in range(lo + 1, e + 1):
            v = min(v, profile[min(max(q, 0), n - 1)])
        eroded[e] = v
    tophat = np.empty(n, np.float64)
    for j in range(n):
        v = eroded[j]
        for e in range(j + 1, j + L):
            v = max(v, eroded[e])
        tophat[j] = profile[j] - v
    lane = max(tophat[band_px - 1], tophat[band_px], tophat[band_px + 1])
    thr = max(lane / 3.0, 0.5 * min_contrast)
    centres = np.empty(n, np.float64)
    bars = 0
    for lo, hi in ((band_px + min_offset_px, n), (0, band_px - min_offset_px + 1)):
        start = -1
        for j in range(lo, hi + 1):
            cur = j < hi and tophat[j] >= thr
            if cur and start < 0:
                start = j
            elif not cur and start >= 0:
                centres[bars] = 0.5 * (start + j - 1) - band_px  # the run's middle, as an offset
                bars += 1
                start = -1
    return centres[:bars]


def neighbour_bars(
    image: np.ndarray, lane: Lane, band_px: int, min_offset_px: int, max_bar_px: int, min_contrast: float
) -> np.ndarray:
    """The offsets (BEV pixels, right positive) of the bright bars beside ``lane`` (see the module
    docstring). The BEV image is sampled along the lane (every 2nd of its rows, offsets
    ``-band_px .. band_px`` from its centre; rows whose strip leaves the image skipped), less each
    row's road level (its darkest pixel). The painted rows are those whose centre (+-1 px) stands
    above the road level by ``min_contrast`` and by half the 90th percentile of that over the
    lane's rows (its paint, not the road's texture): :func:`_bar_profile_kernel` averages them. The profile's white top-hat of
    width ``max_bar_px + 1`` keeps the ridges at most ``max_bar_px`` wide (a pavement's wide
    brightness goes, and so does a ridge cut off at the band's end); a run of offsets from
    ``min_offset_px`` out whose top-hat reaches a third of the lane's own (and ``min_contrast / 2``)
    is a bar, on each side (:func:`_bar_offsets_kernel`). An empty array with fewer than 10
    painted rows."""
    img, r0, r1 = _lane_rows_in(image, lane)
    c0, c1, c2 = (float(c) for c in lane.coeffs)
    profile, painted = _bar_profile_kernel(img, r0, r1, c0, c1, c2, int(band_px), float(min_contrast))
    if painted < 10:
        return np.empty(0)
    return _bar_offsets_kernel(
        profile, int(band_px), int(min_offset_px), int(max_bar_px), float(min_contrast)
    )


def crossing_pattern(offsets: np.ndarray, tolerance: float = 0.25) -> bool:
    """Whether bars at ``offsets`` beside a lane (itself a bar at 0) repeat like a crossing's: the
    nearest bar on each side about as far (within ``tolerance`` of the farther), or on one side a
    second bar about twice as far as the first. A kerb on one side and an arrow on the other, at
    unrelated distances, are not."""
    right = np.sort(offsets[offsets > 0])
    left = np.sort(-offsets[offsets < 0])
    if left.size and right.size and abs(left[0] - right[0]) <= tolerance * max(left[0], right[0]):
        return True
    return any(
        side.size >= 2 and abs(side[1] - 2.0 * side[0]) <= tolerance * side[1] for side in (left, right)
    )


@node_type(
    "lanes.verify",
    inputs=verify_inputs(
        "its pixels set the road level (brightness 'relative'; default: the BEV inside the image)",
        "is a much darker side level with the road",
    ),
    outputs={"lanes": "lanes"},
)
def verify(
    params: VerifyParams,
    lanes: list[Lane],
    image: np.ndarray,
    geometry: BevGeometry,
    mask: np.ndarray | None = None,
    disparity: np.ndarray | None = None,
    road: RoadModel | None = None,
    calib: Calibration | None = None,
) -> dict:
    """Keep the lanes that look like paint on a road: a bright stripe of paint width with road of like brightness on both sides, not among a crossing's bars (optionally: no textured surface beside it)."""
    if not lanes:
        return {"lanes": []}
    image = _grey_bev(image)  # before the road level reads the mask: a wrong image is the image's fault
    gain = 1.0  # measured grey levels -> grey levels of the thresholds
    if params.brightness == "relative":
        level = road_level(image, mask, params.level_quantile)
        if level is not None and level > 0:  # a black road has no level: the grey levels as they are
            gain = params.reference_level / level
    kept = []
    for ln in lanes:
        extra = dict(ln.extra)
        if params.paint_check:
            cues = paint_cues(
                image,
                ln,
                geometry,
                max_distance_m=params.max_distance_m,
                band_m=params.paint_band_m,
                gap_m=params.paint_gap_m,
                align_m=params.align_m,
                min_row_contrast=params.min_row_contrast,
                min_rows=params.min_painted_rows,
            )
            if not _is_paint(cues, params):
                continue
            levels = (ln, geometry, disparity, road, calib)
            if cues.side_ratio < params.min_side_ratio:  # a much darker side: a shadow, or gravel?
                rough = (
                    max(
                        side_texture(
                            image, ln, params.gap_px, params.band_px, params.measure, params.row_quantile
                        )
                    )
                    * gain
                )
                if rough > params.max_dark_side_texture:
                    continue
                if cues.side_ratio < params.step_side_ratio and dark_side_stepped(params, *levels):
                    continue  # smooth, but not level with the other side: a kerb and its gutter
            if kerb_across(params, *levels):
                continue  # a kerb's height across the lane, a level top beyond it: a kerb, not paint
            extra["paint"] = {
                "contrast": round(cues.contrast, 3),
                "side_ratio": round(cues.side_ratio, 3),
                "width_m": round(cues.width_m, 3),
                "foot_width_m": round(cues.foot_width_m, 3),
                "painted_rows": cues.painted,
                "saturated_rows": cues.saturated,
            }
        if params.max_texture is not None:
            left, right = side_texture(
                image, ln, params.gap_px, params.band_px, params.measure, params.row_quantile
            )
            left, right = left * gain, right * gain
            if max(left, right) > params.max_texture:
                continue
            extra["texture"] = [round(left, 1), round(right, 1)]
        if params.crossing_check and crossing_pattern(
            neighbour_bars(
                image,
                ln,
                params.crossing_band_px,
                params.crossing_min_offset_px,
                params.max_bar_px,
                params.min_contrast / gain,
            )
        ):
            continue
        kept.append(Lane(ln.coeffs, ln.bev_rows, ln.side, ln.score, ln.points, extra))
    return {"lanes": kept}


def _is_paint(cues: PaintCues, p: VerifyParams) -> bool:
    """Whether the measured cues are paint's: enough painted rows, bright on both sides, of paint
    width (NaN compares False: not paint). The side ratio is judged with the side's texture."""
    return (
        cues.painted >= p.min_painted_rows
        # paint clipped at the sensor's largest grey level on most of its rows (an overexposed frame)
        # shows less contrast than it has: it is as bright as the image can show
        and (cues.contrast >= p.min_paint_contrast or cues.saturated >= 0.5 * cues.painted)
        and p.min_width_m <= cues.width_m
        and cues.foot_width_m <= p.max_foot_width_m
    )
