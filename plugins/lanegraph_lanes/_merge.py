"""``lanes.merge``: at most one lane each side from the verified Hough lanes and the verified lanes
that ``lanes.follow`` followed (see :func:`merge`)."""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field

from lanegraph import NodeParams, Port, node_type
from lanegraph.types import BevGeometry, FeatureMap, Lane


class MergeParams(NodeParams):
    """Params of ``lanes.merge``."""

    parallel_m: float = Field(
        0.5,
        gt=0.0,
        le=20.0,
        description="a lane and a followed line on its side that never meet and whose distance changes by at most this "
        "over the BEV rows both cover are two parallel markings, metres",
    )
    meet_m: float = Field(
        0.15,
        gt=0.0,
        le=5.0,
        description="a lane and a followed line on its side are one marking where they come this close on some BEV row "
        "(a marking's width), metres",
    )
    min_support_ratio: float = Field(
        1.2,
        ge=0.0,
        le=100.0,
        description="a lane is replaced only when the followed line has this many times its features (within half of "
        "meet_m, on the rows both cover) (unitless)",
    )
    min_followed_m: float = Field(
        15.0,
        ge=0.0,
        le=500.0,
        description="a followed lane that stops short of the same line's lane replaces it (when it is the closer fit) "
        "only when it covers this much road: a dashed line's period, 3 m + 9 m to 6 m + 12 m, so that its parabola "
        "rests on two dashes or more, metres",
    )
    min_lane_width_m: float = Field(
        2.0,
        gt=0.0,
        le=20.0,
        description="a followed lane added beside a lane must be this far from it on every BEV row both cover (a lane's "
        "width), metres",
    )


@node_type(
    "lanes.merge",
    inputs={
        "lanes": Port("lanes", "lanes of one method (the Hough lines' fit, verified)"),
        "followed": Port("lanes", "lanes of another (lanes.follow's, verified)"),
        "straddled": Port(
            "lanes",
            "lines the car straddles (lanes.follow's straddled, verified): a side without a lane",
            optional=True,
        ),
        "features": Port("features", "the features both were found on: which lane they support"),
        "geometry": Port("bev_geometry"),
    },
    outputs={"lanes": "lanes"},
)
def merge_node(
    params: MergeParams,
    lanes: list[Lane],
    followed: list[Lane],
    features: FeatureMap,
    geometry: BevGeometry,
    straddled: list[Lane] | None = None,
) -> dict:
    """At most one lane each side from two lists: a side without a lane takes the followed one; a
    lane that the features support less than the followed line on its side is replaced by it; a
    side still without a lane takes a line the car straddles."""
    out = merge(list(lanes or []), list(followed or []), geometry, params, features)
    return {"lanes": add_straddled(out, list(straddled or []), geometry, params)}


def add_straddled(
    lanes: list[Lane], straddled: list[Lane], geometry: BevGeometry, p: MergeParams
) -> list[Lane]:
    """``lanes`` with each line the car straddles whose side has no lane, when it lies a lane's width
    (``min_lane_width_m``) from every lane on every BEV row both cover: an arrow or a seam in a
    lane's middle lies half a lane's width from its boundaries."""
    out = list(lanes)
    for ln in straddled:
        if any(o.side == ln.side for o in out) or any(
            min(abs(ln.coeffs[0] - o.coeffs[0]), _gaps_px(o, ln, geometry.rows)[1]) * geometry.resolution
            < p.min_lane_width_m
            for o in out
        ):
            continue
        out.append(ln)
    out.sort(key=lambda ln: ln.coeffs[0])
    return out


def _gaps_px(a: Lane, b: Lane, rows: int) -> tuple[float, float, float]:
    """Mean and smallest column distance of two lanes over the BEV rows both cover, and how much it
    changes there (largest minus smallest signed distance); inf when they share no row."""
    lo = max(a.bev_rows[0], b.bev_rows[0])
    hi = min(a.bev_rows[1], b.bev_rows[1])
    if hi <= lo:
        return math.inf, math.inf, 0.0
    t = rows - 1 - np.arange(lo, hi + 1, dtype=np.float64)
    ca = a.coeffs[0] + a.coeffs[1] * t + a.coeffs[2] * t * t
    cb = b.coeffs[0] + b.coeffs[1] * t + b.coeffs[2] * t * t
    d = ca - cb
    return float(np.abs(d).mean()), float(np.abs(d).min()), float(d.max() - d.min())


