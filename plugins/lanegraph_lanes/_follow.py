"""Lane lines followed along their own curvature (``lanes.follow``), from the first frame.

The paper's 1D Hough transform (``hough.line1d``) takes one orientation for every line of the BEV
and a straight line for each: in a tight bend the lines turn through tens of degrees inside the BEV
and leave its side within a few metres, and near a hatched gore area the orientation histogram
locks onto the bars. ``lanes.follow`` finds each line from where it is seen and follows it:

1. **Seeds.** The BEV's near part is cut into bands ``seed_band_m`` tall; in each band every
   feature is moved along its own orientation to the band's lower edge (over at most a band's
   height: a bend of 30 m radius moves a line by 7 cm over 2 m) and the columns are histogrammed.
   A peak with ``min_seed_votes`` features is a seed: a column, a row and the features' mean
   orientation.
2. **Following** (``_follow_kernel``, numba). From a seed, windows ``step_m`` long and
   ``2 half_width_m`` wide step along the line, up the BEV and back down, predicted by the current
   heading and curvature (a circle arc). A window takes the features whose orientation is within
   ``max_angle_deg`` of the line's heading and fits a straight line across them, which corrects
   the position; the heading and the curvature come from a circle through the centres of the
   windows over the last ``base_m`` (a window's own slope over 1 m of a dash is too noisy). Windows without features (a dashed line's
   gaps, a parked car) continue on the prediction up to ``max_gap_m``. A line that leaves the BEV
   through its side stops there: it is fitted on the part that is seen.
   **Guides.** Markings are parallel: a line followed over ``guide_min_m`` or more (longer than a
   hatching bar) guides the lines followed after it. Where one lies within ``guide_m`` across, a
   track takes its heading and curvature from it (those of the parallel curve) after every window,
   and its own windows' features only place it: a dash's own curvature (3 m of paint) is noise, and
   over a 6-12 m gap of a bend of 30 m radius it misses the next dash by a metre or more. A
   window whose curvature reached the clamp (``min_radius_m``, the tightest bend followed) guides
   no line: no road followed bends so, the track measured something else there -- one window's
   1 m slope after a long gap, a track strayed onto other features (kitti15_000024: a track that
   crossed tree shade and an 8 m gap to a kerb's edge, its curvature clamped to a left bend there,
   turned the dashed centre line bending right beside it onto features straight ahead). The
   strongest seeds (solid lines) are followed first; a short track (a dash) followed before the
   long lines beside it is followed again with them. Far ahead the BEV repeats each image row over
   several BEV rows and a slanted line's features read steeper than the line (a staircase): there a
   track longer than a hatching bar also takes features whose orientation lies between its heading
   and straight ahead.
3. **Hatching is not a lane.** A hatched area's bars are short tracks, at an angle to the road,
   repeated at a regular step: a track shorter than ``max_bar_m`` with two or more short tracks
   beside it that are parallel to it (within ``max_angle_deg``) is a bar, and so is a short track
   at more than ``max_angle_deg`` to every long track (the road's direction). A gore area's border
   line is long: it stays, and its window's orientation test leaves the bars touching it out.
4. **Lanes.** Each track's features are fitted with a parabola (robust IRLS, as ``fit.irls``) on
   the part of the track within ``max_heading_deg`` of straight ahead (where ``x(z)`` can describe
   it); its offset at the BEV's bottom row gives its side, and on each side the nearest track
   ``min_offset_m``..``max_offset_m`` from the vehicle with ``min_inliers`` features over
   ``min_extent_m`` is reported. A line nearer than ``min_offset_m`` that the car straddles (a
   narrow street's centre line) goes to the ``straddled`` port, its track counting the free
   features along its parabola (``collect_along``): see :mod:`._straddle`.

Nothing here needs a previous frame: a sequence's first frame and a single pair are like any other.
"""

from __future__ import annotations

import math

import numpy as np

from lanegraph import Port, jit, node_type
from lanegraph.types import BevGeometry, FeatureMap, Lane

