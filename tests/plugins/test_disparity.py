"""The disparity backends (plugins/lanegraph_disparity).

Every numba kernel of ``disparity.sgm`` is compared with a slow, obvious NumPy twin on
small random inputs and edge cases. The backends are checked on synthetic pairs with a
known shift, the file backend by round trips, and SGBM on a real KITTI frame.
"""

from __future__ import annotations

import cv2
import lanegraph_disparity as ld
import numba
import numpy as np
import pytest
from lanegraph_disparity import _common, _sgm
from pydantic import ValidationError

from lanegraph import InputError, node_type_of

# --------------------------------------------------------------------------- NumPy twins


def census_ref(img: np.ndarray, win_h: int, win_w: int) -> np.ndarray:
    """Census by padding with the border value and comparing shifted copies."""
    h, w = img.shape
    rh, rw = win_h // 2, win_w // 2
    pad = np.pad(img, ((rh, rh), (rw, rw)), mode="edge")
    code = np.zeros((h, w), np.uint64)
    for dy in range(-rh, rh + 1):
        for dx in range(-rw, rw + 1):
            if dy == 0 and dx == 0:
                continue
            nb = pad[rh + dy : rh + dy + h, rw + dx : rw + dx + w]
            code = (code << np.uint64(1)) | (nb < img).astype(np.uint64)
    return code


def popcount_ref(x: np.ndarray) -> np.ndarray:
    bits = np.unpackbits(
        np.ascontiguousarray(x, dtype=np.uint64).view(np.uint8).reshape(*x.shape, 8), axis=-1
    )
    return bits.sum(axis=-1)


def cost_volume_ref(cl: np.ndarray, cr: np.ndarray, num_disp: int, invalid_cost: int) -> np.ndarray:
    h, w = cl.shape
    cost = np.full((h, w, num_disp), invalid_cost, np.int64)
    for d in range(num_disp):
        if d < w:
            cost[:, d:, d] = popcount_ref(cl[:, d:] ^ cr[:, : w - d])
    return cost


def path_ref(cost: np.ndarray, d_row: int, d_col: int, p1: int, p2: int) -> np.ndarray:
    """L_r of one direction by the textbook recursion, pixel by pixel in path order."""
    h, w, n = cost.shape
    c64 = cost.astype(np.int64)
    out = np.zeros((h, w, n), np.int64)
    rows = range(h) if d_row >= 0 else range(h - 1, -1, -1)
    cols = list(range(w) if d_col >= 0 else range(w - 1, -1, -1))
    for r in rows:
        for c in cols:
            pr, pc = r - d_row, c - d_col
            if not (0 <= pr < h and 0 <= pc < w):
                out[r, c] = c64[r, c]
                continue
            prev = out[pr, pc]
            m = prev.min()
            best = np.minimum(prev, m + p2)
            if n > 1:
                best[1:] = np.minimum(best[1:], prev[:-1] + p1)
                best[:-1] = np.minimum(best[:-1], prev[1:] + p1)
            out[r, c] = c64[r, c] + best - m
    return out


def wta_ref(total: np.ndarray, uniqueness: int, subpixel: bool, right_view: bool) -> np.ndarray:
    h, w, n = total.shape
    out = np.zeros((h, w), np.float32)
    for r in range(h):
        for c in range(w):
            if right_view:
                s = np.array([int(total[r, c + d, d]) for d in range(min(n, w - c))], np.int64)
            else:
                s = total[r, c].astype(np.int64)
            best = int(np.argmin(s))  # first minimum, like the kernel
            far = np.abs(np.arange(s.size) - best) > 1
            if uniqueness > 0 and np.any(s[far] * (100 - uniqueness) < s[best] * 100):
                continue
            disp = float(best)
            if subpixel and 0 < best < s.size - 1:
                a, b = s[best - 1], s[best + 1]
                denom = a + b - 2 * s[best]
                if denom > 0:
                    disp += (a - b) / (2.0 * denom)
            out[r, c] = disp
    return out


# --------------------------------------------------------------------------- helpers


