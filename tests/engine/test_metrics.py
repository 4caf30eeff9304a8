"""The lane metric of the data README, on tiny hand-made cases."""

from __future__ import annotations

import numpy as np

from lanegraph.evaluation.metrics import evaluate, evaluate_frame, match_score, polyline_x_at

GT_ROWS = [[100.0 + (300 - y) * 0.5, float(y)] for y in range(300, 190, -10)]  # 11 rows, 300..200


def shifted(dx, rows=None):
    pts = [[x + dx, y] for x, y in GT_ROWS]
    return pts if rows is None else [p for p in pts if p[1] in rows]


def test_interpolation_only_inside_range():
    xs = polyline_x_at([[0, 10], [10, 20]], np.array([5, 10, 15, 20, 25]))
    assert np.isnan(xs[0]) and np.isnan(xs[4])
    np.testing.assert_allclose(xs[1:4], [0, 5, 10])


def test_match_requires_half_coverage():
    six = [300, 290, 280, 270, 260, 250]  # 6 of 11 rows -> covered
    five = [300, 290, 280, 270, 260]  # 5 of 11 -> not enough
    assert match_score(shifted(0, six), GT_ROWS) == 0.0
    assert match_score(shifted(0, five), GT_ROWS) is None


def test_match_requires_85_percent_within_20px():
    pts = shifted(5)
    assert match_score(pts, GT_ROWS) == 5.0
    assert match_score(shifted(21), GT_ROWS) is None
    # one row of 11 off by 40 px: 10/11 = 91 % ok -> still a match
    bad_one = [list(p) for p in shifted(0)]
    bad_one[5][0] += 40
    assert match_score(bad_one, GT_ROWS) is not None
    bad_two = [list(p) for p in bad_one]
    bad_two[6][0] += 40
    assert match_score(bad_two, GT_ROWS) is None  # 9/11 = 82 %


def test_one_to_one_greedy_by_mean_dx():
    gt = {"frame": "a", "markings": [{"id": 1, "points": GT_ROWS}], "ego": {"left": 1, "right": None}}
    r = evaluate_frame([{"points": shifted(10)}, {"points": shifted(2)}], gt)
    assert r.matched == 1 and r.dx == [2.0] and not r.correct  # the second lane is false


def test_frame_correctness_rules():
    gt = {
        "frame": "a",
        "markings": [{"id": 1, "points": GT_ROWS}, {"id": 2, "points": shifted(200)}],
        "ego": {"left": 1, "right": None},
    }
    assert evaluate_frame([{"points": shifted(0)}], gt).correct  # non-ego marking need not be reported
    assert evaluate_frame([{"points": shifted(0)}, {"points": shifted(200)}], gt).correct
    assert not evaluate_frame([{"points": shifted(200)}], gt).correct  # ego boundary missed
    empty = {"frame": "b", "markings": [], "ego": {"left": None, "right": None}}
    assert evaluate_frame([], empty).correct
    assert not evaluate_frame([{"points": shifted(0)}], empty).correct


def test_aggregate_and_missing_frames():
    gt = [
        {"frame": "a", "markings": [{"id": 1, "points": GT_ROWS}], "ego": {"left": 1, "right": None}},
        {"frame": "b", "markings": [{"id": 1, "points": GT_ROWS}], "ego": {"left": 1, "right": None}},
    ]
    pred = [{"frame": "a", "lanes": [{"points": shifted(4)}, {"points": shifted(100)}]}]
    res = evaluate(pred, gt)
    assert res["frames"] == 2
    assert res["detection_ratio"] == 0.0  # a has a false lane, b is missing
    assert res["precision"] == 0.5 and res["ego_recall"] == 0.5 and res["mean_abs_dx_px"] == 4.0
    assert [f["frame"] for f in res["failed_frames"]] == ["a", "b"]


