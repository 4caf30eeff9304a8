"""Tests of the road stage (``lanegraph_road``): kernels against NumPy twins, pose recovery,
road mask and IPM on analytic synthetic scenes, and the real KITTI frame when available."""

from __future__ import annotations

import itertools
import math

import cv2
import lanegraph_road as rd
import numpy as np
import pytest
from lanegraph_road import geometry, ipm, mask, profile
from lanegraph_road import mask as mask_mod

from lanegraph.types import BevGeometry, Calibration, RoadModel

CALIB = Calibration(f=500.0, cx=318.3, cy=96.7, baseline=0.5, width=640, height=240)
PITCH, ROLL, HEIGHT = math.radians(1.5), math.radians(1.0), 1.6


# --------------------------------------------------------------------------- NumPy twins


def vdisparity_np(disp, keep, n_bins, bin_size, max_disp, cx, cy, s, c, step=1):
    """The v-disparity of the ``keep`` pixels of every ``step``-th column, in roll-corrected rows."""
    H, W = disp.shape
    v, u = np.mgrid[0:H, 0:W]
    r = np.floor(cy + s * (u - cx) + c * (v - cy) + 0.5).astype(int)
    k = np.floor(np.where(disp > 0, disp, 0) / bin_size).astype(int)
    ok = keep & (u % step == 0) & (disp > 0) & (disp < max_disp) & (r >= 0) & (r < H) & (k < n_bins)
    out = np.zeros((H, n_bins), np.float32)
    np.add.at(out, (r[ok], k[ok]), 1.0)
    return out


def dp_objective(score, path, smoothness):
    steps = path[1:] - path[:-1]  # path[v+1] - path[v] >= 0
    return score[np.arange(len(path)), path].sum() - smoothness * float((steps**2).sum())


def dp_best_brute(score, max_step, smoothness):
    """Best objective over every admissible path (exhaustive; tiny inputs only)."""
    H, D = score.shape
    best = -np.inf
    for path in itertools.product(range(D), repeat=H):
        p = np.array(path)
        steps = p[1:] - p[:-1]
        if np.all(steps >= 0) and np.all(steps <= max_step):
            best = max(best, dp_objective(score, p, smoothness))
    return best


def row_refine_np(disp, keep, centre, radius, cx, cy, s, c):
    H, W = disp.shape
    v, u = np.mgrid[0:H, 0:W]
    r = np.floor(cy + s * (u - cx) + c * (v - cy) + 0.5).astype(int)
    ok = keep & (disp > 0) & (r >= 0) & (r < H)
    rc = np.clip(r, 0, H - 1)
    ok &= np.abs(disp - centre[rc]) <= radius[rc]
    return (
        np.bincount(r[ok], weights=disp[ok].astype(np.float64), minlength=H),
        np.bincount(r[ok], minlength=H).astype(np.float64),
    )


def plane_band_np(disp, b0, b1, b2, height, band):
    H, W = disp.shape
    v, u = np.mgrid[0:H, 0:W]
    return (disp > 0) & np.isfinite(disp) & (np.abs(disp - (b0 + b1 * u + b2 * v)) <= band / height * disp)


def plane_sums_np(disp, step, v_top, min_disp, b0, b1, b2, fixed_tol, plane_tol, height, min_tol, uc, vc):
    """One selection round of the roll plane (``fixed_tol > 0``: that tolerance, else the metric one):
    ``(n, [Su, Sv, Suu, Suv, Svv, Sd, Sud, Svd])`` of the centred normal equations."""
    sub = disp[::step, ::step].astype(np.float64)
    vv, uu = np.mgrid[0 : disp.shape[0] : step, 0 : disp.shape[1] : step].astype(np.float64)
    tol = fixed_tol if fixed_tol > 0 else np.maximum(plane_tol * sub / height, min_tol)
    sel = (sub > min_disp) & np.isfinite(sub) & (vv >= v_top) & (np.abs(sub - (b0 + b1 * uu + b2 * vv)) < tol)
    x, y, d = uu[sel] - uc, vv[sel] - vc, sub[sel]
    sums = [
        x.sum(),
        y.sum(),
        (x * x).sum(),
        (x * y).sum(),
        (y * y).sum(),
        d.sum(),
        (x * d).sum(),
        (y * d).sum(),
    ]
    return int(sel.sum()), np.array(sums)


def ransac_line_np(v, d, w, tol, iterations, seed=0, min_slope=0.0):
    """The former NumPy ``_ransac_line`` (lines rising by more than ``min_slope`` only)."""
    n = v.size
    if n < 2:
        return None
    rng = np.random.default_rng(seed)
    i = rng.integers(0, n, iterations)
    j = rng.integers(0, n, iterations)
    ok = v[i] != v[j]
    i, j = i[ok], j[ok]
    if i.size == 0:
        return None
    a1 = (d[i] - d[j]) / (v[i] - v[j])
    a0 = d[i] - a1 * v[i]
    good = (a1 > 0) & (a1 > min_slope)
    if not good.any():
        return None
    a0, a1 = a0[good], a1[good]
    res = np.abs(d[None, :] - (a0[:, None] + a1[:, None] * v[None, :]))
    score = ((res < tol) * w[None, :]).sum(axis=1)
    return res[int(np.argmax(score))] < tol


def height_class_np(disp, a0, a1, a2, cx, cy, s, c, height, height_tol, min_tol, min_road):
    H, W = disp.shape
    v, u = np.mgrid[0:H, 0:W]
    r = cy + s * (u - cx) + c * (v - cy)
    dr = a0 + a1 * r + a2 * r * r
    tol = np.maximum(height_tol * disp / height, min_tol)
    out = np.where(disp - dr > tol, 2, np.where(dr - disp > tol, 3, 1)).astype(np.uint8)
    out[~((disp > 0) & np.isfinite(disp))] = 4  # NaN and +-inf: no disparity, as 0
    out[dr < min_road] = 0
    return out


def free_space_np(labels, min_run, unknown_is_road):
    H, W = labels.shape
    out = np.zeros((H, W), bool)
    for u in range(W):
        run = 0
        seen = False
        for v in range(H - 1, -1, -1):
            if labels[v, u] == 1 or (unknown_is_road and labels[v, u] == 4 and seen):
                if unknown_is_road and not seen:
                    out[v + 1 :, u] |= labels[v + 1 :, u] == 4
                run = 0
                seen = True
                out[v, u] = True
            elif labels[v, u] == 2:
                run += 1
                if run >= min_run:
                    break
    return out


def fill_holes_np(mask, classes, max_above):
    """The former NumPy ``_fill_holes``: ``~mask`` components off the border with few above-road pixels."""
    n, labels = cv2.connectedComponents((~mask).astype(np.uint8), connectivity=4)
    if n <= 1:
        return mask
    return fill_holes_labels_np(mask, labels, n, classes, max_above)


def fill_holes_labels_np(mask, labels, n, classes, max_above):
    """Given the labels of ``~mask``, fill the components 1..n-1 off the border with few
    above-road pixels (the reference for ``_fill_holes``, which labels only the holes)."""
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    n_above = np.bincount(labels[classes == mask_mod.ABOVE], minlength=n)
    fill = n_above <= max_above * np.bincount(labels.ravel(), minlength=n)
    fill[0] = False
    fill[border] = False
    return mask | fill[labels]


def keep_components_np(m, keep, band_frac, cx, image_rows=None):
    """The former OpenCV ``_keep_components``: every pixel labelled (8-connected), the components
    with at least a tenth of the largest overlap with the seed (the band's central half, then the
    band) kept."""
    H, W = m.shape
    image_rows = H if image_rows is None else image_rows
    n, labels = cv2.connectedComponents(m.astype(np.uint8), connectivity=8)
    if n <= 1:
        return m
    band = labels[max(0, H - max(1, int(round(band_frac * image_rows)))) :]
    lo, hi = int(max(0, cx - W / 4)), int(min(W, cx + W / 4 + 1))
    for region in ([band[:, lo:hi]] if keep == "bottom_centre" else []) + [band]:
        overlap = np.bincount(region.ravel(), minlength=n)[1:]
        if overlap.max() > 0:
            kept = np.zeros(n, bool)
            kept[1:] = overlap >= 0.1 * overlap.max()
            return kept[labels]
    return m


