"""``lanes.near_paint``: a thin line seen over a few metres near the car is found on the fine grid;
a one-cell bright crack, a dark crack, a stripe standing above the road and a side that already
has a lane are not taken. The scenes are rendered here from the road-plane homography (exact
answers)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from lanegraph_lanes._near import (
    NearPaintParams,
    fine_grid,
    near_paint,
    near_paint_lanes,
    painted_pixels,
    row_widths,
    side_levels,
    warp_fine,
)
from lanegraph_road.geometry import homography_img_from_road
from lanegraph_road.ipm import IpmParams, bev_geometry

from lanegraph.testing import check_node_type
from lanegraph.types import Calibration, Lane, RoadModel

W, H = 1241, 376
CALIB = Calibration(f=707.0, cx=604.0, cy=185.0, baseline=0.54, width=W, height=H)
CAM_H = 1.65
ROAD_GREY = 60.0


def render(stripes, seed: int = 0, supersample: int = 3) -> np.ndarray:
    """A grey left image of a flat road seen from CAM_H (pitch and roll 0): ``stripes`` are
    ``(x_centre, width, z_from, z_to, grey)`` rectangles on the road (metres), anti-aliased by
    supersampling; the road ROAD_GREY with sensor noise (sigma 2)."""
    Hr = homography_img_from_road(CALIB, 0.0, 0.0, CAM_H)
    Hinv = np.linalg.inv(Hr)
    s = supersample
    v0 = int(CALIB.cy) + 8  # rows below the horizon
    vv, uu = np.mgrid[v0 * s : H * s, 0 : W * s].astype(np.float64)
    uu, vv = (uu + 0.5) / s - 0.5, (vv + 0.5) / s - 0.5
    q = Hinv @ np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)])
    x, z = q[0] / q[2], q[1] / q[2]
    grey = np.full(x.shape, ROAD_GREY)
    for xc, w, z0, z1, g in stripes:
        grey[(np.abs(x - xc) <= w / 2) & (z >= z0) & (z <= z1)] = g
    grey = grey.reshape(H - v0, s, W, s).mean(axis=(1, 3))
    img = np.full((H, W), 120.0)  # the sky and what stands above the horizon
    img[v0:] = grey
    img += np.random.default_rng(seed).normal(0.0, 2.0, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def geometry():
    """The paper graph's BEV (5 cm, x -10..10 m, z 5..45 m) of the same camera."""
    return bev_geometry(IpmParams(), CALIB, 0.0, 0.0, CAM_H)


def road_model() -> RoadModel:
    """The flat road's v-disparity line (pitch 0): d = f B / h (v - cy)."""
    a1 = CALIB.f * CALIB.baseline / (CALIB.f_y * CAM_H)
    return RoadModel(a0=-a1 * CALIB.cy, a1=a1, pitch=0.0, roll=0.0, height=CAM_H, v_min=int(CALIB.cy) + 1)


