"""Tests of the synthetic stereo scenes (``lanegraph_synthetic``): the geometry of the rendered
disparity against the analytic road plane and boxes, left/right consistency, lane ground truth
against the image and the road model, presets, ``write_sequence`` and the ``io.synthetic`` node."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
import yaml
from lanegraph_synthetic import (
    KITTI_CALIB,
    Box,
    Pole,
    SceneRenderer,
    SceneSpec,
    SyntheticParams,
    SyntheticSource,
    preset,
    write_sequence,
)
from pydantic import ValidationError

from lanegraph import RunContext
from lanegraph.plugins import get_plugin_manager

HALF = KITTI_CALIB.scaled(0.5)  # 621 x 188
QUARTER = KITTI_CALIB.scaled(0.25)  # 310 x 94


def gray(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float64)


def rotation(pitch: float, roll: float) -> np.ndarray:
    """Camera-to-world rotation written out: Rx(pitch) @ Rz(roll) (nose down, clockwise positive)."""
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    rx = np.array([[1, 0, 0], [0, cp, sp], [0, -sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return rx @ rz


def back_project(spec: SceneSpec, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left-image pixels (N, 2) -> road-plane (X, Z), metres, by intersecting their rays with y = h."""
    c = spec.calib
    ray = np.stack([(pts[:, 0] - c.cx) / c.f, (pts[:, 1] - c.cy) / c.f_y, np.ones(len(pts))])
    w = rotation(spec.pitch, spec.roll) @ ray
    t = spec.height / w[1]
    return t * w[0], t * w[2]


def centroid_error(img: np.ndarray, points, half: int = 6) -> np.ndarray:
    """|intensity-weighted centroid - x| of the bright marking around each GT point of a row."""
    g = gray(img)
    errs = []
    for x, y in points:
        c0, c1 = int(round(x)) - half, int(round(x)) + half + 1
        if c0 < 0 or c1 > g.shape[1]:
            continue
        row = g[int(y), c0:c1]
        w = np.clip(row - np.median(g[int(y)]) - 20, 0, None)
        if w.sum() > 0:
            errs.append(abs((w * np.arange(c0, c1)).sum() / w.sum() - x))
    return np.array(errs)


# --------------------------------------------------------------------------- presets, determinism


def test_presets_and_spec_validation():
    for name in ("straight", "curved", "clothoid", "urban", "no_markings", "overexposed", "kerbs"):
        spec = preset(name)
        assert spec.preset == name
    assert preset("curved").curvature > 0 and preset("clothoid").curvature_rate != 0
    assert preset("urban").walls and preset("urban").parked_cars > 0
    with pytest.raises(ValueError, match="unknown synthetic scene preset 'highway'"):
        preset("highway")
    with pytest.raises(ValueError, match="n_lanes"):
        SceneSpec(n_lanes=7)
    with pytest.raises(ValueError, match="inner_kind"):
        SceneSpec(inner_kind="dotted")


