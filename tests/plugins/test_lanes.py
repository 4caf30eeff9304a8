"""Lane plugin: kernels against NumPy twins, synthetic stripes with known answers, robust fits."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from lanegraph_lanes import _features, _hough, _verify
from lanegraph_lanes._features import (  # noqa: F401
    EsltParams,
    MaskParams,
    SltParams,
    edge_orientation,
    eslt,
    mask_features,
    slt,
)
from lanegraph_lanes._fit import IrlsParams, fit_irls, fit_ransac, irls_fit, ransac_fit
from lanegraph_lanes._hough import Hough2dParams, HoughParams, OrientationParams, line1d, line2d, orientation
from lanegraph_lanes._temporal import TemporalParams, ToImageParams, image_points, temporal_mask, to_image
from lanegraph_lanes._verify import VerifyParams, verify

from lanegraph import InputError, node_type_of
from lanegraph.testing import check_node_type, make_bev_image
from lanegraph.types import BevGeometry, FeatureMap, Lane, Line


# ----------------------------------------------------------------------------- NumPy twins
def slt_twin(img, w, T):
    # by the mean, as the paper states it; the kernel compares v n > sum (no division), the same
    # decision on integer images (the twin tests' inputs), see _boundary_rows for float ones
    rows, cols = img.shape
    out = np.zeros((rows, cols), np.uint8)
    for r in range(rows):
        for c in range(cols):
            left = img[r, max(c - w, 0) : c]
            right = img[r, c + 1 : c + 1 + w]
            if left.size and right.size and img[r, c] - T > left.mean() and img[r, c] - T > right.mean():
                out[r, c] = 1
    return out


def eslt_twin(img, gx, gy, w, T, max_angle):
    mag = np.hypot(gx, gy)
    theta = np.mod(np.arctan2(gx, gy), np.pi)
    rows, cols = img.shape
    mask = np.zeros((rows, cols), np.uint8)
    ori = np.full((rows, cols), -1.0, np.float32)
    base = slt_twin(img, w, T)
    for r, c in zip(*np.nonzero(base)):
        lo, hi = max(c - w, 0), min(c + 1 + w, cols)
        bl = lo + int(np.argmax(mag[r, lo:c]))
        br = c + 1 + int(np.argmax(mag[r, c + 1 : hi]))
        if mag[r, bl] <= 0 or mag[r, br] <= 0:
            continue
        a, b = float(theta[r, bl]), float(theta[r, br])
        d = abs(a - b)
        d = min(d, math.pi - d)
        if d >= max_angle:
            continue
        m = 0.5 * math.atan2(math.sin(2 * a) + math.sin(2 * b), math.cos(2 * a) + math.cos(2 * b)) % math.pi
        mask[r, c] = 1
        ori[r, c] = m
    return mask, ori


def vote_twin(r, c, H, inv_tan, offset, n):
    acc = np.zeros(n)
    b = np.floor(c - (H - r) * inv_tan + 0.5).astype(int) + offset
    ok = (b >= 0) & (b < n)
    np.add.at(acc, b[ok], 1.0)
    return acc


@pytest.mark.parametrize(
    "shape, w, T", [((7, 23), 3, 5.0), ((5, 9), 20, 0.0), ((1, 1), 2, 1.0), ((4, 2), 1, 0.0)]
)
def test_slt_kernel_matches_twin(shape, w, T):
    rng = np.random.default_rng(1)
    img = rng.integers(0, 255, shape).astype(np.float32)
    out = np.zeros(shape, np.uint8)
    _features._slt(img, w, T, _features._EVERYWHERE, out)
    np.testing.assert_array_equal(out, slt_twin(img, w, T))


def test_atan2_fast_matches_numpy():
    rng = np.random.default_rng(4)
    y = np.concatenate(
        [rng.normal(0, 1, 3000), rng.normal(0, 1e6, 1000), [0.0, 0.0, 1.0, -1.0, 0.0, 5.0, -5.0]]
    )
    x = np.concatenate(
        [rng.normal(0, 1, 3000), rng.normal(0, 1e6, 1000), [0.0, 1.0, 0.0, 0.0, -1.0, 5.0, -5.0]]
    )
    got = np.array([_features.atan2_fast(float(a), float(b)) for a, b in zip(y, x)])
    assert np.abs(got - np.arctan2(y, x)).max() < 5e-8


def eslt_maps(img, gx, gy, w, threshold, max_angle, where=None):
    """ESLT's kernel (:func:`_features._eslt`) as the twin's dense maps: the 0/1 mask and the
    orientation map (-1 where no feature) made from the features' list, with the list."""
    where = _features._EVERYWHERE if where is None else where
    r, c, v = _features._eslt(img, gx, gy, w, threshold, max_angle, where)
    mask = np.zeros(img.shape, np.uint8)
    ori = np.full(img.shape, -1.0, np.float32)
    mask[r, c] = 1
    ori[r, c] = v
    return mask, ori, (r, c, v)


@pytest.mark.parametrize("w", [2, 4, 30])
def test_eslt_kernel_matches_twin(w):
    img = make_bev_image(rows=24, cols=40, lane_cols=(12.0, 30.0), slope=0.3, noise=10.0, seed=3).astype(
        np.float32
    )
    gx, gy = _features.sobel(img)
    mask, ori, (r, c, v) = eslt_maps(img, gx, gy, w, 8.0, math.radians(15))
    tm, to = eslt_twin(img, gx, gy, w, 8.0, math.radians(15))
    np.testing.assert_array_equal(mask, tm)
    np.testing.assert_allclose(ori, to, atol=1e-5)
    # the features' list: the twin's points in row-major order, the dense map's orientations
    assert r.dtype == c.dtype == np.int64 and v.dtype == np.float32
    np.testing.assert_array_equal(np.stack([r, c]), np.stack(np.nonzero(tm)))
    np.testing.assert_array_equal(v, ori[tm == 1])


@pytest.mark.parametrize("w", [2, 4, 30])
def test_eslt_kernel_on_uint8_and_int16_gradients_matches_twin(w):
    """The node's uint8 path: uint8 grey levels and cv2.spatialGradient's int16 gradients."""
    img = make_bev_image(rows=24, cols=40, lane_cols=(12.0, 30.0), slope=0.3, noise=10.0, seed=4)
    gx, gy = cv2.spatialGradient(np.ascontiguousarray(img, dtype=np.uint8), ksize=3)
    mask, ori, (r, c, v) = eslt_maps(img.astype(np.uint8), gx, gy, w, 8.0, math.radians(15))
    f32 = img.astype(np.float32)
    tm, to = eslt_twin(f32, gx.astype(np.float32), gy.astype(np.float32), w, 8.0, math.radians(15))
    np.testing.assert_array_equal(mask, tm)
    np.testing.assert_allclose(ori, to, atol=1e-5)
    # the features' list: the twin's points in row-major order
    np.testing.assert_array_equal(np.stack([r, c]), np.stack(np.nonzero(tm)))
    np.testing.assert_array_equal(v, ori[tm == 1])


