"""``lanes.near_paint``: a finer look near the car for a side that has no lane.

The 5 cm bird's-eye view resolves a 10-12 cm line as two pixels: its features break up, its
measured width falls under a marking's (the BEV samples a near line every 5-6 image pixels, with no
low-pass), and a line seen over only a few metres (two short dashes beside parked cars) has too few
features for the Hough vote, the fit or the follower. Near the car the image holds far more: at
6-15 m a 12 cm line spans 6-14 image pixels. This node warps the image again, onto a fine grid
(``resolution``, 2 cm) over the near ``near_m`` metres and ``max_offset_m`` to each side, and looks
there, on each side without a lane, for a straight stripe of paint:

- per row of the fine grid, a *painted* pixel is a local brightness maximum (within ``gap_m``)
  that stands ``min_row_contrast`` above the mean of the brighter of its two side bands
  (``gap_m .. band_m`` away; relative, so exposure and shadow change nothing);
- the painted pixels vote for straight lines within ``max_slope`` of straight ahead (a Hough
  transform over offset and slope, one vote a row), offsets ``min_offset_m .. max_offset_m`` from
  the camera's axis;
- a line's *dashes* are its runs of rows with a painted pixel within ``tolerance_m`` (gaps of two
  rows bridged) at least ``min_dash_m`` long whose own direction is the line's (within
  ``max_dash_slope_diff``: a sun streak or a car's edge crossing the line is no dash of it);
- a line is paint when its dashes cover ``min_painted_m`` of road, one of them ``min_run_m``, their
  median contrast is ``min_paint_contrast``, their rows' median widths are ``min_width_m ..
  max_width_m`` at half height and at most ``max_foot_width_m`` at a quarter (each row measured
  on its own, against its own side level: the fine grid measures a 12 cm line as 10-12 cm), and,
  with the disparity wired, its dashes lie on the road plane (their median height above it within
  ``max_line_height_m``: a kerb's lit top stands 7-10 cm above it).

The nearest such line on a side becomes a lane over the rows it is painted on, in the coarse BEV's
coordinates (``geometry``). Sides that already have a lane are not looked at: the node only adds.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from pydantic import Field, model_validator

from lanegraph import NodeParams, Port, node_type
from lanegraph.types import BevGeometry, Calibration, Lane, RoadModel

from ._heights import heights_at, median_height, plane_fits


class NearPaintParams(NodeParams):
    """Params of ``lanes.near_paint``."""

    near_m: float = Field(
        15.0,
        gt=0.0,
        le=100.0,
        description="the fine grid reaches this far ahead of the camera (from the BEV's near end), metres",
    )
    resolution: float = Field(0.02, ge=0.005, le=0.05, description="the fine grid's pixel size, metres")
    min_offset_m: float = Field(
        0.6, ge=0.0, le=20.0, description="closest plausible lateral distance of a lane boundary, metres"
    )
    max_offset_m: float = Field(
        3.2, gt=0.0, le=20.0, description="farthest plausible lateral distance of a lane boundary, metres"
    )
    max_slope: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="lines within this lateral drift per metre ahead of straight ahead are looked for (0.1: 5.7 deg)",
    )
    slope_step: float = Field(
        0.005, gt=0.0, le=0.1, description="the Hough transform's slope step (unitless)"
    )
    gap_m: float = Field(
        0.15,
        gt=0.0,
        le=1.0,
        description="the side bands start this far from a row's centre (beyond the widest paint's half), metres",
    )
    band_m: float = Field(0.35, gt=0.0, le=3.0, description="the side bands end this far from it, metres")
    min_row_contrast: float = Field(
        0.35,
        ge=0.0,
        le=10.0,
        description="a row is painted where its local maximum is this much brighter than the brighter side band's "
        "mean (relative)",
    )
    tolerance_m: float = Field(
        0.06, gt=0.0, le=1.0, description="a painted pixel within this of a line is on it, metres"
    )
    min_painted_m: float = Field(
        1.5, gt=0.0, le=100.0, description="a line's painted rows must cover this much road, metres"
    )
    min_run_m: float = Field(
        0.8,
        gt=0.0,
        le=100.0,
        description="and one run of them (gaps of at most two rows bridged) this much: a dash, metres",
    )
    min_dash_m: float = Field(
        0.3,
        gt=0.0,
        le=100.0,
        description="a run of painted rows shorter than this is no dash (a stone, a patch), metres",
    )
    max_dash_slope_diff: float = Field(
        0.05,
        ge=0.0,
        le=1.0,
        description="a dash's own direction may differ from the line's by this lateral drift per metre (a streak "
        "crossing the line is no dash of it) (unitless)",
    )
    min_paint_contrast: float = Field(
        0.7, ge=0.0, le=10.0, description="the painted rows' median contrast (relative)"
    )
    min_width_m: float = Field(
        0.095,
        ge=0.0,
        le=1.0,
        description="narrowest median profile at half height, metres (the narrowest marking is 10 cm)",
    )
    max_width_m: float = Field(
        0.3, gt=0.0, le=2.0, description="widest median profile at half height, metres"
    )
    max_foot_width_m: float = Field(
        0.36, gt=0.0, le=2.0, description="widest median profile at a quarter of its height, metres"
    )
    max_line_height_m: float | None = Field(
        0.05,
        gt=0.0,
        le=2.0,
        description="with the disparity, road and calib wired: the line's median height above the road plane may be "
        "at most this (paint lies on the road), metres; null: not checked",
    )

    @model_validator(mode="after")
    def _check(self) -> NearPaintParams:
        if self.band_m <= self.gap_m:
            raise ValueError(f"band_m ({self.band_m}) must exceed gap_m ({self.gap_m})")
        if self.max_offset_m <= self.min_offset_m:
            raise ValueError(
                f"max_offset_m ({self.max_offset_m}) must exceed min_offset_m ({self.min_offset_m})"
            )
        if self.max_width_m < self.min_width_m:
            raise ValueError(
                f"max_width_m ({self.max_width_m}) must be at least min_width_m ({self.min_width_m})"
            )
        return self


def fine_grid(geometry: BevGeometry, params: NearPaintParams, sides=("left", "right")) -> BevGeometry:
    """The fine grid: ``max_offset_m + band_m`` to each of ``sides`` (``band_m`` on the other),
    from the coarse BEV's near end to ``near_m`` ahead (at most its far end), at ``resolution``;
    the same road plane and pose."""
    res = float(params.resolution)
    half = params.max_offset_m + params.band_m
    x_min = -half if "left" in sides else -params.band_m
    x_max = half if "right" in sides else params.band_m
    z_min = geometry.z_min
    z_max = min(geometry.z_max, max(params.near_m, geometry.z_min + 1.0))
    # fine pixel (c, r) -> metric (x, z) -> coarse pixel: H_coarse @ G
    rc = geometry.resolution
    g = np.array(
        [
            [res / rc, 0.0, (x_min + 0.5 * res - geometry.x_min) / rc - 0.5],
            [0.0, res / rc, (geometry.z_max - (z_max - 0.5 * res)) / rc - 0.5],
            [0.0, 0.0, 1.0],
        ]
    )
    return BevGeometry(x_min, x_max, z_min, z_max, res, geometry.H_img_from_bev @ g)


def warp_fine(image: np.ndarray, fine: BevGeometry) -> np.ndarray:
    """The grey image on the fine grid (float32; 0 outside the image). A uint8 image is warped as
    it is (the grid is far smaller than the image) and converted after."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2GRAY)
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        img = img.astype(np.float32)
    bev = cv2.warpPerspective(
        np.ascontiguousarray(img),
        fine.H_img_from_bev,
        (fine.cols, fine.rows),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    return bev.astype(np.float32, copy=False)


def side_levels(bev: np.ndarray, gap_px: int, band_px: int) -> np.ndarray:
    """Per pixel: the mean grey level of the brighter of its two side bands (``gap_px .. band_px``
    left and right of it along the row); 0 where a band leaves the grid or holds a 0 (outside the
    image). Box filters (float32)."""
    bev = np.ascontiguousarray(bev, dtype=np.float32)
    rows, cols = bev.shape
    out = np.zeros(bev.shape, np.float32)
    lo, hi = band_px, cols - band_px  # centres whose bands are inside the grid
    if hi <= lo:
        return out
    n = band_px - gap_px + 1
    # mean[:, j] = the mean of bev[:, j .. j + n - 1] (anchor at the window's first pixel); a window
    # holding a 0 has its least value 0 (an erosion with the same window)
    box = functools.partial(
        cv2.boxFilter, ddepth=-1, ksize=(n, 1), anchor=(0, 0), borderType=cv2.BORDER_CONSTANT
    )
    mean = box(bev)
    least = cv2.erode(
        bev, np.ones((1, n), np.uint8), anchor=(0, 0), borderType=cv2.BORDER_CONSTANT, borderValue=0
    )
    mean[least <= 0] = 0.0
    left = mean[:, lo - band_px : hi - band_px]  # bands c - band .. c - gap
    right = mean[:, lo + gap_px : hi + gap_px]  # and c + gap .. c + band
    level = np.maximum(left, right)
    level[(left <= 0) | (right <= 0)] = 0.0
    out[:, lo:hi] = level
    return out


def painted_pixels(bev: np.ndarray, level: np.ndarray, gap_px: int, min_row_contrast: float):
    """The painted pixels ``(rows, cols)``: local maxima of the grey level within ``gap_px`` along
    the row (the first of equal ones) that stand ``min_row_contrast`` (relative) above their
    brighter side band's mean ``level`` (> 0)."""
    k = 2 * gap_px + 1
    peak = cv2.dilate(bev, np.ones((1, k), np.uint8), borderType=cv2.BORDER_REPLICATE)
    cand = (bev >= peak) & (level > 0) & (bev >= (1.0 + min_row_contrast) * level)
    # the first of equal maxima in a row: drop a candidate whose left neighbour is one too
    cand[:, 1:] &= ~(cand[:, :-1] & (bev[:, 1:] == bev[:, :-1]))
    return np.nonzero(cand)


def _runs(rows: np.ndarray, bridge: int) -> list[tuple[int, int]]:
    """The runs of the sorted distinct ``rows`` with gaps of at most ``bridge`` rows: ``(first
    index, last index)`` into ``rows`` of each."""
    if rows.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(rows) > bridge + 1)
    starts = np.concatenate(([0], breaks + 1))
    ends = np.concatenate((breaks, [rows.size - 1]))
    return list(zip(starts.tolist(), ends.tolist()))