def test_deterministic_from_seed():
    spec = preset("urban", calib=QUARTER, seed=3)
    a, b = SceneRenderer(spec).render(4), SceneRenderer(spec).render(4)
    for name in ("left", "right", "disparity", "disparity_right", "road_mask", "object_mask"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.lanes_gt == b.lanes_gt
    c = SceneRenderer(replace(spec, seed=4)).render(4)
    assert not np.array_equal(a.left, c.left)


# --------------------------------------------------------------------------- geometry


@pytest.mark.parametrize("pitch_deg, roll_deg, height", [(2.0, 0.0, 1.4), (-0.5, 2.0, 1.9)])
def test_road_disparity_is_the_analytic_plane(pitch_deg, roll_deg, height):
    spec = preset("straight", calib=HALF, pitch_deg=pitch_deg, roll_deg=roll_deg, height=height)
    fr = SceneRenderer(spec).render(0)
    c = spec.calib
    v, u = np.mgrid[0 : c.height, 0 : c.width].astype(np.float64)
    th, ph = spec.pitch, spec.roll
    if roll_deg == 0:
        # a point on the road at row v has camera depth Z with h = Z (sin(th) + (v - cy) cos(th) / f),
        # so d = f B / Z = (B / h) (f sin(th) + (v - cy) cos(th))
        d_plane = (c.baseline / height) * (c.f * math.sin(th) + (v - c.cy) * math.cos(th))
    else:
        # road normal in camera coordinates n = (cos th sin ph, cos th cos ph, sin th), n.P = h
        n = (math.cos(th) * math.sin(ph), math.cos(th) * math.cos(ph), math.sin(th))
        d_plane = (c.baseline / height) * (n[0] * (u - c.cx) + n[1] * (v - c.cy) + n[2] * c.f)
    road = fr.road_mask
    assert road.sum() > 0.3 * road.size and not fr.object_mask.any()
    np.testing.assert_allclose(fr.disparity[road], d_plane[road], rtol=2e-5, atol=1e-5)
    assert fr.disparity.dtype == np.float32
    assert np.all(fr.disparity[~road] == 0)  # sky (and the road beyond z_far)
    # the road ends at z_far: nothing nearer than f B / z_far is left out above the far end
    assert fr.disparity[road].min() > 0.9 * c.f * c.baseline / spec.z_far


def test_box_and_pole_disparity_and_occlusion():
    h, z_front = 1.65, 20.0
    box = Box(s=z_front + 2.0, lateral=0.0, length=4.0, width=2.0, height=1.2)
    pole = Pole(s=12.0, lateral=-3.0, radius=0.1, height=5.0)
    spec = preset(
        "straight", calib=HALF, pitch_deg=0.0, roll_deg=0.0, height=h, speed=4.0, objects=[box, pole]
    )
    ren = SceneRenderer(spec)
    c = spec.calib
    fb = c.f * c.baseline
    for k, z in ((0, z_front), (5, z_front - 2.0)):  # 4 m/s for 0.5 s: the box comes 2 m nearer
        fr = ren.render(k)
        u, v = int(round(c.cx)), int(round(c.cy + c.f * (h - 0.6) / z))  # mid-height of the front face
        assert fr.object_mask[v, u] and not fr.road_mask[v, u]
        assert fr.disparity[v, u] == pytest.approx(fb / z, rel=1e-5)
        # the front face is fronto-parallel: every pixel on it has the same disparity
        face = fr.disparity[v - 3 : v + 4, u - 10 : u + 11]
        np.testing.assert_allclose(face, fb / z, rtol=1e-5)
        # right view: the same face is seen d pixels to the left
        ur = int(round(u - fb / z))
        assert fr.disparity_right[v, ur] == pytest.approx(fb / z, rel=1e-5)
    # the pole at 12 m: its pixels are objects with the disparity of a point ~12 m away
    fr = ren.render(0)
    up = c.f * (-3.0) / 12.0 + c.cx
    vp = int(round(c.cy + c.f * (h - 2.0) / 12.0))
    assert fr.object_mask[vp, int(round(up))]
    assert fr.disparity[vp, int(round(up))] == pytest.approx(fb / (12.0 - 0.1), rel=2e-3)
    # objects are nearer than the road they hide
    bare = SceneRenderer(replace(spec, objects=[])).render(0)
    hidden = fr.object_mask & bare.road_mask
    assert hidden.sum() > 200
    assert np.all(fr.disparity[hidden] > bare.disparity[hidden])
    # outside the objects nothing changes
    np.testing.assert_array_equal(fr.disparity[~fr.object_mask], bare.disparity[~fr.object_mask])
    np.testing.assert_array_equal(fr.road_mask | fr.object_mask, bare.road_mask | fr.object_mask)


def test_lane_ground_truth_is_cut_where_an_object_hides_it():
    h, z = 1.65, 15.0
    wall = Box(s=z + 0.5, lateral=0.0, length=1.0, width=6.0, height=2.5)  # hides x in [-3, 3] beyond 15 m
    spec = preset("straight", calib=HALF, pitch_deg=0.0, height=h, speed=0.0, objects=[wall])
    gt = SceneRenderer(spec).render(0).lanes_gt
    c = spec.calib
    v_foot = c.cy + c.f * h / z
    marks = {m["id"]: m for m in gt["markings"]}
    assert set(marks) == {0, 1, 2, 3}
    for i in (1, 2):  # the ego lane's lines at -1.8 / +1.8 m: only the part nearer than the wall
        ys = [y for _, y in marks[i]["points"]]
        assert min(ys) > v_foot and len(ys) >= 5
    for i in (0, 3):  # the outer lines at -5.4 / +5.4 m are not hidden
        assert min(y for _, y in marks[i]["points"]) < v_foot - 5
    assert gt["ego"] == {"left": 1, "right": 2}


def warp_right_to_left(fr) -> np.ndarray:
    """The right image resampled at (u - d(u, v), v) for every left pixel."""
    g = gray(fr.right).astype(np.float32)
    v, u = np.mgrid[0 : g.shape[0], 0 : g.shape[1]].astype(np.float32)
    return cv2.remap(g, u - fr.disparity, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1)


def ncc(a: np.ndarray, b: np.ndarray) -> float:
    a0, b0 = a - a.mean(), b - b.mean()
    return float((a0 * b0).sum() / (np.linalg.norm(a0) * np.linalg.norm(b0) + 1e-9))


def test_left_right_consistency():
    spec = preset("urban", calib=HALF, noise_sigma=0.0, right_gain=1.0, seed=1)
    fr = SceneRenderer(spec).render(3)
    left = gray(fr.left)
    warped = warp_right_to_left(fr).astype(np.float64)
    H, W = left.shape
    v, u = np.mgrid[0:H, 0:W]
    # road pixels seen by both cameras: the right view's disparity at (u - d) agrees (not occluded)
    ur = np.clip(np.round(u - fr.disparity).astype(int), 0, W - 1)
    both = fr.road_mask & (u - fr.disparity >= 1) & (np.abs(fr.disparity_right[v, ur] - fr.disparity) < 0.3)
    assert both.sum() > 5000
    assert np.median(np.abs(left[both] - warped[both])) < 3.0
    rng = np.random.default_rng(0)
    m = 10
    ys, xs = np.nonzero(both[m:-m, m:-m] & (fr.disparity[m:-m, m:-m] > 12.0))  # the near road: fine texture
    pick = rng.choice(len(ys), 200, replace=False)
    scores, peaks = [], []
    for y, x in zip(ys[pick] + m, xs[pick] + m, strict=True):
        a = left[y - 4 : y + 5, x - 4 : x + 5]
        c = [ncc(a, warped[y - 4 : y + 5, x - 4 + s : x + 5 + s]) for s in (-1, 0, 1, 4)]
        scores.append(c)
        den = c[0] - 2 * c[1] + c[2]
        peaks.append(0.5 * (c[0] - c[2]) / den if den < 0 else 1.0)  # sub-pixel offset of the best match
    scores = np.array(scores)
    assert np.median(scores[:, 1]) > 0.97  # the same texture at (u - d, v)
    assert np.median(scores[:, 3]) < 0.5  # and not 4 pixels off
    assert np.median(np.abs(peaks)) < 0.1  # to a tenth of a pixel


def test_far_asphalt_keeps_detail_across_the_road():
    """Far away the footprint of a pixel is long along the road and short across it: the texture
    averages out along the road (rip-mapped) but keeps the lateral detail stereo matching needs."""
    fr = SceneRenderer(preset("straight", noise_sigma=0.0, seed=2)).render(0)
    left = gray(fr.left)
    gx = np.abs(np.diff(left, axis=1))[:-1, :]  # across the road
    asphalt = fr.paved_mask[:-1, :-1] & (left[:-1, :-1] < 150)  # no paint
    d = fr.disparity[:-1, :-1]
    far, near = asphalt & (d > 5) & (d < 12), asphalt & (d > 40)  # ~30-75 m; nearer than ~10 m
    assert far.sum() > 2000 and near.sum() > 2000
    assert gx[far].mean() > 1.5  # grey levels between neighbours
    assert gx[far].mean() > 0.8 * gx[near].mean()


def test_verge_texture_roughens_only_the_ground_beyond_the_paved_road():
    """``verge_texture`` scales the texture of the verge (grass, gravel) and leaves the asphalt as it was."""
    base = preset("straight", calib=HALF, noise_sigma=0.0, shoulder=0.4, seed=3)
    smooth, rough = (SceneRenderer(replace(base, verge_texture=v)).render(0) for v in (1.0, 3.0))
    rows = slice(HALF.height * 3 // 4, HALF.height)  # near the car: the verge is resolved
    paved = smooth.paved_mask[rows, :-1] & smooth.paved_mask[rows, 1:]
    verge = ~smooth.paved_mask[rows, :-1] & ~smooth.paved_mask[rows, 1:] & (smooth.disparity[rows, :-1] > 0)
    assert paved.sum() > 1000 and verge.sum() > 1000
    gs, gr = (np.abs(np.diff(gray(f.left)[rows], axis=1)) for f in (smooth, rough))
    np.testing.assert_allclose(gr[paved].mean(), gs[paved].mean(), rtol=0.02)
    assert gr[verge].mean() > 2.0 * gs[verge].mean()
    with pytest.raises(ValueError, match="verge_texture"):
        replace(base, verge_texture=-1.0)


def test_kerbs_preset_raises_a_step_along_both_edges():
    spec = preset("kerbs", calib=HALF, parked_cars=0.0, poles=0.0)
    r = SceneRenderer(spec)
    kerbs = [o for o in r.objects if isinstance(o, Box) and abs(o.height - spec.kerb_height) < 1e-9]
    lats = sorted({round(o.lateral, 2) for o in kerbs})
    assert len(lats) == 2 and lats[0] < 0 < lats[1]
    fr = r.render(0)
    # kerb pixels stand above the road: nearer than the road plane behind them in the same row
    ys, xs = np.nonzero(fr.object_mask[fr.object_mask.shape[0] // 2 :])
    assert ys.size > 100


def _pixel(r: SceneRenderer, X: float, up: float, Z: float) -> tuple[int, int, float]:
    """Left-image pixel (u, v) and camera depth of the world point ``up`` metres above the road at
    (``X``, ``Z``) (frame 0 of a straight road: world X is the lateral position, Z the distance)."""
    q = r.R.T @ np.array([X, r.spec.height - up, Z])
    c = r.calib
    return int(round(c.f * q[0] / q[2] + c.cx)), int(round(c.f_y * q[1] / q[2] + c.cy)), float(q[2])


def test_residential_side_road_kerb_curves_away_from_the_right_edge():
    spec = preset("residential", calib=HALF, shadows=0.0, trees=0.0, parked_cars=0.0, seed=5)
    r = SceneRenderer(spec)
    fr = r.render(0)
    a, R, E, h = spec.side_roads[0], spec.side_road_radius, r.edges[1], spec.kerb_height
    fb = spec.calib.f * spec.calib.baseline
    assert fr.lanes_gt["markings"] == [] and fr.lanes_gt["ego"] == {"left": None, "right": None}
    # the near corner's kerb: its top stands kerb_height above the road along the quarter circle
    # that leaves the right edge at s = a (centred R metres beyond the edge)
    for deg in (10, 25, 40, 60):
        th = math.radians(deg)
        s, lat = a + (R - 0.1) * math.sin(th), E + R - (R - 0.1) * math.cos(th)
        u, v, z = _pixel(r, lat, h, s)
        assert fr.object_mask[v, u], f"no kerb at {deg} deg of the corner ({s:.1f} m, {lat:.1f} m)"
        assert fr.disparity[v, u] == pytest.approx(fb / z, rel=0.03)
        c, pitch = spec.calib, spec.pitch  # the road plane seen in that pixel lies farther away
        d_road = (c.baseline / spec.height) * (c.f * math.sin(pitch) + (v - c.cy) * math.cos(pitch))
        assert fr.disparity[v, u] > d_road * 1.02
    # no kerb along the main road's edge across the mouth; the edge's kerb before it
    u, v, _ = _pixel(r, E + 0.1, h, a + R)
    assert not fr.object_mask[v, u] and fr.paved_mask[v, u]
    u, v, _ = _pixel(r, E + 0.1, h, a - 3.0)
    assert fr.object_mask[v, u]
    # the side road is paved beyond the corners; the corner block inside the quarter circle is not
    u, v, _ = _pixel(r, E + R + 2.0, 0.0, a + R + spec.side_road_width / 2)
    assert fr.road_mask[v, u] and fr.paved_mask[v, u]
    u, v, _ = _pixel(r, E + 4.0, 0.0, a + 2.0)
    assert fr.road_mask[v, u] and not fr.paved_mask[v, u]
    # and the asphalt there is the road's grey, the corner block the verge's green
    g = fr.left.astype(float)
    u, v, _ = _pixel(r, E + 1.0, 0.0, a + R)
    assert g[v, u, 1] < g[v, u, 0] + 15  # asphalt: not green
    with pytest.raises(ValueError, match="side_roads"):
        SceneSpec(side_roads=(10.0,))  # no kerb height
    with pytest.raises(ValueError, match="side_roads"):
        replace(spec, side_roads=(290.0,))  # beyond the tile


def test_a_side_road_on_the_left_mirrors_the_right_one():
    spec = preset(
        "residential", calib=HALF, side_roads=(), side_roads_left=(10.0,), side_road_radius=8.0,
        shadows=0.0, trees=0.0, parked_cars=0.0, seed=6,
    )  # fmt: skip
    r = SceneRenderer(spec)
    fr = r.render(0)
    a, R, E, h = spec.side_roads_left[0], spec.side_road_radius, r.edges[0], spec.kerb_height
    for deg in (15, 35, 55):
        th = math.radians(deg)
        s, lat = a + (R - 0.1) * math.sin(th), E - R + (R - 0.1) * math.cos(th)
        u, v, _ = _pixel(r, lat, h, s)
        assert fr.object_mask[v, u], f"no kerb at {deg} deg of the left corner"
    u, v, _ = _pixel(r, E - 0.1, h, a + R)  # the left edge's kerb is cut across the mouth
    assert not fr.object_mask[v, u] and fr.paved_mask[v, u]
    u, v, _ = _pixel(r, r.edges[1] + 0.1, h, a + R)  # the right one is not
    assert fr.object_mask[v, u]
    u, v, _ = _pixel(r, E - R - 2.0, 0.0, a + R + spec.side_road_width / 2)
    assert fr.road_mask[v, u] and fr.paved_mask[v, u]


# --------------------------------------------------------------------------- lane ground truth


def test_lanes_gt_format_and_bright_pixels():
    spec = preset("straight", noise_sigma=0.0)
    fr = SceneRenderer(spec).render(2)
    gt = fr.lanes_gt
    assert gt["frame"] == "0000000002" and gt["image_size"] == [1242, 375]
    assert [m["id"] for m in gt["markings"]] == [0, 1, 2, 3]
    assert [m["kind"] for m in gt["markings"]] == ["solid", "dashed", "dashed", "solid"]
    assert gt["ego"] == {"left": 1, "right": 2}
    json.dumps(gt)  # plain JSON types
    g = gray(fr.left)
    road_level = np.median(g[fr.road_mask])
    for m in gt["markings"]:
        pts = np.array(m["points"])
        assert np.all(pts[:, 1] % 10 == 0) and np.all(np.diff(pts[:, 1]) < 0)  # rows from the bottom up
        assert pts[:, 0].min() >= 0 and pts[:, 0].max() <= 1241
        vals = g[pts[:, 1].astype(int), np.round(pts[:, 0]).astype(int)]
        bright = vals > road_level + 50
        if m["kind"] == "solid":
            assert bright.mean() > 0.9
            errs = centroid_error(fr.left, m["points"][:12])  # near rows, where the line is > 2 px wide
            assert len(errs) >= 10 and errs.max() < 0.5
        else:  # dashes of 3 m every 9 m: some points on paint, some in the gaps
            assert 0.15 < bright.mean() < 0.8


@pytest.mark.parametrize("name, k", [("curved", 0), ("curved", 7), ("clothoid", 0), ("clothoid", 25)])
def test_curved_markings_follow_the_road_model(name, k):
    spec = preset(name, noise_sigma=0.0)
    ren = SceneRenderer(spec)
    fr = ren.render(k)
    s_k = spec.speed * k / spec.fps
    c_k, r = spec.curvature + spec.curvature_rate * s_k, spec.curvature_rate
    bends = 0.0
    for m in fr.lanes_gt["markings"]:
        offset = ren.markings[m["id"]].offset
        X, Z = back_project(spec, np.array(m["points"], float))
        model = offset + c_k * Z**2 / 2 + r * Z**3 / 6
        assert np.all(np.abs(X - model) < 5e-3 * np.maximum(Z / 10, 1)), np.abs(X - model).max()
        bends = max(bends, np.abs(X - offset).max())
        if m["kind"] == "solid":  # and the paint is where the model says
            assert np.median(centroid_error(fr.left, m["points"][:15])) < 0.5
    assert bends > 0.5  # the markings do curve (more than half a metre off a straight line)


def test_no_markings_preset_has_no_lanes():
    ren = SceneRenderer(preset("no_markings", calib=HALF))
    for k in (0, 5):
        fr = ren.render(k)
        assert fr.lanes_gt["markings"] == [] and fr.lanes_gt["ego"] == {"left": None, "right": None}
        g = gray(fr.left)
        assert np.mean(g[fr.road_mask] > 175) < 0.002  # no paint on the road


def test_lane_change_moves_the_ego_boundaries():
    spec = preset("straight", calib=HALF, lane_change=1, lane_change_start=0.5, lane_change_duration=3.0)
    ren = SceneRenderer(spec)
    assert ren.render(0).lanes_gt["ego"] == {"left": 1, "right": 2}
    end = ren.render(40).lanes_gt  # t = 4 s, after the change
    assert end["ego"] == {"left": 2, "right": 3}
    assert ren.ego_offset(40) == pytest.approx(spec.lane_width)
    mid = ren.ego_offset(20)  # half-way, t = 2 s
    assert mid == pytest.approx(spec.lane_width / 2)


def test_ego_motion_moves_dashes_not_solid_lines():
    ren = SceneRenderer(preset("straight", calib=HALF, noise_sigma=0.0))
    a, b = ren.render(0), ren.render(1)
    assert a.lanes_gt["markings"] == b.lanes_gt["markings"]  # a straight road looks the same
    g0, g1 = gray(a.left), gray(b.left)
    for m in a.lanes_gt["markings"]:
        pts = np.array(m["points"])
        rr, cc = pts[:, 1].astype(int), np.round(pts[:, 0]).astype(int)
        changed = np.abs(g0[rr, cc] - g1[rr, cc]) > 60
        if m["kind"] == "solid":
            assert not changed.any()
        else:
            assert changed.any()


def test_overexposed_frames():
    spec = preset("overexposed", calib=QUARTER)
    ren = SceneRenderer(spec)
    over, normal = ren.render(0), ren.render(1)
    assert over.overexposed and not normal.overexposed
    go, gn = gray(over.left), gray(normal.left)
    assert go[over.road_mask].mean() > 1.8 * gn[normal.road_mask].mean()
    assert np.mean(go >= 254) > 0.3 and np.mean(gn >= 254) < 0.01
    np.testing.assert_array_equal(
        over.disparity, SceneRenderer(replace(spec, overexposed_every=0)).render(0).disparity
    )


# --------------------------------------------------------------------------- files and node


def test_write_sequence(tmp_path):
    spec = preset("urban", calib=QUARTER, seed=2)
    out = write_sequence(spec, tmp_path / "seq", 3)
    stems = [f"{k:010d}" for k in range(3)]
    for sub in ("left", "right", "disparity", "labels"):
        assert sorted(p.stem for p in (out / sub).glob("*.png")) == stems
    left = cv2.imread(str(out / "left" / f"{stems[1]}.png"), cv2.IMREAD_UNCHANGED)
    assert left.shape == (94, 310, 3) and left.dtype == np.uint8
    calib = yaml.safe_load((out / "calib.yaml").read_text())
    assert calib["f"] == pytest.approx(QUARTER.f) and calib["baseline"] == pytest.approx(QUARTER.baseline)
    assert {"cx", "cy", "width", "height"} <= set(calib)
    fr = SceneRenderer(spec).render(1)
    np.testing.assert_array_equal(left, fr.left)
    disp = cv2.imread(str(out / "disparity" / f"{stems[1]}.png"), cv2.IMREAD_UNCHANGED)
    assert disp.dtype == np.uint16
    np.testing.assert_allclose(disp / 256.0, fr.disparity, atol=1 / 512 + 1e-6)
    assert np.all((disp == 0) == (fr.disparity == 0))
    labels = cv2.imread(str(out / "labels" / f"{stems[1]}.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(labels == 2, fr.object_mask)
    lines = (out / "lanes_gt.jsonl").read_text().splitlines()
    assert [json.loads(x)["frame"] for x in lines] == stems
    assert json.loads(lines[1]) == fr.lanes_gt
    scene = json.loads((out / "scene.json").read_text())
    assert scene["preset"] == "urban" and scene["height"] == spec.height
    assert scene["pitch"] == pytest.approx(math.radians(spec.pitch_deg))
    assert scene["roll_deg"] == spec.roll_deg


def test_io_synthetic_node_yields_the_requested_frames():
    nt = get_plugin_manager().get_node_type("io.synthetic")
    assert nt is not None and nt.source and nt.func is SyntheticSource and nt.params is SyntheticParams
    params = SyntheticParams(preset="curved", frames=4, scale=0.25, pitch_deg=2.0, seed=5)
    src = SyntheticSource(params, RunContext(frames=slice(1, 3)))  # the node class, called as it is
    assert len(src) == 2
    calib = src.constants()["calib"]
    assert (calib.width, calib.height) == (310, 94)
    assert src.renderer.spec.pitch_deg == 2.0 and src.renderer.spec.curvature == preset("curved").curvature
    frames = list(src)
    assert [f["frame"] for f in frames] == ["0000000001", "0000000002"]
    for f in frames:
        assert set(f) == set(nt.outputs) - {"calib"}
        assert f["left"].shape == f["right"].shape == (94, 310, 3) and f["left"].dtype == np.uint8
        assert f["gt_disparity"].dtype == np.float32 and f["gt_disparity"].shape == (94, 310)
        assert f["gt_road_mask"].dtype == bool
    with pytest.raises(ValidationError):
        SyntheticParams(presets="urban")
    with pytest.raises(ValidationError):
        SyntheticParams(preset="highway")
    with pytest.raises(ValidationError):
        SyntheticParams(frames=0)
    # the defaults (what io.auto falls back to) render the straight preset at full size
    default = SyntheticSource(SyntheticParams(), RunContext())
    assert len(default) == 10 and default.renderer.spec.preset == "straight"
