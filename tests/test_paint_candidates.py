"""benchmarks/paint_candidates.py: its figures (precision and recall of paint), its labels of what a
candidate that is no paint lies on, and the model it writes (read back by lanes.verify_learned)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from lanegraph_lanes._paint import FEATURES, PaintModel

from lanegraph.types import BevGeometry, Lane

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location(
        "paint_candidates", ROOT / "benchmarks" / "paint_candidates.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_precision_and_recall_of_paint():
    pc = _script()
    decided = np.array([True, True, False, False, True])
    paint = np.array([True, False, True, False, True])
    precision, recall, n_paint, n_other = pc.pr(decided, paint)
    assert precision == pytest.approx(2 / 3) and recall == pytest.approx(2 / 3)
    assert (n_paint, n_other) == (3, 2)
    p, r, _, _ = pc.pr(np.zeros(2, bool), np.zeros(2, bool))
    assert math.isnan(p) and math.isnan(r)


def test_what_a_candidate_that_is_no_paint_lies_on():
    pc = _script()
    g = BevGeometry(-5.0, 5.0, 5.0, 35.0, 0.05, np.eye(3))
    lane = Lane((100.0, 0.0, 0.0), (0, 599), "right", 0.9)
    f = dict.fromkeys(FEATURES, 0.0) | {
        "contrast": 0.5,
        "side_ratio": 0.9,
        "width_m": 0.15,
        "painted_fraction": 0.8,
    }
    assert pc._what(f, 30.0, lane, [lane], g) == "on paint, off"
    assert pc._what(f | {"height_step_m": 0.12}, 80.0, lane, [lane], g) == "kerb"
    rail = Lane((128.0, 0.0, 0.0), (0, 599), "right", 0.9)  # 1.4 m beside it
    assert pc._what(f | {"width_m": 0.06}, 80.0, lane, [lane, rail], g) == "rail"
    assert pc._what(f | {"side_ratio": 0.5, "dark_texture": 5.0}, 80.0, lane, [lane], g) == "shadow edge"
    assert pc._what(f | {"contrast": math.nan}, 80.0, lane, [lane], g) == "crack"
    assert pc._what(f, 80.0, lane, [lane], g) == "other"


def test_the_model_it_writes_is_read_by_the_node():
    pytest.importorskip("sklearn")
    pc = _script()
    rng = np.random.default_rng(0)
    n = 200
    x = rng.normal(0.0, 1.0, (n, len(FEATURES)))
    k = FEATURES.index("painted_fraction")
    y = x[:, k] > 0.0
    x[::17, 0] = np.nan  # not measured: filled
    fill = np.zeros(len(FEATURES))
    spec = pc.fit_model(x, y, FEATURES, fill)
    m = PaintModel(spec)
    assert m.probability({"painted_fraction": 2.0}) > m.threshold > m.probability({"painted_fraction": -2.0})
    assert spec["features"] == list(FEATURES) and all(math.isfinite(v) for v in spec["coef"])