def random_disparity(rng, shape, max_d=40.0, invalid=0.2):
    d = rng.uniform(-2.0, max_d * 1.2, shape).astype(np.float32)
    d[rng.random(shape) < invalid] = 0.0
    return d


EDGE_SHAPES = [(1, 7), (9, 1), (13, 17)]


def select_np(disp, band, cx, cy, s, c, step=1):
    """NumPy twin of ``_select_kernel``'s list: (rows, disparities) of the selected pixels of every
    ``step``-th column, row-major."""
    H, W = disp.shape
    v, u = np.mgrid[0:H, 0:W]
    r = np.floor(cy + s * (u - cx) + c * (v - cy) + 0.5).astype(int)
    ok = (u % step == 0) & (disp > 0) & np.isfinite(disp) & (r >= 0) & (r < H)
    if band is not None:
        k, b0, b1, b2 = band
        ok &= np.abs(disp - (b0 + b1 * u + b2 * v)) <= k * disp
    return r[ok], disp[ok]


@pytest.mark.parametrize("shape", EDGE_SHAPES)
@pytest.mark.parametrize("roll", [0.0, 0.05, -0.2])
@pytest.mark.parametrize("band", [None, (0.6, 1.0, 0.3, 1.2)])
def test_select_kernel_matches_numpy(shape, roll, band):
    """The fused selection + v-disparity kernel: the pixel list and the counts of the twins."""
    rng = np.random.default_rng(1)
    disp = random_disparity(rng, shape)
    s, c = math.sin(roll), math.cos(roll)
    keep = (
        np.ones(shape, bool) if band is None else plane_band_np(disp, band[1], band[2], band[3], 1.0, band[0])
    )
    for step in (1, 2, 3):
        r_np, d_np = select_np(disp, band, 6.3, 4.1, s, c, step)
        rows, d = profile.select_pixels(disp, 6.3, 4.1, s, c, band, step)
        np.testing.assert_array_equal(rows, r_np)
        np.testing.assert_array_equal(d, d_np)
        for bin_size, max_d in ((1.0, 32.0), (0.5, 40.0), (3.0, 10.0), (3.0, 12.0)):
            nb = profile.n_bins(max_d, bin_size)
            rows, d, vd = profile.select_and_count(disp, 6.3, 4.1, s, c, max_d, bin_size, band, step)
            np.testing.assert_array_equal(rows, r_np)
            np.testing.assert_array_equal(d, d_np)
            exp = vdisparity_np(disp, keep, nb, bin_size, max_d, 6.3, 4.1, s, c, step)
            np.testing.assert_array_equal(vd, exp)
            assert vd.shape == (shape[0], nb) and vd.dtype == np.float32


def test_select_kernel_edge_cases():
    # all invalid: nothing selected, nothing counted
    rows, d, vd = profile.select_and_count(
        np.zeros((6, 9), np.float32), 4.0, 3.0, 0.1, 0.99, 16.0, 1.0, None, 2
    )
    assert rows.size == d.size == 0 and vd.shape == (6, 16) and not vd.any()
    # every pixel rotated off the image: nothing selected
    rows, d, vd = profile.select_and_count(np.ones((3, 5), np.float32), 2.0, -5.0, 0.0, 0.0, 16.0, 1.0)
    assert rows.size == 0 and not vd.any()


def test_vdisparity_counts_exact_bin_edges():
    """A disparity exactly on a bin edge goes to the upper bin (d / bin_size, never d * (1 / bin_size))."""
    disp = np.array([[3.0, 6.0, 9.0, 2.9999, 12.0]], np.float32)  # 12 = max: left out
    vd = profile.select_and_count(disp, 0.0, 0.0, 0.0, 1.0, 12.0, 3.0)[2]
    np.testing.assert_array_equal(vd[0], [1, 1, 1, 1])


def test_road_kernels_treat_non_finite_disparities_as_zero():
    """NaNs and infinities are invalid pixels to every kernel that reads the disparity map (no pass
    looks for them first): the selection, the roll plane and the height classes give what they give
    on the map with those pixels set to 0, in sampled and unsampled columns alike, and their twins agree."""
    rng = np.random.default_rng(11)
    H, W = 40, 57
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    disp = (1.0 + 0.02 * u + 0.6 * v + rng.normal(0, 0.05, (H, W))).astype(np.float32)
    bad = disp.copy()
    idx = rng.random(disp.shape) < 0.05
    bad[idx] = rng.choice(np.array([np.nan, np.inf, -np.inf], np.float32), idx.sum())
    zeroed = np.where(idx, 0.0, disp).astype(np.float32)
    band = (0.1, 1.0, 0.02, 0.6)
    for b in (None, band):
        for step in (1, 4):
            got = profile.select_and_count(bad, 28.0, 19.5, 0.01, 0.9999, 64.0, 1.0, b, step)
            exp = profile.select_and_count(zeroed, 28.0, 19.5, 0.01, 0.9999, 64.0, 1.0, b, step)
            for g, e in zip(got, exp):
                np.testing.assert_array_equal(g, e)
            np.testing.assert_array_equal(got[1], select_np(bad, b, 28.0, 19.5, 0.01, 0.9999, step)[1])
    args = (2, 4, 3.0, 1.0, 0.02, 0.6, 1.0, 0.5, 1.6, 0.25, 28.0, 19.5, 3)
    got, exp = profile._plane_fit_kernel(bad, *args), profile._plane_fit_kernel(zeroed, *args)
    assert got[0] and got == exp
    np.testing.assert_allclose(got[1:], plane_fit_np(bad, *args)[1], rtol=1e-9, atol=1e-9)
    hargs = (1.0, 0.6, 0.0, 28.0, 19.5, 0.0, 1.0, 1.6, 0.08, 0.5, 2.0)
    labels, _ = mask._height_class_kernel(bad, 1, *hargs)
    np.testing.assert_array_equal(labels, mask._height_class_kernel(zeroed, 1, *hargs)[0])
    np.testing.assert_array_equal(labels, height_class_np(bad, *hargs))
    seen = idx & (labels > 0)  # where the road would be visible
    assert seen.any() and (labels[seen] == mask.UNKNOWN).all()


def test_profile_treats_non_finite_disparities_as_invalid(scene):
    """A NaN or an infinity is invalid: the road of the map with them set to 0."""
    disp = noisy(scene[0])
    bad = disp.copy()
    rng = np.random.default_rng(4)
    idx = rng.random(disp.shape) < 0.01
    bad[idx] = rng.choice(np.array([np.nan, np.inf, -np.inf], np.float32), idx.sum())
    zeroed = np.where(idx, 0.0, disp).astype(np.float32)
    a, vd_a = profile.estimate_road(rd.ProfileParams(), bad, CALIB)
    b, vd_b = profile.estimate_road(rd.ProfileParams(), zeroed, CALIB)
    assert a.valid and (a.a0, a.a1, a.roll, a.pitch, a.height, a.v_min) == (
        b.a0,
        b.a1,
        b.roll,
        b.pitch,
        b.height,
        b.v_min,
    )
    np.testing.assert_array_equal(a.profile, b.profile)
    np.testing.assert_array_equal(vd_a, vd_b)
    assert np.isnan(bad).any()  # the input is left as it was


def test_vdisparity_edge_cases():
    disp = np.zeros((5, 6), np.float32)
    vd = rd.road_vdisparity(rd.VDisparityParams(max_disparity=16), disparity=disp)["vdisparity"]
    assert vd.shape == (5, 16) and vd.dtype == np.float32 and vd.sum() == 0
    disp[:] = 16.0  # exactly max: left out
    disp[0, 0] = 100.0
    disp[1, 1] = np.nan  # sanitised to invalid
    disp[2, 2] = 15.99
    vd = rd.road_vdisparity(rd.VDisparityParams(max_disparity=16), disparity=disp)["vdisparity"]
    assert vd.sum() == 1 and vd[2, 15] == 1