from ._fit import irls_fit
from ._follow_params import FollowParams
from ._merge import MergeParams, merge, merge_node  # noqa: F401  (lanes.merge, beside lanes.follow)
from ._seeds import _seeds, _steep_rows, _window_sums  # noqa: F401  (_window_sums: the tests')
from ._straddle import collect_along, nearest_each_side

#: the most windows one call of the follow kernel takes: the length (+ 1) of its centres' buffers,
#: its own and the caller's (``out_x`` ...)
MAX_WINDOWS = 400


@jit
def _guide_at(x, y, psi, gx, gy, gpsi, gk, n_guide, guide_max, step, cos_max, max_kappa):
    """The heading and curvature at ``(x, y)`` of the curve parallel to the nearest guide facing
    it (see ``_follow_kernel``; an entry whose curvature is NaN, at the clamp, is skipped);
    ``(False, psi, 0)`` when no guide is near."""
    best = -1
    best_n = guide_max
    for k in range(n_guide):
        ex = x - gx[k]
        ey = y - gy[k]
        if abs(ex) > guide_max + step or abs(ey) > guide_max + step:
            continue
        if abs(math.cos(gpsi[k] - psi)) < cos_max:
            continue
        if gk[k] != gk[k]:  # NaN: its curvature reached the clamp (something else than a road's line)
            continue
        cg = math.cos(gpsi[k])
        sg = math.sin(gpsi[k])
        if abs(ex * cg + ey * sg) > 0.5 * step:
            continue
        nn = abs(-ex * sg + ey * cg)
        if nn <= best_n:
            best_n = nn
            best = k
    if best < 0:
        return False, psi, 0.0
    gp = gpsi[best]
    kg = gk[best]
    if math.cos(gp - psi) < 0.0:  # the guide was followed the other way
        gp += math.pi
        kg = -kg
    ex = x - gx[best]
    ey = y - gy[best]
    gu = ex * math.cos(gp) + ey * math.sin(gp)
    gn = -ex * math.sin(gp) + ey * math.cos(gp)
    d = gp + kg * gu - psi
    new_psi = psi + d - 2.0 * math.pi * math.floor((d + math.pi) / (2.0 * math.pi))
    den = 1.0 - kg * gn
    kappa = kg / den if den > 0.5 else kg
    return True, new_psi, min(max(kappa, -max_kappa), max_kappa)


@jit
def _window_box(x, y, cp, sp, step, v_lo, v_hi, n_rows):
    """Where the features of a window's part ``u`` in [0, step], ``v`` in [v_lo, v_hi] can lie (``u``
    along the heading ``(cp, sp)`` from ``(x, y)``, ``v`` across it to the left, pixels): columns
    ``x_lo``..``x_hi`` and BEV rows ``r_lo``..``r_hi`` of its bounding box padded by a pixel, the
    rows clamped to -1..n_rows (none when ``r_lo > r_hi``). Only where the kernel looks: the tests
    on ``u`` and ``v`` decide which features are in."""
    x_lo = x + min(0.0, step * cp) - max(v_lo * sp, v_hi * sp) - 1.0
    x_hi = x + max(0.0, step * cp) - min(v_lo * sp, v_hi * sp) + 1.0
    y_lo = y + min(0.0, step * sp) + min(v_lo * cp, v_hi * cp) - 1.0
    y_hi = y + max(0.0, step * sp) + max(v_lo * cp, v_hi * cp) + 1.0
    # BEV rows: row = n_rows - 1 - t
    r_lo = min(max(int(math.floor(n_rows - 1 - y_hi)), 0), n_rows)
    r_hi = max(min(int(math.ceil(n_rows - 1 - y_lo)), n_rows - 1), -1)
    return x_lo, x_hi, r_lo, r_hi


