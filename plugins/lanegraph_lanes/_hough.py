"""Global lane orientation (histogram of feature orientations), 1D Hough and 2D Hough.

1D Hough (the paper's eq. 4): with the global orientation ``theta`` known, every feature at BEV
pixel ``(x, y)`` votes for ``rho = x - (H - y) / tan(theta)``, the column where its line crosses the
bottom edge of the BEV (``H`` = number of rows). 2D Hough: the classic accumulator over
(rho, theta) with the same parametrisation, theta sampled in a window around vertical.

Peak selection (``select``):

- ``paper``: the two strongest peaks (after non-maximum suppression), as the paper states.
- ``nearest`` (default): on each side of the vehicle, the nearest peak that is strong enough
  (``min_votes`` and ``min_relative`` of the strongest peak on that side) and at a plausible lateral
  distance (``min_offset_m`` .. ``max_offset_m``). On real roads the two strongest peaks are often
  an outer solid line and a kerb or rail rather than the ego-lane boundaries.

  Lane changes (``lane_change``, with the previous frame's lanes on ``previous``): the line being
  crossed passes under the vehicle, nearer than ``min_offset_m``, and the other boundary of the new
  (or old) lane is then a lane's width away, beyond ``max_offset_m``. A peak nearer than
  ``min_offset_m`` is taken on its side only when it continues a previous lane (within
  ``track_match_m``), which an arrow or a hatching between the lanes does not; the other side's
  boundary may then lie up to ``max_lane_width_m`` from it.
"""

from __future__ import annotations

import functools
import math
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from lanegraph import InputError, NodeParams, Port, jit, node_type, prange
from lanegraph.types import BevGeometry, FeatureMap, Lane, Line


@jit
def _vote_bins(rows_idx, cols_idx, height, inv_tan, offset, bins):
    """``bins[i] = round(x - (height - y) * inv_tan) + offset`` of every feature (a loop without
    branches, vectorised)."""
    for i in range(rows_idx.shape[0]):
        bins[i] = int(math.floor(cols_idx[i] - (height - rows_idx[i]) * inv_tan + 0.5)) + offset


@jit
def _vote_1d(rows_idx, cols_idx, height, inv_tan, offset, acc):
    """Each feature adds 1 at bin ``round(x - (height - y) * inv_tan) + offset`` (if inside): the
    bins first, then the counts."""
    n = acc.shape[0]
    bins = np.empty(rows_idx.shape[0], np.int64)
    _vote_bins(rows_idx, cols_idx, height, inv_tan, offset, bins)
    for i in range(bins.shape[0]):
        b = bins[i]
        if 0 <= b < n:
            acc[b] += 1.0


@jit(parallel=True)
def _vote_2d(rows_idx, cols_idx, height, inv_tans, offset, acc):
    """2D accumulator: for every theta (row of ``acc``) each feature votes like :func:`_vote_1d`.
    Thetas in parallel; per theta the counts go to two interleaved integer accumulators (the
    features of one row often share a bin: one accumulator would chain every increment)."""
    nt, n = acc.shape
    m = rows_idx.shape[0]
    for t in prange(nt):
        bins = np.empty(m, np.int64)
        _vote_bins(rows_idx, cols_idx, height, inv_tans[t], offset, bins)
        part = np.zeros((2, n + 1), np.int64)
        for i in range(m):
            b = bins[i]
            part[i & 1, b if 0 <= b < n else n] += 1
        for b in range(n):
            acc[t, b] += part[0, b] + part[1, b]


@functools.lru_cache(maxsize=32)
def _gaussian_kernel(sigma: float) -> np.ndarray:
    """The normalised Gaussian of ``sigma`` (bins), ``2 * round(3 sigma) + 1`` taps; cached, read-only."""
    r = int(3 * sigma + 0.5)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k = k / k.sum()
    k.flags.writeable = False
    return k