def shifted_pair(shift: int, h: int = 40, w: int = 64, smooth: int = 1, seed: int = 0):
    """A random texture and the same texture seen with disparity ``shift`` everywhere.

    ``right[:, x] == left[:, x + shift]``: left pixel ``x`` matches right pixel ``x - shift``.
    ``smooth > 1`` draws the noise ``smooth`` times coarser and upsamples it (cubic).
    """
    rng = np.random.default_rng(seed)
    tw = w + shift
    if smooth > 1:
        tex = rng.integers(0, 256, (h // smooth, tw // smooth), dtype=np.uint8)
        tex = cv2.resize(tex, (tw, h), interpolation=cv2.INTER_CUBIC)
    else:
        tex = rng.integers(0, 256, (h, tw), dtype=np.uint8)
    return np.ascontiguousarray(tex[:, :w]), np.ascontiguousarray(tex[:, shift : shift + w])


#: (id, node type, params) of every computing backend, sized for small test images
BACKENDS = [
    ("sgbm", ld.sgbm, ld.SgbmParams(num_disparities=16)),
    ("sgbm-3way", ld.sgbm, ld.SgbmParams(num_disparities=16, mode="3way")),
    ("bm", ld.bm, ld.BmParams(num_disparities=16, block_size=9)),
    ("sgm", ld.sgm, ld.SgmParams(num_disparities=16)),
    ("sgm-4paths", ld.sgm, ld.SgmParams(num_disparities=16, paths=4, census_width=5, census_height=5)),
]


def run(node, params, left, right, **update) -> np.ndarray:
    out = node(params.model_copy(update=update) if update else params, left, right)["disparity"]
    assert out.dtype == np.float32 and out.shape == left.shape[:2]
    assert np.all(np.isfinite(out)) and np.all(out >= 0)
    return out


# --------------------------------------------------------------------------- kernels vs twins


def test_popcount_matches_bit_counting():
    rng = np.random.default_rng(1)
    xs = rng.integers(0, 2**63, 200, dtype=np.uint64) * np.uint64(2) + rng.integers(
        0, 2, 200, dtype=np.uint64
    )
    xs[:3] = [np.uint64(0), np.uint64(2**64 - 1), np.uint64(2**63)]
    got = [int(_sgm._popcount64(x)) for x in xs]
    assert got == [bin(int(x)).count("1") for x in xs]


@pytest.mark.parametrize(
    "shape, win",
    [
        ((12, 17), (7, 9)),  # the default window
        ((9, 11), (5, 5)),
        ((3, 4), (7, 9)),  # window wider and taller than the image
        ((1, 6), (3, 3)),  # a single row
        ((5, 1), (3, 5)),  # a single column
    ],
)
def test_census_matches_reference(shape, win):
    img = np.random.default_rng(sum(shape)).integers(0, 256, shape, dtype=np.uint8)
    np.testing.assert_array_equal(_sgm._census(img, *win), census_ref(img, *win))


def test_census_of_constant_image_is_zero():
    img = np.full((6, 8), 77, np.uint8)
    assert not _sgm._census(img, 7, 9).any()


@pytest.mark.parametrize("shape, num_disp", [((6, 20), 8), ((4, 5), 9), ((3, 1), 4), ((5, 12), 1)])
def test_cost_volume_matches_reference(shape, num_disp):
    rng = np.random.default_rng(num_disp)
    cl = census_ref(rng.integers(0, 256, shape, dtype=np.uint8), 7, 9)
    cr = census_ref(rng.integers(0, 256, shape, dtype=np.uint8), 7, 9)
    got = _sgm._cost_volume(cl, cr, num_disp, 62)
    assert got.dtype == np.uint8 and got.shape == (*shape, num_disp)
    np.testing.assert_array_equal(got, cost_volume_ref(cl, cr, num_disp, 62))


def test_cost_volume_with_more_disparities_than_columns_fills_invalid_cost():
    cl = census_ref(np.random.default_rng(2).integers(0, 256, (3, 4), dtype=np.uint8), 3, 3)
    got = _sgm._cost_volume(cl, cl, 10, 8)
    assert np.all(got[:, :, 4:] == 8)
    assert np.all(got[:, :, 0] == 0)  # identical images match at d = 0


@pytest.mark.parametrize("direction", _sgm.DIRECTIONS_8)
@pytest.mark.parametrize("shape", [(5, 7, 6), (1, 6, 4), (6, 1, 3), (4, 5, 1)])
def test_aggregate_path_matches_reference(direction, shape):
    rng = np.random.default_rng(shape[0] * 10 + shape[1])
    cost = rng.integers(0, 63, shape, dtype=np.uint8)
    start = rng.integers(0, 100, shape).astype(np.uint16)
    total = start.copy()
    _sgm._aggregate_path(cost, direction[0], direction[1], 7, 40, total)
    expected = start.astype(np.int64) + path_ref(cost, direction[0], direction[1], 7, 40)
    np.testing.assert_array_equal(total.astype(np.int64), expected)


def test_aggregate_path_of_constant_cost_is_constant():
    cost = np.full((4, 6, 5), 3, np.uint8)
    total = np.zeros(cost.shape, np.uint16)
    _sgm._aggregate_path(cost, 1, -1, 5, 50, total)
    assert np.all(total == 3)  # no disparity change is ever cheaper than staying


@pytest.mark.parametrize("uniqueness", [0, 15])
@pytest.mark.parametrize("subpixel", [False, True])
@pytest.mark.parametrize("right_view", [False, True])
def test_wta_matches_reference(uniqueness, subpixel, right_view):
    rng = np.random.default_rng(uniqueness + 2 * subpixel + 4 * right_view)
    total = rng.integers(0, 400, (5, 9, 7)).astype(np.uint16)
    total[0, 0] = 50  # a tie everywhere: the first minimum, d = 0, is invalid
    total[1, 1, 3] = 0  # a clear winner with a sub-pixel neighbourhood
    got = _sgm._wta(total, uniqueness, subpixel, right_view)
    np.testing.assert_allclose(got, wta_ref(total, uniqueness, subpixel, right_view), rtol=0, atol=1e-6)


def test_wta_subpixel_is_the_parabola_vertex():
    d = np.arange(7, dtype=np.float64)
    costs = np.round(5 * (d - 3.3) ** 2 + 10).astype(np.uint16)  # sampled parabola, minimum at 3.3
    got = _sgm._wta(costs.reshape(1, 1, 7), 0, True, False)[0, 0]
    assert abs(got - 3.3) < 0.15


def test_wta_uniqueness_rejects_a_distant_second_minimum():
    s = np.array([90, 40, 90, 90, 41, 90], np.uint16).reshape(1, 1, 6)
    assert _sgm._wta(s, 0, False, False)[0, 0] == 1.0
    assert _sgm._wta(s, 10, False, False)[0, 0] == 0.0


# --------------------------------------------------------------------------- common helpers


def test_lr_consistency_keeps_consistent_and_drops_the_rest():
    dl = np.array([[0.0, 1.0, 2.0, 2.0, 5.0, 3.0, 1.0]], np.float32)
    dr = np.array([[1.0, 9.0, 2.0, 0.0, 3.0, 3.0, -1.0]], np.float32)
    got = _common.lr_consistency(dl, dr, 0.5)
    # x=1 -> xr=0 (dr 1, ok); x=2 -> xr=0 (dr 1, off by 1); x=3 -> xr=1 (dr 9, off);
    # x=4 -> xr=-1 (outside); x=5 -> xr=2 (dr 2, off by 1); x=6 -> xr=5 (3 vs 1, off)
    np.testing.assert_array_equal(got, [[0, 1, 0, 0, 0, 0, 0]])
    assert _common.lr_consistency(dl, dr, 1.0)[0, 2] == 2.0
    # right pixels marked -1 (not evaluable) keep their left pixel
    dl2 = np.array([[0, 0, 0, 0, 0, 0, 0, 2]], np.float32)
    dr2 = np.array([[0, 0, 0, 0, 0, -1, -1, -1]], np.float32)
    assert _common.lr_consistency(dl2, dr2, 0.5)[0, 7] == 2.0


@pytest.mark.parametrize("mode", ["nearest", "linear"])
def test_upsample_keeps_invalid_zero_and_scales_values(mode):
    d = np.full((4, 6), 3.0, np.float32)
    d[1:3, 2:4] = 0.0  # a hole
    up = _common.upsample_disparity(d, (8, 12), 0.5, mode)
    assert up.shape == (8, 12) and up.dtype == np.float32
    assert set(np.unique(up)) == {0.0, 6.0}  # never a blend of hole and value
    assert (up == 0).sum() == 16


@pytest.mark.parametrize("mode", ["nearest", "linear"])
def test_upsample_is_the_old_formula(mode):
    """The nearest path scales the small map before copying it: the same floats as scaling the
    copy (a NumPy twin: np.repeat), zeros and negatives cleared to 0."""
    rng = np.random.default_rng(2)
    d = (rng.random((9, 13)) * 40 - 4).astype(np.float32)  # some negatives: cleared
    d[2:4, 5:9] = 0.0
    up = _common.upsample_disparity(d, (18, 26), 0.5, mode)
    if mode == "nearest":
        twin = np.repeat(np.repeat(d, 2, axis=0), 2, axis=1) * np.float32(2.0)
        twin[twin <= 0] = 0.0
        np.testing.assert_array_equal(up, twin)
    assert up.dtype == np.float32 and (up >= 0).all()
    assert (up[::2, ::2][d > 0] > 0).all()


def test_reduce_pair_resizes_by_area_and_says_the_factor():
    rng = np.random.default_rng(3)
    gl = rng.integers(0, 256, (31, 50), dtype=np.uint8)
    gr = np.ascontiguousarray(gl[::-1])
    sl, sr, s = _common.reduce_pair(gl, gr, 0.5)
    assert sl.shape == sr.shape == (16, 25) and s == 0.5  # round(15.5) rows, 25 columns
    np.testing.assert_array_equal(sl, cv2.resize(gl, (25, 16), interpolation=cv2.INTER_AREA))
    np.testing.assert_array_equal(sr, cv2.resize(gr, (25, 16), interpolation=cv2.INTER_AREA))
    assert _common.reduce_pair(gl, gr, 0.3)[2] == pytest.approx(15 / 50)  # round(50 * 0.3) columns
    same = _common.reduce_pair(gl, gr, 1.0)
    assert same[0] is gl and same[1] is gr and same[2] == 1.0


def test_scaled_disparities_rounds_up_to_the_multiple():
    assert _common.scaled_disparities(128, 0.5, 16) == 64
    assert _common.scaled_disparities(128, 0.3, 16) == 48
    assert _common.scaled_disparities(16, 0.25, 16) == 16
    assert _common.scaled_disparities(100, 0.25) == 25


# --------------------------------------------------------------------------- backends


@pytest.mark.parametrize("name, node, params", BACKENDS, ids=[b[0] for b in BACKENDS])
def test_backend_recovers_a_known_shift(name, node, params):
    left, right = shifted_pair(7)
    out = run(node, params, left, right)
    margin = 5  # half of the largest window
    interior = out[margin:-margin, 16 + margin : -margin]
    assert np.mean(np.abs(interior - 7) < 0.5) >= 0.9, name


@pytest.mark.parametrize("name, node, params", BACKENDS, ids=[b[0] for b in BACKENDS])
def test_backend_accepts_bgr_like_gray(name, node, params):
    left, right = shifted_pair(5, seed=3)
    bgr = [cv2.cvtColor(x, cv2.COLOR_GRAY2BGR) for x in (left, right)]
    np.testing.assert_array_equal(run(node, params, *bgr), run(node, params, left, right))


@pytest.mark.parametrize("name, node, params", BACKENDS, ids=[b[0] for b in BACKENDS])
def test_backend_at_half_scale_matches_full_resolution(name, node, params):
    left, right = shifted_pair(8, h=64, w=128, smooth=2, seed=5)
    full = run(node, params, left, right)
    half = run(node, params, left, right, scale=0.5, upsample="linear")
    interior = (slice(8, -8), slice(2 * 16 + 8, -8))  # 16 disparities at half scale cover 32 columns
    both = (full[interior] > 0) & (half[interior] > 0)
    assert both.mean() >= 0.5, name
    assert np.median(np.abs(half[interior] - full[interior])[both]) < 0.5, name
    assert np.mean(np.abs(half[interior][both] - 8) < 1.0) >= 0.9, name  # values in input pixels


@pytest.mark.parametrize("name, node, params", BACKENDS, ids=[b[0] for b in BACKENDS])
def test_lr_check_only_removes_pixels(name, node, params):
    left, right = shifted_pair(7, seed=4)
    plain = run(node, params, left, right)
    checked = run(node, params, left, right, lr_check=True)
    kept = checked > 0
    np.testing.assert_array_equal(checked[kept], plain[kept])
    cols = np.broadcast_to(np.arange(left.shape[1]), kept.shape)
    assert np.all(cols[kept] - np.rint(checked[kept]) >= 0)  # no kept match outside the right image
    assert kept[:, :7].mean() < 0.5 * kept[:, 7:].mean()  # the occluded left strip is mostly dropped
    assert np.mean(np.abs(checked[5:-5, 21:-5] - 7) < 0.5) >= 0.9, name


def test_sgm_lr_check_invalidates_an_occlusion():
    """A near square in front of a far background: the background strip it hides in the right view."""
    rng = np.random.default_rng(6)
    h, w, far, near = 40, 80, 4, 12
    back = rng.integers(0, 256, (h, w + far), dtype=np.uint8)
    front = rng.integers(0, 256, (16, 20 + near), dtype=np.uint8)
    left, right = back[:, :w].copy(), back[:, far : far + w].copy()
    left[12:28, 40:60] = front[:, :20]
    right[12:28, 40 - near : 60 - near] = front[:, :20]
    params = ld.SgmParams(num_disparities=16)
    plain = run(ld.sgm, params, left, right)
    checked = run(ld.sgm, params, left, right, lr_check=True)
    assert np.median(plain[14:26, 44:56]) == pytest.approx(near, abs=0.5)
    # the background just left of the square is hidden behind it in the right view
    occluded = (slice(14, 26), slice(40 - (near - far) + 1, 40 - 1))
    assert np.mean(checked[occluded] == 0) >= 0.7
    assert np.mean(checked[occluded] == 0) > np.mean(plain[occluded] == 0)


def test_constant_images_give_no_disparity_with_sgm():
    img = np.full((20, 40), 120, np.uint8)
    assert not run(ld.sgm, ld.SgmParams(num_disparities=8), img, img).any()


@pytest.mark.parametrize("name, node, params", BACKENDS, ids=[b[0] for b in BACKENDS])
def test_constant_images_are_finite(name, node, params):
    img = np.full((24, 48), 90, np.uint8)
    out = run(node, params, img, img)
    assert np.mean(out > 0) <= 1.0  # run() checked dtype, shape, finiteness, >= 0


def test_sgm_with_more_disparities_than_columns_runs():
    left, right = shifted_pair(3, h=12, w=10, seed=7)
    out = run(ld.sgm, ld.SgmParams(num_disparities=32, census_width=3, census_height=3), left, right)
    assert out.max() < 10


@pytest.mark.parametrize("node, params", [(ld.sgbm, ld.SgbmParams()), (ld.bm, ld.BmParams())])
def test_opencv_too_narrow_for_the_range_is_an_input_error(node, params):
    left, right = shifted_pair(3, h=30, w=100)
    with pytest.raises(InputError, match="num_disparities"):
        node(params, left, right)


def test_mismatched_pair_is_an_input_error():
    left, _ = shifted_pair(3)
    with pytest.raises(InputError, match=r"left 40x64, right 40x60"):
        ld.sgm(ld.SgmParams(num_disparities=8), left, left[:, :60])


def test_wrong_image_shape_is_an_input_error():
    with pytest.raises(InputError, match="input 'right'"):
        ld.bm(ld.BmParams(num_disparities=16), np.zeros((40, 64), np.uint8), np.zeros((40, 64, 2), np.uint8))


@pytest.mark.parametrize(
    "node, params",
    [(ld.sgbm, ld.SgbmParams(num_disparities=16)), (ld.bm, ld.BmParams(num_disparities=16, block_size=9))],
)
def test_wls_keeps_a_known_shift(node, params):
    left, right = shifted_pair(7, seed=8)
    plain = run(node, params, left, right)
    filtered = run(node, params, left, right, wls=True)
    interior = (slice(5, -5), slice(21, -5))
    assert np.mean(np.abs(filtered[interior] - 7) < 0.5) >= 0.9
    assert not np.array_equal(filtered, plain)


def test_wls_without_ximgproc_says_what_is_missing(monkeypatch):
    monkeypatch.delattr(cv2, "ximgproc", raising=False)
    left, right = shifted_pair(7)
    with pytest.raises(RuntimeError, match="cv2.ximgproc"):
        ld.sgbm(ld.SgbmParams(num_disparities=16, wls=True), left, right)
    ld.sgbm(ld.SgbmParams(num_disparities=16), left, right)  # without wls it is not needed


# --------------------------------------------------------------------------- params


@pytest.mark.parametrize(
    "model, values, message",
    [
        (ld.SgbmParams, {"num_disparities": 100}, "multiple of 16"),
        (ld.BmParams, {"num_disparities": 40}, "hint: use 32 or 48"),
        (ld.SgbmParams, {"block_size": 4}, "odd"),
        (ld.BmParams, {"prefilter_size": 10}, "odd"),
        (ld.SgmParams, {"census_width": 8}, "census_width: expected an odd"),
        (ld.SgmParams, {"census_width": 9, "census_height": 9}, "80 bits"),
        (ld.SgmParams, {"paths": 6}, "4 or 8"),
        (ld.SgmParams, {"median_size": 4}, "0 \\(off\\), 3 or 5"),
        (ld.SgbmParams, {"p1": 500, "p2": 400}, "p2 \\(400\\) must be greater than p1 \\(500\\)"),
        (ld.SgbmParams, {"p1": 900}, "p2 \\(800\\)"),  # auto p2 for block 5 is 800
        (ld.SgmParams, {"p1": 50, "p2": 20}, "p2"),
        (ld.SgbmParams, {"scale": 0.1}, "greater than or equal to 0.25"),
        (ld.SgbmParams, {"mode": "fast"}, "'sgbm', '3way', 'hh' or 'hh4'"),
        (ld.SgmParams, {"blocksize": 5}, "Extra inputs are not permitted"),
        (ld.FileParams, {}, "dir"),
    ],
)
def test_params_reject_bad_values_with_a_clear_message(model, values, message):
    with pytest.raises(ValidationError, match=message):
        model(**values)


def test_sgbm_auto_penalties_follow_block_size():
    assert ld.SgbmParams(block_size=3).penalties() == (72, 288)
    assert ld.SgbmParams(block_size=3, p1=10, p2=0).penalties() == (10, 288)


@pytest.mark.parametrize("model", [ld.SgbmParams, ld.BmParams, ld.SgmParams, ld.FileParams, ld.OnnxParams])
def test_every_param_is_documented_and_bounded(model):
    for name, f in model.model_fields.items():
        assert f.description and len(f.description) > 10, f"{model.__name__}.{name}"
        if f.annotation in (int, float):
            bounds = {type(m).__name__ for m in f.metadata}
            assert {"Ge", "Le"} <= bounds, f"{model.__name__}.{name} lacks ge/le bounds"


def test_plugin_registers_the_six_backends():
    types = {t.name: t for t in map(node_type_of, ld.lanegraph_node_types())}
    assert set(types) == {
        "disparity.sgbm",
        "disparity.road_sgbm",
        "disparity.bm",
        "disparity.sgm",
        "disparity.file",
        "disparity.onnx",
    }
    for t in types.values():
        assert t.outputs["disparity"].type == "disparity"
        assert t.inputs["left"].type == "image" and t.inputs["right"].type == "image"
        assert ("frame" in t.inputs) == (t.name == "disparity.file")
        assert t.summary
    assert types["disparity.file"].inputs["frame"].optional
    assert types["disparity.sgm"].params is ld.SgmParams
    assert types["disparity.onnx"].params is ld.OnnxParams and types["disparity.onnx"].stateful


# --------------------------------------------------------------------------- file backend


def test_file_backend_reads_a_kitti_png(tmp_path):
    rng = np.random.default_rng(9)
    disp = np.round(rng.uniform(0, 100, (20, 30)) * 256) / 256
    disp[3:6, 4:9] = 0
    assert cv2.imwrite(str(tmp_path / "0000000007.png"), np.round(disp * 256).astype(np.uint16))
    left = np.zeros((20, 30, 3), np.uint8)
    out = ld.file(ld.FileParams(dir=str(tmp_path)), left, None, frame="0000000007")["disparity"]
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, disp, atol=1e-6)
    assert not out[3:6, 4:9].any()


def test_file_backend_reads_npy_and_invalidates_nan(tmp_path):
    disp = np.linspace(1, 50, 12 * 16, dtype=np.float64).reshape(12, 16)
    disp[0, 0], disp[1, 1] = np.nan, -3.0
    np.save(tmp_path / "f1.npy", disp)
    out = ld.file(ld.FileParams(dir=str(tmp_path)), np.zeros((12, 16), np.uint8), frame="f1")["disparity"]
    assert out.dtype == np.float32 and out[0, 0] == 0 and out[1, 1] == 0
    np.testing.assert_allclose(out[2:], disp[2:], rtol=1e-6)


def test_file_backend_wrong_size_names_file_and_frame(tmp_path):
    cv2.imwrite(str(tmp_path / "0000000003.png"), np.ones((20, 30), np.uint16) * 256)
    with pytest.raises(InputError, match=r"20x30 .* left image is 375x1242") as err:
        ld.file(ld.FileParams(dir=str(tmp_path)), np.zeros((375, 1242, 3), np.uint8), frame="0000000003")
    assert err.value.path == str(tmp_path / "0000000003.png") and err.value.frame == "0000000003"
    assert "0000000003.png" in str(err.value) and "frame 0000000003" in str(err.value)


@pytest.mark.parametrize(
    "image, message",
    [
        (np.ones((20, 30), np.uint8), "16-bit"),
        (np.ones((20, 30, 3), np.uint16), "3 channels"),
    ],
)
def test_file_backend_wrong_png_kind(tmp_path, image, message):
    cv2.imwrite(str(tmp_path / "a.png"), image)
    with pytest.raises(InputError, match=message) as err:
        ld.file(ld.FileParams(dir=str(tmp_path)), np.zeros((20, 30), np.uint8), frame="a")
    assert err.value.frame == "a"


def test_file_backend_wrong_npy_kind(tmp_path):
    np.save(tmp_path / "b.npy", np.zeros((2, 20, 30)))
    with pytest.raises(InputError, match="HxW"):
        ld.file(ld.FileParams(dir=str(tmp_path)), np.zeros((20, 30), np.uint8), frame="b")


def test_file_backend_missing_file_or_frame(tmp_path):
    with pytest.raises(InputError, match=r"expected .*nope\.png or .*nope\.npy \(no such file\)") as err:
        ld.file(ld.FileParams(dir=str(tmp_path)), np.zeros((4, 4), np.uint8), frame="nope")
    assert err.value.frame == "nope"
    with pytest.raises(InputError, match="folder does not exist"):
        ld.file(ld.FileParams(dir=str(tmp_path / "missing")), np.zeros((4, 4), np.uint8), frame="x")
    with pytest.raises(InputError, match="needs the 'frame' input"):
        ld.file(ld.FileParams(dir=str(tmp_path)), np.zeros((4, 4), np.uint8))


def test_file_backend_format_restricts_the_extension(tmp_path):
    np.save(tmp_path / "c.npy", np.ones((4, 4)))
    params = ld.FileParams(dir=str(tmp_path), format="png")
    with pytest.raises(InputError, match=r"c\.png \(no such file\)"):
        ld.file(params, np.zeros((4, 4), np.uint8), frame="c")


# --------------------------------------------------------------------------- real data


@pytest.mark.kitti
def test_sgbm_on_kitti_frame(kitti_drive, kitti_calib):
    left = cv2.imread(str(kitti_drive / "image_02" / "data" / "0000000000.png"))
    right = cv2.imread(str(kitti_drive / "image_03" / "data" / "0000000000.png"))
    assert left is not None and right is not None
    out = run(ld.sgbm, ld.SgbmParams(), left, right)
    h, w = out.shape
    assert (out[h // 2 :] > 0).mean() >= 0.6
    # flat road in front of the car: d = baseline * (y - cy) / camera height (KITTI: 1.65 m)
    rows = np.arange(h - 8, h - 2)
    patch = out[rows, w // 2 - 150 : w // 2 + 150]
    road = np.median(patch[patch > 0])
    expected = kitti_calib.baseline * (rows.mean() - kitti_calib.cy) / 1.65
    assert 50 <= expected <= 70
    assert road == pytest.approx(expected, rel=0.1)


@pytest.mark.kitti
@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="a full KITTI frame takes minutes without the jit")
def test_sgm_agrees_with_sgbm_on_kitti(kitti_drive):
    left = cv2.imread(str(kitti_drive / "image_02" / "data" / "0000000000.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(kitti_drive / "image_03" / "data" / "0000000000.png"), cv2.IMREAD_GRAYSCALE)
    ref = run(ld.sgbm, ld.SgbmParams(lr_check=True), left, right)
    own = run(ld.sgm, ld.SgmParams(scale=0.5, lr_check=True), left, right)
    h = own.shape[0]
    assert (own[h // 2 :] > 0).mean() >= 0.8
    both = (ref > 0) & (own > 0)
    assert np.mean(np.abs(ref - own)[both] < 1.5) >= 0.8


def test_strips_and_top_fraction_agree_with_one_pass():
    left, right = shifted_pair(7, h=120, w=96)
    one = run(ld.sgbm, ld.SgbmParams(), left, right, num_disparities=16, block_size=5)
    strips = run(
        ld.sgbm, ld.SgbmParams(), left, right, num_disparities=16, block_size=5, strips=3, strip_overlap=12
    )
    both = (one > 0) & (strips > 0)
    assert both.mean() > 0.5 and np.mean(np.abs(one - strips)[both] < 0.5) > 0.95
    top = run(ld.sgbm, ld.SgbmParams(), left, right, num_disparities=16, block_size=5, top_fraction=0.5)
    assert not top[:60].any() and np.median(top[70:, 30:80]) == pytest.approx(7, abs=0.5)


# --------------------------------------------------------------------------- road-guided bands

from lanegraph_disparity import _road  # noqa: E402

from lanegraph.types import Calibration, RoadModel  # noqa: E402

#: KITTI-like rig: f B = 387 px m, the road 1.65 m below the camera, horizon at row 173
KITTI_CALIB = Calibration(f=721.5, cx=609.6, cy=172.9, baseline=0.537, width=1242, height=375)


def flat_road(calib: Calibration = KITTI_CALIB, height: float = 1.65, roll: float = 0.0) -> RoadModel:
    """The road model of a flat road at zero pitch: d(v) = f B / (fy h) (v - cy)."""
    a1 = calib.f * calib.baseline / (calib.f_y * height)
    return RoadModel(a0=-a1 * calib.cy, a1=a1, roll=roll, height=height, valid=True)


def test_usable_prediction_checks_the_model():
    road = flat_road()
    assert _road.usable_prediction(road, 374, 96.0)
    assert not _road.usable_prediction(None, 374, 96.0)  # the first frame
    assert not _road.usable_prediction(RoadModel(**{**road.__dict__, "valid": False}), 374, 96.0)
    assert not _road.usable_prediction(RoadModel(**{**road.__dict__, "a1": float("nan")}), 374, 96.0)
    assert not _road.usable_prediction(RoadModel(**{**road.__dict__, "height": 0.0}), 374, 96.0)
    # a disparity that falls down the rows, or one beyond the range at the bottom row
    assert not _road.usable_prediction(RoadModel(**{**road.__dict__, "a0": 200.0, "a1": -0.3}), 374, 96.0)
    assert not _road.usable_prediction(road, 374, 40.0)


def test_road_range_holds_the_road_kerbs_and_obstacles_and_skips_beyond_the_far_end():
    road, calib = flat_road(), KITTI_CALIB
    rows = np.arange(375, dtype=float)
    d = road.disparity_at(rows)
    fb = calib.f * calib.baseline
    p = ld.RoadSgbmParams()
    lo, hi, dr = _road.road_range(road, calib, rows, calib.width, p)
    np.testing.assert_allclose(dr, d)  # no roll: the same disparity along the row
    used = lo <= hi
    # rows whose road lies beyond far_m (and the margin) are not matched; the others are
    assert np.array_equal(used, d + p.road_margin_px >= fb / p.far_m)
    assert np.all(lo[used] <= d[used] - p.road_margin_px + 1e-9)
    kerb = d / (1.0 - 0.3 / 1.65)  # what stands 30 cm on the road
    assert np.all(hi[used] >= kerb[used])
    # a car's lower metre, nearer than near_m never
    car = np.minimum(fb / p.near_m, d / (1.0 - p.obstacle_height_m / 1.65))
    assert np.all(hi[used] >= car[used] - 1e-9)
    lo_c, hi_c, _ = _road.road_range(
        road, calib, rows, calib.width, p.model_copy(update={"obstacles": "coarse"})
    )
    assert np.all(hi_c[used] <= hi[used]) and np.any(hi_c[used] < hi[used] - 0.1)


def test_road_range_covers_a_rolled_row_end_to_end():
    calib = KITTI_CALIB
    road = flat_road(roll=np.radians(2.0))
    lo, hi, dr = _road.road_range(road, calib, np.array([300.0]), calib.width, ld.RoadSgbmParams())
    s = np.sin(road.roll) * calib.f_y / calib.f
    ends = [
        road.disparity_at(calib.cy + s * (u - calib.cx) + np.cos(road.roll) * (300.0 - calib.cy))
        for u in (0, 1241)
    ]
    assert lo[0] <= min(ends) - 4.0 + 1e-9 and dr[0] == pytest.approx(max(ends))


def test_band_plan_is_a_fixed_split_with_ranges_that_hold_every_row():
    rng = np.random.default_rng(3)
    n, first, rows = 375, 112, 32
    lo = np.sort(rng.uniform(-10, 90, n))
    hi = lo + rng.uniform(0, 30, n)
    lo[:150], hi[:150] = 1.0, 0.0  # not matched
    c0 = rng.integers(0, 300, n).astype(float)
    c1 = rng.integers(900, 1300, n).astype(float)
    plan = _road.band_plan(n, 1242, first, rows, 0, 96, (lo, hi), (c0, c1))
    full = _road.band_plan(n, 1242, first, rows, 0, 96)
    assert [(b.a, b.b) for b in full] == [(a, min(n, a + rows)) for a in range(first, n, rows)]
    assert all((b.low, b.num, b.c0, b.c1) == (0, 96, 0, 1242) for b in full)
    kept = {(b.a, b.b) for b in plan}
    assert kept == {(a, b) for a, b in ((b.a, b.b) for b in full) if (lo[a:b] <= hi[a:b]).any()}
    for b in plan:
        assert b.num % 16 == 0 and 0 <= b.low and b.low + b.num <= 96
        keep = lo[b.a : b.b] <= hi[b.a : b.b]
        assert b.low <= max(0.0, lo[b.a : b.b][keep].min())
        assert b.low + b.num - 1 >= min(95.0, hi[b.a : b.b][keep].max())
        assert b.c0 == max(0, c0[b.a : b.b].min()) and b.c1 == min(1242, c1[b.a : b.b].max())


@pytest.fixture(scope="module")
def synthetic_pair():
    synthetic = pytest.importorskip("lanegraph_synthetic")
    renderer = synthetic.SceneRenderer(synthetic.preset("urban"))
    prev, fr = renderer.render(3), renderer.render(4)
    road = ld.sgbm(
        ld.SgbmParams(num_disparities=96, top_fraction=0.3, uniqueness_ratio=30), prev.left, prev.right
    )
    from lanegraph.testing import run_node

    model = run_node("road.profile", {"disparity": road["disparity"], "calib": prev.calib})["road"]
    assert model.valid
    return fr, model


PAPER_SGBM = dict(num_disparities=96, block_size=5, top_fraction=0.3, uniqueness_ratio=30)


@pytest.mark.parametrize("guided", [True, False])
def test_road_sgbm_is_the_same_on_any_number_of_threads(synthetic_pair, guided):
    fr, model = synthetic_pair
    road = model if guided else None
    maps = [
        ld.road_sgbm(
            ld.RoadSgbmParams(**PAPER_SGBM, threads=t), fr.left, fr.right, road=road, calib=fr.calib
        )["disparity"]
        for t in (1, 2, 3)
    ]
    assert maps[0].dtype == np.float32 and maps[0].shape == fr.left.shape[:2]
    assert np.array_equal(maps[0], maps[1]) and np.array_equal(maps[0], maps[2])
    assert (maps[0] > 0).mean() > 0.3


def test_road_sgbm_without_a_usable_road_searches_the_full_range(synthetic_pair):
    fr, model = synthetic_pair
    p = ld.RoadSgbmParams(**PAPER_SGBM)
    first = ld.road_sgbm(p, fr.left, fr.right)["disparity"]
    invalid = RoadModel(**{**model.__dict__, "valid": False})
    assert np.array_equal(
        first, ld.road_sgbm(p, fr.left, fr.right, road=invalid, calib=fr.calib)["disparity"]
    )
    guided = ld.road_sgbm(p, fr.left, fr.right, road=model, calib=fr.calib)["disparity"]
    assert not np.array_equal(first, guided)
    assert not first[: round(0.3 * 375)].any()  # top_fraction
    # the guided map leaves the rows beyond the road's far end without a disparity
    horizon = int(-model.a0 / model.a1)
    assert not guided[: horizon - 30].any() and first[round(0.3 * 375) : horizon - 30].any()


@pytest.mark.parametrize("obstacles", ["band", "coarse"])
def test_road_sgbm_on_the_road_is_no_worse_than_sgbm(synthetic_pair, obstacles):
    """Exact ground truth: on the road 5-45 m ahead, where both the road-guided map and one full
    SGBM search give a disparity, their errors (here and in docs/pipeline.md)."""
    fr, model = synthetic_pair
    sgbm = ld.sgbm(ld.SgbmParams(**PAPER_SGBM), fr.left, fr.right)["disparity"]
    p = ld.RoadSgbmParams(**PAPER_SGBM, obstacles=obstacles)
    guided = ld.road_sgbm(p, fr.left, fr.right, road=model, calib=fr.calib)["disparity"]
    fb = fr.calib.f * fr.calib.baseline
    z = np.where(fr.disparity > 0, fb / np.maximum(fr.disparity, 1e-6), np.inf)
    road = fr.road_mask & (z >= 5) & (z <= 45)
    road[:, :128] = False
    # within the BEV's width (the bands match the columns within lateral_m of the axis)
    x = (
        (np.arange(fr.disparity.shape[1])[None, :] - fr.calib.cx)
        * fr.calib.baseline
        / np.maximum(fr.disparity, 1e-6)
    )
    road &= np.abs(x) <= 10.0
    both = road & (sgbm > 0) & (guided > 0)
    assert both.sum() > 50000
    err_sgbm = np.abs(sgbm - fr.disparity)[both].mean()
    err_guided = np.abs(guided - fr.disparity)[both].mean()
    assert err_guided <= err_sgbm + 0.01, (err_guided, err_sgbm)
    # and it covers the road as densely
    assert (guided[road] > 0).mean() >= (sgbm[road] > 0).mean() - 0.02


def test_road_sgbm_needs_the_calibration_with_a_road():
    left, right = shifted_pair(4, 60, 200)
    with pytest.raises(InputError, match="calib"):
        ld.road_sgbm(ld.RoadSgbmParams(num_disparities=16), left, right, road=flat_road())


@pytest.mark.parametrize("field, value", [("lr_check", True), ("wls", True), ("strips", 2)])
def test_road_sgbm_refuses_what_the_bands_replace(field, value):
    with pytest.raises(ValidationError, match=f"{field}: not supported by disparity.road_sgbm"):
        ld.RoadSgbmParams(**{field: value})


def test_sgbm_with_a_min_disparity_reports_no_disparity_below_it():
    """OpenCV marks an invalid pixel (min_disparity - 1) * 16: never a disparity of the map."""
    left, right = shifted_pair(12, 60, 200, smooth=2)
    d = run(ld.sgbm, ld.SgbmParams(num_disparities=16, min_disparity=8), left, right)
    assert (d > 0).any() and not ((d > 0) & (d < 8)).any()
    assert np.median(d[d > 0]) == pytest.approx(12.0, abs=0.5)


@pytest.mark.parametrize(
    "make, field",
    [
        (lambda v: ld.SgbmParams(block_size=v), "block_size"),
        (lambda v: ld.BmParams(block_size=v), "block_size"),
        (lambda v: ld.BmParams(prefilter_size=v), "prefilter_size"),
        (lambda v: ld.SgmParams(census_width=v), "census_width"),
        (lambda v: ld.SgmParams(census_height=v), "census_height"),
    ],
)
def test_an_even_window_names_its_field_and_the_odd_sizes_beside_it(make, field):
    """Every backend's window params go through one check (``_common.odd_pixels``)."""
    assert getattr(make(7), field) == 7
    with pytest.raises(ValidationError) as err:
        make(8)
    assert f"{field}: expected an odd number of pixels, got 8 (hint: use 7 or 9)" in str(err.value)


def test_road_sgbm_keeps_one_left_border_and_the_road_masks_precision():
    """Issue 44: on a residential street (kerbs at road level, verge behind them), the road-guided
    map's far bands used to reach further left than its near ones; the road mask's free-space scan
    then read the near rows without a disparity, and the kerb among them, as road below the far
    rows' verge. With ``one_left_border`` the guided map leaves one border on every row, and its
    road mask takes no more beyond the paved road than that of one full-range search; without it
    (the default) the far rows reach further left."""
    synthetic = pytest.importorskip("lanegraph_synthetic")
    from lanegraph.testing import run_node

    spec = synthetic.preset(
        "residential", side_road_radius=6.0, side_road_width=5.0, parked_cars=0.0, seed=162
    )
    renderer = synthetic.SceneRenderer(spec)
    prev, fr = renderer.render(4), renderer.render(5)
    full_prev = ld.sgbm(ld.SgbmParams(**PAPER_SGBM, strips=2), prev.left, prev.right)["disparity"]
    model = run_node("road.profile", {"disparity": full_prev, "calib": prev.calib})["road"]
    assert model.valid

    def guided_map(**extra):
        p = ld.RoadSgbmParams(**PAPER_SGBM, **extra)
        return ld.road_sgbm(p, fr.left, fr.right, road=model, calib=fr.calib)["disparity"]

    def first_columns(disp):
        rows = [v for v in range(disp.shape[0]) if (disp[v] > 0).any()]
        return np.array([int(np.argmax(disp[v] > 0)) for v in rows])

    first = first_columns(guided_map())
    assert first.min() < first[-20:].min() - 8  # by default a far row reaches further left
    guided = guided_map(one_left_border=True)
    full = ld.sgbm(ld.SgbmParams(**PAPER_SGBM, strips=2), fr.left, fr.right)["disparity"]
    first = first_columns(guided)
    near = first[-20:].min()  # the bottom rows: the widest band's border
    assert first.min() >= near - 8, (first.min(), near)  # no far row reaches further left
    masks = {}
    for name, disp in (("guided", guided), ("full", full)):
        road = run_node("road.profile", {"disparity": disp, "calib": fr.calib})["road"]
        masks[name] = run_node("road.mask", {"disparity": disp, "road": road, "calib": fr.calib})["mask"]
    off_road = {k: int((m & ~fr.paved_mask).sum()) for k, m in masks.items()}
    assert masks["guided"].sum() > 50000
    assert off_road["guided"] <= off_road["full"] + 200, off_road
