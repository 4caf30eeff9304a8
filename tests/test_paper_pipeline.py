"""The paper's pipeline end to end: on the real KITTI drive (the issue's acceptance figures) and on
synthetic scenes with known answers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from lanegraph.cli import main
from lanegraph.evaluation.metrics import evaluate, read_jsonl
from lanegraph.graph.validation import load_graph
from tests.test_sweep_kitti import sweep_kitti  # benchmarks/sweep_kitti.py, as that test loads it

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "graphs" / "paper.yaml")


def run(graph, out, *args):
    r = CliRunner().invoke(main, ["run", graph, "--out", str(out), "--quiet", *args])
    assert r.exit_code == 0, r.output
    return read_jsonl(out / "lanes.jsonl")


@pytest.mark.kitti
def test_paper_graph_on_kitti_reaches_the_target(kitti_drive, tmp_path):
    pred = run(PAPER, tmp_path, "--input", str(kitti_drive))
    assert len(pred) == 54
    res = evaluate(pred, read_jsonl(kitti_drive / "lanes_gt.jsonl"))
    assert res["detection_ratio"] >= 0.90, res["failed_frames"]
    assert res["precision"] >= 0.95
    for rec in pred:
        for lane in rec["lanes"]:
            ys = [p[1] for p in lane["points"]]
            assert all(abs(a - b) <= 10 for a, b in zip(ys, ys[1:]))
            assert all(0 <= p[0] < 1242 and 0 <= p[1] < 375 for p in lane["points"])
    t = json.loads((tmp_path / "timings.json").read_text())
    assert t["nodes"]["disp"]["type"] == "disparity.road_sgbm" and t["frames"] == 54


@pytest.mark.kitti
def test_paper_graph_on_kitti_at_another_exposure(kitti_drive, tmp_path):
    """A camera exposed darker sees paint, gravel and kerbs at 0.6 times the contrast: the road
    mask and the lanes must not depend on the grey levels of one camera setting (lanes.verify
    measures texture relative to the road's level; an absolute threshold let the kerb beside the
    tram tracks through on 25 of 54 frames)."""
    drive = sweep_kitti.write_variant(kitti_drive, tmp_path / "dark", "gain", 0.6)  # both cameras at 0.6
    pred = run(PAPER, tmp_path / "out", "--input", str(drive))
    res = evaluate(pred, read_jsonl(kitti_drive / "lanes_gt.jsonl"))
    assert res["detection_ratio"] >= 0.90, res["failed_frames"]
    assert res["precision"] >= 0.95


@pytest.mark.kitti
def test_paper_graph_reports_no_kerb_on_a_street_of_cracks(tmp_path):
    """kitti_singles/odom00 (two frames of a residential street with tar-sealed cracks, no markings):
    the followed line along the right kerb has a much darker, smooth side (the gutter) and passed
    the side check; the road's height steps 8-17 cm across it (the disparity), which paint on the
    road plane never does."""
    scene = ROOT.parent / "shared" / "data" / "kitti_singles" / "odom00"
    if not (scene / "image_2").is_dir():
        pytest.skip(f"real KITTI data not found at {scene} (a fresh clone has no ../shared/data)")
    pred = run(PAPER, tmp_path / "out", "--input", str(scene))
    assert len(pred) == 2 and all(rec["lanes"] == [] for rec in pred)
    # without the flatness rule the kerb is reported: the test sees the rule, not the data
    pred = run(
        PAPER, tmp_path / "off", "--input", str(scene), "--set", "verify_followed.max_dark_side_step_m=null"
    )
    assert any(rec["lanes"] for rec in pred)


@pytest.mark.parametrize(
    "name, overrides",
    [
        ("no_markings", {}),
        # kerbs are bright parallel-bordered ridges like paint: the road mask must keep them out
        ("kerbs", {"markings": [], "arrows": 0.0, "hatching": 0.0}),
    ],
)
def test_no_painted_markings_reports_no_lanes(name, overrides, tmp_path):
    from lanegraph_synthetic import preset, write_sequence

    seq = write_sequence(preset(name, **overrides), tmp_path / "seq", 4)
    pred = run(PAPER, tmp_path / "out", "--input", str(seq))
    assert len(pred) == 4 and all(rec["lanes"] == [] for rec in pred)


def test_paper_graph_on_the_default_synthetic_scene(tmp_path):
    """The README's first command: every reported lane is a real marking (precision 1)."""
    from lanegraph_synthetic import SceneRenderer, preset

    pred = run(PAPER, tmp_path, "--frames", "0:3")
    assert len(pred) == 3
    renderer = SceneRenderer(preset("straight"))
    res = evaluate(pred, [renderer.lanes_gt(k) for k in range(3)])
    assert sum(len(r["lanes"]) for r in pred) >= 1
    assert res["precision"] == 1.0 and res["mean_abs_dx_px"] < 5
    for rec in pred:
        for lane in rec["lanes"]:
            assert lane["side"] in ("left", "right") and 0 < lane["score"] <= 1


@pytest.mark.parametrize("variant", sorted(p.name for p in (ROOT / "graphs" / "ablations").glob("*.yaml")))
def test_every_ablation_variant_validates(variant):
    g = load_graph(ROOT / "graphs" / "ablations" / variant)
    assert g.nodes and g.source.type.name == "io.auto"
