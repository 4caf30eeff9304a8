"""``disparity.road_sgbm``: OpenCV SGBM over row bands, each searching only the disparities the
road and the obstacles on it can have there.

The previous frame's road profile (a feedback edge, ``road.road@prev``) predicts the road's
disparity ``d_r(v)`` on every row. On a row below the horizon nothing visible lies farther than
the road (nothing is seen through it), and an obstacle standing on the road is nearer: its
disparity exceeds ``d_r(v)``. A pixel at disparity ``d`` on row ``v`` lies ``h (1 - d_r(v) / d)``
above the road (``h`` the camera height), so a row needs at most

    d_r(v) - margin  <=  d  <=  max(d_r(v) / (1 - H_b / h) + margin,  min(f B / near_m, d_r(v) / (1 - H / h)))

with ``H_b = band_height_m`` (a kerb is matched as finely as the road) and ``H =
obstacle_height_m`` (the bottom of whatever stands on the road, nearer than ``near_m`` never: what
the road mask's free-space scan needs to end a column; no height bound when ``H >= h``). A higher
part of an obstacle lies beyond the range: SGBM's best match then sits at the range's top, still
an obstacle to the road mask. With ``obstacles: coarse`` the bands hold only the road's part and
the obstacles come from one SGBM search of the full range at ``obstacle_scale``, taken where it
lies outside the band's range. Rows whose predicted road lies beyond ``far_m`` (the road mask's
``max_distance_m``: nothing is road there) by more than the margin are not matched, and a band
matches only the columns whose road point lies within ``lateral_m`` of the camera's axis (the
bird's-eye view's width and a margin; every column from about 12 m ahead on KITTI).

The rows are split into bands of ``band_rows`` from the first computed row down, a split that
does not depend on the number of threads; each band is one ``cv2.StereoSGBM`` call with its own
``minDisparity`` / ``numDisparities`` (the union of its rows' ranges, a multiple of 16) on the band
extended by ``strip_overlap`` rows above (the paths from above start there) and a few below (the
block and OpenCV's 3x3 median; ``strip_overlap`` rows for the modes whose paths also come from
below), cut back to the band's own rows and columns. The bands run on as many threads as the
process has CPUs (:func:`lanegraph._runtime.available_cpus`: affinity mask and cgroup quota) or
``threads``; the map is the same whatever their number. OpenCV's speckle filter runs once on the
stitched map, so a speckle is judged whole across band borders. A match at a band's lowest
disparity (above ``min_disparity``) is left invalid: it is the range's edge, not a minimum. With
``one_left_border`` the columns left of the widest band's highest disparity are left invalid on
every row (:func:`left_border`), as one search of the full range leaves them: the road mask reads a
pixel without a disparity below a road pixel as road.

Without a usable prediction -- the first frame, a profile judged invalid, or one whose road
disparity does not grow down the rows or does not lie in ``(0, min_disparity + num_disparities]``
at the bottom row -- every band searches the full range ``[min_disparity, min_disparity +
num_disparities)`` on every column from ``top_fraction`` down.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import cv2
import numpy as np
from pydantic import Field, model_validator

from lanegraph import InputError, Port, node_type
from lanegraph.threads import available_cpus, worker_pool
from lanegraph.types import Calibration, RoadModel

from ._common import gray_pair, reduce_pair, scaled_disparities, upsample_disparity
from ._opencv import SgbmParams, _check_range, _sgbm_matcher

#: raw (1/16 px) value of an invalid pixel in the stitched map before the speckle filter
_INVALID_RAW = -16


class RoadSgbmParams(SgbmParams):
    """Params of ``disparity.road_sgbm`` (SGBM over row bands, ranges from the road profile)."""

    strip_overlap: int = Field(
        8,
        ge=0,
        le=256,
        description="rows each band extends upwards (and, for the modes with paths from below, "
        "downwards) for SGBM's paths to start, pixels of the computing resolution",
    )

    band_rows: int = Field(
        48,
        ge=8,
        le=1024,
        description="rows per band, pixels of the computing resolution; the split starts at the first "
        "computed row and does not depend on the number of threads",
    )
    threads: int = Field(
        0,
        ge=0,
        le=64,
        description="threads computing the bands; 0 = the CPUs free to the process (affinity mask, "
        "cgroup CPU quota). The map does not depend on it",
    )
    road_margin_px: float = Field(
        4.0,
        ge=0.0,
        le=128.0,
        description="disparities searched below and above the predicted road disparity, pixels of the "
        "input resolution (the road moves between frames: pitch, bumps)",
    )
    band_height_m: float = Field(
        0.3,
        ge=0.0,
        le=100.0,
        description="the band reaches the disparity of what stands this high on the road, metres (a "
        "kerb), besides the margin: at full resolution, where the road mask tells a kerb from the road",
    )
    one_left_border: bool = Field(
        False,
        description="leave the columns left of the widest band's highest disparity without a disparity "
        "on every row, as one full-range search does (the far bands otherwise reach further left, and "
        "the road mask's free-space scan reads the near rows without a disparity below them as road); "
        "off by default: on the synthetic S-bend it costs a frame and adds a false lane, and no scene "
        "measured gains a lane",
    )
    near_m: float = Field(
        5.0,
        gt=0.0,
        le=1000.0,
        description="the nearest obstacle the range must hold, metres: the range reaches f B / near_m "
        "(where the road itself is nearer, its band reaches further)",
    )
    obstacle_height_m: float = Field(
        0.5,
        gt=0.0,
        le=100.0,
        description="height above the road up to which an obstacle's disparity is searched, metres; a "
        "higher part matches at the range's top, still an obstacle to the road mask",
    )
    obstacles: Literal["band", "coarse"] = Field(
        "band",
        description="where the obstacles' disparities come from: 'coarse', the full range matched at "
        "obstacle_scale (a band at full resolution holds the road only, margin each side); 'band', "
        "each band's range reaches the obstacles' (near_m, obstacle_height_m) at full resolution",
    )
    obstacle_scale: float = Field(
        0.5,
        ge=0.25,
        le=1.0,
        description="resolution of the 'coarse' obstacle pass (unitless fraction of the computing "
        "resolution)",
    )
    coarse_tolerance_px: float = Field(
        2.0,
        ge=0.0,
        le=64.0,
        description="how far outside its band's range, pixels of the input resolution, the coarse "
        "disparity must lie to replace the band's ('coarse' obstacles)",
    )
    lateral_m: float = Field(
        12.0,
        ge=0.0,
        le=1000.0,
        description="a band matches only the columns whose road point lies within this distance of "
        "the camera's axis, metres (bev.ipm's x range, 10 m, and a margin); 0 = every column. "
        "With 'coarse' obstacles the other columns take the coarse disparity",
    )
    far_m: float = Field(
        80.0,
        gt=0.0,
        le=10000.0,
        description="rows whose predicted road lies farther than this (plus the margin), metres, are "
        "not matched: the road mask takes nothing beyond its max_distance_m as road",
    )

    @model_validator(mode="after")
    def _supported(self) -> RoadSgbmParams:
        for name, bad in (("lr_check", self.lr_check), ("wls", self.wls), ("strips", self.strips != 1)):
            if bad:
                raise ValueError(
                    f"{name}: not supported by disparity.road_sgbm (its rows are split in bands: "
                    "band_rows, threads); use disparity.sgbm for it"
                )
        return self


def usable_prediction(road: RoadModel | None, bottom_row: int, max_disp: float) -> bool:
    """Whether the previous frame's road model can guide the ranges: valid, finite, a positive
    camera height, and a disparity that grows down the rows and lies in ``(0, max_disp]`` at
    ``bottom_row`` (input pixels)."""
    if road is None or not road.valid or not road.height > 0:
        return False
    coefs = (road.a0, road.a1, road.a2, road.roll, road.height)
    if not all(math.isfinite(float(x)) for x in coefs):
        return False
    d_bottom = float(road.disparity_at(bottom_row))
    slope = road.a1 + 2.0 * road.a2 * bottom_row
    return 0.0 < d_bottom <= max_disp and slope > 0.0


def road_range(
    road: RoadModel, calib: Calibration, rows: np.ndarray, width: int, params: RoadSgbmParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What each of ``rows`` (input rows) needs matched, from the road model.

    Returns ``(lo, hi, road)``, input pixels: the disparities ``[lo, hi]`` worth searching -- the
    road's, ``road_margin_px`` each side (over the row's first and last column: the roll tilts the
    rows), and with ``obstacles: band`` up to the obstacles' (module docstring) -- and the road's
    largest disparity on the row; ``lo > hi`` marks a row that is not matched (its road beyond
    ``far_m``).
    """
    s = math.sin(road.roll) * calib.f_y / calib.f
    c = math.cos(road.roll)
    v = np.asarray(rows, np.float64)
    ends = (0.0 - calib.cx, (width - 1.0) - calib.cx)
    dr = np.stack([road.disparity_at(calib.cy + s * u + c * (v - calib.cy)) for u in ends])
    d_lo, d_hi = dr.min(axis=0), dr.max(axis=0)
    fb = calib.f * calib.baseline
    m = params.road_margin_px
    h = float(road.height)
    lo = d_lo - m
    # what stands up to band_height_m on the road (a kerb) is in the band
    hb = params.band_height_m
    hi = (d_hi / (1.0 - hb / h) if hb < h else np.full_like(d_hi, fb / params.near_m)) + m
    if params.obstacles == "band":
        H = params.obstacle_height_m
        near = fb / params.near_m
        obstacle = np.full_like(d_hi, near) if H >= h else np.minimum(near, d_hi / (1.0 - H / h))
        hi = np.maximum(hi, obstacle)
    skip = d_hi + m < fb / params.far_m
    lo[skip], hi[skip] = 1.0, 0.0
    return lo, hi, d_hi


