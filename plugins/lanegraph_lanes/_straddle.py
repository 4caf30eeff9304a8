"""A line the car straddles (``lanes.follow``'s ``straddled`` lanes), and the features a track's
windows missed along its own parabola.

On a narrow two-way street a car drives over the worn centre line: the line lies between its
wheels, 0.3-0.6 m from the camera's column, nearer than a lane boundary beside the car
(``min_offset_m``, which keeps arrows and seams in the lane's middle out). ``lanes.follow`` reports
such a line on a port of its own, ``straddled``, one a side at most, when its features show a
marking along the road: the inliers of one parabola (as every followed lane's) over more road than
an arrow or a patch covers (``straddle_min_extent_m``; an arrow's shaft and head are 5 m).
It gets a paint check of its own (in ``paper.yaml`` a ``lanes.verify`` node, ``verify_straddled``,
whose width floor is not the kerb's: no kerb's lit edge lies between a car's wheels), and
``lanes.merge`` adds it only to a side that has no lane, a lane's width from the lanes it keeps.

Gaps (:func:`collect_along`): a track's windows place it by a straight-line fit over the window's
features, and after a long gap (the window widened) stray features in dappled shade can pull the
fit off the line; the next dash is then missed although the track's parabola runs along it
(kitti15_000024: 65 of the line's 110 features taken). A track under the car (its parabola in the
straddled band) whose windows took fewer features than a lane needs (``min_inliers``) counts the
features no other line took within a marking's width (``extend_px``) of its parabola, inside its
own span, oriented along it: the support a lane needs is then measured on the line, not lowered.
Only there: for a line beside the car the windows' count stays the rule (counting along a parabola
that a stray fleck bent at a track's end lets a track of one dash and the fleck through; the
straddled line has its own paint check after it).
"""

from __future__ import annotations

import numpy as np

from ._fit import irls_fit


def collect_along(
    sel, tr: dict, t, c, theta, owner, extend_px: float, cos_max: float, where=None
) -> np.ndarray:
    """``sel`` (the indices of track ``tr``'s features, row-major order) with the free features
    (``owner`` -1) within ``extend_px`` columns of the parabola through them, on the rows the track
    spans (``t_lo``..``t_hi``), whose orientation (when known) lies within ``acos(cos_max)`` of the
    parabola's heading there; those are marked as the track's in ``owner``. Unchanged when the track
    has fewer than 10 features (no parabola to speak of), or when ``where`` (a function of the
    parabola's column at the bottom row) says no."""
    if sel.size < 10:
        return sel
    coef, _ = irls_fit(t[sel], c[sel], 2)
    if where is not None and not where(float(coef[0])):
        return sel
    # the rows t_hi..t_lo: t is descending in the points' row-major order
    i0 = int(np.searchsorted(-t, -tr["t_hi"], side="left"))
    i1 = int(np.searchsorted(-t, -tr["t_lo"], side="right"))
    idx = np.arange(i0, i1)
    tt = t[idx]
    on = np.abs(c[idx] - (coef[0] + coef[1] * tt + coef[2] * tt * tt)) <= extend_px
    heading = np.arctan2(1.0, coef[1] + 2.0 * coef[2] * tt)  # radians from +column towards +t
    th = theta[idx]
    along = (th < 0.0) | (np.abs(np.cos(th - heading)) >= cos_max)
    new = idx[on & along & (owner[idx] < 0)]
    owner[new] = tr["id"]
    return np.union1d(sel, new)


def nearest_each_side(cands: list) -> list:
    """The nearest lane of each side among ``(distance, lane)`` pairs, left to right."""
    out = []
    for side in ("left", "right"):
        same = [ln for d, ln in sorted(cands, key=lambda x: x[0]) if ln.side == side]
        if same:
            out.append(same[0])
    out.sort(key=lambda ln: ln.coeffs[0])
    return out
