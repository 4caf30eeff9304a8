"""CULane-style F1, TuSimple-style accuracy and the lateral error, on tiny hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest

from lanegraph.evaluation.metrics_extra import (
    culane_metrics,
    image_to_road_x,
    lateral_error_cm,
    road_row,
    tusimple_metrics,
)
from lanegraph.types import Calibration

SIZE = [200, 100]


def vertical(x, y0=10, y1=90):
    return [[float(x), float(y)] for y in range(y1, y0 - 1, -10)]


def gt_frame(*xs, frame="a"):
    return {
        "frame": frame,
        "image_size": SIZE,
        "markings": [{"id": i, "points": vertical(x)} for i, x in enumerate(xs)],
        "ego": {"left": None, "right": None},
    }


def pred(frame, *xs):
    return {"frame": frame, "lanes": [{"points": vertical(x)} for x in xs]}


def test_culane_identical_lane_is_a_true_positive():
    r = culane_metrics([pred("a", 50)], [gt_frame(50)])
    assert (r["tp"], r["fp"], r["fn"]) == (1, 0, 0) and r["f1"] == 1.0


def test_culane_far_shift_is_fp_and_fn():
    r = culane_metrics([pred("a", 90)], [gt_frame(50)])
    assert (r["tp"], r["fp"], r["fn"]) == (0, 1, 1) and r["f1"] == 0.0


def test_culane_iou_threshold_for_vertical_lines():
    # width 30 lines 8 px apart: overlap 22, union 38 -> IoU 0.58 >= 0.5 ; 12 px apart: 18/42 = 0.43
    assert culane_metrics([pred("a", 58)], [gt_frame(50)])["tp"] == 1
    assert culane_metrics([pred("a", 62)], [gt_frame(50)])["tp"] == 0


def test_culane_is_one_to_one():
    r = culane_metrics([pred("a", 50, 52)], [gt_frame(50)])
    assert (r["tp"], r["fp"], r["fn"]) == (1, 1, 0)


def test_tusimple_accuracy_counts_rows():
    gt = gt_frame(50)  # 9 rows: 90, 80, ..., 10
    p = {"frame": "a", "lanes": [{"points": [[50.0, 90.0], [50.0, 50.0]]}]}  # covers 5 of 9 rows
    r = tusimple_metrics([p], [gt])
    assert r["accuracy"] == pytest.approx(5 / 9)
    assert r["fn"] == 1.0 and r["fp"] == 1.0  # below 0.85: unmatched on both sides
    r = tusimple_metrics([pred("a", 60)], [gt])  # every row 10 px off: all correct
    assert (r["accuracy"], r["fp"], r["fn"]) == (1.0, 0.0, 0.0)
    r = tusimple_metrics([pred("a", 75)], [gt])  # 25 px off: none correct
    assert r["accuracy"] == 0.0


def test_tusimple_missing_frame_and_empty_gt():
    r = tusimple_metrics([], [gt_frame(50), {"frame": "b", "markings": []}])
    assert r["accuracy"] == pytest.approx(0.5) and r["fn"] == pytest.approx(0.5) and r["fp"] == 0.0


def test_lateral_error_matches_a_known_metric_offset():
    calib = Calibration(f=700.0, cx=600.0, cy=180.0, baseline=0.5, width=1200, height=375)
    pitch, height = np.radians(1.0), 1.6

    def project(x, z):
        cp, sp = np.cos(pitch), np.sin(pitch)
        yc = height * cp - z * sp
        zc = height * sp + z * cp
        return calib.cx + calib.f * x / zc, calib.cy + calib.f * yc / zc

    def polyline(x):
        pts = [project(x, z) for z in np.linspace(6, 60, 200)]
        ys = np.arange(370, 185, -10)
        xs = np.interp(ys, [p[1] for p in pts][::-1], [p[0] for p in pts][::-1])
        return [[float(a), float(b)] for a, b in zip(xs, ys)]

    gt = {"frame": "a", "markings": [{"id": 0, "points": polyline(-1.8)}], "ego": {"left": 0, "right": None}}
    pr = {"frame": "a", "lanes": [{"points": polyline(-1.8 + 0.07)}]}
    err = lateral_error_cm([pr], [gt], calib, pitch, height)
    for k in ("10", "20", "30"):
        assert err[k] == pytest.approx(7.0, abs=1.0)
    # the helpers are inverse to the projection
    x, y = project(2.5, 20.0)
    assert road_row(20.0, calib, pitch, height) == pytest.approx(y)
    assert image_to_road_x(x, y, calib, pitch, height) == pytest.approx(2.5)