@pytest.mark.parametrize("max_step", [1, 2])
@pytest.mark.parametrize("smoothness", [0.0, 0.3])
def test_dp_kernel_is_optimal(max_step, smoothness):
    rng = np.random.default_rng(2)
    for shape in ((1, 4), (4, 1), (5, 4), (6, 3)):
        score = rng.random(shape)
        path = profile._dp_path_kernel(score, max_step, smoothness)
        steps = np.diff(path)
        assert np.all(steps >= 0) and np.all(steps <= max_step), "disparity must not increase upwards"
        assert dp_objective(score, path, smoothness) == pytest.approx(
            dp_best_brute(score, max_step, smoothness)
        )


def dp_np(score: np.ndarray, max_step: int, smoothness: float) -> np.ndarray:
    """The DP of ``_dp_path_kernel`` with the bins vectorised (rows in Python): the path."""
    H, D = score.shape
    pen = smoothness * np.arange(max_step + 1) ** 2
    prev = score[H - 1].copy()
    back = np.zeros((H, D), np.int64)
    for v in range(H - 2, -1, -1):
        cand = np.full((max_step + 1, D), -np.inf)
        for step in range(max_step + 1):
            cand[step, : D - step] = prev[step:] - pen[step]
        back[v] = np.argmax(cand, axis=0)
        prev = score[v] + cand.max(axis=0)
    path = np.zeros(H, np.int64)
    path[0] = int(np.argmax(prev))
    for v in range(1, H):
        path[v] = path[v - 1] + back[v - 1, path[v - 1]]
    return path


@pytest.mark.parametrize("max_step, smoothness", [(1, 0.0), (3, 0.02), (5, 0.5)])
def test_dp_kernel_matches_vectorised_twin(max_step, smoothness):
    rng = np.random.default_rng(max_step)
    for shape in ((1, 6), (30, 1), (120, 40)):
        score = rng.random(shape)
        np.testing.assert_array_equal(
            profile._dp_path_kernel(score, max_step, smoothness), dp_np(score, max_step, smoothness)
        )


def test_dp_follows_a_slanted_line_not_a_vertical_obstacle():
    H, D = 60, 40
    score = np.zeros((H, D))
    line = np.clip((np.arange(H) * 0.5).astype(int), 0, D - 1)  # road: d grows downwards
    score[np.arange(H), line] = 1.0
    score[10:45, 22] = 0.9  # an obstacle: a vertical segment at d = 22 (stands on the road at row 44)
    path = profile._dp_path_kernel(score, 3, 0.05)
    assert np.mean(path == line) > 0.9


@pytest.mark.parametrize("shape", EDGE_SHAPES)
def test_row_refine_kernel_matches_numpy(shape):
    rng = np.random.default_rng(3)
    disp = random_disparity(rng, shape)
    centre = rng.uniform(0, 40, shape[0])
    radius = rng.uniform(0.5, 8.0, shape[0])
    keep = np.ones(shape, bool)
    # any disparities (float sums), and OpenCV's 1/16 pixels (summed in fixed point), some exactly
    # on the window's edge
    sixteenths = (np.round(disp * 16) / 16).astype(np.float32)
    assert not profile._fixed_point(disp.ravel())[0] and profile._fixed_point(sixteenths.ravel())[0]
    for dmap in (disp, sixteenths):
        for cen in (centre, np.round(centre * 16) / 16):
            for s, c in ((0.0, 1.0), (0.1, 0.99), (-0.3, 0.95)):
                rows, d = profile.select_pixels(dmap, 3.0, 2.0, s, c)
                t1, n1 = profile._row_refine_kernel(rows, d, cen, np.round(radius))
                t2, n2 = row_refine_np(dmap, keep, cen, np.round(radius), 3.0, 2.0, s, c)
                np.testing.assert_allclose(t1, t2, rtol=1e-9, atol=1e-6)
                np.testing.assert_array_equal(n1, n2)


def row_refine_list_np(rows, d, centre, radius):
    """NumPy twin of ``_row_refine_kernel`` over the pixel list: per row, the sum and the count of the
    disparities within ``radius`` of ``centre``."""
    rows, d = rows.astype(np.int64), d.astype(np.float64)
    ok = np.abs(d - centre[rows]) <= radius[rows]
    H = centre.size
    return np.bincount(rows[ok], weights=d[ok], minlength=H), np.bincount(rows[ok], minlength=H).astype(
        np.float64
    )


def profile_np(
    vd,
    columns,
    max_step,
    smoothness,
    bin_size,
    radius0,
    rows,
    d,
    height,
    plane_tol,
    min_tol,
    step,
    min_row_count,
    min_fit_disp,
):
    """NumPy twin of ``_profile_kernel`` (the former NumPy steps of ``_profile_pass``)."""
    H = vd.shape[0]
    supported = np.flatnonzero(vd.any(axis=1))
    v0 = int(supported[0]) if supported.size else 0
    bins = np.flatnonzero(vd[v0:].any(axis=0))
    d_hi = int(bins[-1]) + 1 if bins.size else vd.shape[1]
    path = np.empty(H, np.int64)
    path[v0:] = dp_np(vd[v0:, :d_hi].astype(np.float64) / columns, max_step, smoothness)
    path[:v0] = path[v0]
    centre = (path + 0.5) * bin_size
    radius = np.full(H, radius0)
    total, count = row_refine_list_np(rows, d, centre, radius)
    if height > 0:
        for _ in range(2):
            centre = np.where(count > 0, total / np.maximum(count, 1.0), centre)
            radius = np.maximum(plane_tol * centre / height, min_tol)
            total, count = row_refine_list_np(rows, d, centre, radius)
    profile = np.full(H, -1.0, np.float32)
    have = count * step >= min_row_count
    profile[have] = (total[have] / count[have]).astype(np.float32)
    use = have & (profile >= min_fit_disp)
    return profile, np.flatnonzero(use).astype(np.float64), profile[use].astype(np.float64), count[use]


def assert_profiles_match(got, ref):
    # the sums of a row in another order: the profile to rounding, the same rows and counts
    np.testing.assert_allclose(got[0], ref[0], rtol=1e-6)
    np.testing.assert_array_equal(got[1], ref[1])
    np.testing.assert_allclose(got[2], ref[2], rtol=1e-6)
    np.testing.assert_array_equal(got[3], ref[3])


