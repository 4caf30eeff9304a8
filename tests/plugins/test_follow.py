"""lanes.follow: its window kernel against a NumPy twin; bends, lines leaving the BEV's side,
hatching bars, dashed lines and the merge with the Hough lanes, on BEVs with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from lanegraph_lanes._features import EsltParams, eslt
from lanegraph_lanes._follow import (
    MAX_WINDOWS,
    FollowParams,
    MergeParams,
    _follow_kernel,
    _seeds,
    _window_box,
    _window_sums,
    follow,
    merge,
    merge_node,
)

from lanegraph.testing import check_node_type
from lanegraph.types import BevGeometry, FeatureMap, Lane

RES = 0.05


def geometry(rows: int = 800, cols: int = 400) -> BevGeometry:
    return BevGeometry(-cols * RES / 2, cols * RES / 2, 5.0, 5.0 + rows * RES, RES, np.eye(3))


def draw(bev: np.ndarray, cols: np.ndarray, ts: np.ndarray, half: float = 1.5, value: int = 220) -> None:
    """Paint a line through the (column, t) samples, about ``2 half`` pixels wide across it."""
    rows = bev.shape[0]
    for c, t in zip(cols, ts, strict=True):
        r = int(round(rows - 1 - t))
        if 0 <= r < rows:
            lo, hi = int(round(c - half)), int(round(c + half))
            bev[r, max(lo, 0) : max(min(hi + 1, bev.shape[1]), 0)] = value


def arc(c0: float, radius_m: float, s_max_m: float = 60.0):
    """Samples (column, t) every 0.2 px of arc length of a circle starting straight ahead at column
    ``c0`` of the bottom row and bending right (``radius_m`` > 0) or left, up to where it runs
    across the BEV."""
    R = abs(radius_m) / RES
    ang = np.arange(0.0, s_max_m / RES, 0.2) / R
    ang = ang[ang < math.pi / 2]
    return c0 + math.copysign(1.0, radius_m) * R * (1 - np.cos(ang)), R * np.sin(ang)


def features_of(bev: np.ndarray):
    return eslt(EsltParams(), image=bev)["features"]


# ----------------------------------------------------------------------------- the kernel's twin
def feature_arrays(bev: np.ndarray):
    """The ESLT features of ``bev`` as the follow kernel and the seeds take them: ``(t, c, theta,
    row_start)``, ``t`` the rows counted up from the bottom, ``row_start`` each BEV row's first
    feature (the features in row-major order)."""
    rows = bev.shape[0]
    f = features_of(bev)
    r, cc = f.points()
    th = np.ascontiguousarray(f.point_orientations(), dtype=np.float64)
    row_start = np.searchsorted(r, np.arange(rows + 1)).astype(np.int64)
    return (rows - 1 - r).astype(np.float64), cc.astype(np.float64), th, row_start


def follow_twin(
    t,
    c,
    theta,
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
    guide,
    guide_max,
    rows,
    cols,
):
    """NumPy twin of ``_follow_kernel``: every window's features selected with array operations over
    all the features (a window's: within ``half_w`` (widened after a gap) of the predicted arc; the
    features taken: within ``half_w`` of the line fitted across them), the same updates; ``guide``:
    a (4, n) array of the guides' centres, headings and curvatures. Returns the kernel's tuple and
    the (4, k) centres, headings and curvatures."""
    x, y, psi, kappa, gap = c0, t0, psi0, 0.0, 0.0
    windows = taken = 0
    t_lo, t_hi, t_turn, prev_psi = 1e9, -1e9, 1e9, psi0
    centres = []  # the centres of the windows with features, in order
    recorded = []  # (x, y, heading, curvature) of each
    has_theta = theta >= 0
    steep_at = steep[(rows - 1 - t).astype(np.int64)] > 0
    for _ in range(400):
        cp, sp = math.cos(psi), math.sin(psi)
        dx, dy = c - x, t - y
        u = dx * cp + dy * sp
        v = -dx * sp + dy * cp
        o_psi = psi % math.pi
        lo, hi = min(o_psi, math.pi / 2), max(o_psi, math.pi / 2)
        staircase = (windows >= relax_after) & steep_at & (theta >= lo) & (theta <= hi)
        ok_theta = ~has_theta | (np.abs(np.cos(theta - psi)) >= cos_max) | staircase
        ok_theta &= (owner < 0) | (owner == track)
        hw = half_w + widen * gap
        # a window wholly beside the BEV or above or below it (a pixel beyond its corners): the end
        bow = 0.5 * kappa * step * step
        x_lo, x_hi, y_lo, y_hi = window_corners(x, y, cp, sp, step, min(bow, 0.0) - hw, max(bow, 0.0) + hw)
        if x_hi + 1 < 0 or x_lo - 1 > cols - 1:
            break
        if math.floor(rows - 1 - (y_hi + 1)) > rows - 1 or math.ceil(rows - 1 - (y_lo - 1)) < 0:
            break
        sel = (u >= 0) & (u <= step) & (np.abs(v - 0.5 * kappa * u * u) <= hw) & ok_theta
        if sel.sum() >= min_count:
            uu, vv = u[sel], v[sel] - 0.5 * kappa * u[sel] ** 2
            var = np.mean(uu * uu) - np.mean(uu) ** 2
            b = (np.mean(uu * vv) - np.mean(uu) * np.mean(vv)) / var if var > 1.0 else 0.0
            b = min(max(b, -1.0), 1.0)
            a = np.mean(vv) - b * np.mean(uu)
            v_end = a + b * step + 0.5 * kappa * step * step
            new_psi = psi + math.atan(b) + kappa * step
            mu = np.mean(uu)
            vc = a + b * mu + 0.5 * kappa * mu * mu
            centres.append((x + mu * cp - vc * sp, y + mu * sp + vc * cp))
            h = np.array(centres)
            near = np.hypot(*(h[-1] - h).T) <= base
            j = len(h) - 1  # the oldest centre of the run within base of the last
            while j > 0 and near[j - 1]:
                j -= 1
            last, m = len(h) - 1, (j + len(h) - 1) // 2
            A, B, C = h[m] - h[j], h[last] - h[m], h[last] - h[j]
            la, lb, lc = np.linalg.norm(A), np.linalg.norm(B), np.linalg.norm(C)
            if last - j >= 2 and la > 0.5 * step and lb > 0.5 * step:
                kappa = min(max(2.0 * (A[0] * B[1] - A[1] * B[0]) / (la * lb * lc), -max_kappa), max_kappa)
                d = math.atan2(B[1], B[0]) + kappa * (0.5 * lb + step - mu) - psi
                new_psi = psi + (d + math.pi) % (2 * math.pi) - math.pi
            else:
                kappa = min(max(0.7 * kappa + 0.3 * (new_psi - prev_psi) / step, -max_kappa), max_kappa)
            # a curvature at the clamp (beyond the tightest bend followed) is recorded as NaN: no guide
            recorded.append(
                (*h[last], new_psi - kappa * (step - mu), kappa if abs(kappa) < max_kappa else math.nan)
            )
            mark = (u >= 0) & (u <= step) & (np.abs(v - a - b * u) <= half_w) & ok_theta & (owner < 0)
            owner[mark] = track
            taken += int(mark.sum())
            if mark.any():
                t_lo, t_hi = min(t_lo, t[mark].min()), max(t_hi, t[mark].max())
            x, y = x + step * cp - v_end * sp, y + step * sp + v_end * cp
            prev_psi, psi = psi, new_psi
            windows += 1
            gap = 0.0
        else:
            half = psi + 0.5 * kappa * step
            x, y = x + step * math.cos(half), y + step * math.sin(half)
            prev_psi, psi = psi, psi + kappa * step
            gap += step
            if gap > max_gap:
                break
        found = guide_twin(x, y, prev_psi, guide, guide_max, step, cos_max, max_kappa)
        if found is not None:
            psi, kappa = found
        if abs(math.cos(psi)) > sin_turn and t_turn > 1e8:
            t_turn = y
        if y < 0.0 or y > rows - 1:
            break
    return (windows, taken, t_lo, t_hi, t_turn, len(recorded)), np.array(recorded).reshape(-1, 4).T


def window_corners(x, y, cp, sp, step, v_lo, v_hi):
    """The least and greatest column and t of a window's corners: ``u`` in {0, step} along the
    heading ``(cp, sp)`` from ``(x, y)``, ``v`` in {v_lo, v_hi} across it."""
    xs = [x + u * cp - v * sp for u in (0.0, step) for v in (v_lo, v_hi)]
    ys = [y + u * sp + v * cp for u in (0.0, step) for v in (v_lo, v_hi)]
    return min(xs), max(xs), min(ys), max(ys)


def guide_twin(x, y, psi, guide, guide_max, step, cos_max, max_kappa):
    """NumPy twin of ``_guide_at``: (heading, curvature) of the curve parallel to the nearest guide
    centre facing ``(x, y)`` whose curvature is not NaN (at the clamp), or None."""
    gx, gy, gp, gk = guide
    u = (x - gx) * np.cos(gp) + (y - gy) * np.sin(gp)
    n = np.abs(-(x - gx) * np.sin(gp) + (y - gy) * np.cos(gp))
    ok = (np.abs(np.cos(gp - psi)) >= cos_max) & (np.abs(u) <= 0.5 * step) & (n <= guide_max) & ~np.isnan(gk)
    if not ok.any():
        return None
    k = np.flatnonzero(ok & (n == n[ok].min()))[-1]  # the kernel keeps the last of equals
    g, kg = gp[k], gk[k]
    if math.cos(g - psi) < 0:
        g, kg = g + math.pi, -kg
    gu = (x - gx[k]) * math.cos(g) + (y - gy[k]) * math.sin(g)
    gn = -(x - gx[k]) * math.sin(g) + (y - gy[k]) * math.cos(g)
    d = g + kg * gu - psi
    den = 1.0 - kg * gn
    return psi + (d + math.pi) % (2 * math.pi) - math.pi, min(
        max(kg / den if den > 0.5 else kg, -max_kappa), max_kappa
    )


#: the kernel's window parameters after the start (step, half width, cos of the largest angle, the
#: longest gap, the clamp's curvature, features per window, sin of the turn, widening, base), px
WINDOW_ARGS = (
    20.0,
    5.0,
    math.cos(math.radians(25)),
    280.0,
    RES / 20.0,
    12.0,
    math.sin(math.radians(60)),
    0.1,
    200.0,
)


def kernel_and_twin(feats, rows, cols, start, owner, steep=None, guide=None, args=WINDOW_ARGS, relax_after=3):
    """Follow one line (track 0) with ``_follow_kernel`` and with ``follow_twin`` from ``start``
    ``(t0, c0, psi0)`` over the features ``feats`` (``feature_arrays``), each with its own copy of
    ``owner``; assert that they agree exactly (counts, owners) and to 1e-6 (t's, centres). Returns
    the kernel's tuple, its owners and the (4, k) centres, headings and curvatures."""
    tt, cf, th, row_start = feats
    steep = np.zeros(rows, np.uint8) if steep is None else steep
    g = np.ascontiguousarray(np.zeros((4, 0)) if guide is None else guide)
    o_k, o_t = owner.copy(), owner.copy()
    out = np.zeros((4, MAX_WINDOWS + 1))
    got = _follow_kernel(
        tt, cf, th, row_start, cols, *start, *args, o_k, 0, steep, relax_after, *g, g.shape[1], 90.0, *out
    )
    exp, centres = follow_twin(tt, cf, th, *start, *args, o_t, 0, steep, relax_after, g, 90.0, rows, cols)
    assert got[:2] == exp[:2] and got[5] == exp[5]
    np.testing.assert_array_equal(o_k, o_t)
    np.testing.assert_allclose(got[2:5], exp[2:5], atol=1e-6)
    np.testing.assert_allclose(out[:, : got[5]], centres, atol=1e-6)
    return got, o_k, centres


@pytest.mark.parametrize("radius_m", [30.0, -80.0, 1e6])
def test_follow_kernel_matches_numpy_twin(radius_m):
    """A solid line followed first, then a dashed line 70 px beside it with the solid one's centres
    as its guide; the upper half of the BEV's rows stretched (``steep``)."""
    rows, cols = 400, 300
    bev = np.full((rows, cols), 80, np.uint8)
    c, t = arc(100.0, radius_m)
    draw(bev, c, t)
    c2, t2 = arc(170.0, radius_m - 70 * RES * math.copysign(1.0, radius_m))  # concentric, 3.5 m right
    dash = (np.arange(c2.size) * 0.2 // 60) % 3 == 0  # 3 m dashes, 6 m gaps
    draw(bev, c2[dash], t2[dash])
    # hatching bars beside it and noise features
    for k in range(6):
        draw(bev, 220 + np.arange(0, 40, 0.5), 60 + 30 * k + np.arange(0, 40, 0.5))
    rng = np.random.default_rng(3)
    bev[rng.integers(0, rows, 300), rng.integers(0, cols, 300)] = 200
    tt, cf, th, row_start = feature_arrays(bev)
    steep = np.zeros(rows, np.uint8)
    steep[: rows // 2] = 1
    # the staircase of stretched rows: the features there read nearly straight ahead (on the 30 m
    # bend more than 25 degrees off the line: taken only as a staircase's)
    up = (rows - 1 - tt < rows // 2) & (th >= 0)  # the far half: image rows above the middle
    th[up] = 0.1 * th[up] + 0.9 * math.pi / 2
    guide = np.zeros((4, 0))
    for c0, psi0 in ((100.0, math.pi / 2), (170.0, math.pi / 2), (170.0, math.pi / 2 + math.pi)):
        owner = np.full(tt.shape, -1, np.int32)
        owner[::7] = 1  # another track's features
        got, _, centres = kernel_and_twin(
            (tt, cf, th, row_start), rows, cols, (0.0, c0, psi0), owner, steep, guide
        )
        assert got[0] >= 0
        if c0 == 100.0:
            guide = centres  # the solid line guides the dashed one
            assert got[0] > 5
            if radius_m == 30.0:  # the staircase's features counted: the line followed to the top
                assert got[3] > 0.9 * rows
    assert guide.shape[1] > 5


@pytest.mark.parametrize("seed", range(10))
def test_follow_kernel_matches_numpy_twin_on_random_slanted_strokes(seed):
    """Strokes 10-70 degrees off straight ahead, straight or bending (20-200 m radius), 2-5 px
    wide, among noise features and features of another track, some leaving the BEV's side, some
    on stretched rows: followed up, then down, from a point on the stroke with a heading up to 17
    degrees off, the kernel takes exactly the twin's features and windows. Two ways it did not:
    a window's fitted line slants across it, and the band within ``half_w`` of it where features
    are taken reaches beyond the box around the predicted path that the kernel searched (1-10
    features of a stroke left untaken: seeds 0, 2, 3, 8); and a track leaving the BEV's right
    side went on along its prediction where one leaving the left side stopped (another ``t_turn``:
    seeds 2, 3, 9)."""
    rng = np.random.default_rng(seed)
    rows, cols = 200, 160
    for _ in range(5):
        bev = np.full((rows, cols), 80, np.uint8)
        off = math.radians(rng.uniform(10.0, 70.0)) * rng.choice([-1.0, 1.0])  # +: leaning right
        c0 = rng.uniform(10.0, cols - 10.0)
        s = np.arange(0.0, 600.0, 0.5)  # px of arc length
        radius = rng.uniform(20.0, 200.0) / RES * rng.choice([-1.0, 1.0, np.inf])
        ang = off + s / radius  # the heading from straight ahead
        cs = c0 + np.cumsum(np.sin(ang)) * 0.5
        ts = np.cumsum(np.cos(ang)) * 0.5
        draw(bev, cs, ts, half=rng.uniform(1.0, 2.5))
        bev[rng.integers(0, rows, 80), rng.integers(0, cols, 80)] = 200
        feats = feature_arrays(bev)
        owner = np.full(feats[0].shape, -1, np.int32)
        owner[rng.random(owner.size) < 0.05] = 1  # another track's
        steep = ((rng.random() < 0.5) & (np.arange(rows) < rng.integers(0, rows))).astype(np.uint8)
        inside = np.flatnonzero((cs >= 0) & (cs <= cols - 1) & (ts <= rows - 1))
        k = rng.choice(inside)  # a start on the stroke in the BEV, its heading a little off
        psi0 = math.pi / 2 - ang[k] + rng.uniform(-0.3, 0.3)
        for psi in (psi0, psi0 + math.pi):  # up, then down (the way up's features its own)
            _, owner, _ = kernel_and_twin(feats, rows, cols, (float(ts[k]), float(cs[k]), psi), owner, steep)


def test_the_window_box_holds_every_point_of_its_window():
    """``_window_box``, where the kernel looks for a window's features: every point of the window
    (``u`` in [0, step], ``v`` in [v_lo, v_hi], corners included) lies in its columns, and every BEV
    row such a point lies on or between; the box reaches a pixel beyond the corners, no further;
    no rows where the window lies wholly above or below the BEV."""
    rng = np.random.default_rng(4)
    n_rows = 200
    for _ in range(300):
        x, y = rng.uniform(-60.0, 260.0, 2)
        psi = rng.uniform(0.0, 2 * math.pi)
        cp, sp = math.cos(psi), math.sin(psi)
        step, v_lo = rng.uniform(5.0, 40.0), rng.uniform(-30.0, 5.0)
        v_hi = v_lo + rng.uniform(0.0, 30.0)
        x_lo, x_hi, r_lo, r_hi = _window_box(x, y, cp, sp, step, v_lo, v_hi, n_rows)
        u = np.concatenate([[0.0, 0.0, step, step], rng.uniform(0.0, step, 400)])
        v = np.concatenate([[v_lo, v_hi, v_lo, v_hi], rng.uniform(v_lo, v_hi, 400)])
        px, py = x + u * cp - v * sp, y + u * sp + v * cp
        assert (px > x_lo).all() and (px < x_hi).all()
        assert np.isclose(px[:4].min() - 1.0, x_lo) and np.isclose(px[:4].max() + 1.0, x_hi)
        rows = n_rows - 1 - py  # the BEV rows the points lie on or between
        on = (rows > -1) & (rows < n_rows)
        assert (np.floor(rows[on]).clip(0, n_rows - 1) >= r_lo).all()
        assert (np.ceil(rows[on]).clip(0, n_rows - 1) <= r_hi).all()
        assert (r_lo > r_hi) == (py[:4].min() - 1.0 >= n_rows or py[:4].max() + 1.0 <= -1.0)


def test_a_guide_window_whose_curvature_reached_the_clamp_guides_no_line():
    """A dashed line bending right (40 m radius; 3 m dashes, 5 m gaps) and, straight ahead of its
    first dash, a decoy dash; beside the gap a guide heading straight ahead and bending left at
    the tightest curvature followed (the clamp: kitti15_000024's stray track, its curvature from
    one window's slope after an 8 m gap), recorded as NaN. Skipped, the line keeps its own bend
    across the gap and takes the next dashes, never the decoy; the same guide with its clamped
    curvature taken as it is (what the kernel did before) turns the line onto the decoy. The NumPy
    twin agrees in both."""
    rows, cols = 400, 300
    bev = np.full((rows, cols), 80, np.uint8)
    c, t = arc(100.0, 40.0)
    s = np.arange(c.size) * 0.2 * RES  # arc length, metres
    dash = (s % 8.0) < 3.0
    draw(bev, c[dash], t[dash])
    decoy_t = np.arange(230.0, 290.0, 0.5)  # 11.5-14.5 m, straight ahead of the first dash's end
    draw(bev, np.full(decoy_t.size, 104.0), decoy_t)
    tt, cf, th, row_start = feature_arrays(bev)
    on_line = (
        np.min(np.hypot(cf[:, None] - c[None, dash][:, ::10], tt[:, None] - t[None, dash][:, ::10]), 1) < 3
    )
    on_decoy = (np.abs(cf - 104.0) < 3) & (tt >= 225)
    assert on_decoy.sum() > 30 and not (on_line & on_decoy).any()
    gt_ = np.arange(70.0, 240.0, 20.0)  # the guide: 3 m right of the line's start, bending left
    guide = np.stack(
        [np.full(gt_.size, 160.0), gt_, np.full(gt_.size, math.pi / 2), np.full(gt_.size, np.nan)]
    )
    taken = {}
    for name, gk in (("clamped", np.nan), ("taken", WINDOW_ARGS[4])):  # the clamp's curvature
        g = guide.copy()
        g[3] = gk
        start, none = (0.0, 100.0, math.pi / 2), np.full(tt.shape, -1, np.int32)
        _, owner, _ = kernel_and_twin((tt, cf, th, row_start), rows, cols, start, none, guide=g)
        taken[name] = (np.count_nonzero((owner == 0) & on_line), np.count_nonzero((owner == 0) & on_decoy))
    line_nm, decoy_nm = taken["clamped"]
    line_m, decoy_m = taken["taken"]
    assert decoy_nm == 0 and line_nm > 0.5 * on_line.sum()  # the bend kept: the dashes beyond the gap
    assert decoy_m > 20 and line_m < line_nm  # the clamped guide taken turns the line onto the decoy


def test_a_window_whose_curvature_reaches_the_clamp_is_recorded_as_no_guide():
    """The tightest bend followed 60 m (the clamp); a 3 m stroke straight ahead, a 5 m gap and a
    stroke 15 degrees off, offset by 40 cm (no road's line: a track that strays across a gap
    onto other features): the windows after the gap reach the clamp and are recorded as NaN, as
    the twin records them; a line on a 150 m bend is recorded with its curvature, none at the
    clamp."""
    rows, cols = 300, 200
    max_kappa = RES / 60.0
    args = WINDOW_ARGS[:4] + (max_kappa,) + WINDOW_ARGS[5:]
    recorded = {}
    for name in ("kink", "bend"):
        bev = np.full((rows, cols), 80, np.uint8)
        if name == "kink":
            draw(bev, np.full(300, 100.0), np.arange(0.0, 60.0, 0.2))  # a 3 m stroke
            u = np.arange(0.0, 100.0, 0.2)  # 5 m on, 5 m of a stroke 15 degrees off
            draw(bev, 108.0 + u * math.cos(math.radians(75)), 160.0 + u * math.sin(math.radians(75)))
        else:
            c, t = arc(100.0, 150.0)
            draw(bev, c, t)
        feats = feature_arrays(bev)
        owner = np.full(feats[0].shape, -1, np.int32)
        got, _, centres = kernel_and_twin(feats, rows, cols, (0.0, 100.0, math.pi / 2), owner, args=args)
        assert got[0] >= 5
        recorded[name] = centres[3]
    assert np.isnan(recorded["kink"]).sum() >= 3
    assert np.isfinite(recorded["bend"]).all() and (np.abs(recorded["bend"]) < max_kappa).all()


def seeds_band_by_band(t, c, theta, row_start, rows, cols, p, res):
    """The seeds as ``_seeds`` defines them, one band at a time with a loop over its histogram's
    bins (the reference of its one pass over every band)."""
    band = max(1, int(round(p.seed_band_m / res)))
    bin_px = max(1, int(round(0.25 / res)))
    n_bins = cols // bin_px + 2
    out = []
    for j in range(p.seed_bands):
        t_b = j * band
        if t_b >= rows:
            break
        r_hi = rows - 1 - t_b
        i0, i1 = row_start[max(0, r_hi - band + 1)], row_start[r_hi + 1]
        if i1 - i0 < p.min_seed_votes:
            continue
        tt, cc, th = t[i0:i1], c[i0:i1], theta[i0:i1]
        ok = (th > math.radians(20.0)) & (th < math.radians(160.0))
        tt, cc, th = tt[ok], cc[ok], th[ok]
        b = np.floor((cc - (tt - t_b) * np.cos(th) / np.sin(th)) / bin_px).astype(np.int64)
        keep = (b >= 0) & (b < n_bins)
        b, th = b[keep], th[keep]
        if b.size < p.min_seed_votes:
            continue
        hist = np.bincount(b, minlength=n_bins).astype(np.float64)
        s2 = np.bincount(b, weights=np.sin(2 * th), minlength=n_bins)
        c2 = np.bincount(b, weights=np.cos(2 * th), minlength=n_bins)
        h3 = hist.copy()
        h3[1:] += hist[:-1]
        h3[:-1] += hist[1:]
        for k in np.flatnonzero(h3 >= p.min_seed_votes):
            if h3[k] < h3[max(0, k - 1)] or h3[k] < h3[min(n_bins - 1, k + 1)]:
                continue
            if k > 0 and h3[k] == h3[k - 1]:
                continue  # a plateau: its first bin
            lo, hi = max(0, k - 1), min(n_bins, k + 2)
            psi = 0.5 * math.atan2(float(s2[lo:hi].sum()), float(c2[lo:hi].sum()))
            out.append((float(t_b), (k + 0.5) * bin_px, psi + math.pi if psi < 0 else psi, float(h3[k])))
    return out


@pytest.mark.parametrize("rows", [800, 150, 30])
def test_seeds_of_every_band_at_once_are_those_band_by_band(rows):
    """Solid and dashed lines, hatching bars and noise (and BEVs shorter than the seed bands): the
    seeds of the one pass over every band are those of the band-by-band loop, bit for bit."""
    cols = 400
    bev = np.full((rows, cols), 80, np.uint8)
    for c0, radius_m in ((120.0, 60.0), (190.0, 60.0), (300.0, -250.0)):
        c, t = arc(c0, radius_m)
        draw(bev, c, t)
    for k in range(5):
        draw(bev, 320 + np.arange(0, 30, 0.5), 10 + 25 * k + np.arange(0, 30, 0.5))
    rng = np.random.default_rng(5)
    bev[rng.integers(0, rows, 500), rng.integers(0, cols, 500)] = 200
    t, cf, th, row_start = feature_arrays(bev)
    for p in (FollowParams(), FollowParams(min_seed_votes=5, seed_bands=9), FollowParams(seed_band_m=0.7)):
        got = _seeds(t, cf, th, row_start, rows, cols, p, RES)
        exp = seeds_band_by_band(t, cf, th, row_start, rows, cols, p, RES)
        assert got == exp
        assert rows < 100 or len(got) >= 3  # the lines' seeds at least


def test_window_sums_add_as_numpy_sums_a_slice():
    """Each value with its neighbours, bit for bit ``a[j, k - 1 : k + 2].sum()`` (a -0.0 included)."""
    rng = np.random.default_rng(2)
    for a in (
        rng.normal(size=(3, 40)) * 10.0 ** rng.uniform(-8, 8, size=(3, 40)),
        rng.choice([0.0, -0.0, 1e16, -1e16, 1.0, 3.5], size=(3, 40)),
    ):
        got = _window_sums(a)
        exp = np.array([[a[j, max(0, k - 1) : k + 2].sum() for k in range(a.shape[1])] for j in range(3)])
        assert np.array_equal(got, exp) and np.array_equal(np.signbit(got), np.signbit(exp))


# ----------------------------------------------------------------------------- the node
def lane_cols(lane: Lane, t: np.ndarray) -> np.ndarray:
    a, b, c = lane.coeffs
    return a + b * t + c * t * t


@pytest.mark.parametrize("radius_m", [30.0, 60.0, -60.0, 250.0])
def test_follow_keeps_both_lines_of_a_bend_on_the_part_that_is_seen(radius_m):
    """Two lines 3.5 m apart on a bend: both found, on their sides, where they are within 60 degrees
    of straight ahead, also where they leave the BEV's side within metres. A parabola fitted on the
    near 20 m of a circle of 30-60 m radius and followed beyond is off by up to 30 cm (6 px) where
    the line is far: 11 image pixels at 20 m, under the lane metric's 20 px."""
    rows, cols = 800, 400
    bev = np.full((rows, cols), 80, np.uint8)
    truth = []
    for c0 in (165.0, 235.0):  # 1.75 m left and right of the vehicle
        c, t = arc(c0, radius_m - (c0 - 200.0) * RES)  # concentric: one centre of curvature
        draw(bev, c, t)
        truth.append((c, t))
    lanes = follow(FollowParams(), features=features_of(bev), geometry=geometry(rows, cols))["lanes"]
    assert [ln.side for ln in lanes] == ["left", "right"]
    for ln, (c, t) in zip(lanes, truth, strict=True):
        slope = np.gradient(c, t)
        seen = (
            (t <= rows - 1 - ln.bev_rows[0]) & (np.abs(slope) < math.tan(math.radians(60))) & (t < rows - 1)
        )
        assert seen.sum() > 40 / RES * 0.1  # at least 4 m of the line fitted
        assert np.abs(lane_cols(ln, t[seen]) - c[seen]).max() < (6.0 if abs(radius_m) < 100 else 2.5)
        assert np.abs(lane_cols(ln, t[seen]) - c[seen]).mean() < 3.0
        assert ln.extra["followed"]


@pytest.mark.parametrize("radius_m", [30.0, -30.0, 45.0, 60.0])
@pytest.mark.parametrize("phase_m", [1.0, 2.5])
def test_follow_keeps_a_dashed_line_parallel_to_the_solid_lines_across_its_gaps(radius_m, phase_m):
    """A dashed line (3 m dashes, 9 m gaps) between two solid lines on a bend, among scattered
    noise features, only a metre or two of its first dash in the BEV: its own curvature over a dash
    is noise, and without the solid lines as guides (``guide_m`` 0) it is lost on some bends; with
    them it is followed across its gaps, its lane within 5 px (25 cm) of the line where seen."""
    rows, cols = 800, 400
    bev = np.full((rows, cols), 80, np.uint8)
    for c0 in (95.0, 165.0, 235.0):  # concentric, 3.5 m apart; the dashed one 1.75 m left
        c, t = arc(c0, radius_m - (c0 - 200.0) * RES)
        if c0 == 165.0:
            keep = (np.arange(c.size) * 0.2 * RES + phase_m) % 12.0 < 3.0
            truth = c, t
            c, t = c[keep], t[keep]
        draw(bev, c, t)
    rng = np.random.default_rng(5)
    bev[rng.integers(0, rows, 600), rng.integers(0, cols, 600)] = 200
    f = features_of(bev)

    def left_lane(params):
        return [
            ln
            for ln in follow(params, features=f, geometry=geometry(rows, cols))["lanes"]
            if ln.side == "left"
        ]

    (ln,) = left_lane(FollowParams())
    c, t = truth
    seen = (t <= rows - 1 - ln.bev_rows[0]) & (np.abs(np.gradient(c, t)) < math.tan(math.radians(60)))
    assert t[seen].max() > 12.0 / RES  # beyond the first gap
    assert np.abs(lane_cols(ln, t[seen]) - c[seen]).max() < 5.0
    if (radius_m, phase_m) == (45.0, 1.0):
        assert left_lane(FollowParams(guide_m=0.0)) == []  # what the guides change


def test_follow_drops_hatching_bars_and_keeps_the_gore_border_line():
    """A solid line with a chevron-hatched area on its left (bars 45 degrees to it, every 2 m,
    touching it): the line is the left lane; no bar is a lane."""
    rows, cols = 800, 400
    bev = np.full((rows, cols), 80, np.uint8)
    t = np.arange(0.0, rows, 0.5)
    draw(bev, 170.0 + 0 * t, t)  # the gore's right border (ego left), 1.5 m left
    draw(bev, 100.0 + 0 * t, t)  # its left border
    draw(bev, 240.0 + 0 * t, t)  # the ego lane's right line
    for k in range(0, rows, 40):  # chevron bars between the borders, 45 degrees
        s = np.arange(0.0, 30.0, 0.5)
        draw(bev, 105.0 + s, k + s)
        draw(bev, 165.0 - s, k + s)
    lanes = follow(FollowParams(), features=features_of(bev), geometry=geometry(rows, cols))["lanes"]
    assert [ln.side for ln in lanes] == ["left", "right"]
    tt = np.arange(0, rows, 10.0)
    assert np.abs(lane_cols(lanes[0], tt) - 170.0).max() < 1.5
    assert np.abs(lane_cols(lanes[1], tt) - 240.0).max() < 1.5


def test_follow_bridges_a_dashed_lines_gaps_and_needs_support():
    rows, cols = 800, 400
    bev = np.full((rows, cols), 80, np.uint8)
    t = np.arange(0.0, rows, 0.5)
    dashed = (t // 60) % 3 == 0  # 3 m dashes, 6 m gaps
    draw(bev, (170.0 + 0.05 * t)[dashed], t[dashed])
    draw(bev, 240.0 + 0 * t[:40], t[:40])  # 1 m of a line on the right: too little for a lane
    lanes = follow(FollowParams(), features=features_of(bev), geometry=geometry(rows, cols))["lanes"]
    assert [ln.side for ln in lanes] == ["left"]
    assert np.abs(lane_cols(lanes[0], t) - (170.0 + 0.05 * t)).max() < 2.0
    assert lanes[0].bev_rows[0] < 100  # followed across the gaps to the far end


def test_follow_on_no_features_and_node_contract():
    bev = np.full((200, 160), 80, np.uint8)
    f = features_of(bev)
    assert follow(FollowParams(), features=f, geometry=geometry(200, 160))["lanes"] == []
    check_node_type(follow, {"features": f, "geometry": geometry(200, 160)})
    lanes = [_lane(165.0, 0.0, "left")]
    check_node_type(
        merge_node, {"lanes": lanes, "followed": [], "features": f, "geometry": geometry(200, 160)}
    )


def _lane(c0: float, c1: float, side: str, support: int = 100) -> Lane:
    return Lane((c0, c1, 0.0), (0, 799), side, 1.0, extra={"support": support})


def test_merge_adds_a_missing_side_and_replaces_a_misplaced_lane():
    g = geometry()
    p = MergeParams()
    rows = np.arange(800)
    # features on a line at column 165 and on a solid line at 100
    f = FeatureMap.from_points((800, 400), np.repeat(rows, 2), np.tile([100, 165], 800))
    hough = [_lane(165.0, 0.0, "left")]
    followed = [_lane(166.0, 0.0, "left", 50), _lane(240.0, 0.1, "right")]
    out = merge(hough, followed, g, p, f)
    assert [ln.coeffs[0] for ln in out] == [165.0, 240.0]  # the left kept (the same line), right added
    # a straight lane that leaves the line the followed one keeps to: replaced
    out = merge([_lane(165.0, 0.05, "left")], [_lane(165.0, 0.0, "left", 10)], g, p, f)
    assert out[0].coeffs[1] == 0.0
    # ... but not by a followed line with fewer features on it
    out = merge([_lane(165.0, 0.0, "left")], [_lane(165.0, 0.05, "left")], g, p, f)
    assert out[0].coeffs[1] == 0.0
    # a parallel marking beside the lane (the followed line has more features): another marking
    out = merge([_lane(165.0, 0.0, "left")], [_lane(100.0, 0.0, "left")], g, p, f)
    assert out[0].coeffs[0] == 165.0
    # a followed lane on the other side nearer than a lane's width to a lane: not added
    out = merge([_lane(195.0, 0.0, "left")], [_lane(215.0, 0.0, "right")], g, p, f)
    assert len(out) == 1


def test_merge_replaces_first_then_adds_and_prefers_the_shorter_closer_followed_lane():
    """Issue 28's bends: the replacements come before the additions, and of two fits of the same
    line the followed one is taken where it stops short and more features lie on it."""
    g = geometry()
    p = MergeParams()
    rows = np.arange(800)
    t = 799.0 - rows
    # a bend to the right: a left line 3.5 m (70 px) left of a right line, both curving right
    right = 240.0 + 2e-4 * t * t
    f = FeatureMap.from_points(
        (800, 400), np.repeat(rows, 2), np.stack([right - 70, right], 1).ravel().round()
    )
    followed = [
        Lane((170.0, 0.0, 2e-4), (300, 799), "left", 1.0, extra={"support": 500}),
        Lane((240.0, 0.0, 2e-4), (300, 799), "right", 1.0, extra={"support": 500}),
    ]
    # the Hough lane on the right: straight, it runs into the left line's path at the top
    hough = [Lane((240.0, -0.1, 0.0), (0, 799), "right", 1.0)]
    out = merge(hough, followed, g, p, f)
    # replaced by the followed right lane, and the followed left lane is then a lane's width from it
    assert [ln.coeffs[0] for ln in out] == [170.0, 240.0] and out[1].coeffs[1] == 0.0
    # the same line where both are, the Hough lane reaching farther: the followed lane, shorter,
    # with more features within half a marking's width, is taken ...
    compromise = Lane((241.5, 0.0, 2e-4), (0, 799), "right", 1.0)
    out = merge([compromise], followed[1:], g, p, f)
    assert out[0].bev_rows == (300, 799)
    # ... when it covers a dashed line's period (min_followed_m): 5 m rest on one dash
    short = Lane((240.0, 0.0, 2e-4), (700, 799), "right", 1.0)
    assert merge([compromise], [short], g, p, f)[0].bev_rows == (0, 799)
    # ... but not when the Hough lane is the closer fit
    out = merge(
        [Lane((240.0, 0.0, 2e-4), (0, 799), "right", 1.0)],
        [Lane((241.5, 0.0, 2e-4), (300, 799), "right", 1.0)],
        g,
        p,
        f,
    )
    assert out[0].bev_rows == (0, 799)


def test_merge_counts_a_crossing_lanes_support_within_half_a_marking():
    """A Hough lane on the same curving line near the car that leaves it far ahead (0.2 m apart on
    average, 0.6 m at the far end: one parabola over a changing curvature): within a whole
    marking's width it keeps nearly as many features as the followed lane (1.18 times fewer:
    kept before), within half of it clearly fewer: replaced."""
    g = geometry()
    rows = np.arange(800)
    t = 799.0 - rows
    c = 240.0 + 2e-4 * t * t
    near = t < 400  # a marking 3 px wide near, one feature on every 4th row far
    rr = np.concatenate([np.repeat(rows[near], 3), rows[~near & (rows % 4 == 0)]])
    cc = np.concatenate([np.repeat(c[near], 3) + np.tile([-1, 0, 1], near.sum()), c[~near & (rows % 4 == 0)]])
    order = np.argsort(rr, kind="stable")
    f = FeatureMap.from_points((800, 400), rr[order], cc[order].round())
    followed = Lane((240.0, 0.0, 2e-4), (0, 799), "right", 1.0)
    hough = Lane((240.0, 0.0, 2.2e-4), (0, 799), "right", 1.0)
    assert merge([hough], [followed], g, MergeParams(), f) == [followed]
    # the Hough lane on the line, the followed one leaving it: kept
    assert merge([followed], [hough], g, MergeParams(), f) == [followed]