@pytest.mark.parametrize("shape", [(2, 2), (3, 5), (2, 9), (24, 40), (1, 7), (7, 1)])
def test_eslt_node_uint8_path_equals_float_path(shape):
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, shape).astype(np.uint8)
    img[:, shape[1] // 2 :: 5] = 255  # some stripes
    p = EsltParams(window=3, threshold=5.0)
    a = eslt(p, image=img)["features"]
    b = eslt(p, image=img.astype(np.float32))["features"]  # cv2.Sobel on float32
    np.testing.assert_array_equal(a.mask, b.mask)
    # the same integer gradients; the kernels compiled for int16 and float32 may round the last bit
    np.testing.assert_allclose(a.orientation, b.orientation, rtol=0, atol=1e-6)


@pytest.mark.parametrize("ksize", [2, 4, 6])
def test_eslt_even_sobel_aperture_is_refused_where_it_is_set(tmp_path, ksize):
    # an even aperture was once replaced by 3 without a word; now the graph does not load, and the
    # error names the file, the node and the param
    from lanegraph.errors import GraphError
    from lanegraph.graph.validation import load_graph

    g = tmp_path / "g.yaml"
    g.write_text(f"nodes:\n  feat: {{type: features.eslt, params: {{sobel_ksize: {ksize}}}}}\n")
    with pytest.raises(GraphError) as info:
        load_graph(g)
    msg = str(info.value)
    assert "g.yaml" in msg and "feat" in msg and "sobel_ksize" in msg and "odd" in msg, msg
    for k in (1, 3, 5, 7):
        assert EsltParams(sobel_ksize=k).sobel_ksize == k


def _boundary_rows(count=3):
    """Rows ``[window, 255, zeros]`` of float32 pixels, with a threshold T that puts the bright
    pixel on SLT's boundary with its left window: ``v > sum / n`` and ``v n > sum`` (v = 255 - T)
    round different ways. ``count`` rows where the product passes and ``count`` where it fails."""
    rng = np.random.default_rng(3)
    found = {True: [], False: []}
    for _ in range(100_000):
        n = int(rng.choice([3, 5, 6, 7]))
        left = (rng.random(n) * 255).astype(np.float32)
        s = float(np.cumsum(left.astype(np.float64))[-1])
        T = 255.0 - s / n
        v = 255.0 - T
        passes = v * n > s
        if (v > s / n) != passes and len(found[passes]) < count:
            found[passes].append(
                (np.concatenate([left, [255], np.zeros(n)]).astype(np.float32), n, T, passes)
            )
        if all(len(f) == count for f in found.values()):
            break
    return found[True] + found[False]


def test_slt_and_eslt_make_one_threshold_test_on_a_float_boundary():
    # ESLT's features must be a subset of SLT's (the ablation compares them). SLT once tested
    # v > sum / n and ESLT v n > sum: on these rows one passed and the other did not
    rows = _boundary_rows()
    assert len(rows) == 6, "the search must find rows on both sides of the boundary"
    for row, n, T, passes in rows:
        img = np.tile(row, (3, 1))  # a vertical stripe: the borders' gradients are parallel
        s = np.zeros(img.shape, np.uint8)
        _features._slt(img, n, T, _features._EVERYWHERE, s)
        gx, gy = _features.sobel(img, 3)
        m, _, _ = eslt_maps(img, gx, gy, n, T, math.radians(90))
        assert s[1, n] == m[1, n] == passes, (row.tolist(), n, T)
        assert not (m.astype(bool) & ~s.astype(bool)).any()


def _random_where(shape, seed):
    """A road-like BEV mask (a blob with holes and ragged rows) and some empty rows."""
    rng = np.random.default_rng(seed)
    where = np.zeros(shape, np.uint8)
    for r in range(shape[0]):
        if rng.random() < 0.15:
            continue  # an empty row
        a = int(rng.integers(0, shape[1]))
        b = int(rng.integers(a, shape[1] + 1))
        where[r, a:b] = 1
    where[rng.random(shape) < 0.1] = 0
    return where


@pytest.mark.parametrize("w", [1, 3, 30])
def test_slt_eslt_kernels_with_where_match_masked_twins(w):
    """Tested only where ``where`` is set: the twins' features AND the map, at every image border."""
    img = make_bev_image(rows=30, cols=41, lane_cols=(10.0, 31.0), slope=0.3, noise=12.0, seed=6).astype(
        np.float32
    )
    gx, gy = _features.sobel(img)
    for seed in range(3):
        where = _random_where(img.shape, seed)
        where[0, :] = 1  # a whole row: both borders
        out = np.full(img.shape, 7, np.uint8)
        _features._slt(img, w, 5.0, where, out)
        np.testing.assert_array_equal(out, slt_twin(img, w, 5.0) * where)
        mask, ori, _ = eslt_maps(img, gx, gy, w, 5.0, math.radians(15), where)
        tm, to = eslt_twin(img, gx, gy, w, 5.0, math.radians(15))
        assert tm.any() and (tm & ~where.astype(bool)).any()  # some features are masked away
        np.testing.assert_array_equal(mask, tm * where)
        np.testing.assert_allclose(ori, np.where(where > 0, to, -1.0), atol=1e-5)
    empty = np.zeros(img.shape, np.uint8)  # nothing to test: no features, every row skipped
    mask, ori, (r, _, _) = eslt_maps(img, gx, gy, w, 5.0, math.radians(15), empty)
    assert not mask.any() and (ori == -1.0).all() and r.size == 0


@pytest.mark.parametrize("node", [slt, eslt])
def test_feature_nodes_where_input(node):
    """The node's ``where`` input gives the features of the unmasked node on the mask, and a
    mask of the wrong shape is refused with the port named."""
    img = make_bev_image(rows=60, cols=80, lane_cols=(20.0, 60.0), slope=0.2, noise=8.0, seed=7).astype(
        np.uint8
    )
    where = _random_where(img.shape, 9).astype(bool)
    p = node_type_of(node).params(window=4, threshold=6.0)
    full = node(p, image=img)["features"]
    part = node(p, image=img, where=where)["features"]
    assert full.mask.any() and (full.mask & ~where).any()
    np.testing.assert_array_equal(part.mask, full.mask & where)
    if full.orientation is not None:
        np.testing.assert_array_equal(part.orientation, np.where(where, full.orientation, np.float32(-1.0)))
    with pytest.raises(InputError, match=r"where: expected a BEV mask of the image's shape \(60, 80\)"):
        node(p, image=img, where=where[:, :10])


def test_vote_kernels_match_twin():
    rng = np.random.default_rng(2)
    r = rng.integers(0, 50, 300)
    c = rng.integers(-10, 80, 300)
    # float coordinates, and int32 pixel coordinates as the nodes pass them
    for dtype in (np.float64, np.int32):
        r, c = r.astype(dtype), c.astype(dtype)
        for inv_tan in (0.0, 0.3, -0.7):
            acc = np.zeros(200)
            _hough._vote_1d(r, c, 50.0, inv_tan, 60, acc)
            np.testing.assert_array_equal(acc, vote_twin(r, c, 50.0, inv_tan, 60, 200))
        inv = np.array([0.0, 0.2, -0.2])
        acc2 = np.zeros((3, 200))
        _hough._vote_2d(r, c, 50.0, inv, 60, acc2)
        for t in range(3):
            np.testing.assert_array_equal(acc2[t], vote_twin(r, c, 50.0, inv[t], 60, 200))
    empty = np.zeros(10)
    _hough._vote_1d(np.zeros(0), np.zeros(0), 5.0, 0.0, 0, empty)
    assert empty.sum() == 0


# ----------------------------------------------------------------------------- features
def test_slt_and_eslt_find_stripes_with_orientation():
    bev = make_bev_image(rows=120, cols=100, lane_cols=(30.0, 70.0), width_px=3, slope=0.25, noise=3)
    f = slt(SltParams(), image=bev)["features"]
    assert f.orientation is None
    cols = np.nonzero(f.mask[-1])[0]
    assert set(cols) <= {29, 30, 31, 69, 70, 71} and len(cols) >= 2
    e = eslt(EsltParams(), image=bev)["features"]
    ori = e.orientation[e.mask]
    assert e.mask.sum() > 100
    assert np.median(ori) == pytest.approx(math.atan2(1.0, 0.25), abs=math.radians(3))
    assert (e.orientation[~e.mask] == -1).all()


def test_eslt_rejects_a_single_edge():
    img = np.full((20, 40), 80, np.uint8)
    img[:, 20:] = 200  # a step: bright on one side only
    e = eslt(EsltParams(), image=img)["features"]
    assert e.mask.sum() == 0


def test_mask_features_erodes_and_combines():
    fm = FeatureMap(mask=np.ones((20, 20), bool), orientation=np.full((20, 20), 1.5, np.float32))
    road = np.zeros((20, 20), bool)
    road[:, 5:15] = True
    tmp = np.ones((20, 20), bool)
    tmp[:10] = False
    out = mask_features(MaskParams(erode_px=2), features=fm, mask=road, temporal=tmp)["features"]
    assert out.mask[15, 7:13].all() and not out.mask[15, 5:7].any() and not out.mask[5].any()
    assert (out.orientation[~out.mask] == -1).all()


# ----------------------------------------------------------------------------- orientation and Hough
def geometry(rows=200, cols=160, res=0.05):
    return BevGeometry(-cols * res / 2, cols * res / 2, 5.0, 5.0 + rows * res, res, np.eye(3))


def features_for(lane_cols, rows=200, cols=160, slope=0.0):
    bev = make_bev_image(rows=rows, cols=cols, lane_cols=lane_cols, slope=slope, noise=2)
    return eslt(EsltParams(), image=bev)["features"]


def test_orientation_histogram_and_default():
    f = features_for((50.0, 110.0), slope=0.2)
    th = orientation(OrientationParams(), features=f)["orientation"]
    assert th == pytest.approx(math.atan2(1, 0.2), abs=math.radians(1.5))
    assert orientation(OrientationParams(default_deg=80), features=FeatureMap(f.mask))[
        "orientation"
    ] == pytest.approx(math.radians(80))


def test_line1d_finds_rho_and_sides():
    f = features_for((50.0, 110.0), slope=0.2)
    th = math.atan2(1, 0.2)
    lines = line1d(HoughParams(min_votes=20), features=f, orientation=th, geometry=geometry())["lines"]
    assert [ln.side for ln in lines] == ["left", "right"]
    assert lines[0].rho == pytest.approx(50, abs=1.5) and lines[1].rho == pytest.approx(110, abs=1.5)


def test_nearest_rule_vs_paper_rule():
    # a strong outer line far right, a weaker ego line right, one ego line left
    rows, cols = 200, 240
    bev = make_bev_image(rows=rows, cols=cols, lane_cols=(90.0, 150.0, 200.0), noise=2)
    bev[:, 197:204] = 230  # wide bright outer stripe: more votes
    f = slt(SltParams(window=8), image=bev)["features"]
    g = geometry(rows, cols)
    near = line1d(HoughParams(min_votes=20), features=f, orientation=math.pi / 2, geometry=g)["lines"]
    assert [round(ln.rho) for ln in near] == [90, 150]
    paper = line1d(
        HoughParams(min_votes=20, select="paper"), features=f, orientation=math.pi / 2, geometry=g
    )["lines"]
    assert any(abs(ln.rho - 200) < 5 for ln in paper)


def test_line2d_finds_the_same_lines():
    f = features_for((50.0, 110.0), slope=0.2)
    lines = line2d(Hough2dParams(min_votes=20), features=f, geometry=geometry())["lines"]
    assert [round(ln.rho) for ln in lines] == pytest.approx([50, 110], abs=2)
    assert lines[0].theta == pytest.approx(math.atan2(1, 0.2), abs=math.radians(1))


@pytest.mark.parametrize("node", [line1d, line2d])
def test_nearest_rule_takes_the_line_being_crossed_in_a_lane_change(node):
    # the vehicle (column 119.5) is over a line at column 122 (0.125 m right of it); the other
    # boundary of its lane is 3.6 m left (column 50), beyond max_offset_m (3.2 m)
    rows, cols = 200, 240
    g = geometry(rows, cols)

    def lines(lane_cols, previous, **params):
        f = slt(
            SltParams(window=8), image=make_bev_image(rows=rows, cols=cols, lane_cols=lane_cols, noise=2)
        )["features"]
        p = node_type_of(node).params(min_votes=20, **params)
        return [
            round(ln.rho)
            for ln in node(p, features=f, orientation=math.pi / 2, geometry=g, previous=previous)["lines"]
        ]

    def lane(col, side):
        return Lane((col, 0.0, 0.0), (0, rows - 1), side, 0.9)

    crossing = [lane(126.0, "right"), lane(54.0, "left")]  # last frame: 0.33 m right, 3.3 m left
    assert lines((50.0, 122.0), crossing) == [50, 122]
    # without a previous lane near it, a peak under the vehicle is no boundary (an arrow, a seam)
    assert lines((50.0, 122.0), None) == []
    assert lines((50.0, 122.0), [lane(160.0, "right")]) == []
    assert lines((50.0, 122.0), crossing, lane_change=False) == []
    # the other side's line must lie within a lane's width of the crossed one
    assert lines((20.0, 122.0), crossing) == [122]
    assert lines((20.0, 122.0), crossing, max_lane_width_m=5.2) == [20, 122]


def test_hough_on_empty_features():
    empty = FeatureMap(np.zeros((50, 40), bool), np.full((50, 40), -1, np.float32))
    g = geometry(50, 40)
    assert line1d(HoughParams(), features=empty, orientation=math.pi / 2, geometry=g)["lines"] == []
    assert line2d(Hough2dParams(), features=empty, geometry=g)["lines"] == []
    assert fit_irls(IrlsParams(), features=empty, lines=[], geometry=g)["lanes"] == []


# ----------------------------------------------------------------------------- fitting
def parabola_with_outliers(n=400, frac=0.3, seed=0):
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 300, n)
    true = np.array([40.0, 0.1, 2e-4])
    y = true[0] + true[1] * t + true[2] * t * t + rng.normal(0, 0.5, n)
    k = int(frac * n)
    y[:k] += rng.uniform(-20, 20, k) + np.sign(rng.uniform(-1, 1, k)) * 5
    return t, y, true


@pytest.mark.parametrize("fit", ["irls", "ransac"])
def test_parabola_recovered_with_30_percent_outliers(fit):
    t, y, true = parabola_with_outliers()
    coef, w = irls_fit(t, y) if fit == "irls" else ransac_fit(t, y)
    pred = np.polyval(coef[::-1], t)
    truth = np.polyval(true[::-1], t)
    assert np.abs(pred - truth).max() < 1.0
    assert coef[2] == pytest.approx(true[2], abs=3e-5)
    plain = np.polyfit(t, y, 2)[::-1]
    assert np.abs(np.polyval(plain[::-1], t) - truth).max() > np.abs(pred - truth).max()


def roi_points_np(features, line, width_px):
    """The plain twin of ``roi_points``: from the dense mask's pixels (the node reads the map's
    points and builds no mask)."""
    rows = features.mask.shape[0]
    r, c = np.nonzero(features.mask)
    inv_tan = np.cos(line.theta) / max(np.sin(line.theta), 1e-6)
    x_line = line.rho + (rows - r) * inv_tan
    keep = np.abs(c - x_line) <= width_px / 2
    return (rows - 1 - r[keep]).astype(np.float64), c[keep].astype(np.float64)


