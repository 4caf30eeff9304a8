"""The paint decision's measured features (``lanegraph_lanes._paint``), the road's height beside a
lane (``_heights``), the side check's flatness rule in ``lanes.verify`` and ``lanes.verify_learned``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from lanegraph_lanes import _paint
from lanegraph_lanes._heights import lane_heights, step_across
from lanegraph_lanes._verify import VerifyParams, verify
from lanegraph_lanes._verify_learned import VerifyLearnedParams, verify_learned

from lanegraph import InputError
from lanegraph.types import Calibration, Lane, RoadModel

from .test_lanes import _paint_scene, geometry

#: a road model whose disparity at row v is 10 + 0.05 v, the camera 1.5 m above the road
ROAD = RoadModel(a0=10.0, a1=0.05, height=1.5)


def _disparity(rows: int, cols: int, raised_from: int | None = None, raise_m: float = 0.12) -> np.ndarray:
    """The road plane's disparity (the BEV geometry of the tests maps BEV pixels to the same image
    pixels), the columns from ``raised_from`` on ``raise_m`` above it (eq. 4 inverted)."""
    d_road = ROAD.disparity_at(np.arange(rows, dtype=np.float64))[:, None] * np.ones((1, cols))
    d = d_road.copy()
    if raised_from is not None:
        d[:, raised_from:] = d_road[:, raised_from:] / (1.0 - raise_m / ROAD.height)
    return d.astype(np.float32)


def _calib(rows: int, cols: int) -> Calibration:
    return Calibration(f=700.0, cx=cols / 2, cy=0.0, baseline=0.5, width=cols, height=rows)


def test_lane_heights_measure_a_kerb_step_and_a_flat_road():
    g = geometry(600, 200)
    lane = Lane((100.0, 0.0, 0.0), (0, 599), "right", 0.9)
    cal = _calib(600, 200)
    left, line, right = lane_heights(lane, g, _disparity(600, 200), ROAD, cal, 25.0)
    assert abs(left) < 1e-4 and abs(line) < 1e-4 and abs(right) < 1e-4
    left, line, right = lane_heights(lane, g, _disparity(600, 200, raised_from=103), ROAD, cal, 25.0)
    assert abs(left) < 1e-4 and right == pytest.approx(0.12, abs=1e-3)
    # no disparity there, an invalid road, a map of another size: nothing measured
    assert all(
        math.isnan(v) for v in lane_heights(lane, g, np.zeros((600, 200), np.float32), ROAD, cal, 25.0)
    )
    bad = RoadModel(a0=10.0, a1=0.05, height=1.5, valid=False)
    assert all(math.isnan(v) for v in lane_heights(lane, g, _disparity(600, 200), bad, cal, 25.0))
    assert all(math.isnan(v) for v in lane_heights(lane, g, _disparity(300, 100), ROAD, cal, 25.0))


def test_verify_drops_a_darker_side_that_is_not_level_with_the_road():
    """Paint with a smooth, very dark side (a shadow cast along it) is kept; the same picture with
    that side 12 cm above the road (a kerb's gutter in its shade, and the kerb) is not, when the
    disparity is wired; without it, or with the rule off, it is kept. A side only somewhat darker
    (a parked car's shadow, 0.55 of the road: above step_side_ratio) is not asked."""
    img, lane, g = _paint_scene("shadow")  # the right side at 55 against a road at 100
    cal = _calib(*img.shape)
    raised = _disparity(*img.shape, raised_from=108)
    assert (
        len(
            verify(
                VerifyParams(), lanes=[lane], image=img, geometry=g, disparity=raised, road=ROAD, calib=cal
            )["lanes"]
        )
        == 1
    )
    img = img.copy()
    img[:, 103:] = (img[:, 103:].astype(np.float64) * 0.6).astype(img.dtype)  # 33: a kerb's gutter
    p = VerifyParams()
    flat = _disparity(*img.shape)
    assert len(verify(p, lanes=[lane], image=img, geometry=g)["lanes"]) == 1
    assert (
        len(verify(p, lanes=[lane], image=img, geometry=g, disparity=flat, road=ROAD, calib=cal)["lanes"])
        == 1
    )
    assert (
        verify(p, lanes=[lane], image=img, geometry=g, disparity=raised, road=ROAD, calib=cal)["lanes"] == []
    )
    off = VerifyParams(max_dark_side_step_m=None)
    kept = verify(off, lanes=[lane], image=img, geometry=g, disparity=raised, road=ROAD, calib=cal)["lanes"]
    assert len(kept) == 1
    # a side of like brightness is not asked: paint beside a raised verge or a car's body stays
    img2, lane2, _ = _paint_scene("paint")
    kept = verify(p, lanes=[lane2], image=img2, geometry=g, disparity=raised, road=ROAD, calib=cal)["lanes"]
    assert len(kept) == 1


def _heights_disparity(rows: int, cols: int, heights: dict[tuple[int, int], float]) -> np.ndarray:
    """The road plane's disparity with the columns ``a .. b - 1`` of each ``(a, b)`` of ``heights``
    that many metres above it (a kerb's top, a pavement, a car's body)."""
    d_road = ROAD.disparity_at(np.arange(rows, dtype=np.float64))[:, None] * np.ones((1, cols))
    d = d_road.copy()
    for (a, b), h in heights.items():
        d[:, a:b] = d_road[:, a:b] / (1.0 - h / ROAD.height)
    return d.astype(np.float32)


#: a lane at column 100 of the 5 cm BEV: its right side 0.3-0.8 m out is columns 106-116, 0.8-1.2 m
#: out columns 116-124
SIDES = {
    # a kerb's lit top at the lane, the pavement behind it level, 14 cm up (the known hole: 14.6 cm)
    "kerb top": ({(102, 200): 0.14}, False),
    # a low cobbled strip behind a flush edge, 5 cm up: not a kerb's height
    "low strip": ({(102, 200): 0.05}, True),
    # paint on the road, a raised verge from 0.4 m out (seq2's edge line: up to 8.4 cm)
    "verge": ({(108, 200): 0.08}, True),
    # paint beside a parked car: its sill 12 cm up from 0.4 m, its body 40 cm up from 0.7 m
    "parked car": ({(108, 114): 0.12, (114, 200): 0.4}, True),
    # paint on a flat road
    "flat": ({}, True),
}


@pytest.mark.parametrize("kind", list(SIDES))
def test_every_lane_must_be_level_to_within_a_kerbs_height(kind):
    """A bright stripe of paint's width and contrast, its sides of like brightness (the paint check
    passes it), on a kerb's top: the road steps 14 cm across it and the pavement behind stays level,
    so it is dropped (max_step_m); paint beside a raised verge (8 cm), beside a parked car (the
    step's higher side rises beyond a kerb's height further out: an obstacle) or on a low strip
    (5 cm) is kept. Without the disparity, or with the rule off, every one is kept."""
    heights, keep = SIDES[kind]
    img, lane, g = _paint_scene("paint")
    cal = _calib(*img.shape)
    disp = _heights_disparity(*img.shape, heights)
    p = VerifyParams(max_step_m=0.1)
    kept = verify(p, lanes=[lane], image=img, geometry=g, disparity=disp, road=ROAD, calib=cal)["lanes"]
    assert len(kept) == int(keep), step_across(lane, g, disp, ROAD, cal, p.max_distance_m)
    assert len(verify(p, lanes=[lane], image=img, geometry=g)["lanes"]) == 1
    off = VerifyParams(max_step_m=None)
    assert (
        len(verify(off, lanes=[lane], image=img, geometry=g, disparity=disp, road=ROAD, calib=cal)["lanes"])
        == 1
    )


@pytest.mark.parametrize("node", ["verify", "verify_followed", "verify_straddled"])
def test_the_paper_graph_keeps_an_edge_line_inside_a_kerb(node):
    """An edge line 0.3 m inside a 12 cm kerb, the pavement behind it level (a residential street's
    edge line: the synthetic ``residential_side_road_edge_lines``): its side steps by a kerb's height
    0.3-0.8 m out, so ``max_step_m`` = 10 cm drops it (that scene went from 100 % to 0 % with the rule
    on) -- which is why the paper graph's paint checks leave the rule off and keep the line."""
    from lanegraph.graph.files import load_graph_named

    heights = {(106, 200): 0.12}  # the kerb's face 6 BEV columns (0.3 m) right of the lane
    img, lane, g = _paint_scene("paint")
    cal = _calib(*img.shape)
    disp = _heights_disparity(*img.shape, heights)
    ins = dict(lanes=[lane], image=img, geometry=g, disparity=disp, road=ROAD, calib=cal)
    assert verify(VerifyParams(max_step_m=0.1), **ins)["lanes"] == []
    params = load_graph_named("paper").nodes[node].params
    assert params.max_step_m is None
    assert len(verify(params, **ins)["lanes"]) == 1


def test_step_across_measures_the_step_and_what_stands_beyond():
    """The step between the two sides 0.3-0.8 m out, and the higher side's height 0.8-1.2 m out over
    the lower side: a kerb's pavement stays at the kerb's height, a car's body rises beyond it; on the
    left as on the right; NaN without a disparity."""
    img, lane, g = _paint_scene("paint")
    cal = _calib(*img.shape)
    step, beyond = step_across(lane, g, _heights_disparity(*img.shape, {(102, 200): 0.14}), ROAD, cal, 25.0)
    assert step == pytest.approx(0.14, abs=2e-3) and beyond == pytest.approx(0.14, abs=2e-3)
    car = {(0, 84): 0.4, (84, 92): 0.12}  # mirrored: the car on the left
    step, beyond = step_across(lane, g, _heights_disparity(*img.shape, car), ROAD, cal, 25.0)
    assert step == pytest.approx(0.12, abs=2e-3) and beyond == pytest.approx(0.4, abs=5e-3)
    assert step_across(lane, g, _heights_disparity(*img.shape, {}), ROAD, cal, 25.0) == pytest.approx(
        (0, 0), abs=1e-4
    )
    none = np.zeros(img.shape, np.float32)
    assert all(math.isnan(v) for v in step_across(lane, g, none, ROAD, cal, 25.0))


def test_row_widths_and_runs():
    band = 5
    strips = np.ones((3, 2 * band + 1))
    strips[0, band - 1 : band + 2] = 2.0  # 3 px at twice the side level
    strips[1, band] = 3.0  # 1 px
    strips[2, :] = 2.0  # the whole strip
    strips[2, band + 3] = 1.0  # ... but a dip 3 px right of the centre ends the run there
    assert row_widths_list(strips, band) == [3, 1, 8]
    rows = np.array([0, 1, 2, 3, 10, 11, 12, 40, 41, 60])
    assert _paint.runs_of(rows, max_gap=6, min_len=3).tolist() == [13]  # 0-12 bridged (gap of 6 rows)
    assert _paint.runs_of(rows, max_gap=5, min_len=2).tolist() == [4, 3, 2]
    assert _paint.runs_of(np.empty(0, np.int64), 5, 1).size == 0


def row_widths_list(strips, band):
    return [int(v) for v in _paint.row_widths(strips, band)]


def test_paint_features_tell_paint_a_dashed_line_and_a_gutter():
    img, lane, g = _paint_scene("paint")
    f = _paint.paint_features(img, lane, g)
    assert set(f) == {*_paint.FEATURES, "step_beyond_m"}  # the model's inputs, and the step's far side
    assert 0.1 <= f["width_m"] <= 0.2 and f["foot_width_m"] <= 0.25
    assert f["width_spread"] < 0.4 and f["painted_fraction"] > 0.9
    assert f["contrast"] > 0.8 and f["side_ratio"] > 0.9
    assert f["dash_runs"] == 1 and f["longest_run_m"] == pytest.approx(20.0, abs=0.5)
    assert math.isnan(f["height_step_m"]) and math.isnan(f["step_beyond_m"])  # no disparity given
    assert f["parallel_spread_m"] == _paint.UNPARALLEL_M  # no other lane
    dashed = _paint.paint_features(*_paint_scene("dashed"))
    # 3 m dashes every 9 m on BEV rows 0-59, 180-239, 360-419, 540-599; the near 25 m are rows 199-599
    assert dashed["dash_runs"] == 3 and dashed["longest_run_m"] == pytest.approx(3.0, abs=0.2)
    gutter = _paint.paint_features(*_paint_scene("gutter"))
    assert gutter["foot_width_m"] > 0.36
    step = _paint.paint_features(*_paint_scene("step"))
    assert step["painted_fraction"] < 0.1 and math.isnan(step["contrast"])


def test_parallel_spread():
    g = geometry(600, 200)
    lane = Lane((100.0, 0.0, 0.0), (0, 599), "right", 0.9)
    parallel = Lane((40.0, 0.0, 0.0), (0, 599), "left", 0.9)  # 3 m left, parallel
    diverging = Lane((40.0, 0.02, 0.0), (0, 599), "left", 0.9)  # 0.02 px a row: 0.6 m over 600 rows
    same = Lane((101.0, 0.0, 0.0), (0, 599), "right", 0.9)  # the same line: not another marking
    assert _paint.parallel_spread(lane, [parallel], g) == pytest.approx(0.0, abs=1e-9)
    assert _paint.parallel_spread(lane, [diverging], g) == pytest.approx(0.02 * 599 * 0.05, rel=1e-6)
    steep = Lane((40.0, 0.2, 0.0), (0, 599), "left", 0.9)  # 6 m over the rows: capped
    assert _paint.parallel_spread(lane, [steep, diverging], g) == pytest.approx(0.02 * 599 * 0.05, rel=1e-6)
    assert _paint.parallel_spread(lane, [steep], g) == _paint.UNPARALLEL_M
    assert _paint.parallel_spread(lane, [same], g) == _paint.UNPARALLEL_M
    assert _paint.parallel_spread(lane, [], g) == _paint.UNPARALLEL_M


def _model(**over) -> dict:
    """A model on the painted rows' share alone: paint above half."""
    n = len(_paint.FEATURES)
    spec = {
        "features": list(_paint.FEATURES),
        "fill": [0.0] * n,
        "mean": [0.0] * n,
        "scale": [1.0] * n,
        "coef": [10.0 if k == "painted_fraction" else 0.0 for k in _paint.FEATURES],
        "intercept": -5.0,
        "threshold": 0.5,
    }
    spec.update(over)
    return spec


def test_paint_model_reads_its_json_and_says_what_is_wrong(tmp_path):
    m = _paint.PaintModel(_model())
    assert m.probability({"painted_fraction": 1.0}) > 0.99 and m.probability({"painted_fraction": 0.0}) < 0.01
    assert m.probability({}) < 0.01  # not measured: its fill value
    with pytest.raises(InputError, match="coef"):
        _paint.PaintModel({k: v for k, v in _model().items() if k != "coef"}, "m.json")
    with pytest.raises(InputError, match="unknown features"):
        _paint.PaintModel(_model(features=["paintiness"] + list(_paint.FEATURES[1:])), "m.json")
    with pytest.raises(InputError, match="scale"):
        _paint.PaintModel(_model(scale=[0.0] * len(_paint.FEATURES)), "m.json")
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2]")
    with pytest.raises(InputError, match="bad.json: expected a JSON object"):
        _paint.PaintModel.load(bad)
    packaged = _paint.PaintModel.load()
    assert packaged.features == list(_paint.FEATURES) and 0.0 < packaged.threshold < 1.0


def test_verify_learned_keeps_what_its_model_calls_paint(tmp_path):
    path = tmp_path / "model.json"
    path.write_text(json.dumps(_model()))
    p = VerifyLearnedParams(model=str(path))
    img, lane, g = _paint_scene("paint")
    kept = verify_learned(p, lanes=[lane], image=img, geometry=g)["lanes"]
    assert len(kept) == 1 and kept[0].extra["paint_probability"] > 0.99
    img, lane, g = _paint_scene("step")
    assert verify_learned(p, lanes=[lane], image=img, geometry=g)["lanes"] == []
    # its own threshold overridden
    img, lane, g = _paint_scene("paint")
    strict = VerifyLearnedParams(model=str(path), min_probability=1.0)
    assert verify_learned(strict, lanes=[lane], image=img, geometry=g)["lanes"] == []
    assert verify_learned(p, lanes=[], image=img, geometry=g) == {"lanes": []}


def test_the_packaged_model_keeps_paint_and_drops_a_kerb():
    p = VerifyLearnedParams()
    img, lane, g = _paint_scene("paint")
    assert len(verify_learned(p, lanes=[lane], image=img, geometry=g)["lanes"]) == 1
    img, lane, g = _paint_scene("step")
    assert verify_learned(p, lanes=[lane], image=img, geometry=g)["lanes"] == []