def row_widths(strips: np.ndarray, band: int, gap: int, fraction: float) -> np.ndarray:
    """Per row of ``strips`` (offsets ``-band .. band`` around a painted pixel): the width (pixels,
    linearly interpolated at both ends) of the run around the centre at or above the row's base
    (the brighter side band's mean, ``gap .. band`` away) plus ``fraction`` of the centre's height
    above it."""
    n, w = strips.shape
    base = np.maximum(strips[:, : band - gap + 1].mean(axis=1), strips[:, band + gap :].mean(axis=1))
    thr = base + fraction * (strips[:, band] - base)
    above = strips >= thr[:, None]
    # consecutive pixels above from the centre outwards, each way
    nl = np.cumprod(above[:, band::-1], axis=1).sum(axis=1) - 1
    nr = np.cumprod(above[:, band:], axis=1).sum(axis=1) - 1
    i = np.arange(n)
    a, b = band - nl, band + nr
    am, bp = np.maximum(a - 1, 0), np.minimum(b + 1, w - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        fl = np.where(
            (a > 0) & (strips[i, a] > strips[i, am]),
            (strips[i, a] - thr) / (strips[i, a] - strips[i, am]),
            0.0,
        )
        fr = np.where(
            (b < w - 1) & (strips[i, b] > strips[i, bp]),
            (strips[i, b] - thr) / (strips[i, b] - strips[i, bp]),
            0.0,
        )
    return (b - a) + fl + fr


def line_measures(
    bev: np.ndarray,
    level: np.ndarray,
    pr: np.ndarray,
    pc: np.ndarray,
    x0: float,
    slope: float,
    fine: BevGeometry,
    params: NearPaintParams,
) -> dict | None:
    """What the line ``x = x0 + slope (z - z_min)`` (metres) measures on the fine grid (see the module
    docstring): its dashes (runs of rows with a painted pixel within ``tolerance_m``, gaps of two
    rows bridged, ``min_dash_m`` long or more, each straight along the line), their painted length
    and longest one, median contrast and median row widths at half and a quarter height, and the
    line refitted on them; None without a dash."""
    res = fine.resolution
    tol = params.tolerance_m / res
    _, z = fine.bev_to_metric(np.zeros(pr.size), pr)
    cl, _ = fine.metric_to_bev(x0 + slope * (z - fine.z_min), z)
    near = np.abs(pc - cl) <= tol
    r, c, d = pr[near], pc[near], np.abs(pc - cl)[near]
    band = int(round(params.band_m / res))
    gap = int(round(params.gap_m / res))
    keep = (c - band >= 0) & (c + band < bev.shape[1])
    r, c, d = r[keep], c[keep], d[keep]
    if r.size < 3:
        return None
    # one painted pixel a row (the nearest to the line), rows in order
    order = np.lexsort((d, r))
    r, c = r[order], c[order]
    first = np.concatenate(([True], r[1:] != r[:-1]))
    r, c = r[first], c[first]
    min_dash = max(int(round(params.min_dash_m / res)), 3)
    dashes = []
    for a, b in _runs(r, 2):
        rr, cc = r[a : b + 1], c[a : b + 1]
        if rr[-1] - rr[0] + 1 < min_dash:
            continue
        # straight along the line: its own slope (columns per row, rows run against z) within
        # max_dash_slope_diff of the line's
        rf = rr - rr.mean()
        ds = -float((rf * (cc - cc.mean())).sum() / (rf * rf).sum())
        if abs(ds - slope) > params.max_dash_slope_diff:
            continue
        dashes.append((rr, cc))
    if not dashes:
        return None
    r = np.concatenate([q[0] for q in dashes])
    c = np.concatenate([q[1] for q in dashes])
    lengths = [int(q[0][-1] - q[0][0] + 1) for q in dashes]
    xr, zr = fine.bev_to_metric(c, r)
    m = {
        "painted_m": sum(lengths) * res,
        "run_m": max(lengths) * res,
        "dashes": len(dashes),
        "contrast": float(np.median(bev[r, c] / level[r, c])) - 1.0,
        "width_m": math.nan,
        "foot_width_m": math.nan,
        "z_near": float(zr.min()),
        "z_far": float(zr.max()),
        "x0": x0,
        "slope": slope,
        "rows": r,
        "cols": c,
    }
    if (
        m["painted_m"] < params.min_painted_m
        or m["run_m"] < params.min_run_m
        or m["contrast"] < params.min_paint_contrast
    ):
        return m  # not paint whatever its width: the profiles are not measured
    strips = bev[r[:, None], c[:, None] + np.arange(-band, band + 1)]
    m["width_m"] = float(np.median(row_widths(strips, band, gap, 0.5))) * res
    m["foot_width_m"] = float(np.median(row_widths(strips, band, gap, 0.25))) * res
    if np.ptp(zr) > 0.5:
        m["slope"], m["x0"] = (float(v) for v in np.polyfit(zr - fine.z_min, xr, 1))
    return m


def _is_paint(m: dict, p: NearPaintParams) -> bool:
    return (
        m["painted_m"] >= p.min_painted_m
        and m["run_m"] >= p.min_run_m
        and m["contrast"] >= p.min_paint_contrast
        and p.min_width_m <= m["width_m"] <= p.max_width_m
        and m["foot_width_m"] <= p.max_foot_width_m
    )


def hough_lines(pr, pc, fine: BevGeometry, params: NearPaintParams, side: str, min_votes: int):
    """Straight lines through the painted pixels on ``side``: ``(votes, x0, slope)`` of the peaks
    of the (offset, slope) accumulator (one bin a fine pixel), strongest first, at least
    ``min_votes``; offsets ``x0`` at the grid's near end, metres."""
    res = fine.resolution
    x, z = fine.bev_to_metric(pc, pr)
    sel = (x < 0) if side == "left" else (x > 0)
    x, z = x[sel], z[sel] - fine.z_min
    if x.size < min_votes:
        return []
    n_s = int(round(params.max_slope / params.slope_step))
    slopes = np.arange(-n_s, n_s + 1) * params.slope_step
    lo = -params.max_offset_m - params.max_slope * (fine.z_max - fine.z_min) if side == "left" else 0.0
    hi = 0.0 if side == "left" else params.max_offset_m + params.max_slope * (fine.z_max - fine.z_min)
    nb = int(math.ceil((hi - lo) / res)) + 1
    # the bin of each pixel's line at each slope (float32: bins of 2 cm over a few metres)
    xb = ((x - lo) / res).astype(np.float32)
    zb = (z / res).astype(np.float32)
    b = np.rint(xb[None, :] - slopes.astype(np.float32)[:, None] * zb[None, :]).astype(np.int32)
    ok = (b >= 0) & (b < nb)
    b += (np.arange(slopes.size, dtype=np.int32) * nb)[:, None]  # one row of bins a slope
    acc = np.bincount(b[ok], minlength=slopes.size * nb).reshape(slopes.size, nb).astype(np.float32)
    # a line's painted pixels spread over the bins within its tolerance
    k = 2 * int(round(params.tolerance_m / res)) + 1
    acc = cv2.blur(acc, (k, 1), borderType=cv2.BORDER_CONSTANT) * k
    peaks = []
    work = acc
    # peaks apart by 30 cm halfway up the grid (where the lines are seen), whatever their slopes
    sep = 0.3
    z_mid = 0.5 * (fine.z_max - fine.z_min)
    bins = np.arange(nb, dtype=np.float64)[None, :]
    slopes = slopes[:, None]
    for _ in range(6):
        i = int(np.argmax(work))
        si, bi = divmod(i, nb)
        v = work[si, bi]
        if v < min_votes:
            break
        x0p, sp = lo + bi * res, float(slopes[si, 0])
        peaks.append((float(v), x0p, sp))
        # the bins of every slope whose line passes within sep of this one halfway up
        mid = x0p + sp * z_mid
        work[
            (bins >= (mid - sep - slopes * z_mid - lo) / res - 1.0)
            & (bins <= (mid + sep - slopes * z_mid - lo) / res + 1.0)
        ] = 0.0
    return peaks


def near_paint_lanes(
    params: NearPaintParams,
    lanes: list[Lane],
    image: np.ndarray,
    geometry: BevGeometry,
    disparity: np.ndarray | None = None,
    road: RoadModel | None = None,
    calib: Calibration | None = None,
) -> tuple[list[Lane], list[dict]]:
    """The lanes and, for every side looked at, what its candidate lines measured (for the debug
    data and the tests)."""
    sides = [s for s in ("left", "right") if not any(ln.side == s for ln in lanes)]
    if not sides:
        return list(lanes), []
    fine = fine_grid(geometry, params, sides)
    bev = warp_fine(image, fine)
    res = fine.resolution
    gap = max(int(round(params.gap_m / res)), 1)
    band = max(int(round(params.band_m / res)), gap + 1)
    level = side_levels(bev, gap, band)
    pr, pc = painted_pixels(bev, level, gap, params.min_row_contrast)
    out = list(lanes)
    seen: list[dict] = []
    min_votes = int(params.min_painted_m / res)
    wired = disparity is not None and road is not None and calib is not None
    z_mid = 0.5 * (fine.z_max - fine.z_min)
    for side in sides:
        peaks = hough_lines(pr, pc, fine, params, side, min_votes)
        # nearest first (the offset halfway up the grid); the first that is paint is the lane
        peaks.sort(key=lambda q: abs(q[1] + q[2] * z_mid))
        for votes, x0, slope in peaks:
            if not params.min_offset_m - 0.5 <= abs(x0 + slope * z_mid) <= params.max_offset_m + 0.5:
                continue
            m = line_measures(bev, level, pr, pc, x0, slope, fine, params)
            if m is None:
                continue
            m.update(side=side, votes=votes)
            seen.append(m)
            off = abs(m["x0"] + m["slope"] * (0.5 * (m["z_near"] + m["z_far"]) - fine.z_min))
            if not (params.min_offset_m <= off <= params.max_offset_m) or not _is_paint(m, params):
                continue
            if params.max_line_height_m is not None and wired:
                disp = np.asarray(disparity)
                h = math.nan
                if plane_fits(disp, road, calib):  # the dashes' median height above the road plane
                    h = median_height(heights_at(fine, disp, road, calib, m["rows"], m["cols"]))
                m["line_height_m"] = h
                if not abs(h) <= params.max_line_height_m:  # NaN: not known to lie on the road
                    continue
            m["chosen"] = True
            out.append(_lane(m, geometry, side))
            break
    return out, seen


def _lane(m: dict, geometry: BevGeometry, side: str) -> Lane:
    """The lane ``x = x0 + slope (z - z_near_end)`` in the coarse BEV over the rows it is painted on."""
    res = geometry.resolution
    rows = geometry.rows
    x0, s = m["x0"], m["slope"]
    # coarse row r <-> z = z_min + (t + 0.5) res with t = rows - 1 - r; col = (x - x_min) / res - 0.5
    c0 = (x0 + s * 0.5 * res - geometry.x_min) / res - 0.5
    c1 = s
    _, r_far = geometry.metric_to_bev(0.0, m["z_far"])
    _, r_near = geometry.metric_to_bev(0.0, m["z_near"])
    r0 = max(int(math.floor(float(r_far))), 0)
    r1 = min(int(math.ceil(float(r_near))), rows - 1)
    extra = {
        "near_paint": {
            k: round(float(m[k]), 3) for k in ("painted_m", "run_m", "contrast", "width_m", "foot_width_m")
        }
    }
    score = min(1.0, m["painted_m"] / max(m["z_far"] - m["z_near"], res))
    return Lane((float(c0), float(c1), 0.0), (r0, r1), side, score, None, extra)


@node_type(
    "lanes.near_paint",
    inputs={
        "lanes": Port("lanes", "the lanes found so far (lanes.merge's): a side with one is not looked at"),
        "image": Port("image", "the left image (grey or BGR), warped again onto the fine grid"),
        "geometry": Port("bev_geometry", "the BEV grid the lanes are in (bev.ipm's): pose and coordinates"),
        "disparity": Port(
            "disparity", "the left disparity map: does the line lie on the road", optional=True
        ),
        "road": Port("road_model", "the road profile and pose (road.profile)", optional=True),
        "calib": Port("calibration", "stereo calibration", optional=True, rate="constant"),
    },
    outputs={"lanes": "lanes"},
)
def near_paint(
    params: NearPaintParams,
    lanes: list[Lane],
    image: np.ndarray,
    geometry: BevGeometry,
    disparity: np.ndarray | None = None,
    road: RoadModel | None = None,
    calib: Calibration | None = None,
) -> dict:
    """A side without a lane: the nearest straight stripe of paint on a finer bird's-eye view of the
    near road (2 cm over the near 15 m), added as a lane."""
    found, _ = near_paint_lanes(params, list(lanes or []), image, geometry, disparity, road, calib)
    return {"lanes": found}