@jit
def _follow_kernel(
    t,
    c,
    theta,
    row_start,
    n_cols,
    t0,
    c0,
    psi0,
    step,
    half_w,
    cos_max,
    max_gap,
    max_kappa,
    min_count,
    sin_turn,
    widen,
    base,
    owner,
    track,
    steep,
    relax_after,
    gx,
    gy,
    gpsi,
    gk,
    n_guide,
    guide_max,
    out_x,
    out_y,
    out_psi,
    out_k,
):
    """Follow one line from ``(c0, t0)`` (BEV column, BEV rows above the bottom row) with heading
    ``psi0`` (radians from +column towards +t; ``pi`` added: downwards) through windows.

    ``t``, ``c``, ``theta``: the features' t (descending: row-major order of the BEV), column and
    orientation (radians in [0, pi), -1 unknown); ``row_start``: index of the first feature of each
    BEV row (length rows + 1); ``n_cols``: the BEV's columns. A window fits a straight line across
    its features (``u`` in [0, step] along the heading, within ``half_w`` (widened after a gap)
    across the predicted arc, the orientation test passed); the features within ``half_w`` across
    that line (``u`` in [0, step], the orientation test passed) are taken: they get
    ``owner[i] = track`` where ``owner`` was -1; features of other tracks (``owner[i]`` >= 0, not
    ``track``) are not looked at. A window that lies wholly beside the BEV (the line left it
    through its side) or above or below it ends the track.

    ``steep``: per BEV row, 1 where the BEV repeats one image row over several BEV rows (a slanted
    line turns into a staircase there and its features read steeper than the line); once the track
    has ``relax_after`` windows with features, a feature there also counts when its orientation
    lies between the line's heading and straight ahead. ``gx``, ``gy``, ``gpsi``, ``gk``: the first
    ``n_guide`` entries are window centres (column, t), headings and curvatures of lines followed
    before (guides); after every window the heading and curvature are taken from the nearest guide
    within ``guide_max`` pixels across (a centre within half a window's length along it, its
    heading within ``acos(cos_max)`` of the track's heading before the window), when there is one:
    lane markings are parallel, and the parallel curve at a distance ``n`` to the left of a guide of
    curvature ``k`` has curvature ``k / (1 - k n)``; the window's features still place the track.
    A guide entry whose curvature is NaN is no guide. ``out_x``, ``out_y``, ``out_psi``, ``out_k``
    (length ``MAX_WINDOWS + 1``) receive this track's window centres, headings and curvatures; the
    curvature is NaN where it reached the clamp ``max_kappa`` (no road followed bends so: the track
    measured something else there), so that such a window guides no other line.

    Returns ``(windows with features, features taken, lowest and highest t taken, t where the
    heading first turns further from straight ahead than ``asin(sin_turn)``, window centres written)``."""
    n_rows = row_start.shape[0] - 1
    x = c0
    y = t0
    psi = psi0
    kappa = 0.0
    gap = 0.0
    windows = 0
    taken = 0
    t_lo = 1e9
    t_hi = -1e9
    t_turn = 1e9
    prev_psi = psi0
    steps = 0
    hx = np.empty(MAX_WINDOWS + 1, np.float64)  # the dtype named: the other kernels' np.empty
    hy = np.empty(MAX_WINDOWS + 1, np.float64)
    nh = 0
    while steps < MAX_WINDOWS:
        steps += 1
        cp = math.cos(psi)
        sp = math.sin(psi)
        # a long track (not a hatching bar) also takes, where the BEV stretches the image's rows,
        # features whose orientation lies between its heading (an orientation in [0, pi)) and
        # straight ahead (pi / 2): the staircase of the stretched rows reads steeper than the line
        relaxed = windows >= relax_after
        o_psi = psi - math.pi * math.floor(psi / math.pi)
        o_lo = min(o_psi, 0.5 * math.pi)
        o_hi = max(o_psi, 0.5 * math.pi)
        # window: along u in [0, step] from (x, y), across v within hw of the predicted arc (its
        # bow 0.5 kappa u^2 included); after a gap the prediction is less sure: the window widens
        # with the gap's length
        hw = half_w + widen * gap
        bow = 0.5 * kappa * step * step
        x_lo, x_hi, r_lo, r_hi = _window_box(
            x, y, cp, sp, step, min(bow, 0.0) - hw, max(bow, 0.0) + hw, n_rows
        )
        if r_lo > r_hi or x_hi < 0.0 or x_lo > n_cols - 1:
            break
        sw = 0.0
        su = 0.0
        sv = 0.0
        suu = 0.0
        suv = 0.0
        for i in range(row_start[r_lo], row_start[r_hi + 1]):
            ci = c[i]
            if ci < x_lo or ci > x_hi:
                continue
            dx = ci - x
            dy = t[i] - y
            u = dx * cp + dy * sp
            if u < 0.0 or u > step:
                continue
            v = -dx * sp + dy * cp - 0.5 * kappa * u * u
            if v > hw or v < -hw:
                continue
            th = theta[i]
            if th >= 0.0 and abs(math.cos(th - psi)) < cos_max:
                if not (relaxed and steep[n_rows - 1 - int(t[i])] and th >= o_lo and th <= o_hi):
                    continue
            if owner[i] >= 0 and owner[i] != track:  # another line's, followed already
                continue
            sw += 1.0
            su += u
            sv += v
            suu += u * u
            suv += u * v
        if sw >= min_count:
            mu = su / sw
            mv = sv / sw
            var = suu / sw - mu * mu
            b = 0.0
            if var > 1.0:
                b = (suv / sw - mu * mv) / var
            if b > 1.0:
                b = 1.0
            elif b < -1.0:
                b = -1.0
            a = mv - b * mu
            # the end of the window on the fitted line (plus the predicted bend)
            v_end = a + b * step + 0.5 * kappa * step * step
            new_psi = psi + math.atan(b) + kappa * step
            # the window's centre on the line, kept: heading and curvature over a longer base
            vc = a + b * mu + 0.5 * kappa * mu * mu
            hx[nh] = x + mu * cp - vc * sp
            hy[nh] = y + mu * sp + vc * cp
            nh += 1
            last = nh - 1
            j = last
            while j > 0 and math.hypot(hx[last] - hx[j - 1], hy[last] - hy[j - 1]) <= base:
                j -= 1
            m = (j + last) // 2
            used = False
            if last - j >= 2:
                ax = hx[m] - hx[j]
                ay = hy[m] - hy[j]
                bx = hx[last] - hx[m]
                by = hy[last] - hy[m]
                la = math.hypot(ax, ay)
                lb = math.hypot(bx, by)
                lc = math.hypot(hx[last] - hx[j], hy[last] - hy[j])
                if la > 0.5 * step and lb > 0.5 * step:
                    # a circle through three window centres (Menger curvature), its tangent at
                    # the window's end
                    kappa = 2.0 * (ax * by - ay * bx) / (la * lb * lc)
                    if kappa > max_kappa:
                        kappa = max_kappa
                    elif kappa < -max_kappa:
                        kappa = -max_kappa
                    h = math.atan2(by, bx) + kappa * (0.5 * lb + step - mu)
                    d = h - psi
                    d = d - 2.0 * math.pi * math.floor((d + math.pi) / (2.0 * math.pi))
                    new_psi = psi + d
                    used = True
            if not used:
                k_meas = (new_psi - prev_psi) / step
                kappa = 0.7 * kappa + 0.3 * k_meas
                if kappa > max_kappa:
                    kappa = max_kappa
                elif kappa < -max_kappa:
                    kappa = -max_kappa
            out_x[last] = hx[last]
            out_y[last] = hy[last]
            out_psi[last] = new_psi - kappa * (step - mu)
            # a curvature at the clamp (beyond the tightest bend followed) guides no other line
            out_k[last] = kappa if abs(kappa) < max_kappa else math.nan
            # mark the features taken, within half_w of the fitted line: a second pass, over the box
            # of that band (the line slants across the window: the band can reach beyond its box)
            b_end = a + b * step
            x_lo, x_hi, r_lo, r_hi = _window_box(
                x, y, cp, sp, step, min(a, b_end) - half_w, max(a, b_end) + half_w, n_rows
            )
            for i in range(row_start[r_lo], row_start[r_hi + 1]):
                ci = c[i]
                if ci < x_lo or ci > x_hi:
                    continue
                dx = ci - x
                dy = t[i] - y
                u = dx * cp + dy * sp
                if u < 0.0 or u > step:
                    continue
                v = -dx * sp + dy * cp - a - b * u
                if v > half_w or v < -half_w:
                    continue
                th = theta[i]
                if th >= 0.0 and abs(math.cos(th - psi)) < cos_max:
                    if not (relaxed and steep[n_rows - 1 - int(t[i])] and th >= o_lo and th <= o_hi):
                        continue
                if owner[i] < 0:
                    owner[i] = track
                    taken += 1
                    if t[i] < t_lo:
                        t_lo = t[i]
                    if t[i] > t_hi:
                        t_hi = t[i]
            x = x + step * cp - v_end * sp
            y = y + step * sp + v_end * cp
            prev_psi = psi
            psi = new_psi
            windows += 1
            gap = 0.0
        else:
            half = psi + 0.5 * kappa * step
            x = x + step * math.cos(half)
            y = y + step * math.sin(half)
            prev_psi = psi
            psi = psi + kappa * step
            gap += step
            if gap > max_gap:
                break
        if n_guide > 0:
            # parallel to the nearest guide facing the track's new position
            found, g_psi, g_kappa = _guide_at(
                x, y, prev_psi, gx, gy, gpsi, gk, n_guide, guide_max, step, cos_max, max_kappa
            )
            if found:
                psi = g_psi
                kappa = g_kappa
        if abs(math.cos(psi)) > sin_turn and t_turn > 1e8:
            t_turn = y
        if y < 0.0 or y > n_rows - 1:
            break
    return windows, taken, t_lo, t_hi, t_turn, nh