@pytest.mark.parametrize("height", [0.0, HEIGHT])
@pytest.mark.parametrize("roll", [0.0, ROLL])
def test_profile_kernel_matches_numpy(scene, height, roll):
    """DP, refinements, profile and fit rows in one kernel against the NumPy steps, on the noisy
    synthetic road (pass-2-like with a height) and on random counts and pixels."""
    disp = noisy(scene[0])
    s, c = geometry.roll_row_coeffs(roll, CALIB)
    for step in (1, 4):
        rows, d, vd = profile.select_and_count(disp, CALIB.cx, CALIB.cy, s, c, 64.0, 1.0, None, step)
        args = (
            vd,
            float(-(-CALIB.width // step)),
            3,
            0.02,
            1.0,
            1.0,
            rows,
            d,
            height,
            0.05,
            0.25,
            step,
            10,
            np.float32(3.0),
        )
        got = profile._profile_kernel(*args)
        assert got[1].size > 50
        assert_profiles_match(got, profile_np(*args))
    rng = np.random.default_rng(13)
    for H, D in ((1, 5), (7, 1), (30, 12)):
        vd = (rng.random((H, D)) < 0.3).astype(np.float32) * rng.integers(1, 9, (H, D)).astype(np.float32)
        vd[: H // 3] = 0.0  # unsupported rows on top
        rows = np.sort(rng.integers(0, H, 200)).astype(np.int16)
        d = rng.uniform(0.1, D, 200).astype(np.float32)
        for radius0 in (0.5, 3.0):
            args = (vd, 3.0, 2, 0.1, 1.0, radius0, rows, d, height, 0.3, 0.5, 2, 2, np.float32(1.5))
            assert_profiles_match(profile._profile_kernel(*args), profile_np(*args))
    # nothing supported, no pixels: level path at bin 0, no profile, no fit rows
    prof, fit_rows, _, _ = profile._profile_kernel(
        np.zeros((5, 4), np.float32),
        3.0,
        2,
        0.1,
        1.0,
        1.0,
        np.zeros(0, np.int16),
        np.zeros(0, np.float32),
        height,
        0.3,
        0.5,
        2,
        2,
        np.float32(1.5),
    )
    assert (prof == -1).all() and fit_rows.size == 0


def test_ransac_line_kernel_matches_numpy():
    rng = np.random.default_rng(10)
    for n in (1, 2, 3, 30, 200):
        v = rng.integers(0, 100, n).astype(np.float64)
        d = 0.3 * v - 5.0 + rng.normal(0, 0.4, n)
        d[rng.random(n) < 0.3] += rng.uniform(-10, 10)
        w = rng.integers(10, 500, n).astype(np.float64)
        for iterations in (1, 50, 300):
            got = ransac_kernel(v, d, w, 1.0, iterations)
            ref = ransac_line_np(v, d, w, 1.0, iterations)
            assert (got is None) == (ref is None)
            if ref is not None:
                np.testing.assert_array_equal(got, ref)
    # no admissible pair: every slope <= 0
    v = np.arange(10.0)
    assert ransac_kernel(v, -v, np.ones(10), 1.0, 20) is None


def ransac_kernel(v, d, w, tol, iterations, min_slope=0.0):
    """``_ransac_line_kernel`` on the pairs ``_sample_pairs`` draws: the inliers or None."""
    if v.size < 2:
        return None
    i, j = profile._sample_pairs(v.size, iterations, 0)
    found, inl = profile._ransac_line_kernel(v, d, w, i, j, tol, min_slope)
    return inl if found else None


def line_fit_np(v, d, w, tol, iterations, min_slope=0.0):
    """NumPy twin of ``_line_fit``: ``(status, coef, inliers)`` of RANSAC then the least squares."""
    inl = ransac_line_np(v, d, w, tol, iterations, min_slope=min_slope)
    if inl is None or np.count_nonzero(inl) < 2:
        return 0, None, None
    coef, inl = profile._robust_refit_np(v, d, w, 1, tol, inl)
    return (2 if coef is not None else 1), coef, inl


def test_line_fit_matches_numpy():
    """RANSAC + least squares in one kernel (and ``_robust_fit`` around it) against the twins."""
    rng = np.random.default_rng(11)
    for n in (2, 3, 30, 200):
        for iterations in (1, 50, 300):
            v = rng.integers(0, 100, n).astype(np.float64)
            d = 0.3 * v - 5.0 + rng.normal(0, 0.4, n)
            d[rng.random(n) < 0.3] += rng.uniform(-10, 10)
            counts = rng.integers(0, 500, n).astype(np.float64)
            # pixel counts (summed as integers), and weights that are not (the float sums; halves
            # keep every sum exact, so the twin's order gives the same scores)
            for w in (counts, counts + 0.5):
                i, j = profile._sample_pairs(n, iterations, 0)
                status, a0, a1, inl = profile._line_fit(v, d, w, i, j, 1.0, 4, 0.0)
                ref_status, ref, ref_inl = line_fit_np(v, d, w, 1.0, iterations)
                assert status == ref_status
                coef, fit_inl = profile._robust_fit(v, d, w, 1, 1.0, iterations, None)
                if status > 0:
                    np.testing.assert_array_equal(inl, ref_inl)
                    np.testing.assert_array_equal(fit_inl, ref_inl)
                if status == 2:
                    np.testing.assert_allclose([a0, a1], ref, rtol=1e-9, atol=1e-9)
                    np.testing.assert_array_equal(coef, [a0, a1])
                else:
                    assert coef is None
    # no admissible pair (every slope <= 0), one point, one abscissa: no line
    v = np.arange(10.0)
    assert profile._robust_fit(v, -v, np.ones(10), 1, 1.0, 20, None) == (None, None)
    assert profile._robust_fit(v[:1], v[:1], np.ones(1), 1, 1.0, 20, None) == (None, None)
    i, j = profile._sample_pairs(5, 20, 0)
    assert profile._line_fit(np.full(5, 3.0), np.arange(5.0), np.ones(5), i, j, 1.0, 4, 0.0)[0] == 0


def test_line_refit_kernel_matches_numpy():
    """The line rounds of ``_robust_fit`` (numba) against its NumPy rounds: same inliers, same line."""
    rng = np.random.default_rng(12)
    for n in (2, 3, 30, 200):
        for _ in range(5):
            v = rng.integers(0, 100, n).astype(np.float64)
            d = 0.3 * v - 5.0 + rng.normal(0, 0.4, n)
            d[rng.random(n) < 0.3] += rng.uniform(-10, 10)
            w = rng.integers(0, 500, n).astype(np.float64)  # zero weights too
            inl = rng.random(n) < 0.7
            ok, a0, a1, got_inl = profile._line_refit_kernel(v, d, w, inl, 1.0, 4)
            ref, ref_inl = profile._robust_refit_np(v, d, w, 1, 1.0, inl)
            assert ok == (ref is not None)
            np.testing.assert_array_equal(got_inl, ref_inl)
            if ok:
                np.testing.assert_allclose([a0, a1], ref, rtol=1e-9, atol=1e-9)
    # all inliers on one abscissa: no line
    v = np.full(5, 3.0)
    ok, *_ = profile._line_refit_kernel(v, v, np.ones(5), np.ones(5, bool), 1.0, 4)
    assert not ok


def plane_fit_np(
    disp, step, v_top, min_disp, b0, b1, b2, first_tol, plane_tol, height, min_tol, uc, vc, rounds
):
    """NumPy twin of ``_plane_fit_kernel``: ``(ok, b)``, the rounds of ``plane_sums_np`` and a solve."""
    b = np.array([b0, b1, b2])
    fixed = first_tol
    for _ in range(rounds):
        n, S = plane_sums_np(disp, step, v_top, min_disp, *b, fixed, plane_tol, height, min_tol, uc, vc)
        if n < 50:
            return False, None
        su, sv, suu, suv, svv, sd, sud, svd = S
        M = np.array([[n, su, sv], [su, suu, suv], [sv, suv, svv]], np.float64)
        try:
            a, c1, c2 = np.linalg.solve(M, np.array([sd, sud, svd]))
        except np.linalg.LinAlgError:
            return False, None
        b = np.array([a - c1 * uc - c2 * vc, c1, c2])
        if not np.all(np.isfinite(b)):
            return False, None
        fixed = 0.0
    return (True, b) if b[2] > 0 else (False, None)


@pytest.mark.parametrize("shape", EDGE_SHAPES + [(40, 57), (90, 130)])
def test_plane_fit_kernel_matches_numpy(shape):
    """Every round of the roll plane in one kernel against the NumPy rounds, on noisy planes with
    outliers and invalid pixels (the small shapes have too few pixels: no plane)."""
    rng = np.random.default_rng(6)
    H, W = shape
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    for b_true in ((-2.0, 0.05, 0.6), (1.0, -0.08, 0.3), (30.0, 0.0, -0.2)):
        disp = (b_true[0] + b_true[1] * u + b_true[2] * v + rng.normal(0, 0.05, shape)).astype(np.float32)
        disp[rng.random(shape) < 0.15] += rng.uniform(2, 10)
        disp[rng.random(shape) < 0.1] = 0.0
        for step in (1, 2, 3):
            for rounds in (1, 3):
                args = (
                    step,
                    4,
                    3.0,
                    b_true[0],
                    0.0,
                    b_true[2],
                    1.0,
                    0.5,
                    1.6,
                    0.25,
                    0.5 * (W - 1),
                    0.5 * (H - 1),
                    rounds,
                )
                ok, *b = profile._plane_fit_kernel(disp, *args)
                ref_ok, ref = plane_fit_np(disp, *args)
                assert ok == ref_ok
                if ok:
                    np.testing.assert_allclose(b, ref, rtol=1e-9, atol=1e-9)
    # all invalid: no plane
    assert not profile._plane_fit_kernel(
        np.zeros((40, 57), np.float32), 1, 0, 3.0, 0.0, 0.0, 0.5, 1.0, 0.5, 1.6, 0.25, 28.0, 19.5, 3
    )[0]


def test_fit_road_plane_matches_lstsq():
    """The normal-equation plane of ``_fit_road_plane`` is the least-squares plane of its pixels."""
    rng = np.random.default_rng(7)
    H, W = 60, 90
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    b_true = np.array([-8.0, 0.02, 0.6])
    disp = (b_true[0] + b_true[1] * u + b_true[2] * v + rng.normal(0, 0.05, (H, W))).astype(np.float32)
    disp[rng.random((H, W)) < 0.1] += 5.0  # outliers above the road
    calib = Calibration(f=100.0, cx=W / 2, cy=H / 2, baseline=0.5)
    params = profile.ProfileParams(roll_subsample=2, roll_iterations=3)
    _, h1 = geometry.pose_from_line(b_true[0], b_true[2], calib)
    b = profile._fit_road_plane(disp, np.array([b_true[0], b_true[2]]), h1, 20, params)
    # reference: the same selection rounds with np.linalg.lstsq on the selected pixels
    sub = disp[::2, ::2].astype(np.float64)
    vv, uu = np.mgrid[0:H:2, 0:W:2].astype(np.float64)
    valid = (sub > params.min_fit_disparity_px) & (vv >= 20)
    sel = valid & (np.abs(sub - (b_true[0] + b_true[2] * vv)) < params.roll_tolerance_px)
    tol = np.maximum(params.plane_tolerance_m * sub / h1, params.min_plane_tolerance_px)
    for _ in range(params.roll_iterations):
        A = np.stack([np.ones(np.count_nonzero(sel)), uu[sel], vv[sel]], axis=1)
        ref, *_ = np.linalg.lstsq(A, sub[sel], rcond=None)
        sel = valid & (np.abs(sub - (ref[0] + ref[1] * uu + ref[2] * vv)) < tol)
    np.testing.assert_allclose(b, ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(b, b_true, atol=0.05)


def test_fit_road_plane_without_a_plane_is_none():
    """Every selected pixel in one column: the normal equations are singular, no plane (and no roll)."""
    H, W = 120, 90
    disp = np.zeros((H, W), np.float32)
    disp[20:, 45] = 0.6 * np.arange(20, H) - 8.0
    calib = Calibration(f=100.0, cx=W / 2, cy=H / 2, baseline=0.5)
    params = profile.ProfileParams(roll_subsample=1, roll_iterations=2)
    # enough pixels (>= 50): the plane is refused for being singular, not for want of pixels
    n, _ = plane_sums_np(
        disp,
        1,
        20,
        params.min_fit_disparity_px,
        -8.0,
        0.0,
        0.6,
        params.roll_tolerance_px,
        0.1,
        1.6,
        0.5,
        44.5,
        59.5,
    )
    assert n >= 50
    _, h1 = geometry.pose_from_line(-8.0, 0.6, calib)
    assert profile._fit_road_plane(disp, np.array([-8.0, 0.6]), h1, 20, params) is None


def test_ransac_sample_pairs_are_cached_read_only_draws():
    i, j = profile._sample_pairs(37, 50, 0)
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(i, rng.integers(0, 37, 50))
    np.testing.assert_array_equal(j, rng.integers(0, 37, 50))
    assert profile._sample_pairs(37, 50, 0)[0] is i  # the same arrays again
    assert not i.flags.writeable and not j.flags.writeable


@pytest.mark.parametrize("shape", EDGE_SHAPES)
def test_mask_kernels_match_numpy(shape):
    rng = np.random.default_rng(5)
    disp = random_disparity(rng, shape)
    args = (-5.0, 0.4, 0.001, 3.0, 2.0, 0.02, 0.999, 1.6, 0.08, 0.5, 2.0)
    for step in (1, 2, 3):  # every step-th column read in place: the twin on the strided copy
        labels, first = mask._height_class_kernel(disp, step, *args)
        twin = height_class_np(np.ascontiguousarray(disp[:, ::step]), *args)
        np.testing.assert_array_equal(labels, twin)
        labelled = np.flatnonzero(twin.any(axis=1))
        assert first == (labelled[0] if labelled.size else shape[0])
    labels, _ = mask._height_class_kernel(disp, 1, *args)
    # beyond range everywhere: no labelled row
    far, first = mask._height_class_kernel(disp, 2, *args[:-1], 1e9)
    assert not far.any() and first == shape[0]
    for min_run in (1, 2, 4):
        for unknown in (False, True):
            np.testing.assert_array_equal(
                mask._free_space_kernel(labels, min_run, unknown), free_space_np(labels, min_run, unknown)
            )


def test_free_space_takes_unknown_bottom_rows_below_the_first_road_pixel():
    """Columns scanned bottom-up (row 9 first). Pixels with no disparity (4) at the bottom of a
    column are road once a road pixel (1) follows them before an obstacle run ends the column; an
    obstacle run (2, 2) first leaves them out, as does ``unknown_is_road=False``. Before, a
    column's unknown bottom rows were never road (a smooth road's nearest rows lost with a strict
    SGBM uniqueness ratio)."""
    R, A, B, U = mask.ROAD, mask.ABOVE, mask.BELOW, mask.UNKNOWN
    cols = [
        [0, A, A, U, R, R, U, B, U, U],  # unknown bottom, a below-road pixel, then road
        [0, R, R, R, U, A, A, U, U, U],  # the obstacle run comes first: nothing is road
        [U, U, U, U, U, U, U, U, U, U],  # no road pixel at all
    ]
    labels = np.array(cols, np.uint8).T.copy()
    out = mask._free_space_kernel(labels, 2, True)
    np.testing.assert_array_equal(out[:, 0], [0, 0, 0, 1, 1, 1, 1, 0, 1, 1])
    assert not out[:, 1].any() and not out[:, 2].any()
    np.testing.assert_array_equal(
        mask._free_space_kernel(labels, 2, False)[:, 0], [0, 0, 0, 0, 1, 1, 0, 0, 0, 0]
    )
    np.testing.assert_array_equal(out, free_space_np(labels, 2, True))


@pytest.mark.parametrize("shape", EDGE_SHAPES + [(30, 41)])
@pytest.mark.parametrize("max_above", [0.0, 0.1, 0.5, 1.0])
def test_fill_holes_matches_numpy(shape, max_above):
    rng = np.random.default_rng(8)
    for density in (0.3, 0.6, 0.9):
        m = rng.random(shape) < density
        classes = rng.integers(0, 5, shape).astype(np.uint8)
        np.testing.assert_array_equal(
            mask._fill_holes(m, classes, max_above), fill_holes_np(m, classes, max_above)
        )
    m = np.ones(shape, bool)
    m[shape[0] // 2, shape[1] // 2] = False  # one hole off the border (when the shape allows)
    classes = np.ones(shape, np.uint8)
    np.testing.assert_array_equal(
        mask._fill_holes(m, classes, max_above), fill_holes_np(m, classes, max_above)
    )


def widen_np(red, step, width):
    """NumPy twin of ``widen_columns`` (OpenCV)."""
    k = np.arange(width) // step
    nxt = np.minimum(k + 1, red.shape[1] - 1)
    exact = (np.arange(width) % step == 0) | (k + 1 >= red.shape[1])
    return red[:, k] & (red[:, nxt] | exact[None, :])


@pytest.mark.parametrize("step", [1, 2, 3])
def test_widen_columns_matches_numpy(step):
    rng = np.random.default_rng(13)
    for width in (1, 2, 7, 10, 31):
        n = -(-width // step)
        for rows in (1, 5):
            red = rng.random((rows, n)) < 0.6
            np.testing.assert_array_equal(mask.widen_columns(red, step, width), widen_np(red, step, width))
            # into the rows of a given array (OpenCV interleaves straight into it when width = n step)
            out = np.ones((rows + 2, width), bool)
            got = mask.widen_columns(red, step, width, out[2:])
            assert np.shares_memory(got, out)
            np.testing.assert_array_equal(out[2:], widen_np(red, step, width))
            assert out[:2].all()


def test_keep_components_one_or_several():
    """One component kept (the comparison path) or several (the label lookup): the same rule."""
    m = np.zeros((40, 60), bool)
    m[25:40, 0:12] = True  # bottom band, left of the central half (cols 15-45)
    m[30:40, 35:55] = True  # bottom band, in the central half
    m[2:6, 28:32] = True  # a far speck
    left, right = np.zeros_like(m), np.zeros_like(m)
    left[25:40, 0:12] = True
    right[30:40, 35:55] = True
    np.testing.assert_array_equal(mask._keep_components(m, "bottom_centre", 0.15, 30.0), right)
    np.testing.assert_array_equal(mask._keep_components(m, "bottom", 0.15, 30.0), left | right)
    # without any component in the band: unchanged
    np.testing.assert_array_equal(mask._keep_components(m[:20], "bottom", 0.15, 30.0), m[:20])
    # many components kept (the lookup path): five blocks along the bottom band, a far speck
    many = np.zeros((40, 60), bool)
    for k in range(5):
        many[34:40, 12 * k : 12 * k + 8] = True
    kept = many.copy()
    many[2:6, 28:32] = True
    np.testing.assert_array_equal(mask._keep_components(many, "bottom", 0.15, 30.0), kept)


@pytest.mark.parametrize("shape", EDGE_SHAPES + [(30, 41), (12, 70)])
def test_components_kernel_matches_labelling(shape):
    """``_components_kernel`` (runs joined by union-find) against OpenCV's labelling of every pixel:
    random masks of every density (many small components, specks, thin diagonal links), seed
    columns partly or wholly outside the image, bands of one row to all of them."""
    rng = np.random.default_rng(21)
    for density in (0.05, 0.3, 0.5, 0.7, 0.95):
        for _ in range(4):
            m = rng.random(shape) < density
            classes = rng.integers(0, 5, shape).astype(np.uint8)
            for max_above in (0.0, 0.1, 0.5):
                np.testing.assert_array_equal(
                    mask._fill_holes(m, classes, max_above), fill_holes_np(m, classes, max_above)
                )
            for keep in ("bottom", "bottom_centre"):
                cx = rng.uniform(-0.5, 1.5) * shape[1]
                band, rows = rng.uniform(0.01, 1.0), shape[0] + int(rng.integers(0, 5))
                np.testing.assert_array_equal(
                    mask._keep_components(m, keep, band, cx, rows),
                    keep_components_np(m, keep, band, cx, rows),
                )
    # diagonal neighbours: one component (8-connected) to keep, two holes (4-connected) to fill
    diag = np.zeros((6, 6), bool)
    diag[np.arange(6), np.arange(6)] = True
    np.testing.assert_array_equal(mask._keep_components(diag, "bottom", 0.2, 3.0), diag)
    ring = np.ones((5, 6), bool)
    ring[1, 1] = ring[2, 2] = ring[3, 4] = False  # (1, 1) and (2, 2) touch only diagonally
    filled = mask._fill_holes(ring, np.zeros((5, 6), np.uint8), 0.0)
    assert filled.all()
    ring_above = np.zeros((5, 6), np.uint8)
    ring_above[3, 4] = mask.ABOVE  # a hole made of an above-road pixel stays
    np.testing.assert_array_equal(mask._fill_holes(ring, ring_above, 0.5), ring_above != mask.ABOVE)
    # classes of another dtype: compared as they are (258 is not ABOVE, as uint8 it would be)
    wide = ring_above.astype(np.int64)
    wide[3, 4] = 256 + mask.ABOVE
    assert mask._fill_holes(ring, wide, 0.5).all()
    np.testing.assert_array_equal(
        mask._fill_holes(ring, ring_above.astype(float), 0.5), ring_above != mask.ABOVE
    )


# --------------------------------------------------------------------------- geometry


def test_pose_line_round_trip_and_plane_disparity():
    for pitch, height in ((0.0, 1.65), (math.radians(-2.0), 1.2), (math.radians(4.0), 2.5)):
        a0, a1 = geometry.line_from_pose(pitch, height, CALIB)
        p2, h2 = geometry.pose_from_line(a0, a1, CALIB)
        assert p2 == pytest.approx(pitch, abs=1e-12) and h2 == pytest.approx(height, rel=1e-12)
    # the homography's road points, triangulated, have the road model's disparity
    a0, a1 = geometry.line_from_pose(PITCH, HEIGHT, CALIB)
    road = RoadModel(a0=a0, a1=a1, roll=ROLL, pitch=PITCH, height=HEIGHT)
    Hm = geometry.homography_img_from_road(CALIB, PITCH, ROLL, HEIGHT)
    x, z = np.meshgrid([-4.0, 0.0, 3.0], [6.0, 15.0, 40.0])
    q = Hm @ np.stack([x.ravel(), z.ravel(), np.ones(x.size)])
    u, v = q[0] / q[2], q[1] / q[2]
    P = geometry.camera_rotation(PITCH, ROLL) @ np.stack([x.ravel(), np.full(x.size, HEIGHT), z.ravel()])
    d_true = CALIB.f * CALIB.baseline / P[2]
    np.testing.assert_allclose(geometry.road_disparity(road, CALIB, u, v), d_true, rtol=1e-9)
    np.testing.assert_allclose(geometry.height_above_road(road, CALIB, u, v, d_true), 0.0, atol=1e-9)


# --------------------------------------------------------------------------- synthetic scenes


def render_scene(calib=CALIB, pitch=PITCH, roll=ROLL, height=HEIGHT, box=None, kerb=None, marks=()):
    """Ray-cast a planar road (plus a box and a kerb) seen by a camera at ``height`` with the given
    pitch (nose down) and roll (clockwise as seen by the camera).

    Returns (disparity, labels, image): labels 0 nothing, 1 road, 2 kerb top, 3 kerb face, 4 box;
    the image is 200 on the ``marks`` (lateral positions, 0.2 m wide) and 80 elsewhere on the road.
    ``box = (x0, x1, z0, z1, box_height)``; ``kerb = (x_edge, step)``: the ground is ``step`` higher
    for ``x > x_edge``.
    """
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    rx = np.array([[1, 0, 0], [0, cp, sp], [0, -sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    R_cw = rx @ rz  # camera-to-world
    v, u = np.mgrid[0 : calib.height, 0 : calib.width].astype(np.float64)
    ray = np.stack([(u - calib.cx) / calib.f, (v - calib.cy) / calib.f_y, np.ones_like(u)])
    rw = np.tensordot(R_cw, ray, axes=1)  # world direction per unit camera depth
    best = np.full(u.shape, np.inf)
    label = np.zeros(u.shape, np.uint8)
    X_hit = np.zeros(u.shape)

    def consider(t, ok, lab):
        ok = ok & (t > 0) & (t < best)
        best[ok] = t[ok]
        label[ok] = lab
        X_hit[ok] = (t * rw[0])[ok]

    with np.errstate(divide="ignore", invalid="ignore"):
        t = height / rw[1]
        ok = rw[1] > 0
        if kerb is not None:
            ok &= t * rw[0] <= kerb[0]
        consider(t, ok, 1)
        if kerb is not None:
            xe, step = kerb
            t = (height - step) / rw[1]
            consider(t, (rw[1] > 0) & (t * rw[0] > xe), 2)
            t = xe / rw[0]
            y = t * rw[1]
            consider(t, (rw[0] > 0) & (y >= height - step) & (y <= height), 3)
        if box is not None:
            x0, x1, z0, z1, bh = box
            for t, coord, lo, hi in (
                (z0 / rw[2], 0, x0, x1),  # front face z = z0, x in [x0, x1]
                (x0 / rw[0], 2, z0, z1),  # left face x = x0
                (x1 / rw[0], 2, z0, z1),  # right face x = x1
            ):
                p = t * rw[coord]
                y = t * rw[1]
                consider(t, (p >= lo) & (p <= hi) & (y >= height - bh) & (y <= height), 4)
    hit = np.isfinite(best) & (best < 1e4)
    disp = np.where(hit, calib.f * calib.baseline / np.where(hit, best, 1.0), 0.0).astype(np.float32)
    label[~hit] = 0
    img = np.where(label > 0, 80, 0).astype(np.uint8)
    for x in marks:
        img[(label == 1) & (np.abs(X_hit - x) < 0.1)] = 200
    return disp, label, img


def noisy(disp, seed=0, sigma=0.05, invalid=0.02):
    rng = np.random.default_rng(seed)
    d = disp + rng.normal(0, sigma, disp.shape).astype(np.float32)
    d[(disp <= 0) | (rng.random(disp.shape) < invalid)] = 0.0
    return d.astype(np.float32)


@pytest.fixture(scope="module")
def scene():
    return render_scene(box=(-1.0, 0.6, 14.0, 16.0, 2.0), kerb=(3.5, 0.12))


def test_profile_recovers_pitch_roll_height(scene):
    disp, _, _ = scene
    out = rd.road_profile(rd.ProfileParams(), disparity=noisy(disp), calib=CALIB)
    road = out["road"]
    assert road.valid
    assert math.degrees(abs(road.pitch - PITCH)) < 0.2
    assert math.degrees(abs(road.roll - ROLL)) < 0.2
    assert abs(road.height - HEIGHT) < 0.02
    assert out["vdisparity"].shape == (CALIB.height, 128)
    assert road.profile.shape == (CALIB.height,)


@pytest.mark.parametrize("pitch_deg, roll_deg, height", [(-1.0, -1.5, 1.3), (2.5, 0.0, 2.0)])
def test_profile_other_poses_and_quadratic(pitch_deg, roll_deg, height):
    disp, _, _ = render_scene(pitch=math.radians(pitch_deg), roll=math.radians(roll_deg), height=height)
    for model in ("linear", "quadratic"):
        road = rd.road_profile(rd.ProfileParams(model=model), disparity=noisy(disp, 1), calib=CALIB)["road"]
        assert road.valid
        assert math.degrees(road.pitch) == pytest.approx(pitch_deg, abs=0.2)
        assert math.degrees(road.roll) == pytest.approx(roll_deg, abs=0.2)
        assert road.height == pytest.approx(height, abs=0.02)
        if model == "quadratic":
            assert abs(road.a2) < 1e-3  # a flat road has no curvature


def test_profile_without_roll_estimation_is_biased_by_roll(scene):
    disp, _, _ = scene
    road = rd.road_profile(rd.ProfileParams(estimate_roll=False), disparity=noisy(disp), calib=CALIB)["road"]
    assert road.roll == 0.0 and road.valid


@pytest.mark.parametrize("shape", [(40, 50), (1, 50), (30, 1)])
def test_profile_all_invalid_disparity(shape):
    disp = np.zeros(shape, np.float32)
    out = rd.road_profile(rd.ProfileParams(), disparity=disp, calib=CALIB)
    assert out["road"].valid is False
    m = rd.road_mask(rd.MaskParams(), disparity=disp, road=out["road"], calib=CALIB)["mask"]
    assert m.shape == shape and m.all()
    m = rd.road_mask(rd.MaskParams(invalid_road="none"), disparity=disp, road=out["road"], calib=CALIB)[
        "mask"
    ]
    assert not m.any()


def test_profile_rejects_a_mismatched_vdisparity(scene):
    with pytest.raises(ValueError, match="vdisparity: expected shape"):
        rd.road_profile(rd.ProfileParams(), disparity=scene[0], calib=CALIB, vdisparity=np.zeros((3, 3)))


def test_profile_accepts_the_vdisparity_node_output(scene):
    disp = noisy(scene[0])
    vd = rd.road_vdisparity(rd.VDisparityParams(), disparity=disp)["vdisparity"]
    # every column: the node's v-disparity is the profile's own first one
    p1 = rd.ProfileParams(column_step=1, first_pass_column_step=1)
    a = rd.road_profile(p1, disparity=disp, calib=CALIB, vdisparity=vd)["road"]
    b = rd.road_profile(p1, disparity=disp, calib=CALIB)["road"]
    assert (a.pitch, a.roll, a.height) == (b.pitch, b.roll, b.height)
    # every 2nd column (the default): the full-resolution v-disparity is scaled, the pose agrees
    a = rd.road_profile(rd.ProfileParams(), disparity=disp, calib=CALIB, vdisparity=vd)["road"]
    assert (
        a.valid
        and abs(a.pitch - b.pitch) < 1e-3
        and abs(a.roll - b.roll) < 1e-3
        and abs(a.height - b.height) < 0.01
    )


def test_mask_removes_box_and_kerb_keeps_road(scene):
    disp, label, _ = scene
    d = noisy(disp)
    road = rd.road_profile(rd.ProfileParams(), disparity=d, calib=CALIB)["road"]
    m = rd.road_mask(rd.MaskParams(), disparity=d, road=road, calib=CALIB)["mask"]
    near = disp > CALIB.f * CALIB.baseline / 40.0  # within 40 m
    box, kerb_top, road_px = label == 4, (label == 2) & near, (label == 1) & near
    assert box.sum() > 500 and kerb_top.sum() > 500
    assert m[box].mean() <= 0.05, "the box standing on the road must be removed"
    assert m[kerb_top].mean() <= 0.05, "a 12 cm kerb must be rejected"
    assert m[road_px].mean() >= 0.95, "the road must be kept"
    # the raw height test alone (no morphology / free space) rejects the kerb too, as far as the
    # stereo resolves it: 12 cm is 0.75 px of disparity at 25 m with f = 500 px (tolerance 0.5 px)
    resolvable = disp > CALIB.f * CALIB.baseline / 25.0
    kerb_top &= resolvable
    road_px &= resolvable
    raw = rd.road_mask(
        rd.MaskParams(free_space=False, open_px=0, close_px=0, keep="all", fill_holes_max_above=0),
        disparity=d,
        road=road,
        calib=CALIB,
    )["mask"]
    assert raw[kerb_top].mean() <= 0.05 and raw[road_px].mean() >= 0.95


def test_mask_column_step_matches_every_column(scene):
    """Every 2nd column (the default) against every column: the same mask but at object edges, and
    the height classes of the computed columns are those of every column there."""
    disp, label, _ = scene
    d = noisy(disp)
    road = rd.road_profile(rd.ProfileParams(), disparity=d, calib=CALIB)["road"]
    full = rd.road_mask(rd.MaskParams(column_step=1), disparity=d, road=road, calib=CALIB)["mask"]
    half = rd.road_mask(rd.MaskParams(column_step=2), disparity=d, road=road, calib=CALIB)["mask"]
    assert half.shape == full.shape and full.any()
    assert np.mean(half == full) >= 0.99
    raw = dict(free_space=False, open_px=0, close_px=0, keep="all", fill_holes_max_above=0)
    a = rd.road_mask(rd.MaskParams(column_step=1, **raw), disparity=d, road=road, calib=CALIB)["mask"]
    b = rd.road_mask(rd.MaskParams(column_step=2, **raw), disparity=d, road=road, calib=CALIB)["mask"]
    assert np.mean(a[:, ::2] == b[:, ::2]) >= 0.9999  # rounding of the roll-corrected row at most
    np.testing.assert_array_equal(b[:, 1:-1:2], b[:, 0:-2:2] & b[:, 2::2])


def test_mask_height_tolerance_is_metric():
    # a kerb of 5 cm passes a 8 cm tolerance, a 12 cm one does not
    for step, rejected in ((0.05, False), (0.12, True)):
        disp, label, _ = render_scene(kerb=(2.0, step))
        road = RoadModel(
            *geometry.line_from_pose(PITCH, HEIGHT, CALIB), roll=ROLL, pitch=PITCH, height=HEIGHT
        )
        p = rd.MaskParams(free_space=False, open_px=0, close_px=0, keep="all", fill_holes_max_above=0)
        m = rd.road_mask(p, disparity=disp, road=road, calib=CALIB)["mask"]
        top = (label == 2) & (disp > CALIB.f * CALIB.baseline / 25.0)
        assert (m[top].mean() < 0.05) == rejected


# --------------------------------------------------------------------------- IPM


IPM_PARAMS = dict(x_min=-4.0, x_max=4.0, z_min=6.0, z_max=30.0, resolution=0.05)


def _line_columns(bev, mask):
    """Per BEV row: the centroid column of the bright pixels in the left and the right half."""
    cols = np.arange(bev.shape[1])
    out = []
    for half in (cols < bev.shape[1] // 2, cols >= bev.shape[1] // 2):
        w = ((bev > 140) & mask)[:, half].astype(float)
        n = w.sum(1)
        out.append(np.where(n > 0, (w * cols[half]).sum(1) / np.maximum(n, 1), np.nan))
    return out


@pytest.mark.parametrize("interp", ["linear", "nearest"])
def test_ipm_maps_lane_lines_to_vertical_columns(interp):
    _, _, img = render_scene(marks=(-1.8, 1.8))
    road = RoadModel(*geometry.line_from_pose(PITCH, HEIGHT, CALIB), roll=ROLL, pitch=PITCH, height=HEIGHT)
    out = rd.bev_ipm(rd.IpmParams(**IPM_PARAMS, interpolation=interp), image=img, road=road, calib=CALIB)
    geom: BevGeometry = out["geometry"]
    assert out["image"].shape == (geom.rows, geom.cols) == (480, 160)
    left, right = _line_columns(out["image"], out["mask"])
    exp_l, exp_r = geom.metric_to_bev(np.array([-1.8, 1.8]), np.array([10.0, 10.0]))[0]
    assert np.isfinite(left).mean() > 0.95 and np.isfinite(right).mean() > 0.95
    err = np.abs(np.concatenate([left - exp_l, right - exp_r]))
    assert np.nanmax(err) <= 1.0 + 1e-9 and np.nanmean(err) < 0.3  # within a BEV pixel (5 cm) everywhere


def test_ipm_with_estimated_pose(scene):
    disp, _, _ = render_scene()
    _, _, img = render_scene(marks=(-1.8, 1.8))
    road = rd.road_profile(rd.ProfileParams(), disparity=noisy(disp, 3), calib=CALIB)["road"]
    out = rd.bev_ipm(rd.IpmParams(**IPM_PARAMS), image=img, road=road, calib=CALIB)
    left, right = _line_columns(out["image"], out["mask"])
    exp_l, exp_r = out["geometry"].metric_to_bev(np.array([-1.8, 1.8]), np.array([10.0, 10.0]))[0]
    assert np.nanmax(np.abs(left - exp_l)) < 2.0 and np.nanmax(np.abs(right - exp_r)) < 2.0


def test_ipm_mask_geometry_and_fallback():
    img = np.full((CALIB.height, CALIB.width, 3), 120, np.uint8)
    road = RoadModel(*geometry.line_from_pose(PITCH, HEIGHT, CALIB), roll=ROLL, pitch=PITCH, height=HEIGHT)
    p = rd.IpmParams(x_min=-20.0, x_max=20.0, z_min=2.0, z_max=60.0, resolution=0.1)
    out = rd.bev_ipm(p, image=img, road=road, calib=CALIB)
    bev, m, geom = out["image"], out["mask"], out["geometry"]
    assert bev.ndim == 2 and bev.dtype == np.uint8 and m.dtype == bool
    assert 0.05 < m.mean() < 0.95  # wide grid: part of it is outside the image
    assert np.all(bev[m] == 120) and np.all(bev[~m] == 0)
    # the mask says exactly which BEV pixels map inside the image
    r, c = np.nonzero(np.ones_like(m))
    xy = geom.bev_to_image(c, r)
    inside = (
        (xy[:, 0] >= 0) & (xy[:, 0] <= CALIB.width - 1) & (xy[:, 1] >= 0) & (xy[:, 1] <= CALIB.height - 1)
    ).reshape(m.shape)
    # nearest-pixel convention of the warp: the two may differ only within half a pixel of the border
    near_border = (
        (xy[:, 0] > -0.5)
        & (xy[:, 0] < CALIB.width - 0.5)
        & (xy[:, 1] > -0.5)
        & (xy[:, 1] < CALIB.height - 0.5)
    ).reshape(m.shape) & ~inside
    assert not (inside & ~m).any()
    assert not (m & ~inside & ~near_border).any()
    # an image mask is carried over
    half = np.zeros(img.shape[:2], bool)
    half[:, : CALIB.width // 2] = True
    m2 = rd.bev_ipm(p, image=img, road=road, calib=CALIB, mask=half)["mask"]
    assert m2.sum() < m.sum() and not (m2 & ~m).any()
    # invalid road: the fallback pose is used
    bad = RoadModel(a0=0.0, a1=0.0, valid=False)
    fb = rd.bev_ipm(
        rd.IpmParams(fallback_pitch_deg=1.5, fallback_height_m=1.6), image=img, road=bad, calib=CALIB
    )
    exp = ipm.bev_geometry(rd.IpmParams(), CALIB, math.radians(1.5), 0.0, 1.6).H_img_from_bev
    np.testing.assert_allclose(fb["geometry"].H_img_from_bev, exp)
    assert fb["mask"].any()


def test_ipm_params_are_validated():
    with pytest.raises(ValueError, match="x_max"):
        rd.IpmParams(x_min=5.0, x_max=1.0)
    with pytest.raises(ValueError):
        rd.ProfileParams(model="cubic")
    with pytest.raises(ValueError):
        rd.MaskParams(bogus=1)


# --------------------------------------------------------------------------- registration


def test_node_types_are_registered_with_documented_params():
    from lanegraph.plugins import PluginManager

    pm = PluginManager()
    pm.register(rd, name="lanegraph_road")
    types = pm.node_types
    for name in ("road.vdisparity", "road.profile", "road.mask", "bev.ipm"):
        nt = types[name]
        assert nt.summary
        for field_name, f in nt.params.model_fields.items():
            assert f.description, f"{name}: params.{field_name} has no description"
    assert types["road.profile"].inputs["calib"].rate == "constant"
    assert types["road.profile"].inputs["vdisparity"].optional
    assert types["bev.ipm"].inputs["mask"].optional
    assert set(types["bev.ipm"].outputs) == {"image", "mask", "geometry"}
    assert types["road.mask"].outputs["mask"].type == "mask"


# --------------------------------------------------------------------------- real data


def _sgbm(left, right):
    from lanegraph.plugins import get_plugin_manager

    nt = get_plugin_manager().get_node_type("disparity.sgbm")
    if nt is not None and not nt.stateful:
        try:
            return np.asarray(next(iter(nt.func(nt.params(), left=left, right=right).values())), np.float32)
        except Exception:  # the disparity plugin's interface may differ; OpenCV directly then
            pass
    gl, gr = (cv2.cvtColor(x, cv2.COLOR_BGR2GRAY) for x in (left, right))
    sgbm = cv2.StereoSGBM_create(
        0,
        128,
        5,
        P1=8 * 25,
        P2=32 * 25,
        disp12MaxDiff=1,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    return sgbm.compute(gl, gr).astype(np.float32) / 16.0


@pytest.mark.kitti
def test_kitti_frame0_height_and_pitch(kitti_drive, kitti_calib):
    left = cv2.imread(str(kitti_drive / "image_02" / "data" / "0000000000.png"), cv2.IMREAD_COLOR)
    right = cv2.imread(str(kitti_drive / "image_03" / "data" / "0000000000.png"), cv2.IMREAD_COLOR)
    disp = _sgbm(left, right)
    road = rd.road_profile(rd.ProfileParams(), disparity=disp, calib=kitti_calib)["road"]
    assert road.valid
    assert 1.45 <= road.height <= 1.85
    assert abs(math.degrees(road.pitch)) < 3.0
    m = rd.road_mask(rd.MaskParams(), disparity=disp, road=road, calib=kitti_calib)["mask"]
    # the road ahead of the car is road; the sky, the parked cars' bodies and the tram bed are not
    assert m[330:375, 450:700].mean() > 0.95
    assert not m[:150].any()
    assert m[300:375, 950:1242].mean() < 0.05
    bev = rd.bev_ipm(rd.IpmParams(), image=left, mask=m, road=road, calib=kitti_calib)
    assert bev["image"].shape == (800, 400) and bev["mask"].any()