def _support(features: FeatureMap | None, lane: Lane, lo: int, hi: int, half_px: float) -> int:
    """How many features lie within ``half_px`` columns of ``lane`` on BEV rows ``lo..hi``."""
    if features is None:
        return 0
    r, c = features.points()
    i0, i1 = np.searchsorted(r, [lo, hi + 1])
    rr, cc = r[i0:i1], c[i0:i1]
    rows = features.shape[0]
    t = (rows - 1 - rr).astype(np.float64)
    a, b, q = lane.coeffs
    return int(np.count_nonzero(np.abs(cc - (a + b * t + q * t * t)) <= half_px))


def merge(
    have: list[Lane],
    found: list[Lane],
    geometry: BevGeometry,
    p: MergeParams,
    features: FeatureMap | None = None,
) -> list[Lane]:
    """The lanes ``have`` (a straight Hough line's fit, verified) with the followed lanes ``found``:
    a side without a lane takes the followed one; a side whose lane runs elsewhere than the followed
    line there (more than ``meet_m``, a marking's width, apart on average over the rows both cover)
    and either meets it (within ``meet_m`` on some row) or is not parallel to it (their distance
    changes by more than ``parallel_m``) takes the followed one when more features lie on it
    (``min_support_ratio`` times, within half of ``meet_m``, on those rows); a parallel line is another marking:
    one orientation and a straight Hough line misplace a lane in a bend, while a followed line keeps
    to its features window by window (asking the followed line for more features as well lost
    one ramp frame in 16 and changed nothing on the other sequences)."""
    rows = geometry.rows
    res = geometry.resolution
    out = list(have)
    # the replacements first, then the additions: a lane added beside the others is checked against
    # the lanes that are kept (a misplaced Hough lane that a followed line replaces must not keep
    # the other side's followed line out)
    sides = {o.side for o in out}
    for ln in [f for f in found if f.side in sides] + [f for f in found if f.side not in sides]:
        same = [o for o in out if o.side == ln.side]
        if same:
            o = same[0]
            mean_gap, min_gap, spread = _gaps_px(o, ln, rows)
            if mean_gap * res <= p.meet_m:
                # the same line where both are. The followed lane's parabola stops where the line's
                # features leave it (its curvature changes there); a lane reaching beyond it is one
                # parabola over a changing curvature (an S-bend; a dashed line is fitted over the
                # whole BEV), a compromise on the near part too: the followed lane is taken when
                # more features lie within half a marking's width of it on the rows both cover and
                # it covers a dashed line's period (a shorter one rests on one dash: it may stray)
                if (
                    ln.bev_rows[0] > o.bev_rows[0]
                    and ln.bev_rows[1] - ln.bev_rows[0] >= p.min_followed_m / res
                ):
                    lo, hi = max(o.bev_rows[0], ln.bev_rows[0]), min(o.bev_rows[1], ln.bev_rows[1])
                    half = 0.5 * p.meet_m / res
                    if _support(features, ln, lo, hi, half) > _support(features, o, lo, hi, half):
                        out[out.index(o)] = ln
                continue
            if min_gap * res >= p.meet_m and spread * res <= p.parallel_m:
                continue  # another marking beside it, parallel
            # the features within half a marking's width of each (as above): within a whole width
            # a lane that crosses the line at a small angle keeps most of them
            lo, hi = max(o.bev_rows[0], ln.bev_rows[0]), min(o.bev_rows[1], ln.bev_rows[1])
            half = 0.5 * p.meet_m / res
            if _support(features, ln, lo, hi, half) > p.min_support_ratio * _support(
                features, o, lo, hi, half
            ):
                out[out.index(o)] = ln
            continue
        # a lane beside the others: a lane's width from each on every BEV row both cover
        if any(
            min(abs(ln.coeffs[0] - o.coeffs[0]), _gaps_px(o, ln, rows)[1]) * res < p.min_lane_width_m
            for o in out
        ):
            continue
        out.append(ln)
    out.sort(key=lambda ln: ln.coeffs[0])
    return out