@pytest.mark.parametrize("sparse", [False, True])
def test_roi_points_match_the_twin(sparse):
    from lanegraph_lanes._fit import roi_points

    rng = np.random.default_rng(12)
    dense = FeatureMap(mask=rng.random((60, 45)) < 0.3, orientation=None)
    for theta in (np.pi / 2, 1.3, 1.9, 0.2, 3.0, 0.0, 1e-9):
        for rho in (-30.0, 0.0, 12.3, 22.0, 44.5, 80.0):
            for width in (4.0, 9.0, 40.0):
                line = Line(rho=rho, theta=theta, side="left")
                # a map of points (features.mask's output): no dense mask is built for the ROI
                feats = FeatureMap.from_points((60, 45), *np.nonzero(dense.mask)) if sparse else dense
                got = roi_points(feats, line, width)
                assert "mask" in vars(feats) or sparse
                assert "mask" not in vars(feats) or not sparse
                ref = roi_points_np(dense, line, width)
                np.testing.assert_array_equal(got[0], ref[0])
                np.testing.assert_array_equal(got[1], ref[1])


def ransac_np(t, y, samples, inlier_px):
    """NumPy twin of ``_ransac_kernel``: every sample's polynomial by ``np.linalg.solve`` on the
    scaled Vandermonde system, its inliers counted; the first sample with the most wins."""
    lo, hi = t.min(), t.max()
    mid, half = 0.5 * (lo + hi), (0.5 * (hi - lo) if hi > lo else 1.0)
    x = (t - mid) / half
    m = samples.shape[1]
    best, best_inl = -1, np.zeros(t.size, bool)
    for idx in samples:
        if np.unique(t[idx]).size < m:
            continue
        try:
            a = np.linalg.solve(np.vander(x[idx], m, increasing=True), y[idx])
        except np.linalg.LinAlgError:
            continue
        inl = np.abs(np.vander(x, m, increasing=True) @ a - y) <= inlier_px
        if inl.sum() > best:
            best, best_inl = int(inl.sum()), inl
    return best_inl


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_ransac_kernel_matches_numpy_twin(degree):
    from lanegraph_lanes._fit import _ransac_kernel, ransac_samples

    for seed in range(4):
        t, y, _ = parabola_with_outliers(n=50 + 120 * seed, seed=seed)
        t = np.round(t)  # BEV rows: repeated abscissae happen
        samples = ransac_samples(t.size, degree + 1, 60, seed)
        assert samples.shape == (60, degree + 1) and np.all(
            np.sort(samples, 1)[:, 1:] != np.sort(samples, 1)[:, :-1]
        )
        np.testing.assert_array_equal(ransac_samples(t.size, degree + 1, 60, seed), samples)  # deterministic
        tol = np.full(t.size, 3.0)
        tol[::3] = 1.5  # per point, as the residuals in image pixels give them
        np.testing.assert_array_equal(_ransac_kernel(t, y, samples, tol), ransac_np(t, y, samples, tol))
    # every sample degenerate (one abscissa): nothing usable
    t = np.full(10, 4.0)
    assert not _ransac_kernel(t, np.arange(10.0), ransac_samples(10, 2, 20), np.ones(10)).any()


def lane_roi_points_np(features, lane, width_px):
    """The plain twin of ``lane_roi_points`` (around a parabola), from the dense mask's pixels."""
    rows = features.mask.shape[0]
    r, c = np.nonzero(features.mask)
    t = rows - 1 - r
    c0, c1, c2 = lane.coeffs
    x = (c0 - c1) + (rows - r) * c1 + c2 * t * t
    keep = np.abs(c - x) <= width_px / 2
    return t[keep].astype(np.float64), c[keep].astype(np.float64)


def test_lane_roi_points_match_the_twin():
    from lanegraph_lanes._fit import lane_roi_points

    rng = np.random.default_rng(13)
    feats = FeatureMap(mask=rng.random((70, 50)) < 0.3, orientation=None)
    for coeffs in (
        (20.0, 0.1, 0.002),
        (-5.0, 0.5, 0.0),
        (45.5, -0.3, -0.004),
        (25.0, 0.0, 0.05),
        (np.nan, 0.0, 0.0),
    ):
        for width in (4.0, 9.0, 40.0):
            lane = Lane(coeffs, (0, 69), "left", 0.5)
            got, ref = lane_roi_points(feats, lane, width), lane_roi_points_np(feats, lane, width)
            np.testing.assert_array_equal(got[0], ref[0])
            np.testing.assert_array_equal(got[1], ref[1])


def side_band_np(lane_cols_rows, c_lo, c_hi, band_px, feat):
    rows = lane_cols_rows.shape[1]
    cols = feat.shape[1]
    cc = np.arange(cols)[None, :]
    sel = np.broadcast_to((cc >= c_lo) & (cc < c_hi), (rows, cols))
    band = np.zeros((rows, cols), bool)
    for lc in lane_cols_rows:
        band |= np.abs(cc - lc[:, None]) <= band_px
    band &= sel
    return band, int((feat & sel).sum()), int((feat & band).sum())


def test_side_band_kernel_matches_numpy_twin():
    from lanegraph_lanes._temporal import _side_band_kernel

    rng = np.random.default_rng(11)
    rows, cols = 37, 53
    feat = rng.random((rows, cols)) < 0.2
    for n_lanes in (1, 2):
        lcols = rng.uniform(-10, 60, (n_lanes, 1)) + rng.uniform(-0.3, 0.3, (1, rows)) * np.arange(rows)
        for c_lo, c_hi in ((0, 26), (26, 53), (0, 0), (0, 53)):
            for band_px in (3.0, 7.5):
                band = np.zeros((rows, cols), bool)
                fr, fc = np.nonzero(feat)
                n_side, n_band = _side_band_kernel(lcols, c_lo, c_hi, band_px, fr, fc, band)
                ref, ref_side, ref_band = side_band_np(lcols, c_lo, c_hi, band_px, feat)
                np.testing.assert_array_equal(band, ref)
                assert (n_side, n_band) == (ref_side, ref_band)