@node_type(
    "lanes.follow",
    inputs={"features": "features", "geometry": Port("bev_geometry")},
    outputs={
        "lanes": "lanes",
        "straddled": Port(
            "lanes",
            "lines the car straddles, nearer than min_offset_m: a narrow street's centre line between the wheels",
        ),
    },
)
def follow(params: FollowParams, features: FeatureMap, geometry: BevGeometry) -> dict:
    """Lane lines followed through windows along their own heading and curvature from seeds in the
    BEV's near part; hatching bars dropped; a parabola on each line's seen part; the nearest line
    each side, and on the straddled port a line the car drives over. Needs no previous frame."""
    rows, cols = features.shape
    r, c = features.points()
    straddled: list[Lane] = []
    lanes = follow_lanes(
        r, c, features.point_orientations(), rows, cols, geometry, params, straddled=straddled
    )
    return {"lanes": lanes, "straddled": straddled}


def follow_lanes(r, c, theta, rows, cols, geometry, p, debug=None, straddled=None):
    """The lanes of ``lanes.follow`` from the feature points ``(r, c)`` and orientations; the lines
    the car straddles (``straddle_offset_m``..``min_offset_m`` from it) appended to ``straddled``
    when given."""
    res = geometry.resolution
    if theta is None:
        theta = np.full(r.shape, -1.0)
    t = (rows - 1 - r).astype(np.float64)
    cf = c.astype(np.float64)
    th = np.ascontiguousarray(theta, dtype=np.float64)
    # the first feature of each BEV row (the points are in row-major order): the counts per row summed
    row_start = np.zeros(rows + 1, np.int64)
    np.cumsum(np.bincount(r, minlength=rows)[:rows], out=row_start[1:])
    owner = np.full(r.shape, -1, np.int32)
    tracks = []
    step = p.step_m / res
    half_w = p.half_width_m / res
    cos_max = math.cos(math.radians(p.max_angle_deg))
    max_gap = p.max_gap_m / res
    max_kappa = res / p.min_radius_m
    # the strongest seeds first: a solid line is followed before a dashed one beside it, whose
    # windows then leave its features alone, and guides it across its gaps
    seeds = sorted(_seeds(t, cf, th, row_start, rows, cols, p, res), key=lambda sd: -sd[3])
    steep = _steep_rows(geometry)
    relax_after = max(1, int(math.ceil(p.max_bar_m / p.step_m)))
    sin_turn = math.sin(math.radians(p.max_heading_deg))
    widen = math.tan(math.radians(p.gap_heading_deg))
    out = np.empty((4, MAX_WINDOWS + 1))

    def run(t0, c0, psi0, k, guide):
        """Follow from a seed up the BEV and down; the track's record and its window centres."""
        args = (
            step,
            half_w,
            cos_max,
            max_gap,
            max_kappa,
            float(p.min_window_features),
            sin_turn,
            widen,
            p.base_m / res,
            owner,
            k,
            steep,
            relax_after,
            *guide,
            guide.shape[1],
            p.guide_m / res,
        )
        w_up, n_up, lo_up, hi_up, turn_up, h_up = _follow_kernel(
            t, cf, th, row_start, cols, t0, c0, psi0, *args, *out
        )
        centres = out[:, :h_up].copy()
        w_dn, n_dn, lo_dn, hi_dn, _, h_dn = _follow_kernel(
            t, cf, th, row_start, cols, t0, c0, psi0 + math.pi, *args, *out
        )
        track = {
            "id": k,
            "n": n_up + n_dn,
            "windows": w_up + w_dn,
            "t_lo": min(lo_up, lo_dn),
            "t_hi": max(hi_up, hi_dn),
            "t_turn": turn_up,
            "psi": psi0,
            "seed": (t0, c0, psi0),
            "guides": guide.shape[1],
        }
        centres = np.concatenate([centres, out[:, :h_dn]], axis=1)
        along = (centres[0] - c0) * math.cos(psi0) + (centres[1] - t0) * math.sin(psi0)
        track["span"] = float(along.max() - along.min()) * res if along.size else 0.0
        return track, centres

    band = max(1, int(round(p.seed_band_m / res)))
    guide = np.zeros((4, 0))
    for t0, c0, psi0, _votes in seeds:
        # a seed on a line already followed: the features of its band that voted for it (moved
        # along the seed's heading to the band's lower edge) are taken (none before the first track)
        if tracks:
            i0, i1 = row_start[max(0, rows - int(t0) - band)], row_start[rows - int(t0)]
            moved = cf[i0:i1] - (t[i0:i1] - t0) * (math.cos(psi0) / max(math.sin(psi0), 1e-3))
            voted = np.abs(moved - c0) < half_w
            n_voted = np.count_nonzero(voted)
            if n_voted and np.count_nonzero(owner[i0:i1][voted] >= 0) / n_voted > 0.3:
                continue
        track, centres = run(t0, c0, psi0, len(tracks), guide)
        if track["span"] >= p.guide_min_m:  # a long line (not a hatching bar) guides the next ones
            guide = np.ascontiguousarray(np.concatenate([guide, centres], axis=1))
        if track["n"]:
            tracks.append(track)
    # a short track (a dash) followed before the long lines beside it were is followed again with
    # them as guides: across its gaps it keeps parallel to them
    for i, tr in enumerate(tracks):
        if tr["windows"] < relax_after and tr["guides"] < guide.shape[1]:
            owner[owner == tr["id"]] = -1
            tracks[i], _ = run(*tr["seed"], tr["id"], guide)
    if debug is not None:
        debug.update(tracks=tracks, owner=owner, t=t, c=cf)
    if not tracks:
        return []
    # hatching: short tracks parallel to two or more short tracks, or across the long tracks
    short_px = p.max_bar_m / res
    for tr in tracks:
        tr["short"] = (tr["t_hi"] - tr["t_lo"]) < short_px
    long_psi = [tr["psi"] for tr in tracks if not tr["short"]]
    for tr in tracks:
        tr["bar"] = False
        if not tr["short"]:
            continue
        parallel = sum(
            1 for o in tracks if o is not tr and o["short"] and abs(math.cos(o["psi"] - tr["psi"])) >= cos_max
        )
        across = bool(long_psi) and all(abs(math.cos(lp - tr["psi"])) < cos_max for lp in long_psi)
        tr["bar"] = parallel >= 2 or across
    lanes = []
    tan_max = math.tan(math.radians(p.max_heading_deg))
    near = []  # (distance, lane) of the lines nearer than min_offset_m: straddled

    def under_car(c0: float) -> bool:
        return p.straddle_offset_m <= abs(geometry.lateral_m(c0)) < p.min_offset_m

    for tr in tracks:
        if tr["bar"]:
            continue
        # the track's features, in the points' row-major order: t does not increase along them, so
        # the near part, the inliers' ends and the farthest feature on the parabola are ends of runs
        sel = np.flatnonzero(owner == tr["id"])
        if (
            straddled is not None
            and p.collect_along
            and p.straddle_offset_m is not None
            and sel.size < p.min_inliers
        ):
            # a line under the car whose windows missed a dash: see _straddle
            sel = collect_along(sel, tr, t, cf, th, owner, p.extend_px, cos_max, where=under_car)
        if sel.size < p.min_inliers:
            continue
        tt, cc = t[sel], cf[sel]
        if tr["t_turn"] < 1e8:
            keep = tt <= tr["t_turn"]
            tt, cc = tt[keep], cc[keep]
        t_all, c_all = tt, cc
        if p.near_fit_m is not None:
            # a road's curvature changes (entering a bend, an S-bend), a parabola's does not: the
            # near part, where the image shows the line largest, when it is seen over half of it
            j = tt.size - int(np.count_nonzero(tt * res <= p.near_fit_m))  # the near part: tt[j:]
            if j < tt.size and (tt[j] - tt[-1]) * res >= 0.5 * p.near_fit_m:
                tt, cc = tt[j:], cc[j:]
        if tt.size < p.min_inliers:
            continue
        coef, w = irls_fit(tt, cc, 2)
        inl = w > 0.5
        n_inl = int(np.count_nonzero(inl))
        if n_inl < max(p.min_inliers, p.min_inlier_fraction * tt.size):
            continue  # one parabola does not describe the track: it strayed onto other features
        t_in = tt[inl]  # from the farthest inlier to the nearest
        extent = (t_in[0] - t_in[-1]) * res
        if extent < p.min_extent_m or t_in[-1] * res > p.max_start_m:
            continue
        # the path's curvature where it is seen nearest (x(z)'s second derivative over (1 + x'^2)^1.5)
        t_near = float(t_in[-1])
        slope = coef[1] + 2 * coef[2] * t_near
        if abs(2 * coef[2] / res) / (1 + slope * slope) ** 1.5 > p.max_curvature:
            coef, w = irls_fit(tt, cc, 1)
            coef = np.array([coef[0], coef[1], 0.0])
            inl = w > 0.5
            n_inl = int(np.count_nonzero(inl))
            t_in = tt[inl]
        # the lane reaches as far as the line's features stay on the parabola (a marking's width)
        on = np.abs(coef[0] + coef[1] * t_all + coef[2] * t_all * t_all - c_all) <= p.extend_px
        i_on = int(on.argmax())  # the farthest feature on it (when any is)
        t_top = float(max(t_in[0], t_all[i_on] if on[i_on] else 0.0))
        # the parabola's slope must stay within max_heading_deg over its fitted rows
        if abs(coef[1] + 2 * coef[2] * t_top) > tan_max and abs(coef[1]) > tan_max:
            continue
        lateral = geometry.lateral_m(float(coef[0]))
        straddle = (
            straddled is not None
            and p.straddle_offset_m is not None
            and under_car(float(coef[0]))
            and extent >= p.straddle_min_extent_m  # more than an arrow: a marking along the road
        )
        if not (p.min_offset_m <= abs(lateral) <= p.max_offset_m or straddle):
            continue
        (near if straddle else lanes).append(
            (
                abs(lateral),
                Lane(
                    coeffs=(float(coef[0]), float(coef[1]), float(coef[2])),
                    bev_rows=(rows - 1 - int(t_top), rows - 1),
                    side="left" if lateral < 0 else "right",
                    score=float(min(1.0, n_inl / max(1.0, (t_top + 1) * 2.0))),
                    extra={"support": n_inl, "extent_m": round(float(extent), 2), "followed": True}
                    | ({"straddled": True} if straddle else {}),
                ),
            )
        )
    if straddled is not None:
        straddled.extend(nearest_each_side(near))
    return nearest_each_side(lanes)