def disparity(raised=()) -> np.ndarray:
    """The road's disparity, and ``raised`` stripes ``(x_centre, width, z_from, z_to, height)``:
    the pixels that show those road rectangles see instead a surface ``height`` above the road
    (a nearer point on the same ray: its disparity times ``h / (h - height)``)."""
    v = np.arange(H, dtype=np.float64)[:, None] * np.ones((1, W))
    u = np.ones((H, 1)) * np.arange(W, dtype=np.float64)[None, :]
    d = np.where(v > CALIB.cy, CALIB.baseline / CAM_H * (v - CALIB.cy), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = CALIB.f * CAM_H / (v - CALIB.cy)
        x = (u - CALIB.cx) * z / CALIB.f
    for xc, w, z0, z1, h in raised:
        top = (v > CALIB.cy) & (np.abs(x - xc) <= w / 2) & (z >= z0) & (z <= z1)
        d[top] *= CAM_H / (CAM_H - h)
    return d.astype(np.float32)


#: two short dashes of a 12 cm line 2 m left of the car, 6-7 m and 11-12.3 m ahead (as
#: kitti_singles/kitti12_000070's parking-strip line), paint 110 on a road of 60
THIN_DASHES = [(-2.0, 0.12, 6.0, 7.0, 110.0), (-2.0, 0.12, 11.0, 12.3, 110.0)]


def _run(image, lanes=(), disp=None, road=None, **params):
    p = NearPaintParams(**params)
    calib = CALIB if disp is not None else None
    return near_paint_lanes(p, list(lanes), image, geometry(), disp, road, calib)


def _x_of(lane: Lane, z: float) -> float:
    g = geometry()
    _, r = g.metric_to_bev(0.0, z)
    t = g.rows - 1 - float(r)
    col = lane.coeffs[0] + lane.coeffs[1] * t + lane.coeffs[2] * t * t
    return g.x_min + (col + 0.5) * g.resolution


def test_thin_short_line_near_the_car_is_found():
    img = render(THIN_DASHES)
    lanes, seen = _run(img, disp=disparity(), road=road_model())
    assert len(lanes) == 1, seen
    (ln,) = lanes
    assert ln.side == "left"
    for z in (6.5, 9.0, 11.5):  # on the line, across the gap too
        assert abs(_x_of(ln, z) + 2.0) < 0.04, (z, _x_of(ln, z))
    g = geometry()
    _, r_far = g.metric_to_bev(0.0, 12.3)
    _, r_near = g.metric_to_bev(0.0, 6.0)
    assert abs(ln.bev_rows[0] - r_far) <= 3 and abs(ln.bev_rows[1] - r_near) <= 3
    m = ln.extra["near_paint"]
    assert 0.10 <= m["width_m"] <= 0.14  # a 12 cm line measures 12 cm on the 2 cm grid
    assert m["painted_m"] >= 2.0 and m["run_m"] >= 1.0


def test_the_coarse_bev_measures_the_same_line_narrower_than_paint():
    """Why the finer look: on the 5 cm BEV the same 12 cm line's half-height width is under the
    paint check's 9 cm on some of the near rows (it depends on where the samples fall)."""
    from lanegraph_lanes._verify import paint_cues
    from lanegraph_road.ipm import warp_to_bev

    img = render(THIN_DASHES)
    road = road_model()
    bev, _, g = warp_to_bev(IpmParams(), img, road, CALIB)
    col = float(g.metric_to_bev(-2.0, 6.5)[0])
    t0 = g.rows - 1
    _, r_far = g.metric_to_bev(0.0, 7.0)
    cues = paint_cues(bev, Lane((col, 0.0, 0.0), (int(r_far), t0), "left", 1.0), g, min_rows=3)
    fine, _ = _run(img)
    assert fine and fine[0].extra["near_paint"]["width_m"] > cues.width_m


def test_one_cell_bright_crack_is_not_paint():
    """A 5 cm bright stripe (one cell of the coarse BEV; a lit crack's edge, a rail head) as long
    and as bright as the line: too narrow for paint on the fine grid."""
    img = render([(-2.0, 0.05, 6.0, 7.0, 110.0), (-2.0, 0.05, 11.0, 12.3, 110.0)])
    lanes, seen = _run(img, disp=disparity(), road=road_model())
    assert lanes == []
    assert seen and all(m["width_m"] < 0.08 for m in seen if math.isfinite(m["width_m"]))


def test_dark_crack_and_empty_road_give_nothing():
    img = render([(1.5, 0.03, 5.5, 14.0, 25.0), (-2.0, 0.05, 6.0, 14.0, 30.0)])
    lanes, seen = _run(img)
    assert lanes == [] and seen == []
    lanes, seen = _run(render([]))
    assert lanes == [] and seen == []


def test_faint_line_below_the_contrast_is_not_taken():
    img = render([(xc, w, z0, z1, ROAD_GREY * 1.4) for xc, w, z0, z1, _ in THIN_DASHES])
    lanes, seen = _run(img)
    assert lanes == []
    lanes, _ = _run(img, min_paint_contrast=0.3, min_row_contrast=0.2)
    assert len(lanes) == 1  # the same line at a lower contrast threshold: the threshold decides


def test_stripe_above_the_road_is_not_paint():
    """A bright stripe 10 cm above the road (a kerb's lit top): painted and of paint width in the
    image, but the disparity puts it above the road plane."""
    raised = [(-2.0, 0.12, 6.0, 7.0, 0.10), (-2.0, 0.12, 11.0, 12.3, 0.10)]
    img = render(THIN_DASHES)
    lanes, seen = _run(img, disp=disparity(raised), road=road_model())
    assert lanes == []
    assert any(m.get("line_height_m", 0) > 0.05 for m in seen)
    lanes, _ = _run(img, disp=disparity(raised), road=road_model(), max_line_height_m=None)
    assert len(lanes) == 1


def test_short_or_single_dash_is_not_enough():
    img = render([THIN_DASHES[0]])  # one metre of line: under min_painted_m (1.5 m)
    lanes, _ = _run(img)
    assert lanes == []


def test_side_with_a_lane_is_not_looked_at():
    img = render(THIN_DASHES)
    have = Lane((100.0, 0.0, 0.0), (0, 799), "left", 1.0)
    lanes, seen = _run(img, lanes=[have])
    assert lanes == [have] and seen == []
    # the right side is looked at, and has nothing
    lanes, seen = _run(img, lanes=[Lane((300.0, 0.0, 0.0), (0, 799), "right", 1.0)])
    assert len(lanes) == 2 and lanes[1].side == "left"


def test_nearest_line_on_a_side_is_taken():
    img = render(THIN_DASHES + [(-3.0, 0.12, 6.0, 14.0, 110.0)])
    lanes, seen = _run(img)
    assert len(lanes) == 1 and abs(_x_of(lanes[0], 9.0) + 2.0) < 0.04
    # the farther line (the stronger one: 8 m of paint) is a lane on its own
    lanes, _ = _run(render([(-3.0, 0.12, 6.0, 14.0, 110.0)]))
    assert len(lanes) == 1 and abs(_x_of(lanes[0], 9.0) + 3.0) < 0.04


def test_side_levels_and_painted_pixels_match_plain_numpy():
    rng = np.random.default_rng(3)
    bev = rng.integers(0, 200, (40, 90)).astype(np.float32)
    bev[:, :4] = 0.0  # outside the image
    bev[5, 30:60] = 0.0
    gap, band = 4, 9
    got = side_levels(bev, gap, band)
    want = np.zeros_like(bev)
    for r in range(bev.shape[0]):
        for c in range(band, bev.shape[1] - band):
            left, right = bev[r, c - band : c - gap + 1], bev[r, c + gap : c + band + 1]
            if (left > 0).all() and (right > 0).all():
                want[r, c] = max(left.mean(), right.mean())
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-3)
    pr, pc = painted_pixels(bev, got, gap, 0.3)
    k = set(zip(pr.tolist(), pc.tolist()))
    for r in range(bev.shape[0]):
        for c in range(bev.shape[1]):
            win = bev[r, max(c - gap, 0) : c + gap + 1]
            first = c == 0 or not (bev[r, c - 1] == bev[r, c] and (r, c - 1) in k)
            ok = got[r, c] > 0 and bev[r, c] >= win.max() and bev[r, c] >= 1.3 * got[r, c] and first
            assert ((r, c) in k) == ok, (r, c)