@pytest.mark.parametrize("degree", [1, 2, 3])
@pytest.mark.parametrize("loss", ["tukey", "huber"])
def test_irls_kernel_matches_lstsq_twin(degree, loss):
    """The normal-equation IRLS kernel against the NumPy ``lstsq`` IRLS it replaces."""
    from lanegraph_lanes._fit import _irls_kernel, irls_fit_lstsq

    for seed in range(5):
        t, y, _ = parabola_with_outliers(n=60 + 100 * seed, seed=seed)
        t = np.round(t)  # BEV rows
        ok, coef, w = _irls_kernel(
            t,
            y,
            degree,
            10,
            loss == "tukey",
            4.685 if loss == "tukey" else 1.345,
            0.01,
            np.empty(0),
            np.empty(0),
        )
        assert ok
        ref, wref = irls_fit_lstsq(t, y, degree, 10, loss)
        np.testing.assert_allclose(coef, ref, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(w, wref, atol=1e-7)
        np.testing.assert_allclose(irls_fit(t, y, degree, 10, loss)[0], ref, rtol=1e-7, atol=1e-9)
    # one row only: singular for a line or a parabola; the lstsq path takes over
    t, y = np.full(20, 7.0), np.arange(20.0)
    ok, _, _ = _irls_kernel(t, y, 1, 10, True, 4.685, 0.01, np.empty(0), np.empty(0))
    assert not ok
    np.testing.assert_allclose(irls_fit(t, y, 1)[0], irls_fit_lstsq(t, y, 1)[0])
    # beyond the kernel's degree 3: the lstsq path
    t, y, _ = parabola_with_outliers(n=200, seed=1)
    np.testing.assert_array_equal(irls_fit(t, y, 4)[0], irls_fit_lstsq(t, y, 4)[0])


@pytest.mark.parametrize("node", [fit_irls, fit_ransac])
def test_fit_nodes_on_curved_stripe(node):
    rows, cols = 300, 160
    bev = np.full((rows, cols), 80, np.uint8)
    t = np.arange(rows)
    centre = 60 + 0.05 * t + 3e-4 * t * t
    for tt, cc in zip(t, centre):
        bev[rows - 1 - tt, int(round(cc)) - 1 : int(round(cc)) + 2] = 220
    f = eslt(EsltParams(), image=bev)["features"]
    line = Line(rho=60.0, theta=math.atan2(1, 0.1), side="left")
    lanes = node(node_type_of(node).params(), features=f, lines=[line], geometry=geometry(rows, cols))[
        "lanes"
    ]
    assert len(lanes) == 1
    c0, c1, c2 = lanes[0].coeffs
    fitted = c0 + c1 * t + c2 * t * t
    assert np.abs(fitted - centre).max() < 1.5 and lanes[0].side == "left"


def _clothoid_bev(dashed: bool, rows: int = 800, cols: int = 240) -> tuple[np.ndarray, np.ndarray]:
    """A BEV (5 cm pixels, 5-45 m) of a line whose curvature grows with the distance (a clothoid:
    ``col = 100 + 0.02 t + 1e-7 t^3``), solid or dashed (3 m of paint, 9 m gaps); and its centre."""
    bev = np.full((rows, cols), 80, np.uint8)
    t = np.arange(rows)
    centre = 100 + 0.02 * t + 1e-7 * t**3
    for tt, cc in zip(t, centre):
        if not dashed or (tt // 60) % 4 == 1:
            bev[rows - 1 - tt, int(round(cc)) - 1 : int(round(cc)) + 2] = 220
    return bev, centre


def test_near_fit_counts_the_rows_as_np_unique():
    """``_near_fit`` counts the near rows its ROI points cover where ``t`` changes (the ROI's
    row-major order): the count ``np.unique`` gives, so the same points are kept."""
    from lanegraph_lanes._fit import _near_fit, _roi_points

    rng = np.random.default_rng(3)
    for _ in range(30):
        mask = rng.random((200, 120)) < rng.uniform(0.02, 0.5)
        feats = FeatureMap(mask=mask)
        t, y = _roi_points(feats, float(rng.uniform(20, 100)), float(rng.uniform(-0.2, 0.2)), 0.0, 20.0)
        for t_near, coverage in ((50.0, 0.7), (120.0, 0.9), (30.0, 0.2), (300.0, 0.5)):
            want = t.size and t.max() >= t_near and np.unique(t[t < t_near]).size >= coverage * t_near
            got_t, got_y = _near_fit(t, y, t_near, coverage)
            assert got_t.size == (np.count_nonzero(t < t_near) if want else t.size)
            assert np.array_equal(got_y, y[t < t_near] if want else y)


@pytest.mark.parametrize("node", [fit_irls, fit_ransac])
def test_near_fit_follows_a_solid_line_whose_curvature_changes(node):
    """A parabola over 5-45 m misses the near part of a clothoid; fitted to the near 25 m it does
    not, and the lane then ends there."""
    bev, centre = _clothoid_bev(dashed=False)
    f = eslt(EsltParams(), image=bev)["features"]
    g = geometry(*bev.shape)
    line = Line(rho=100.0, theta=math.atan2(1, 0.06), side="left")
    near = 400  # BEV rows of the near 20 m (near_fit_m 25 from z_min 5)
    t = np.arange(near)

    def near_error(params):
        (lane,) = node(params, features=f, lines=[line], geometry=g)["lanes"]
        c0, c1, c2 = lane.coeffs
        return np.abs(c0 + c1 * t + c2 * t * t - centre[:near]).max(), lane

    err_full, full = near_error(node_type_of(node).params())
    err_near, lane = near_error(node_type_of(node).params(near_fit_m=25.0))
    assert err_full > 1.5 and err_near < 0.5 * err_full and err_near < 1.0
    assert lane.bev_rows[0] >= bev.shape[0] - near and full.bev_rows[0] < bev.shape[0] - near


@pytest.mark.parametrize("node", [fit_irls, fit_ransac])
def test_near_fit_leaves_a_dashed_line_to_the_whole_bev(node):
    """A dashed line covers a quarter of the near rows: its one or two near dashes would bend the
    parabola, so it is fitted over the whole BEV, as without near_fit_m."""
    bev, _ = _clothoid_bev(dashed=True)
    f = eslt(EsltParams(), image=bev)["features"]
    g = geometry(*bev.shape)
    line = Line(rho=100.0, theta=math.atan2(1, 0.06), side="left")
    a = node(node_type_of(node).params(near_fit_m=25.0), features=f, lines=[line], geometry=g)["lanes"]
    b = node(node_type_of(node).params(), features=f, lines=[line], geometry=g)["lanes"]
    assert len(a) == len(b) == 1 and a[0].coeffs == b[0].coeffs and a[0].bev_rows == b[0].bev_rows


@pytest.mark.parametrize("node", [fit_irls, fit_ransac])
def test_fit_follows_the_previous_lane_where_the_hough_found_nothing(node):
    """A dashed, sharply curving line: no Hough line on its side, but the previous frame's lane
    there; the ROI follows that lane, its curvature is kept and the offset and slope are fitted."""
    rows, cols = 300, 160
    bev = np.full((rows, cols), 80, np.uint8)
    t = np.arange(rows)
    centre = 50 + 0.05 * t + 4e-4 * t * t
    for tt, cc in zip(t, centre):
        if (tt // 20) % 2 == 0:  # dashes
            bev[rows - 1 - tt, int(round(cc)) - 1 : int(round(cc)) + 2] = 220
    f = eslt(EsltParams(), image=bev)["features"]
    g = geometry(rows, cols)
    previous = [Lane((48.0, 0.06, 4e-4), (0, rows - 1), "left", 0.5)]  # 10 cm off, a little turned
    lanes = node(node_type_of(node).params(), features=f, lines=[], geometry=g, previous=previous)["lanes"]
    assert len(lanes) == 1 and lanes[0].side == "left" and lanes[0].extra["tracked"] is True
    c0, c1, c2 = lanes[0].coeffs
    assert c2 == pytest.approx(4e-4)  # the previous lane's curvature
    assert np.abs(c0 + c1 * t + c2 * t * t - centre).max() < 1.5
    # without the previous lane, or with a weak one, nothing is reported on that side
    assert node(node_type_of(node).params(), features=f, lines=[], geometry=g)["lanes"] == []
    weak = [Lane((48.0, 0.06, 4e-4), (0, rows - 1), "left", 0.05)]
    assert node(node_type_of(node).params(), features=f, lines=[], geometry=g, previous=weak)["lanes"] == []
    # the side is where the lane is now: a previous "right" lane that lies left of the vehicle
    # (column 79.5 here) after a lane change is reported as the left one
    moved = [Lane((48.0, 0.06, 4e-4), (0, rows - 1), "right", 0.5)]
    lanes = node(node_type_of(node).params(), features=f, lines=[], geometry=g, previous=moved)["lanes"]
    assert [ln.side for ln in lanes] == ["left"]
    # a line the vehicle has moved away from (after a lane change: 3.5 m from it) is no ego
    # boundary: not kept alive by fitting around it. A line under the vehicle (0.05 m) is the one
    # being crossed in a lane change: kept (track_lane_change), else rejected like the far one
    bev_far = np.full((rows, cols), 80, np.uint8)
    bev_far[:, 77:80] = 220  # a solid line 0.05 m left of the vehicle (column 79.5)
    bev_far[:, 8:11] = 220  # and one 3.5 m left of it
    f_far = eslt(EsltParams(), image=bev_far)["features"]
    strict = node_type_of(node).params(track_lane_change=False)
    for x, kept in ((78.0, True), (9.0, False)):
        prev = [Lane((x, 0.0, 0.0), (0, rows - 1), "left", 0.5)]
        assert len(
            node(node_type_of(node).params(), features=f_far, lines=[], geometry=g, previous=prev)["lanes"]
        ) == int(kept)
        assert node(strict, features=f_far, lines=[], geometry=g, previous=prev)["lanes"] == []
        wide = node_type_of(node).params(
            track_min_offset_m=0.0, track_max_offset_m=10.0, track_lane_change=False
        )  # the check is what rejects them
        assert len(node(wide, features=f_far, lines=[], geometry=g, previous=prev)["lanes"]) == 1
    # a side with a Hough line is fitted around the line only
    line = Line(rho=50.0, theta=math.atan2(1, 0.05), side="left")
    lanes = node(
        node_type_of(node).params(),
        features=f,
        lines=[line],
        geometry=g,
        previous=[Lane((120.0, 0.0, 0.0), (0, 299), "left", 0.9)],
    )["lanes"]
    assert len(lanes) <= 1 and all("tracked" not in ln.extra for ln in lanes)


@pytest.mark.parametrize("node", [fit_irls, fit_ransac])
def test_fit_does_not_report_the_line_being_crossed_twice(node):
    # the Hough line is the crossed line, labelled right; the previous frame had it left of the
    # vehicle (column 79.5): fitting around the previous lane finds the same line again
    rows, cols = 300, 160
    bev = np.full((rows, cols), 80, np.uint8)
    bev[:, 77:80] = 220
    f = eslt(EsltParams(), image=bev)["features"]
    g = geometry(rows, cols)
    line = Line(rho=80.5, theta=math.pi / 2, side="right")
    previous = [Lane((77.0, 0.0, 0.0), (0, rows - 1), "left", 0.9)]
    lanes = node(node_type_of(node).params(), features=f, lines=[line], geometry=g, previous=previous)[
        "lanes"
    ]
    assert len(lanes) == 1 and "tracked" not in lanes[0].extra


def test_fit_rejects_weak_support():
    f = FeatureMap(np.zeros((100, 80), bool))
    f.mask[90:100, 40] = True  # 10 features only
    lanes = fit_irls(IrlsParams(), features=f, lines=[Line(40.0, math.pi / 2)], geometry=geometry(100, 80))[
        "lanes"
    ]
    assert lanes == []


# ----------------------------------------------------------------------------- temporal mask, verify, projection
def test_temporal_mask_falls_back_and_bands():
    g = geometry(100, 80)
    full = temporal_mask(TemporalParams(), geometry=g, previous=None)["mask"]
    assert full.all()
    assert temporal_mask(TemporalParams(), geometry=g, previous=[])["mask"].all()
    lane = Lane((20.0, 0.0, 0.0), (0, 99), "left", 0.9)
    m = temporal_mask(TemporalParams(band_px=5), geometry=g, previous=[lane])["mask"]
    assert m[50, 20] and m[50, 25] and not m[50, 30] and not m[50, 10]
    assert m[:, 40:].all()  # the right side has no previous lane: open
    weak = Lane((20.0, 0.0, 0.0), (0, 99), "left", 0.01)
    assert temporal_mask(TemporalParams(), geometry=g, previous=[weak])["mask"].all()


def test_temporal_mask_band_follows_a_line_across_the_vehicle():
    # a lane change: last frame's right lane lies just right of the vehicle (column 39.5); its band
    # reaches into the left side, which has a lane of its own (else it would be open anyway)
    g = geometry(100, 80)
    prev = [Lane((20.0, 0.0, 0.0), (0, 99), "left", 0.9), Lane((42.0, 0.0, 0.0), (0, 99), "right", 0.9)]
    m = temporal_mask(TemporalParams(band_px=5, open_crossing_m=0.0), geometry=g, previous=prev)["mask"]
    assert m[:, 37:48].all() and not m[:, 48:].any() and not m[:, 26:37].any()
    # and the side of the crossed line (0.125 m from the vehicle) stays open: the lane the vehicle
    # moves into has its far boundary there
    m = temporal_mask(TemporalParams(band_px=5), geometry=g, previous=prev)["mask"]
    assert m[:, 40:].all() and m[:, 37:40].all() and not m[:, 26:37].any()
    assert (
        temporal_mask(TemporalParams(band_px=5, open_crossing_m=0.1), geometry=g, previous=prev)["mask"][
            :, 48:
        ].sum()
        == 0
    )


def test_temporal_mask_reacquires_when_band_is_unsupported():
    g = geometry(100, 80)
    lane = Lane((20.0, 0.0, 0.0), (0, 99), "left", 0.9)
    fm = np.zeros((100, 80), bool)
    fm[:, 5] = True  # this frame's marking is elsewhere on the left side
    m = temporal_mask(TemporalParams(band_px=5), geometry=g, previous=[lane], features=FeatureMap(fm))["mask"]
    assert m[:, :40].all()


def band_textures_twin(image, lane, gap_px, band_px, measure):
    """NumPy twin of ``_band_texture_kernel`` (through ``band_textures``): per-row band textures."""
    rows, cols = image.shape[:2]
    r = np.arange(lane.bev_rows[0], lane.bev_rows[1] + 1)
    t = rows - 1 - r
    c0, c1, c2 = lane.coeffs
    centre = c0 + c1 * t + c2 * t * t
    out = []
    for sign in (-1, 1):
        offs = sign * np.arange(gap_px, band_px + 1)
        cc = np.round(centre[:, None] + offs[None, :]).astype(np.int64)
        vals = image[r[:, None], np.clip(cc, 0, cols - 1)].astype(np.float64)
        diffs = np.abs(np.diff(vals, axis=1))
        tex = {"diff": diffs.mean(axis=1), "mdiff": np.median(diffs, axis=1), "std": vals.std(axis=1)}[
            measure
        ]
        out.append(np.where(((cc >= 0) & (cc < cols)).all(axis=1), tex, np.nan))
    return out


#: lanes for the side-band texture twins, all within the 90 x 70 test image's rows
TEXTURE_LANES = [
    Lane((35.0, 0.05, 0.0), (0, 89), "left", 0.9),
    Lane((3.0, 0.2, 0.001), (10, 80), "left", 0.9),  # leaves the image on the left at the bottom
    Lane((66.4, -0.1, 0.0), (5, 60), "right", 0.9),
    Lane((35.5, 0.0, 0.0), (89, 89), "right", 0.9),  # one row, a .5 centre (round half to even)
]


@pytest.mark.parametrize("measure", ["diff", "mdiff", "std"])
@pytest.mark.parametrize("gap, band", [(6, 30), (0, 2), (3, 60)])
def test_band_texture_kernel_matches_twin(measure, gap, band):
    rng = np.random.default_rng(8)
    img8 = rng.integers(0, 256, (90, 70)).astype(np.uint8)
    # uint8 (mdiff: medians by counting), uint16 and float (mdiff: by sorting)
    for img in (img8, img8.astype(np.uint16) * 200, (img8 + rng.random(img8.shape)).astype(np.float32)):
        for lane in TEXTURE_LANES:
            got = _verify.band_textures(img, lane, gap, band, measure)
            exp = band_textures_twin(img, lane, gap, band, measure)
            for g, e in zip(got, exp):
                np.testing.assert_allclose(g, e, rtol=1e-12, atol=1e-9)


def side_texture_twin(image, lane, gap_px, band_px, measure, quantile=0.5):
    """NumPy twin of ``_side_texture_kernel`` (through ``side_texture``): each side's per-row
    textures, then the ``quantile`` of the rows inside the image (0 when none)."""
    rows = image.shape[0]
    r0, r1 = max(lane.bev_rows[0], 0), min(lane.bev_rows[1], rows - 1)
    clipped = Lane(lane.coeffs, (r0, r1), lane.side, lane.score)
    out = []
    for tex in band_textures_twin(image, clipped, gap_px, band_px, measure):
        inside = tex[~np.isnan(tex)]
        out.append(float(np.quantile(inside, quantile)) if inside.size else 0.0)
    return tuple(out)


@pytest.mark.parametrize("measure", ["diff", "mdiff", "std"])
@pytest.mark.parametrize("gap, band", [(6, 30), (0, 2), (3, 60)])
def test_side_texture_kernel_matches_twin(measure, gap, band):
    rng = np.random.default_rng(9)
    img8 = rng.integers(0, 256, (90, 70)).astype(np.uint8)
    lanes = TEXTURE_LANES + [
        Lane((35.0, 0.0, 0.0), (-20, 200), "right", 0.9),  # rows beyond the image: clipped
        Lane((-300.0, 0.0, 0.0), (0, 89), "left", 0.9),  # every band outside: 0
        Lane((35.0, 0.0, 0.0), (50, 40), "left", 0.9),  # no rows: 0
    ]
    # integer grey levels (summed as integers) and float ones; the median and other quantiles
    for img in (img8, (img8 + rng.random(img8.shape)).astype(np.float32)):
        for lane in lanes:
            for q in (0.5, 0.75, 0.0, 1.0):
                got = _verify.side_texture(img, lane, gap, band, measure, q)
                exp = side_texture_twin(img, lane, gap, band, measure, q)
                np.testing.assert_allclose(got, exp, rtol=1e-12, atol=1e-9)


def TEXTURE(**kw):
    """``lanes.verify`` params with the texture check (at its former default threshold, 13.3)
    instead of the paint check."""
    return VerifyParams(**{"paint_check": False, "max_texture": 13.3, **kw})


def test_verify_drops_lane_beside_texture():
    rng = np.random.default_rng(0)
    img = np.full((100, 80), 100, np.uint8)
    img[:, 50:80] = rng.integers(0, 255, (100, 30))  # gravel right of column 50
    kerb = Lane((46.0, 0.0, 0.0), (0, 99), "right", 0.9)
    paint = Lane((12.0, 0.0, 0.0), (0, 99), "left", 0.9)
    out = verify(TEXTURE(), geometry=geometry(*img.shape), lanes=[kerb, paint], image=img)["lanes"]
    assert [ln.side for ln in out] == ["left"]
    out = verify(
        TEXTURE(measure="std", max_texture=18), geometry=geometry(*img.shape), lanes=[kerb, paint], image=img
    )["lanes"]
    assert [ln.side for ln in out] == ["left"]


def test_verify_keeps_lane_beside_a_shadow_edge_by_default():
    # a car's shadow: a smooth dark band right of the line, a step at column 60
    img = np.full((100, 120), 100, np.uint8)
    img[:, 60:] = 40
    img[:, 58:62] = [85, 70, 55, 45]  # a soft edge
    line = Lane((46.0, 0.0, 0.0), (0, 99), "right", 0.9)
    assert [
        ln.side for ln in verify(TEXTURE(), geometry=geometry(*img.shape), lanes=[line], image=img)["lanes"]
    ] == ["right"]
    # the std measure mistakes it for texture
    assert (
        verify(
            TEXTURE(measure="std", max_texture=18), geometry=geometry(*img.shape), lanes=[line], image=img
        )["lanes"]
        == []
    )


def _kerb_scene(gain: float = 1.0) -> tuple[np.ndarray, Lane, Lane]:
    """A BEV of sunlit asphalt (level 160, noise 2) with a painted line at column 20 and a kerb at
    column 70 with gravel beyond it (+-25 grey levels), at exposure ``gain``: ``(image, paint, kerb)``."""
    rng = np.random.default_rng(3)
    img = 160 + rng.normal(0, 2, (120, 110))
    img[:, 18:23] = 230
    img[:, 74:] = 150 + rng.uniform(-25, 25, (120, 36))  # gravel
    img[:, 68:73] = 220  # the kerb's top
    img = np.clip(img * gain, 0, 255).astype(np.uint8)
    return img, Lane((20.0, 0.0, 0.0), (0, 119), "left", 0.9), Lane((70.0, 0.0, 0.0), (0, 119), "right", 0.9)


@pytest.mark.parametrize("gain", [1.0, 0.6, 0.4, 1.3])
def test_verify_decides_the_same_at_any_exposure(gain):
    img, paint, kerb = _kerb_scene(gain)
    out = verify(TEXTURE(), geometry=geometry(*img.shape), lanes=[paint, kerb], image=img)["lanes"]
    assert [ln.side for ln in out] == ["left"]
    # the textures are reported in the reference road's grey levels: about the same at every gain
    ref = verify(TEXTURE(), geometry=geometry(*img.shape), lanes=[paint], image=_kerb_scene()[0])["lanes"][
        0
    ].extra["texture"]
    assert np.allclose(out[0].extra["texture"], ref, atol=1.0)


def test_absolute_brightness_lets_a_dark_kerb_through():
    """The reason for 'relative': at 0.4 exposure the gravel's texture is 0.4 times as large and an
    absolute threshold no longer sees it."""
    img, paint, kerb = _kerb_scene(0.4)
    out = verify(
        TEXTURE(brightness="absolute"), geometry=geometry(*img.shape), lanes=[paint, kerb], image=img
    )["lanes"]
    assert [ln.side for ln in out] == ["left", "right"]


def test_verify_road_level_from_the_mask():
    img, paint, kerb = _kerb_scene()
    dark = img.copy()
    dark[:, :60] //= 2  # the road in shadow: level about 80, not 160
    mask = np.zeros(img.shape, bool)
    mask[:, :60] = True
    assert _verify.road_level(dark, mask, 0.8) == pytest.approx(
        np.quantile(dark[::4, ::4][mask[::4, ::4]], 0.8), abs=1
    )
    assert _verify.road_level(dark, None, 0.8) == pytest.approx(
        np.quantile(dark[::4, ::4][dark[::4, ::4] > 0], 0.8), abs=1
    )
    with pytest.raises(InputError, match="mask: expected the BEV image's shape"):
        verify(TEXTURE(), geometry=geometry(*img.shape), lanes=[paint], image=img, mask=mask[:, :50])


def test_verify_wants_a_grey_bev():
    img, paint, _ = _kerb_scene()
    with pytest.raises(InputError, match="image: expected an Hb x Wb grey BEV image"):
        verify(
            TEXTURE(),
            geometry=geometry(*img.shape),
            lanes=[paint],
            image=np.dstack([img] * 3),
            mask=np.ones(img.shape, bool),
        )


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
def test_road_level_matches_quantile(dtype):
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (160, 90)).astype(dtype)
    mask = rng.random(img.shape) < 0.5
    for q in (0.1, 0.5, 0.8, 0.99):
        vals = img[::4, ::4][mask[::4, ::4]].astype(np.float64)
        got = _verify.road_level(img, mask, q)
        # the uint8 histogram gives the lower of the two values a quantile falls between
        lo, hi = np.quantile(vals, q, method="lower"), np.quantile(vals, q, method="higher")
        assert lo - 1e-9 <= got <= hi + 1e-9
    assert _verify.road_level(img, np.zeros(img.shape, bool), 0.8) is None  # no road: no level
    assert _verify.road_level(np.zeros((10, 10), dtype), None, 0.8) is None


def test_row_quantile_sees_gravel_resolved_on_the_near_rows_only():
    """Far rows (the top of the BEV) and shadows smooth the gravel beside a kerb; on the near 40 %
    of the rows it is resolved: the median over rows misses it, the rougher quarter does not."""
    img, paint, kerb = _kerb_scene()
    far = np.random.default_rng(4).normal(150, 2, (72, 36))
    img[:72, 74:] = np.clip(far, 0, 255).astype(np.uint8)  # the gravel smoothed on the far 60 %
    assert [
        ln.side
        for ln in verify(TEXTURE(), geometry=geometry(*img.shape), lanes=[paint, kerb], image=img)["lanes"]
    ] == ["left"]
    kept = verify(TEXTURE(row_quantile=0.5), geometry=geometry(*img.shape), lanes=[paint, kerb], image=img)[
        "lanes"
    ]
    assert [ln.side for ln in kept] == ["left", "right"]


def test_mdiff_ignores_a_few_sharp_edges():
    """A kerb's face or a hatching's bars beside a line: a few large steps in a smooth band raise
    the mean difference, not the median one."""
    img = np.full((60, 80), 120, np.uint8)
    img[:, 30:33] = 220  # a bright bar 10-12 px right of the line
    img[:, 40:] = 150  # a step to a smooth pavement
    line = Lane((20.0, 0.0, 0.0), (0, 59), "left", 0.9)
    _, right_mean = _verify.side_texture(img, line, 6, 30, "diff")
    _, right_median = _verify.side_texture(img, line, 6, 30, "mdiff")
    assert right_mean > 9 and right_median == 0.0


def paint_rows_twin(img, r0, r1, coeffs, band, gap, align, min_row_contrast, sat):
    """NumPy twin of ``_paint_rows_kernel``: ``(inside, painted, saturated, painted rows' strips divided
    by their level, contrasts, ratios)``."""
    rows, cols = img.shape
    c0, c1, c2 = coeffs
    prof = []
    con, rat = [], []
    inside = saturated = 0
    for r in range(max(r0, 0), min(r1, rows - 1) + 1):
        t = rows - 1 - r
        ce = int(np.rint(c0 + c1 * t + c2 * t * t))
        if ce - band - align < 0 or ce + band + align >= cols:
            continue
        best = ce - align + int(np.argmax(img[r, ce - align : ce + align + 1]))  # the first brightest
        strip = img[r, best - band : best + band + 1].astype(np.float64)
        if (strip == 0).any() or np.isnan(strip).any():  # outside the camera's view
            continue
        inside += 1
        left, right = np.median(strip[: band - gap + 1]), np.median(strip[band + gap :])
        hi = max(left, right)
        if hi <= 0 or strip[band] / hi - 1.0 < min_row_contrast:
            continue
        prof.append(strip / hi)
        con.append(strip[band] / hi - 1.0)
        rat.append(min(left, right) / hi)
        saturated += int(strip[band] >= sat)
    return inside, len(con), saturated, np.reshape(prof, (-1, 2 * band + 1)), np.array(con), np.array(rat)


def painted_strips(img, band, painted, row, start, inv):
    """The strips of ``_paint_rows_kernel``'s painted rows, each divided by its level (as its records say)."""
    return np.array(
        [img[row[k], start[k] : start[k] + 2 * band + 1] * inv[k] for k in range(painted)]
    ).reshape(painted, 2 * band + 1)


def random_paint_case(rng, dtype):
    """A random image with a bright line and zeros (outside the camera's view), and the row pass's
    arguments: ``(img, r0, r1, coeffs, band, gap, align, min_row_contrast)``."""
    rows, cols = int(rng.integers(20, 90)), int(rng.integers(30, 120))
    img = rng.integers(0, 256, (rows, cols)).astype(dtype)
    img[rng.random((rows, cols)) < 0.02] = 0  # outside the camera's view
    if img.dtype.kind == "f":
        img[rng.random((rows, cols)) < 0.01] = np.nan  # so is a NaN
    c = float(rng.uniform(-5, cols + 5))
    col = np.clip(np.rint(c).astype(int), 0, cols - 1)
    img[:, max(col - 1, 0) : col + 2] = np.maximum(img[:, max(col - 1, 0) : col + 2], 200)  # a line
    coeffs = (c, float(rng.uniform(-0.2, 0.2)), float(rng.uniform(-1e-3, 1e-3)))
    band = int(rng.integers(3, 20))
    gap = int(rng.integers(1, band))
    align = int(rng.integers(0, 3))
    r0, r1 = int(rng.integers(-5, rows // 2)), int(rng.integers(rows // 2, rows + 5))
    mrc = float(rng.choice([0.0, 0.15, 0.5]))
    return img, r0, r1, coeffs, band, gap, align, mrc


@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
def test_paint_rows_kernel_matches_twin(dtype):
    rng = np.random.default_rng(21)
    for _ in range(25):
        img, r0, r1, coeffs, band, gap, align, mrc = random_paint_case(rng, dtype)
        n = max(r1 - r0 + 1, 0)
        row, start = np.empty(n, np.int64), np.empty(n, np.int64)
        inv, measures = np.empty(n), np.empty((n, 2))
        hist = _verify._median_hist(img)
        sat = 250.0
        got = _verify._paint_rows_kernel(
            img, r0, r1, *coeffs, band, gap, align, mrc, sat, hist, row, start, inv, measures
        )
        ref = paint_rows_twin(img, r0, r1, coeffs, band, gap, align, mrc, sat)
        assert got == ref[:3]
        painted = got[1]
        np.testing.assert_allclose(painted_strips(img, band, painted, row, start, inv), ref[3], rtol=1e-12)
        np.testing.assert_allclose(measures[:painted, 0], ref[4], rtol=1e-12)
        np.testing.assert_allclose(measures[:painted, 1], ref[5], rtol=1e-12)
        assert not hist.any()  # the counting buffer is left empty


def test_column_medians_match_numpy():
    """``_column_medians`` (selection in place) against ``np.median(..., axis=0)``: odd and even
    row counts, ties, one row."""
    rng = np.random.default_rng(5)
    for n in (1, 2, 3, 4, 7, 64, 127):
        for ties in (False, True):
            strips = rng.random((130, 9))
            if ties:
                strips = np.round(strips * 3)
            out = np.empty(9)
            _verify._column_medians(strips, n, out)
            np.testing.assert_allclose(out, np.median(strips[:n], axis=0), rtol=0, atol=0)


def _road_bev(rows=600, cols=200, level=100.0, noise=3.0, seed=0):
    """A BEV of asphalt (5 cm pixels, 30 m of road from 5 m) and its geometry."""
    rng = np.random.default_rng(seed)
    return level + rng.normal(0, noise, (rows, cols)), geometry(rows, cols)


def _stripe(img, centre, width_px, value, soft_px=0.0):
    """A stripe of ``width_px`` (its edges ramping over ``soft_px`` each side) at column ``centre``."""
    x = np.arange(img.shape[1]) - centre
    ramp = (
        np.clip((width_px / 2 + soft_px - np.abs(x)) / max(soft_px, 1e-9), 0, 1)
        if soft_px
        else (np.abs(x) <= width_px / 2)
    )
    img[:] = img * (1 - ramp) + value * ramp
    return img


def _paint_scene(kind: str, gain: float = 1.0) -> tuple[np.ndarray, Lane, BevGeometry]:
    """A BEV with one candidate at column 100: ``paint`` (15 cm at twice the road's level),
    ``dashed`` (3 m painted, 6 m gaps), ``edge_grass`` (paint, then rough darker grass from 40 cm),
    ``kerb`` (a kerb's lit edge, 5 cm, then dark gravel), ``kerb_top`` (a kerb's top 15 cm wide,
    brighter than the road, then dark gravel), ``shadow`` (paint with a smooth shadow along its
    right), ``step`` (the road's edge against a darker verge, no stripe), ``gutter`` (a light
    concrete band 45 cm wide with soft edges), ``sun_patches`` (paint in deep shade, hard-edged sun
    patches 0.8-1.8 m across every 2.5 m, three times as bright, over it on half of its rows)."""
    img, g = _road_bev()
    rng = np.random.default_rng(1)
    if kind == "sun_patches":
        img = 0.4 * img
        _stripe(img, 100, 3, 80.0)
        rr, cc = np.mgrid[: img.shape[0], : img.shape[1]]
        for centre in range(20, img.shape[0], 50):
            radius = rng.uniform(8, 18)
            sun = (rr - centre) ** 2 + (cc - 100 - rng.uniform(-6, 6)) ** 2 <= radius**2
            img[sun] *= 3.0
    if kind in ("paint", "dashed", "edge_grass", "shadow"):
        _stripe(img, 100, 3, 200.0)
        if kind == "shadow":
            img[:, 103:] = 55 + rng.normal(0, 2, (img.shape[0], img.shape[1] - 103))
        if kind == "dashed":
            for start in range(0, img.shape[0], 180):
                img[start + 60 : start + 180, 98:103] = _road_bev(seed=2)[0][start + 60 : start + 180, 98:103]
        if kind == "edge_grass":
            img[:, 108:] = 80 + rng.normal(0, 18, (img.shape[0], img.shape[1] - 108))
    elif kind == "kerb":
        img[:, 100] = 135.0
        img[:, 101:] = 50 + rng.normal(0, 20, (img.shape[0], img.shape[1] - 101))
    elif kind == "kerb_top":
        _stripe(img, 100, 3, 140.0)
        img[:, 102:] = 55 + rng.normal(0, 20, (img.shape[0], img.shape[1] - 102))
    elif kind == "step":
        img[:, 101:] = 60 + rng.normal(0, 5, (img.shape[0], img.shape[1] - 101))
    elif kind == "gutter":
        _stripe(img, 100, 5, 150.0, soft_px=2.5)
    elif kind != "sun_patches":
        raise ValueError(kind)
    img = np.clip(img * gain, 1, 255).astype(np.uint8)
    return img, Lane((100.0, 0.0, 0.0), (0, img.shape[0] - 1), "right", 0.9), g


@pytest.mark.parametrize("gain", [1.0, 0.4, 1.3])
@pytest.mark.parametrize(
    ("kind", "paint"),
    [
        ("paint", True),
        ("dashed", True),
        ("edge_grass", True),
        ("shadow", True),
        ("kerb", False),
        ("kerb_top", False),
        ("step", False),
        ("gutter", False),
    ],
)
def test_verify_keeps_paint_drops_kerbs_edges_and_gutters(kind, paint, gain):
    """What the paint check is for, at any exposure (its measures are relative)."""
    img, lane, g = _paint_scene(kind, gain)
    kept = verify(VerifyParams(), lanes=[lane], image=img, geometry=g)["lanes"]
    assert len(kept) == int(paint), _verify.paint_cues(img, lane, g)
    if paint:
        cues = kept[0].extra["paint"]
        assert 0.12 <= cues["width_m"] <= 0.2 and cues["contrast"] > 0.6
        assert (cues["side_ratio"] < 0.75) == (kind == "shadow")


def test_overexposed_paint_is_kept():
    """Clipped at 255 in a bright frame (road at 215), paint shows 19 % over the road: as bright as
    the image can show it. A kerb's lit edge clipped alike stays too narrow."""
    img, lane, g = _paint_scene("paint", gain=1.0)
    bright = np.clip(img.astype(np.float64) * 2.15, 0, 255).astype(np.uint8)
    cues = _verify.paint_cues(bright, lane, g)
    assert cues.contrast < VerifyParams().min_paint_contrast and cues.saturated == cues.painted
    assert len(verify(VerifyParams(), lanes=[lane], image=bright, geometry=g)["lanes"]) == 1
    img, lane, g = _paint_scene("kerb")
    bright = np.clip(img.astype(np.float64) * 2.15, 0, 255).astype(np.uint8)
    assert verify(VerifyParams(), lanes=[lane], image=bright, geometry=g)["lanes"] == []


def test_sun_patches_do_not_widen_the_paint():
    """Sun patches a metre or more across that cross a shaded line on half of its rows are painted rows
    too (their centre stands far above the shade beside them); the median profile over the rows
    keeps the paint's width where their mean profile would take the patches' (issue 28: the
    synthetic shade with saturated sun patches, 20 % -> 100 %)."""
    img, lane, g = _paint_scene("sun_patches")
    cues = _verify.paint_cues(img, lane, g)
    assert 0.1 <= cues.width_m <= 0.2 and cues.foot_width_m <= VerifyParams().max_foot_width_m
    assert len(verify(VerifyParams(), lanes=[lane], image=img, geometry=g)["lanes"]) == 1
    # their mean profile (as before issue 28) is wider than paint at a quarter height
    band, gap = 30, 5
    n = img.shape[0]
    strips = paint_rows_twin(img, 0, n - 1, lane.coeffs, band, gap, 2, 0.15, 255.0)[3]
    mean = strips.mean(axis=0)
    base = max(np.median(mean[: band - gap + 1]), np.median(mean[band + gap :]))
    foot = _verify._crossing_width(mean, band, base + 0.25 * (mean[band] - base)) * g.resolution
    assert foot > VerifyParams().max_foot_width_m


def test_paint_cues_name_the_failing_cue():
    """Each non-paint candidate fails for its own reason."""
    p = VerifyParams()
    kerb = _verify.paint_cues(*_paint_scene("kerb"))
    assert kerb.side_ratio < 0.75 and kerb.width_m < p.min_width_m
    gutter = _verify.paint_cues(*_paint_scene("gutter"))
    assert (
        gutter.contrast > p.min_paint_contrast
        and gutter.side_ratio > 0.9
        and gutter.foot_width_m > p.max_foot_width_m
    )
    top = _verify.paint_cues(*_paint_scene("kerb_top"))  # like paint but for the rough dark side
    assert (
        top.contrast > p.min_paint_contrast
        and p.min_width_m < top.width_m
        and top.foot_width_m < p.max_foot_width_m
    )
    assert top.side_ratio < p.min_side_ratio
    assert (
        len(
            verify(
                VerifyParams(min_side_ratio=0.0),
                lanes=[_paint_scene("kerb_top")[1]],
                image=_paint_scene("kerb_top")[0],
                geometry=_paint_scene("kerb_top")[2],
            )["lanes"]
        )
        == 1
    )
    step = _verify.paint_cues(*_paint_scene("step"))
    assert step.painted < p.min_painted_rows  # no row's centre stands above the brighter side
    dashed = _verify.paint_cues(*_paint_scene("dashed"))
    paint = _verify.paint_cues(*_paint_scene("paint"))
    assert 0.25 < dashed.painted / paint.painted < 0.45 and abs(dashed.width_m - paint.width_m) < 0.02


def test_the_texture_check_drops_an_edge_line_beside_grass():
    """Why the paint check replaced it: rough grass beside an edge line measures as a kerb's gravel."""
    img, lane, g = _paint_scene("edge_grass")
    assert verify(TEXTURE(), lanes=[lane], image=img, geometry=g)["lanes"] == []
    assert len(verify(VerifyParams(), lanes=[lane], image=img, geometry=g)["lanes"]) == 1


def test_paint_check_reads_the_near_rows_only():
    """Paint only beyond max_distance_m (25 m: BEV rows above 100 of 600) is not measured."""
    img, lane, g = _paint_scene("paint")
    img[101:, 95:106] = _road_bev()[0][101:, 95:106]
    assert verify(VerifyParams(), lanes=[lane], image=img, geometry=g)["lanes"] == []
    assert len(verify(VerifyParams(max_distance_m=40.0), lanes=[lane], image=img, geometry=g)["lanes"]) == 1


def bar_profile_twin(img, r0, r1, coeffs, band, min_contrast):
    """NumPy twin of ``_bar_profile_kernel``."""
    rows, cols = img.shape
    r = np.arange(r0, r1 + 1, 2)
    t = rows - 1 - r.astype(np.float64)
    c0, c1, c2 = coeffs
    ce = np.rint(c0 + c1 * t + c2 * t * t).astype(np.int64)
    ok = (ce - band >= 0) & (ce + band < cols)
    r, ce = r[ok], ce[ok]
    w = 2 * band + 1
    if r.size < 10:
        return np.zeros(w), 0
    strip = img[r[:, None], ce[:, None] + np.arange(-band, band + 1)[None, :]].astype(np.float64)
    strip -= strip.min(axis=1, keepdims=True)
    contrast = strip[:, band - 1 : band + 2].max(axis=1)
    painted = contrast >= max(min_contrast, 0.5 * np.percentile(contrast, 90))
    return strip[painted].mean(axis=0), int(painted.sum())


def bar_offsets_twin(profile, band, min_offset, max_bar, min_contrast):
    """NumPy twin of ``_bar_offsets_kernel``: the top-hat by sliding windows, runs by differences."""
    L = max_bar + 1
    pad = np.pad(profile, L - 1, mode="edge")
    eroded = np.lib.stride_tricks.sliding_window_view(pad, L).min(axis=1)
    opened = np.lib.stride_tricks.sliding_window_view(eroded, L).max(axis=1)
    tophat = profile - opened[: profile.size]
    ridge = tophat >= max(tophat[band - 1 : band + 2].max() / 3.0, 0.5 * min_contrast)
    out = []
    for lo, hi in ((band + min_offset, profile.size), (0, band - min_offset + 1)):
        d = np.diff(np.concatenate(([0], ridge[lo:hi].view(np.int8), [0])))
        starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        out += [0.5 * (a + b - 1) + lo - band for a, b in zip(starts, ends)]
    return np.array(out)


@pytest.mark.parametrize("band", [3, 12, 50])
def test_bar_kernels_match_twins(band):
    rng = np.random.default_rng(band)
    for shape, rows_range in [
        ((120, 150), (0, 119)),
        ((60, 2 * band + 1), (5, 59)),
        ((30, 40), (10, 12)),
        ((200, 90), (50, 40)),
    ]:
        img = rng.integers(0, 255, shape).astype(np.uint8)
        img[:, ::7] = 250  # bright stripes: painted rows and bars
        for coeffs in [(shape[1] / 2, 0.0, 0.0), (shape[1] / 2 + 0.5, 0.05, -1e-4), (3.0, 0.3, 0.0)]:
            got, n = _verify._bar_profile_kernel(img, rows_range[0], rows_range[1], *coeffs, band, 15.0)
            exp, n_exp = bar_profile_twin(img, rows_range[0], rows_range[1], coeffs, band, 15.0)
            assert n == n_exp
            np.testing.assert_allclose(got, exp, rtol=1e-12, atol=1e-9)
    for _ in range(200):
        prof = rng.normal(0, 20, 2 * band + 1)
        prof[rng.integers(0, prof.size, 3)] += 80
        mo, mb = int(rng.integers(1, band)), int(rng.integers(1, 20))
        np.testing.assert_array_equal(
            _verify._bar_offsets_kernel(prof, band, mo, mb, 15.0), bar_offsets_twin(prof, band, mo, mb, 15.0)
        )


def _bev_with_bars(cols_bars, width=10, value=200, rows=(300, 380), shape=(400, 300)):
    img = np.full(shape, 90, np.uint8)
    img += np.random.default_rng(0).integers(0, 6, shape).astype(np.uint8)  # asphalt
    for c in cols_bars:
        img[rows[0] : rows[1], c : c + width] = value
    return img


def test_crossing_pattern():
    assert _verify.crossing_pattern(np.array([20.0, -21.0]))  # a bar between two
    assert _verify.crossing_pattern(np.array([20.0, 41.0]))  # the outer bar: two on one side
    assert not _verify.crossing_pattern(np.array([-20.0, 35.0]))  # a kerb and an arrow
    assert not _verify.crossing_pattern(np.array([20.0, 30.0]))
    assert not _verify.crossing_pattern(np.array([20.0])) and not _verify.crossing_pattern(np.empty(0))


def test_verify_drops_a_crossing_bar_keeps_lane_lines():
    """A pedestrian crossing's bars (10 px = 0.5 m wide, 20 px = 1 m apart) are dropped, whichever
    bar the lane is on; a lane line alone, a double line (a second line 4 px away), a line with a
    kerb-like ridge on one side, a line with a kerb on one side and an arrow on the other, and a
    line beside a wide bright pavement are kept."""
    zebra = _bev_with_bars([60, 80, 100, 120, 140, 160])
    for c in (65.0, 105.0, 165.0):  # a bar at the edge, one inside, the last
        lane = Lane((c - 0.5, 0.0, 0.0), (300, 399), "left", 0.9)
        assert _verify.crossing_pattern(_verify.neighbour_bars(zebra, lane, 50, 12, 16, 15.0))
        # the paint check off: a bar is 0.5 m wide, wider than paint, and would be dropped anyway
        g = geometry(*zebra.shape)
        assert verify(VerifyParams(paint_check=False), lanes=[lane], image=zebra, geometry=g)["lanes"] == []
        assert (
            len(
                verify(
                    VerifyParams(paint_check=False, crossing_check=False),
                    lanes=[lane],
                    image=zebra,
                    geometry=g,
                )["lanes"]
            )
            == 1
        )
        assert (
            verify(VerifyParams(crossing_check=False), lanes=[lane], image=zebra, geometry=g)["lanes"] == []
        )
    cases = {
        "single": _bev_with_bars([145], width=4, rows=(0, 400)),
        "double": _bev_with_bars([145, 153], width=4, rows=(0, 400)),
        "kerb ridge": _bev_with_bars([145, 175], width=4, rows=(0, 400)),
        "kerb and arrow": _bev_with_bars([125, 145, 180], width=4, rows=(0, 400)),
        "pavement": _bev_with_bars([145], width=4, rows=(0, 400)),
    }
    cases["pavement"][:, 175:] = 200  # a wide bright pavement from 1.4 m on
    for name, img in cases.items():
        lane = Lane((146.5, 0.0, 0.0), (0, 399), "left", 0.9)
        assert (
            len(verify(VerifyParams(), lanes=[lane], image=img, geometry=geometry(*img.shape))["lanes"]) == 1
        ), name


def test_to_image_spacing_and_extent():
    # a homography that maps BEV (c, r) to image (2c + 10, r/2 + 100): rows shrink by half
    H = np.array([[2.0, 0, 10], [0, 0.5, 100], [0, 0, 1]])
    g = BevGeometry(-4, 4, 5, 15, 0.05, H)
    lane = Lane((40.0, 0.1, 0.0), (20, 180), "left", 0.8)
    out = to_image(ToImageParams(), lanes=[lane], geometry=g)["lanes"][0]
    y = out.points[:, 1]
    assert np.all(np.abs(np.diff(y)) <= 10) and y[0] == pytest.approx(190) and y[-1] == pytest.approx(110)
    assert np.all(np.diff(y) < 0)  # bottom first


def test_nodes_follow_the_contract():
    bev = make_bev_image(rows=60, cols=50, lane_cols=(15.0, 35.0))
    check_node_type(slt, {"image": bev})
    check_node_type(eslt, {"image": bev})
    f = eslt(EsltParams(), image=bev)["features"]
    check_node_type(orientation, {"features": f})


# ----------------------------------------------------------------------------- sparse feature maps
def _random_feature_map(shape=(37, 53), density=0.2, seed=0, oriented=True):
    rng = np.random.default_rng(seed)
    mask = rng.random(shape) < density
    ori = np.where(mask, rng.uniform(0, math.pi, shape), -1).astype(np.float32) if oriented else None
    return mask, ori


@pytest.mark.parametrize("oriented", [True, False])
def test_feature_map_sparse_dense_round_trip(oriented):
    """A map built from its points equals the dense one; mask and orientation appear only when read."""
    import copy
    import pickle

    from lanegraph.testing import _equal

    mask, ori = _random_feature_map(oriented=oriented)
    dense = FeatureMap(mask, ori)
    r, c = dense.points()
    np.testing.assert_array_equal(np.stack([r, c]), np.stack(np.nonzero(mask)))
    vals = dense.point_orientations()
    assert (vals is None) == (not oriented)
    sparse = FeatureMap.from_points(mask.shape, r, c, vals)
    assert "mask" not in vars(sparse) and "orientation" not in vars(sparse)
    assert sparse.shape == mask.shape and "mask" not in vars(sparse)  # no materialisation
    assert sparse.points()[0] is r and sparse.point_orientations() is vals
    # copies and pickles stay lazy and equal
    for twin in (copy.deepcopy(sparse), pickle.loads(pickle.dumps(sparse))):
        assert "mask" not in vars(twin)
        assert _equal(twin, dense)
    # materialised on first read, once; -1 off the points
    np.testing.assert_array_equal(sparse.mask, mask)
    assert sparse.mask is sparse.mask
    if oriented:
        np.testing.assert_array_equal(sparse.orientation, ori)
        assert sparse.orientation.dtype == np.float32
    else:
        assert sparse.orientation is None
    assert _equal(sparse, dense) and _equal(dense, sparse)
    # and back: the materialised map gives the same points again
    again = FeatureMap(sparse.mask, sparse.orientation)
    np.testing.assert_array_equal(again.points()[1], c)


def test_feature_map_from_points_validates_and_keeps_dense_companions():
    with pytest.raises(ValueError, match="rows and cols"):
        FeatureMap.from_points((4, 4), np.arange(3), np.arange(2))
    with pytest.raises(ValueError, match="orientation_values"):
        FeatureMap.from_points((4, 4), np.arange(3), np.arange(3), np.zeros(2))
    with pytest.raises(AttributeError):
        FeatureMap.from_points((4, 4), np.arange(3), np.arange(3)).nothing  # noqa: B018
    mask, ori = _random_feature_map(seed=3)
    r, c = np.nonzero(mask)
    fm = FeatureMap.from_points(mask.shape, r, c, ori[r, c], mask=mask, orientation=ori)
    assert fm.mask is mask and fm.orientation is ori
    empty = FeatureMap.from_points((5, 6), np.zeros(0, int), np.zeros(0, int), np.zeros(0, np.float32))
    assert empty.mask.shape == (5, 6) and not empty.mask.any() and (empty.orientation == -1).all()


@pytest.mark.parametrize("dense", [True, False])
def test_feature_map_select(dense):
    mask, ori = _random_feature_map(seed=5)
    r, c = np.nonzero(mask)
    fm = FeatureMap(mask, ori) if dense else FeatureMap.from_points(mask.shape, r, c, ori[r, c])
    keep = np.random.default_rng(1).random(r.size) < 0.5
    sub = fm.select(keep)
    ref = np.zeros_like(mask)
    ref[r[keep], c[keep]] = True
    np.testing.assert_array_equal(sub.mask, ref)
    np.testing.assert_array_equal(sub.orientation, np.where(ref, ori, np.float32(-1)))
    assert FeatureMap(mask).select(keep).orientation is None


@pytest.mark.parametrize("cols", [48, 53, 8, 1])
@pytest.mark.parametrize("oriented", [True, False])
def test_feature_map_points_match_nonzero(cols, oriented):
    """The feature nodes' points, gathered once with the map, against np.nonzero."""
    for seed, density in ((0, 0.0), (1, 0.02), (2, 0.5), (3, 1.0)):
        mask, ori = _random_feature_map((23, cols), density, seed, oriented)
        fm = _features._feature_map(mask.astype(np.uint8), ori)
        r, c = np.nonzero(mask)
        np.testing.assert_array_equal(fm.points()[0], r)
        np.testing.assert_array_equal(fm.points()[1], c)
        if oriented:
            np.testing.assert_array_equal(fm.point_orientations(), ori[r, c])
        else:
            assert fm.point_orientations() is None
        np.testing.assert_array_equal(fm.mask, mask)


@pytest.mark.parametrize("node", [slt, eslt])
def test_feature_nodes_carry_their_points(node):
    bev = make_bev_image(rows=60, cols=50, lane_cols=(15.0, 35.0))
    f = node(node_type_of(node).params(), image=bev)["features"]
    ref = FeatureMap(np.array(f.mask), None if f.orientation is None else np.array(f.orientation))
    for a, b in zip(f.points(), ref.points()):
        np.testing.assert_array_equal(a, b)
    if f.orientation is not None:
        np.testing.assert_array_equal(f.point_orientations(), ref.point_orientations())


def mask_features_twin(features, mask, temporal, erode_px):
    """The dense features.mask it replaced: eroded road mask, logical and, masked orientation copy."""
    keep = np.asarray(mask, bool)
    if erode_px > 0:
        k = 2 * erode_px + 1
        keep = cv2.erode(keep.astype(np.uint8), np.ones((k, k), np.uint8), borderValue=0).astype(bool)
    m = np.asarray(features.mask, bool) & keep
    if temporal is not None:
        m &= np.asarray(temporal, bool)
    ori = (
        None
        if features.orientation is None
        else np.where(m, np.asarray(features.orientation, np.float32), np.float32(-1))
    )
    return m, ori


@pytest.mark.parametrize("erode_px", [0, 1, 4])
@pytest.mark.parametrize("oriented", [True, False])
def test_mask_features_sparse_equals_dense_twin(erode_px, oriented):
    from lanegraph.testing import _equal

    rng = np.random.default_rng(erode_px)
    mask, ori = _random_feature_map((41, 30), 0.3, erode_px, oriented)
    road = rng.random(mask.shape) < 0.9
    road[:, :3] = False
    temporal = rng.random(mask.shape) < 0.7
    for tm in (temporal, None):
        for fm in (FeatureMap(mask, ori), _features._feature_map(mask.astype(np.uint8), ori)):
            out = mask_features(MaskParams(erode_px=erode_px), features=fm, mask=road, temporal=tm)[
                "features"
            ]
            assert "mask" not in vars(out)  # sparse: nothing dense made
            m, o = mask_features_twin(fm, road, tm, erode_px)
            np.testing.assert_array_equal(out.mask, m)
            if oriented:
                assert out.orientation.dtype == np.float32
                np.testing.assert_array_equal(out.orientation, o)
            else:
                assert out.orientation is None
            assert _equal(out, FeatureMap(m, o))
    # a float64 orientation map: float32 out, as before
    f64 = FeatureMap(mask, np.where(mask, 1.2345678912345, -1.0))
    out = mask_features(MaskParams(erode_px=erode_px), features=f64, mask=road)["features"]
    assert out.point_orientations().dtype == np.float32


def test_orientation_reads_sparse_and_dense_maps_alike():
    f = features_for([50.0, 110.0])
    r, c = f.points()
    sparse = FeatureMap.from_points(f.shape, r, c, f.point_orientations())
    p = OrientationParams()
    assert orientation(p, features=sparse)["orientation"] == orientation(p, features=f)["orientation"]
    assert "orientation" not in vars(sparse)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("nb", [1, 7, 70, 140])
def test_uniform_histogram_is_np_histogram(dtype, nb):
    """Counts and edges bit for bit, also for values exactly on the edges and at both ends."""
    lo, hi = math.radians(55), math.radians(125)
    rng = np.random.default_rng(nb)
    edges = np.linspace(lo, hi, nb + 1, dtype=dtype)
    for n in (0, 1, 50, 3000):
        v = rng.uniform(lo, hi, n).astype(dtype)
        v = np.concatenate(
            [v, edges, [dtype(lo), dtype(hi)], np.nextafter(edges, dtype(0)), np.nextafter(edges, dtype(10))]
        )
        v = v[(v >= lo) & (v <= hi)]  # as the node filters them
        hist, e = _hough.uniform_histogram(v, lo, hi, nb)
        ref_hist, ref_e = np.histogram(v, bins=nb, range=(lo, hi))
        np.testing.assert_array_equal(hist, ref_hist)
        assert hist.dtype == ref_hist.dtype
        np.testing.assert_array_equal(e, ref_e)
        assert e.dtype == ref_e.dtype
    ints = np.arange(10)
    np.testing.assert_array_equal(
        _hough.uniform_histogram(ints, 0.0, 9.0, 3)[0], np.histogram(ints, 3, (0.0, 9.0))[0]
    )


def find_peaks_twin(acc, min_separation, min_value):
    """The peak search it replaced: all peaks by a full stable sort, then those reaching min_value."""
    if acc.size == 0 or acc.max() <= 0:
        return []
    taken, suppressed = [], np.zeros(acc.size, bool)
    for i in np.argsort(-acc, kind="stable"):
        if acc[i] <= 0:
            break
        if not suppressed[i]:
            taken.append(int(i))
            suppressed[max(0, i - min_separation) : i + min_separation + 1] = True
    return [i for i in taken if acc[i] >= min_value]


def test_find_peaks_with_min_value_matches_twin():
    rng = np.random.default_rng(4)
    for trial in range(200):
        acc = np.round(rng.random(rng.integers(1, 300)) * 20) * (rng.random() < 0.9)  # ties, zeros
        acc = _hough._smooth(acc, 2.0) if trial % 2 else acc
        for sep in (1, 5, 24):
            for mv in (0.0, 3.0, 10.0, 40.0):
                assert _hough.find_peaks(acc, sep, mv) == find_peaks_twin(acc, sep, mv)


def test_side_band_kernel_writes_only_its_columns():
    from lanegraph_lanes._temporal import _side_band_kernel

    rows, cols = 30, 40
    band = np.zeros((rows, cols), bool)
    band[:, 20:] = True  # the other side's columns, already written
    lcols = np.full((1, rows), 18.0)
    none = np.zeros(0, np.int64)
    assert _side_band_kernel(lcols, 0, 20, 5.0, none, none, band) == (0, 0)
    assert band[:, 20:].all() and band[:, 13:20].all() and not band[:, :13].any()


def test_temporal_mask_rejects_features_of_another_shape():
    g = geometry()
    lane = Lane((80.0, 0.0, 0.0), (0, 199), "right", 0.9)
    with pytest.raises(InputError, match="features"):
        temporal_mask(
            TemporalParams(), geometry=g, previous=[lane], features=FeatureMap(np.zeros((10, 10), bool))
        )


def to_image_twin(lane, geometry, row_step, w=None, h=None):
    """The ordering it replaced: sort by image row, np.unique, interpolate (the projected points
    from the node's own :func:`image_points`)."""
    pts = image_points(lane, geometry, w, h)
    if len(pts) < 2:
        return None
    order = np.argsort(-pts[:, 1])
    x, y = pts[order, 0], pts[order, 1]
    y_uniq, idx = np.unique(y, return_index=True)
    ys = np.append(np.arange(y_uniq[-1], y_uniq[0], -row_step), y_uniq[0])
    return np.stack([np.interp(ys, y_uniq, x[idx]), ys], axis=1)


@pytest.mark.parametrize(
    "H",
    [
        np.array([[2.0, 0, 10], [0, 0.5, 100], [0, 0, 1]]),  # y grows with the row (the usual case)
        np.array([[2.0, 0, 10], [0, -0.5, 300], [0, 0, 1]]),  # y falls with the row
        np.array([[2.0, 0, 10], [0.8, 0.3, 100], [0, 0, 1]]),  # y depends on the column: a curve turns it
        np.array([[1.0, 0, 0], [0, 0, 100], [0, 0, 1]]),  # every point on one image row
    ],
)
def test_to_image_matches_sort_unique_twin(H):
    g = BevGeometry(-4, 4, 5, 15, 0.05, H)
    lanes = [
        Lane((40.0, 0.1, 0.0), (20, 180), "left", 0.8),
        Lane((120.0, -0.9, 0.004), (0, 199), "right", 0.5),
    ]
    out = to_image(ToImageParams(), lanes=lanes, geometry=g)["lanes"]
    ref = [p for p in (to_image_twin(ln, g, 5.0) for ln in lanes) if p is not None]
    assert len(out) == len(ref)
    for ln, p in zip(out, ref):
        np.testing.assert_array_equal(ln.points, p)


def test_eslt_node_dense_orientation_is_minus_one_off_the_features():
    """The node writes no dense map; the map's dense mask and orientation, built on first read,
    are the kernel's features (-1 where no feature)."""
    img = make_bev_image(rows=60, cols=50, lane_cols=(15.0, 35.0), noise=6.0, seed=2)
    f = eslt(EsltParams(), image=img)["features"]
    gx, gy = cv2.spatialGradient(np.ascontiguousarray(img, dtype=np.uint8), ksize=3)
    p = EsltParams()
    mask, ori, _ = eslt_maps(
        img.astype(np.uint8), gx, gy, p.window, float(p.threshold), math.radians(p.max_angle_deg)
    )
    assert mask.any()
    np.testing.assert_array_equal(f.mask, mask.view(bool))
    np.testing.assert_array_equal(f.orientation, ori)


@pytest.mark.parametrize("threads", [1, 3, 7])
def test_eslt_gives_the_same_maps_on_any_number_of_threads(threads, monkeypatch):
    img = make_bev_image(rows=150, cols=120, lane_cols=(40.0, 80.0), noise=8)
    gx, gy = cv2.spatialGradient(img, ksize=3)
    where = np.zeros(img.shape, np.uint8)
    where[20:140, 5:115] = 1
    maps = []
    for n in (2, threads):
        monkeypatch.setattr(_features, "_threads", lambda n=n: n)
        mask, ori, points = eslt_maps(img, gx, gy, 6, 10.0, math.radians(15), where)
        maps.append((mask, ori, *points))
    assert maps[0][0].any() and set(np.unique(maps[0][0])) <= {0, 1}  # every row written
    for a, b in zip(maps[0], maps[1]):  # the maps and the features' list, blocks joined in order
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(np.stack(maps[1][2:4]), np.stack(np.nonzero(maps[1][0])))