def _smooth(acc: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing of a 1D histogram; the result has the length of ``acc`` (also when the
    kernel is longer than ``acc``, where ``np.convolve(mode="same")`` would return the kernel's)."""
    if sigma <= 0 or acc.size == 0:
        return acc
    k = _gaussian_kernel(float(sigma))
    r = k.size // 2
    return np.convolve(acc, k, mode="full")[r : r + acc.size]


def find_peaks(acc: np.ndarray, min_separation: int, min_value: float = 0.0) -> list[int]:
    """Indices of local maxima, strongest first (the first index on ties), with non-maximum
    suppression within ``min_separation`` bins. Only values ``> 0`` and ``>= min_value`` are
    peaks; the peaks that reach ``min_value`` are the same as without it (a weaker peak suppresses
    only weaker ones), found without sorting the whole accumulator."""
    if acc.size == 0 or acc.max() <= 0:
        return []
    cand = np.flatnonzero((acc > 0) & (acc >= min_value))
    order = cand[np.argsort(-acc[cand], kind="stable")]  # stable: index order on ties, as before
    taken: list[int] = []
    suppressed = np.zeros(acc.size, bool)
    for i in order:
        if suppressed[i]:
            continue
        taken.append(int(i))
        suppressed[max(0, i - min_separation) : i + min_separation + 1] = True
    return taken


class OrientationParams(NodeParams):
    """Params of ``lanes.orientation``."""

    bin_deg: float = Field(1.0, ge=0.01, le=10.0, description="histogram bin width, degrees")
    smooth_bins: float = Field(1.5, ge=0.0, le=20.0, description="Gaussian smoothing of the histogram, bins")
    max_deviation_deg: float = Field(
        35.0,
        gt=0.0,
        le=90.0,
        description="only orientations within this of straight ahead (90 deg) count, degrees",
    )
    default_deg: float = Field(
        90.0, ge=1.0, le=179.0, description="orientation when there are no oriented features (SLT), degrees"
    )
    min_features: int = Field(
        50, ge=1, le=1000000, description="fewer oriented features than this: use the default"
    )


@functools.lru_cache(maxsize=32)
def _uniform_edges(lo: float, hi: float, nb: int, dtype: str) -> np.ndarray:
    """The ``nb + 1`` bin edges of ``np.histogram(..., bins=nb, range=(lo, hi))`` on values of
    ``dtype`` (its ``np.linspace``), cached: a node asks for the same ones every frame. Read-only."""
    edges = np.linspace(lo, hi, nb + 1, endpoint=True, dtype=np.dtype(dtype))
    edges.flags.writeable = False
    return edges


def uniform_histogram(values: np.ndarray, lo: float, hi: float, nb: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.histogram(values, bins=nb, range=(lo, hi))`` for float ``values`` already within
    ``[lo, hi]`` (the last bin closed on the right), with the same counts (intp) and edges, bit for
    bit: numpy's own binning of a uniform range (the index ``(x - lo) / (hi - lo) * nb`` in the same
    dtypes, then corrected by one where it disagrees with the edges) without its per-call checks
    and edge computation (a quarter of a millisecond on a few thousand values)."""
    a = np.asarray(values)
    if a.dtype.kind != "f":  # integers and the like: numpy's full path
        return np.histogram(a, bins=nb, range=(lo, hi))
    edges = _uniform_edges(lo, hi, nb, np.result_type(lo, hi, a).str)
    a = a.astype(edges.dtype, copy=False)
    norm_denom = np.subtract(hi, lo, dtype=np.result_type(hi, lo))
    idx = ((np.subtract(a, lo, dtype=np.result_type(a, lo)) / norm_denom) * nb).astype(np.intp)
    idx[idx == nb] -= 1
    idx[a < edges[idx]] -= 1
    idx[(a >= edges[idx + 1]) & (idx != nb - 1)] += 1
    return np.bincount(idx, minlength=nb), edges


@node_type("lanes.orientation", inputs={"features": "features"}, outputs={"orientation": "orientation"})
def orientation(params: OrientationParams, features: FeatureMap) -> dict:
    """Global lane orientation: the peak of the histogram of feature orientations (lanes are parallel in the BEV)."""
    default = math.radians(params.default_deg)
    ori = features.point_orientations()
    if ori is None:
        return {"orientation": default}
    lo, hi = math.radians(90 - params.max_deviation_deg), math.radians(90 + params.max_deviation_deg)
    ori = ori[(ori >= lo) & (ori <= hi)]  # also drops the unknown ones (-1)
    if ori.size < params.min_features:
        return {"orientation": default}
    nb = max(1, int(round(math.degrees(hi - lo) / params.bin_deg)))
    hist, edges = uniform_histogram(ori, lo, hi, nb)
    sm = _smooth(hist.astype(np.float64), params.smooth_bins)
    k = int(np.argmax(sm))
    centre = 0.5 * (edges[k] + edges[k + 1])
    near = np.abs(ori - centre) <= 1.5 * (edges[1] - edges[0])
    theta = float(np.mean(ori[near])) if near.any() else float(centre)
    return {"orientation": theta}


class HoughParams(NodeParams):
    """Peak selection params shared by ``hough.line1d`` and ``hough.line2d``."""

    select: Literal["nearest", "paper"] = Field(
        "nearest",
        description="nearest strong peak each side of the vehicle, or the paper's two strongest peaks",
    )
    smooth_px: float = Field(
        2.0, ge=0.0, le=50.0, description="Gaussian smoothing of the accumulator, BEV pixels"
    )
    min_separation_m: float = Field(
        1.2, gt=0.0, le=20.0, description="non-maximum suppression distance between peaks, metres"
    )
    min_votes: float = Field(
        40.0, ge=0.0, le=1e7, description="a peak needs at least this many (smoothed) votes"
    )
    min_votes_visible: float | None = Field(
        None,
        ge=0.0,
        le=1e7,
        description="with the BEV road mask wired (`mask`): a line the mask shows on a fraction f of the BEV's rows needs "
        "max(min_votes_visible, min_votes f) (smoothed) votes, at most min_votes: a line hidden by parked cars or beyond "
        "the road's end collects votes only where the road is seen (a metre of a 15 cm line gives about 10); None: "
        "min_votes for every line",
    )
    min_relative: float = Field(
        0.25,
        ge=0.0,
        le=1.0,
        description="nearest rule: a peak needs this fraction of the strongest peak on its side",
    )
    min_offset_m: float = Field(
        0.6,
        ge=0.0,
        le=20.0,
        description="nearest rule: closest plausible lateral distance of a lane boundary, metres",
    )
    max_offset_m: float = Field(
        3.2,
        gt=0.0,
        le=50.0,
        description="nearest rule: farthest plausible lateral distance of a lane boundary, metres",
    )
    lane_change: bool = Field(
        True,
        description="nearest rule with `previous` lanes: a peak nearer than min_offset_m that continues a previous lane is the "
        "line being crossed in a lane change, and the other side's boundary may then lie up to max_lane_width_m from it",
    )
    track_match_m: float = Field(
        0.8,
        gt=0.0,
        le=5.0,
        description="lane change: a peak continues a previous lane within this lateral distance (the lane at its bottom row, the peak where its straight line meets the bottom edge: on a curve they differ), metres",
    )
    max_lane_width_m: float = Field(
        4.6, gt=0.0, le=20.0, description="lane change: widest plausible lane, metres"
    )


def _select(
    acc: np.ndarray,
    offset: int,
    theta: float,
    geometry: BevGeometry,
    p: HoughParams,
    previous: list[Lane] | None = None,
    mask: np.ndarray | None = None,
) -> list[Line]:
    res = geometry.resolution
    sm = _smooth(acc, p.smooth_px)
    sep = max(1, int(round(p.min_separation_m / res)))
    if mask is None or p.min_votes_visible is None or p.min_votes_visible >= p.min_votes:
        peaks = find_peaks(sm, sep, p.min_votes)
    else:
        # the weaker peaks of lines the road mask shows on part of the BEV only (a weaker peak
        # suppresses only weaker ones: the peaks above min_votes are those find_peaks gives)
        peaks = [
            i
            for i in find_peaks(sm, sep, p.min_votes_visible)
            if sm[i]
            >= min(
                p.min_votes, max(p.min_votes_visible, p.min_votes * visible_fraction(mask, i - offset, theta))
            )
        ]

    def lateral(i: int) -> float:
        return geometry.lateral_m(i - offset)  # the peak's offset from the vehicle at the bottom row

    if p.select == "paper":
        chosen = sorted(peaks, key=lambda i: -sm[i])[:2]
    else:
        # lane change: the previous lanes' lateral offsets at the bottom row (their model's c0)
        prev_lat = [
            geometry.lateral_m(ln.coeffs[0])
            for ln in previous or []
            if p.lane_change and math.isfinite(ln.coeffs[0])
        ]

        def crossing(i: int) -> bool:
            """A peak under the vehicle that continues a previous lane: the line being crossed."""
            return abs(lateral(i)) < p.min_offset_m and any(
                abs(lateral(i) - lp) <= p.track_match_m for lp in prev_lat
            )

        strong = {}
        chosen_side = {}
        for sign in (-1, 1):
            side = [i for i in peaks if sign * lateral(i) > 0]
            if not side:
                continue
            best = max(sm[i] for i in side)
            strong[sign] = [i for i in side if sm[i] >= p.min_relative * best]
            ok = [
                i for i in strong[sign] if p.min_offset_m <= abs(lateral(i)) <= p.max_offset_m or crossing(i)
            ]
            if ok:
                chosen_side[sign] = min(ok, key=lambda i: abs(lateral(i)))
        for sign in (-1, 1):
            c = chosen_side.get(-sign)
            if sign in chosen_side or sign not in strong or c is None or not crossing(c):
                continue
            # the other side of a lane change: its boundary is a lane's width from the crossed line
            ok = [
                i
                for i in strong[sign]
                if abs(lateral(i)) >= p.min_offset_m and abs(lateral(i) - lateral(c)) <= p.max_lane_width_m
            ]
            if ok:
                chosen_side[sign] = min(ok, key=lambda i: abs(lateral(i)))
        chosen = list(chosen_side.values())
    lines = [
        Line(
            rho=float(i - offset), theta=theta, votes=float(sm[i]), side="left" if lateral(i) < 0 else "right"
        )
        for i in chosen
    ]
    return sorted(lines, key=lambda ln: ln.rho)


def visible_fraction(mask: np.ndarray, rho: float, theta: float) -> float:
    """The fraction of the BEV's rows on which the road mask (bool, rows x cols) is set where the
    line of ``rho`` (its column at the bottom edge, as the 1D Hough votes) and orientation ``theta``
    (radians) crosses them; rows where it runs outside the BEV count as not shown."""
    m = np.asarray(mask, dtype=bool)
    rows, cols = m.shape
    if rows == 0:
        return 0.0
    inv_tan = math.cos(theta) / max(math.sin(theta), 1e-6)
    y = np.arange(rows)
    x = np.floor(rho + (rows - y) * inv_tan + 0.5).astype(np.int64)
    ok = (x >= 0) & (x < cols)
    return float(m[y[ok], x[ok]].sum()) / rows


_MASK_PORT = Port(
    "bev_mask",
    "the BEV road mask: the vote minimum of a line it shows on part of the BEV only (see min_votes_visible)",
    optional=True,
)

_PREVIOUS_PORT = Port(
    "lanes", "the previous frame's lanes (a feedback edge): lane changes (see lane_change)", optional=True
)


def _feature_coords(features: FeatureMap) -> tuple[np.ndarray, np.ndarray]:
    """The features' rows and columns as int32 (pixel coordinates: the voting kernels read half
    the memory of int64 or float64 and convert them to float64 exactly)."""
    r, c = features.points()
    return r.astype(np.int32), c.astype(np.int32)


@node_type(
    "hough.line1d",
    inputs={
        "features": "features",
        "orientation": "orientation",
        "geometry": Port("bev_geometry"),
        "previous": _PREVIOUS_PORT,
        "mask": _MASK_PORT,
    },
    outputs={"lines": "lines"},
)
def line1d(
    params: HoughParams,
    features: FeatureMap,
    orientation: float,
    geometry: BevGeometry,
    previous: list[Lane] | None = None,
    mask: np.ndarray | None = None,
) -> dict:
    """1D Hough over rho = x - (H - y) / tan(theta) with the global orientation; at most two lines."""
    rows, cols = features.shape
    r, c = _feature_coords(features)
    theta = float(orientation)
    if not math.isfinite(theta):
        raise InputError(f"hough.line1d: orientation: expected a finite angle in radians, got {theta}")
    inv_tan = math.cos(theta) / max(math.sin(theta), 1e-6)
    offset = 2 * cols  # rho may lie left of the BEV when lines slant
    acc = np.zeros(5 * cols, np.float64)
    _vote_1d(r, c, float(rows), inv_tan, offset, acc)
    if mask is not None and np.shape(mask) != (rows, cols):
        raise InputError(
            f"hough.line1d: mask: expected a BEV mask of the features' shape {(rows, cols)}, got {np.shape(mask)}"
        )
    return {"lines": _select(acc, offset, theta, geometry, params, previous, mask)}


class Hough2dParams(HoughParams):
    """Params of ``hough.line2d``."""

    theta_range_deg: float = Field(
        30.0, gt=0.0, le=89.0, description="thetas searched: 90 deg +- this, degrees"
    )
    theta_step_deg: float = Field(
        0.5, ge=0.05, le=10.0, description="theta resolution, degrees (at most 600 thetas)"
    )

    @model_validator(mode="after")
    def _thetas_bounded(self):
        # the accumulator and the voting grow with the number of thetas: at most 5x the default's 121
        n = 2 * self.theta_range_deg / self.theta_step_deg + 1
        if n > 600:
            raise ValueError(
                f"2 * theta_range_deg / theta_step_deg + 1 = {n:.0f} thetas, more than 600; raise theta_step_deg"
            )
        return self


@node_type(
    "hough.line2d",
    inputs={
        "features": "features",
        "orientation": Port("orientation", "ignored; kept for drop-in swaps", optional=True),
        "geometry": Port("bev_geometry"),
        "previous": _PREVIOUS_PORT,
        "mask": _MASK_PORT,
    },
    outputs={"lines": "lines"},
)
def line2d(
    params: Hough2dParams,
    features: FeatureMap,
    geometry: BevGeometry,
    orientation: float | None = None,
    previous: list[Lane] | None = None,
    mask: np.ndarray | None = None,
) -> dict:
    """Classic 2D (rho, theta) Hough: the strongest theta row is the lane orientation; peaks chosen as in 1D."""
    rows, cols = features.shape
    r, c = _feature_coords(features)
    thetas = np.radians(
        np.arange(90 - params.theta_range_deg, 90 + params.theta_range_deg + 1e-9, params.theta_step_deg)
    )
    inv = np.cos(thetas) / np.maximum(np.sin(thetas), 1e-6)
    offset = 2 * cols
    acc = np.zeros((thetas.size, 5 * cols), np.float64)
    _vote_2d(r, c, float(rows), inv, offset, acc)
    if not r.size:
        return {"lines": []}
    # the theta whose smoothed accumulator has the strongest peak structure (sum of the top peaks)
    score = [np.sort(_smooth(a, params.smooth_px))[-3:].sum() for a in acc]
    t = int(np.argmax(score))
    if mask is not None and np.shape(mask) != (rows, cols):
        raise InputError(
            f"hough.line2d: mask: expected a BEV mask of the features' shape {(rows, cols)}, got {np.shape(mask)}"
        )
    return {"lines": _select(acc[t], offset, float(thetas[t]), geometry, params, previous, mask)}