class Band(NamedTuple):
    """One SGBM call: rows ``a .. b - 1`` and columns ``c0 .. c1 - 1`` (computing resolution),
    disparities ``low .. low + num - 1``."""

    a: int
    b: int
    low: int
    num: int
    c0: int
    c1: int


def band_plan(
    n_rows: int,
    width: int,
    first: int,
    band_rows: int,
    d_min: int,
    n_disp: int,
    ranges: tuple[np.ndarray, np.ndarray] | None = None,
    columns: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[Band]:
    """The bands of the rows ``first .. n_rows - 1`` (computing resolution), ``band_rows`` at a
    time from ``first`` down, whatever the number of threads.

    ``ranges``: per-row ``(lo, hi)`` disparities of all ``n_rows`` rows, ``lo > hi`` for a row not
    matched; None: every band searches ``[d_min, d_min + n_disp)``. A band's range is the union
    of its rows', widened to a multiple of 16 disparities and kept inside the full range; bands
    whose rows are all unmatched are left out. ``columns``: per-row ``(c0, c1)`` columns needed; a
    band covers the union of its rows' (all columns when None).
    """
    plan = []
    top = d_min + n_disp
    for a in range(first, n_rows, band_rows):
        b = min(n_rows, a + band_rows)
        c0, c1 = 0, width
        if columns is not None:
            c0 = max(0, int(columns[0][a:b].min()))
            c1 = min(width, int(columns[1][a:b].max()))
        if ranges is None:
            plan.append(Band(a, b, d_min, n_disp, c0, c1))
            continue
        lo, hi = ranges[0][a:b], ranges[1][a:b]
        keep = lo <= hi
        if not keep.any() or c1 <= c0:
            continue
        low = min(max(d_min, int(math.floor(float(lo[keep].min())))), top - 16)
        high = min(top, max(low + 1, int(math.ceil(float(hi[keep].max()))) + 1))
        num = min(n_disp, 16 * math.ceil((high - low) / 16))
        plan.append(Band(a, b, min(low, top - num), num, c0, c1))
    return plan


def left_border(plan: list[Band]) -> int:
    """The columns ``0 .. left_border - 1`` (computing resolution) that the road-guided map leaves
    without a disparity on every row: those left of the widest band's highest disparity.

    OpenCV's SGBM matches a column only where its whole range lies inside the image, so a band
    with a narrow range (the far rows) reaches further left than one with a wide range (the near
    rows). Column by column, the road mask would then see disparities on the far rows above none
    on the near rows, and its free-space scan reads a pixel without a disparity below a road pixel
    as road (smooth asphalt): a kerb or a verge at the image's left edge would become road, which
    one search of the full range (one border, every row) does not do."""
    return max((b.low + b.num for b in plan), default=0)


def _band(
    params: RoadSgbmParams, gl: np.ndarray, gr: np.ndarray, band: Band, d_min: int, out: np.ndarray
) -> None:
    """Raw 1/16-px disparities of one band's own rows and columns written into ``out`` (the whole
    map, ``_INVALID_RAW`` elsewhere; where invalid, ``_INVALID_RAW``). The bands write disjoint
    blocks of ``out``, so that they can run on threads without a copy per band."""
    h, w = gl.shape
    below = params.block_size // 2 + 1 if params.mode == "sgbm" else params.strip_overlap
    r0, r1 = max(0, band.a - params.strip_overlap), min(h, band.b + below)
    # the columns left of c0 that its pixels' matches reach (OpenCV leaves them invalid) and
    # a block's half beyond c1
    x0 = max(0, band.c0 - (band.low + band.num))
    x1 = min(w, band.c1 + params.block_size // 2 + 1)
    matcher = _sgbm_matcher(params.model_copy(update={"speckle_window_size": 0}), band.num, band.low)
    raw = matcher.compute(np.ascontiguousarray(gl[r0:r1, x0:x1]), np.ascontiguousarray(gr[r0:r1, x0:x1]))
    raw = raw[band.a - r0 : band.b - r0, band.c0 - x0 : band.c1 - x0]
    floor = 16 * (band.low + 1) if band.low > d_min else 16 * band.low
    # below the floor (or not positive): invalid. One masked copy (cv2 compare and copyTo, no
    # temporaries of np.where) into the band's block of the map
    mask = cv2.compare(raw, max(floor, 1), cv2.CMP_GE)
    cv2.copyTo(raw, mask, out[band.a : band.b, band.c0 : band.c1])


@node_type(
    "disparity.road_sgbm",
    inputs={
        "left": Port("image", "left rectified image"),
        "right": Port("image", "right rectified image"),
        "road": Port(
            "road_model",
            "the road profile that predicts this frame's road disparity: the previous frame's "
            "(a feedback edge, road.road@prev); the full range on every row when not wired or invalid",
            optional=True,
        ),
        "calib": Port(
            "calibration",
            "stereo calibration (f B, cx, cy), needed with 'road'",
            rate="constant",
            optional=True,
        ),
    },
    outputs={"disparity": "disparity"},
    ahead=True,
)
def road_sgbm(
    params: RoadSgbmParams,
    left: np.ndarray,
    right: np.ndarray,
    road: RoadModel | None = None,
    calib: Calibration | None = None,
) -> dict:
    """Disparity by OpenCV SGBM over row bands, each searching the range the road predicts.

    Parameters
    ----------
    params : RoadSgbmParams
        Matcher params, band height, threads, margins and distances.
    left, right : ndarray
        Rectified pair, HxW gray or HxWx3 BGR uint8, same size.
    road : RoadModel, optional
        The previous frame's road profile; the full range when None or not usable.
    calib : Calibration, optional
        Stereo calibration; required when ``road`` is given.

    Returns
    -------
    dict
        ``disparity``: HxW float32 disparity of the left image in pixels (input resolution);
        invalid pixels (and rows not matched) are 0.
    """
    if road is not None and calib is None:
        raise InputError("input 'calib': needed with the 'road' input (f B, cx, cy of the road model)")
    gl, gr = gray_pair(left, right)
    H, W = gl.shape
    gl, gr, s = reduce_pair(gl, gr, float(params.scale))
    h, w = gl.shape
    n_disp = scaled_disparities(params.num_disparities, s, 16)
    d_min = int(round(params.min_disparity * s))
    _check_range(w, d_min, n_disp, params.block_size, s)
    first = min(int(round(params.top_fraction * h)), h - 1)
    ranges = columns = None
    if road is not None and usable_prediction(
        road, H - 1, float(params.min_disparity + params.num_disparities)
    ):
        assert calib is not None
        rows_in = (np.arange(h) + 0.5) / (h / H) - 0.5  # input rows of the computing rows' centres
        lo, hi, d_road = road_range(road, calib, rows_in, W, params)
        ranges = (lo * s, hi * s)
        if params.lateral_m > 0:
            # x = (u - cx) B / d on the road: |x| <= lateral_m within cx -+ d lateral_m / B
            half = d_road * s * params.lateral_m / calib.baseline
            cx = (calib.cx + 0.5) * s - 0.5
            pad = params.block_size
            columns = (np.floor(cx - half) - pad, np.ceil(cx + half) + pad + 1)
    plan = band_plan(h, w, first, params.band_rows, d_min, n_disp, ranges, columns)
    jobs: list = [("band", job) for job in plan]
    coarse = ranges is not None and params.obstacles == "coarse" and bool(plan)
    if coarse:
        jobs.append(("coarse", plan[0].a))
    raw = np.full((h, w), _INVALID_RAW, np.int16)
    results = _run_jobs(params, gl, gr, jobs, d_min, raw)
    if params.one_left_border and ranges is not None and plan:
        # one left border for every band, the widest band's: a column there is matched on no row
        raw[:, : left_border(plan)] = _INVALID_RAW
    if plan and params.speckle_window_size > 0:
        # on the rows the bands cover only: the rows above are all invalid, and OpenCV's speckle
        # filter neither starts from nor joins an invalid pixel, so it is the same map
        top = plan[0].a
        cv2.filterSpeckles(raw[top:], _INVALID_RAW, params.speckle_window_size, 16 * params.speckle_range)
    # every valid value is positive (the bands keep > 0), every other one _INVALID_RAW: clipping
    # at 0 before the exact scaling by 1/16 gives the 0 of an invalid pixel in place
    d = raw.astype(np.float32)
    np.maximum(d, 0.0, out=d)
    d *= np.float32(1.0 / 16.0)
    if coarse:
        d = merge_coarse(d, results[-1], plan, (w, h), params.coarse_tolerance_px * s)
    return {"disparity": upsample_disparity(d, (H, W), s, params.upsample)}


def _run_jobs(
    params: RoadSgbmParams,
    gl: np.ndarray,
    gr: np.ndarray,
    jobs: list,
    d_min: int,
    raw: np.ndarray,
) -> list[np.ndarray | None]:
    """Every band (written into ``raw``) and the coarse pass on the thread pool; the results in
    the jobs' order (None for a band)."""

    def run(item):
        kind, job = item
        if kind == "band":
            return _band(params, gl, gr, job, d_min, raw)
        return _coarse(params, gl, gr, job)

    if not jobs:
        return []
    n = params.threads or available_cpus()
    n = max(1, min(n, len(jobs)))
    if n == 1:
        return [run(item) for item in jobs]
    # the coarse pass is the longest job: started first, the bands fill the other threads
    order = sorted(range(len(jobs)), key=lambda i: jobs[i][0] != "coarse")
    done = dict(zip(order, worker_pool("bands", n).map(run, [jobs[i] for i in order])))
    return [done[i] for i in range(len(jobs))]


def _coarse(params: RoadSgbmParams, gl: np.ndarray, gr: np.ndarray, first: int) -> np.ndarray:
    """The full range at ``obstacle_scale`` on the rows from ``first`` (computing rows) down,
    brought back to the computing resolution: float32 disparities, invalid = 0."""
    h, w = gl.shape
    cl, cr, cs = reduce_pair(gl, gr, float(params.obstacle_scale))
    size = (cl.shape[1], cl.shape[0])
    top = max(0, int(math.floor(first * size[1] / h)) - params.strip_overlap)
    cl, cr = cl[top:], cr[top:]
    num = scaled_disparities(params.num_disparities, cs, 16)
    mind = int(round(params.min_disparity * cs))
    _check_range(size[0], mind, num, params.block_size, cs)
    raw = _sgbm_matcher(params, num, mind).compute(cl, cr)
    dc = np.zeros((size[1], size[0]), np.float32)
    dc[top:] = raw.astype(np.float32) * np.float32(1.0 / 16.0)
    dc[top:][raw < max(16 * mind, 1)] = 0.0
    return upsample_disparity(dc, (h, w), cs, "nearest")


def merge_coarse(
    fine: np.ndarray, coarse: np.ndarray, plan: list[Band], size: tuple[int, int], tol: float
) -> np.ndarray:
    """The road bands' disparities, and the coarse pass's where it lies outside the range the
    pixel's band searched.

    A pixel takes the coarse disparity when that lies more than ``tol`` pixels above or below its
    band's range (an obstacle nearer than the band reaches, something beyond the road) or when no
    band covers it (its columns or rows); else the band's, also where the band found none (an
    ambiguous match at full resolution stays without a disparity, as in one SGBM call). Both HxW
    float32 at the computing resolution, invalid = 0."""
    w, h = size
    lo = np.full((h, w), np.inf, np.float32)
    hi = np.full((h, w), -np.inf, np.float32)
    for band in plan:
        lo[band.a : band.b, band.c0 : band.c1] = band.low
        hi[band.a : band.b, band.c0 : band.c1] = band.low + band.num - 1
    use = (coarse > 0) & ((coarse > hi + tol) | (coarse < lo - tol))
    return np.where(use, coarse, fine).astype(np.float32)