def test_row_widths():
    band, gap = 10, 4
    strip = np.full(2 * band + 1, 50.0)
    strip[band - 2 : band + 3] = 100.0  # 5 pixels at 100 on 50: 5 pixels at half height
    strip[band - 3] = strip[band + 3] = 75.0  # ramps: the half level crossed at their middle
    w = row_widths(strip[None, :], band, gap, 0.5)
    assert w[0] == pytest.approx(6.0)
    w = row_widths(strip[None, :], band, gap, 0.25)
    assert w[0] == pytest.approx(7.0)


def test_fine_grid_maps_to_the_same_road_points():
    g = geometry()
    p = NearPaintParams()
    f = fine_grid(g, p)
    assert f.resolution == p.resolution and f.z_min == g.z_min and f.z_max == pytest.approx(p.near_m)
    for x, z in ((-2.0, 6.0), (1.3, 14.2), (0.0, 9.0)):
        c, r = f.metric_to_bev(x, z)
        c0, r0 = g.metric_to_bev(x, z)
        np.testing.assert_allclose(f.bev_to_image([c], [r]), g.bev_to_image([c0], [r0]), atol=1e-6)
    one_side = fine_grid(g, p, ("right",))
    assert one_side.x_min == -p.band_m and one_side.x_max == pytest.approx(p.max_offset_m + p.band_m)
    img = render(THIN_DASHES)
    assert warp_fine(img, f).shape == (f.rows, f.cols)
    assert warp_fine(np.dstack([img] * 3), f).shape == (f.rows, f.cols)


def test_params_are_checked():
    with pytest.raises(ValueError, match="band_m"):
        NearPaintParams(gap_m=0.3, band_m=0.2)
    with pytest.raises(ValueError, match="max_offset_m"):
        NearPaintParams(min_offset_m=3.0, max_offset_m=2.0)


def test_node_conformance():
    img = render(THIN_DASHES)
    check_node_type(near_paint, {"lanes": [], "image": img, "geometry": geometry()})