def test_match_frame_exposes_each_lane_and_marking_outcome():
    from lanegraph.evaluation.metrics import match_frame

    gt = {
        "frame": "a",
        "markings": [
            {"id": 7, "points": GT_ROWS},
            {"id": 8, "points": shifted(200)},
            {"id": 9, "points": shifted(-200)},
        ],
        "ego": {"left": 7, "right": 8},
    }
    # lane 0 is 30 px off every marking (false), lane 1 lies on marking 9 (not an ego boundary),
    # lane 2 on marking 7, 3 px off; marking 8 (ego right) is missed
    lanes = [{"points": shifted(30)}, {"points": shifted(-200)}, {"points": shifted(3)}]
    m = match_frame(lanes, gt)
    assert m.lane_marking == [None, 2, 0] and m.lane_dx == [None, 0.0, 3.0]
    assert m.marking_lane == [2, None, 1]
    assert m.lane_outcomes() == ["false", "matched", "matched"]
    assert m.marking_outcomes() == ["matched", "missed_ego", "matched"]
    assert m.ego == {"left": 0, "right": 1}
    # the frame's figures are counted from this matching
    r = evaluate_frame(lanes, gt)
    assert r.match == m and not r.correct and r.matched == 2 and r.ego_matched == 1
    assert r.reasons == [
        "1 false lane(s) (reported lane index [0])",
        "ego right boundary (marking 8) not matched",
    ]
    # an ego id that names no marking counts as missed, and no marking is flagged for it
    m2 = match_frame([], {"markings": [{"id": 1, "points": GT_ROWS}], "ego": {"left": 5, "right": None}})
    assert m2.ego == {"left": None} and m2.marking_outcomes() == ["unmatched"]
    assert not evaluate_frame([], {"frame": "b", "markings": [], "ego": {"left": 5}}).correct


def _gt_frames(n: int) -> list[dict]:
    return [
        {"frame": f"{i:04d}", "markings": [{"id": 1, "points": GT_ROWS}], "ego": {"left": 1, "right": None}}
        for i in range(n)
    ]


def test_only_the_frames_a_run_selected_are_scored():
    """After a run of frames 0:3 of 8, the 5 frames not run are not failures: they are counted apart."""
    from lanegraph.evaluation.metrics import select_frames

    gt = _gt_frames(8)
    pred = [{"frame": f"{i:04d}", "lanes": [{"points": shifted(1)}]} for i in range(3)]
    whole = evaluate(pred, gt)
    assert whole["frames"] == 8 and whole["detection_ratio"] == 3 / 8 and whole["frames_not_run"] == 0
    by_ids = evaluate(pred, gt, frames=["0000", "0001", "0002"])
    assert by_ids["frames"] == 3 and by_ids["detection_ratio"] == 1.0 and by_ids["failed_frames"] == []
    assert by_ids["frames_not_run"] == 5 and by_ids["ego_recall"] == 1.0
    assert evaluate(pred, gt, frames=slice(0, 3))["detection_ratio"] == 1.0
    # a selected frame the run did not write (it failed) is still scored: nothing reported
    res = evaluate(pred, gt, frames=["0000", "0001", "0002", "0005"])
    assert res["frames"] == 4 and [f["frame"] for f in res["failed_frames"]] == ["0005"]
    assert res["frames_not_run"] == 4
    kept, not_run = select_frames(gt, slice(2, 8, 2))
    assert [g["frame"] for g in kept] == ["0002", "0004", "0006"] and not_run == 5
    # ids of frames the ground truth does not have select nothing of it
    assert select_frames(gt, ["x"]) == ([], 8)
    # the records are kept in file order, as the docstring says, whatever the step's sign
    kept, not_run = select_frames(gt, slice(6, 1, -2))
    assert [g["frame"] for g in kept] == ["0002", "0004", "0006"] and not_run == 5
    res = evaluate(pred, gt, frames=slice(None, None, -1))
    assert [r.frame for r in res["per_frame"]] == [f"{i:04d}" for i in range(8)]


def test_evaluate_sequences_with_the_frames_of_each_run():
    from lanegraph.evaluation.dataset import POOLED, evaluate_sequences

    gt_a, gt_b = _gt_frames(6), _gt_frames(4)
    pred_a = [{"frame": f"{i:04d}", "lanes": [{"points": shifted(0)}]} for i in range(2)]
    pred_b = [{"frame": f"{i:04d}", "lanes": [{"points": shifted(0)}]} for i in range(4)]
    res = evaluate_sequences([("a", pred_a, gt_a), ("b", pred_b, gt_b)], frames={"a": ["0000", "0001"]})
    assert res["a"]["frames"] == 2 and res["a"]["frames_not_run"] == 4 and res["a"]["detection_ratio"] == 1.0
    assert res["b"]["frames"] == 4 and res["b"]["frames_not_run"] == 0
    assert res[POOLED]["frames"] == 6 and res[POOLED]["detection_ratio"] == 1.0
    assert res[POOLED]["frames_not_run"] == 4
