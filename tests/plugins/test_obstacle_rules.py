"""Issue 44's rules for a line painted beside parked cars (kitti_singles/kitti12_000070), all off
by default: ``features.mask`` keeping the road mask's border along an obstacle's foot
(``obstacle_height_m``, :mod:`lanegraph_lanes._border`), ``hough.line1d``'s vote minimum for a
line the road mask shows on part of the BEV only (``min_votes_visible``) and ``lanes.verify``'s
step check telling a kerb from an obstacle's side (``max_kerb_step_m``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from lanegraph_lanes._border import obstacle_border
from lanegraph_lanes._features import MaskParams, mask_features
from lanegraph_lanes._hough import HoughParams, _select, visible_fraction
from lanegraph_lanes._verify import VerifyParams, verify

from lanegraph.types import FeatureMap, Lane

from .test_lanes import _paint_scene, geometry
from .test_paint import ROAD, _calib, _disparity


def _raised(rows: int, cols: int, spans: list[tuple[int, int, float]]) -> np.ndarray:
    """The road plane's disparity with the columns ``[c0, c1)`` of each span ``h`` metres above it."""
    d = _disparity(rows, cols).astype(np.float64)
    for c0, c1, h in spans:
        d[:, c0:c1] = d[:, c0:c1] / (1.0 - h / ROAD.height)
    return d.astype(np.float32)


def _scene(rows=200, cols=160):
    """A road mask on columns 40-119; left of it a parked car's side (50 cm up), right of it a kerb's
    top (12 cm up); a feature on the mask's second column on each side and one in the middle."""
    mask = np.zeros((rows, cols), bool)
    mask[:, 40:120] = True
    disp = _raised(rows, cols, [(0, 40, 0.5), (120, cols, 0.12)])
    r = np.repeat(np.arange(rows), 3)
    c = np.tile([41, 80, 118], rows)
    feats = FeatureMap.from_points((rows, cols), r, c, np.full(r.size, math.pi / 2, np.float32))
    return mask, disp, feats


def test_obstacle_border_marks_a_cars_foot_not_a_kerb():
    mask, disp, _ = _scene()
    g, cal = geometry(200, 160), _calib(200, 160)
    ob = obstacle_border(mask, g, disp, ROAD, cal, band_px=4, max_kerb_height_m=0.2, reach_px=8)
    # (away from the BEV's top and bottom edges, where the erosion cuts the mask too)
    assert ob[10:-10, 40:44].all()  # the car's side: the ring along it
    assert not ob[10:-10, 44:].any()  # not inside the eroded mask, not along the kerb
    # a kerb higher than the limit is an obstacle too; an all-flat surround marks nothing
    assert obstacle_border(mask, g, disp, ROAD, cal, 4, 0.1, 8)[10:-10, 116:120].all()
    flat = _disparity(200, 160)
    assert not obstacle_border(mask, g, flat, ROAD, cal, 4, 0.2, 8).any()
    # no disparity beyond the border counts for nothing: not an obstacle
    assert not obstacle_border(mask, g, np.zeros_like(disp), ROAD, cal, 4, 0.2, 8).any()


def test_mask_keeps_features_along_an_obstacle_only_when_asked():
    mask, disp, feats = _scene()
    g, cal = geometry(200, 160), _calib(200, 160)
    plain = mask_features(MaskParams(), features=feats, mask=mask)["features"]
    assert sorted(set(plain.points()[1].tolist())) == [80]  # the erosion drops both border features
    on = MaskParams(obstacle_height_m=0.2)
    # without the disparity wired, the rule has nothing to read: the plain erosion
    same = mask_features(on, features=feats, mask=mask)["features"]
    assert sorted(set(same.points()[1].tolist())) == [80]
    kept = mask_features(on, features=feats, mask=mask, geometry=g, disparity=disp, road=ROAD, calib=cal)
    assert sorted(set(kept["features"].points()[1].tolist())) == [41, 80]  # the car's side, not the kerb's


def test_visible_fraction_counts_the_rows_the_mask_shows():
    mask = np.zeros((100, 50), bool)
    mask[60:, :] = True  # the near 40 rows only
    assert visible_fraction(mask, 20.0, math.pi / 2) == pytest.approx(0.4)
    mask[:, 30:] = True
    assert visible_fraction(mask, 35.0, math.pi / 2) == pytest.approx(1.0)
    # a slanted line leaving the BEV: x = 45 + 0.1 (100 - y) rounds inside the 50 columns on the
    # rows y = 56..99 only; the rows outside it are not shown
    assert visible_fraction(np.ones((100, 50), bool), 45.0, math.atan2(1.0, 0.1)) == pytest.approx(0.44)


def test_min_votes_visible_lowers_the_minimum_of_a_partly_hidden_line_only():
    rows, cols = 200, 160
    g = geometry(rows, cols)
    offset = 2 * cols
    acc = np.zeros(5 * cols)
    acc[offset + 50] = 30.0  # a line 1.5 m left, seen on 20 % of the rows: 30 votes
    acc[offset + 120] = 30.0  # a line 2 m right, seen on every row: 30 votes
    mask = np.ones((rows, cols), bool)
    mask[: int(0.8 * rows), :60] = False
    p = HoughParams(smooth_px=0.0, min_votes=40.0)
    assert _select(acc, offset, math.pi / 2, g, p, None, mask) == []
    q = HoughParams(smooth_px=0.0, min_votes=40.0, min_votes_visible=10.0)
    lines = _select(acc, offset, math.pi / 2, g, q, None, mask)
    assert [(ln.rho, ln.side) for ln in lines] == [(50.0, "left")]  # 30 >= max(10, 40 x 0.2); 30 < 40
    assert _select(acc, offset, math.pi / 2, g, q, None, None) == []  # no mask: min_votes
    high = HoughParams(smooth_px=0.0, min_votes=40.0, min_votes_visible=35.0)
    assert _select(acc, offset, math.pi / 2, g, high, None, mask) == []  # the floor holds


def test_max_kerb_step_keeps_paint_beside_an_obstacles_side():
    """Paint with a kerb's gutter in shade beside it: a 12 cm step drops it, as before; a 50 cm
    step (a parked car's side) drops it without the rule and keeps it with it."""
    img, lane, g = _paint_scene("shadow")
    img = img.copy()
    img[:, 103:] = (img[:, 103:].astype(np.float64) * 0.6).astype(img.dtype)
    cal = _calib(*img.shape)
    kerb = _disparity(*img.shape, raised_from=108, raise_m=0.12)
    car = _disparity(*img.shape, raised_from=108, raise_m=0.5)
    old, new = VerifyParams(), VerifyParams(max_kerb_step_m=0.2)
    for p in (old, new):
        assert (
            verify(p, lanes=[lane], image=img, geometry=g, disparity=kerb, road=ROAD, calib=cal)["lanes"]
            == []
        )
    assert (
        verify(old, lanes=[lane], image=img, geometry=g, disparity=car, road=ROAD, calib=cal)["lanes"] == []
    )
    kept = verify(new, lanes=[lane], image=img, geometry=g, disparity=car, road=ROAD, calib=cal)["lanes"]
    assert len(kept) == 1 and isinstance(kept[0], Lane)
