"""The quick start's result: a run of the synthetic scene writes the scene's exact ground truth
beside its lanes, ends with its detection ratio and a picture's path, and ``lanegraph eval OUT``
scores it without being told where the ground truth is."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from lanegraph import RunContext
from lanegraph.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_the_synthetic_source_writes_its_exact_ground_truth(tmp_path):
    from lanegraph_synthetic import SceneRenderer, SyntheticParams, SyntheticSource, preset

    params = SyntheticParams(frames=4)
    # a resumed run that did frame 1 already: its line is written first, then one per frame rendered
    src = SyntheticSource(params, RunContext(out_dir=tmp_path, frames=slice(1, 4), skip=1))
    gt = tmp_path / "lanes_gt.jsonl"
    assert [json.loads(x)["frame"] for x in gt.read_text().splitlines()] == ["0000000001"]
    frames = [f["frame"] for f in src]
    assert frames == ["0000000002", "0000000003"]
    renderer = SceneRenderer(preset("straight"))
    want = [renderer.lanes_gt(k) for k in (1, 2, 3)]
    got = [json.loads(x) for x in gt.read_text().splitlines()]
    assert got == json.loads(json.dumps(want)) and all(g["markings"] for g in got)
    # no output folder (a report reading the left images): nothing written
    list(SyntheticSource(params, RunContext(frames=slice(0, 1))))


def test_the_quick_start_ends_with_a_score_and_a_picture(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, ["run", str(ROOT / "graphs/paper.yaml"), "--frames", "0:2"])
    assert r.exit_code == 0, r.output
    assert "detection ratio 100.0 % on 2 frame(s)" in r.output
    assert f"against {Path('out') / 'lanes_gt.jsonl'}" in r.output
    assert f"writes {Path('out') / 'report' / 'index.html'}" in r.output
    assert len((tmp_path / "out" / "lanes_gt.jsonl").read_text().splitlines()) == 2
    r = CliRunner().invoke(main, ["eval", "out", "--json"])
    assert r.exit_code == 0, r.output
    res = json.loads(r.output.splitlines()[-1])
    assert res["frames"] == 2 and res["detection_ratio"] == 1.0
    # --overwrite replaces the ground truth with the rest of lanegraph's files
    r = CliRunner().invoke(
        main, ["run", str(ROOT / "graphs/paper.yaml"), "--frames", "0:1", "--overwrite", "-q"]
    )
    assert r.exit_code == 0, r.output
    assert "detection ratio" not in r.output
    assert len((tmp_path / "out" / "lanes_gt.jsonl").read_text().splitlines()) == 1


def test_eval_without_gt_uses_only_the_runs_own_input(tmp_path):
    """A run of an input folder is scored against that folder's ground truth only: one in the run
    folder is not its answer."""
    from lanegraph_synthetic import preset, write_sequence

    seq = write_sequence(preset("straight"), tmp_path / "seq", 2)
    out = tmp_path / "run"
    r = CliRunner().invoke(
        main, ["run", str(ROOT / "graphs/paper.yaml"), "--input", str(seq), "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    assert f"against {seq / 'lanes_gt.jsonl'}" in r.output
    assert not (out / "lanes_gt.jsonl").exists()  # written by the synthetic source only
    (seq / "lanes_gt.jsonl").rename(out / "lanes_gt.jsonl")
    r = CliRunner().invoke(main, ["eval", str(out)])
    assert r.exit_code == 2 and "no ground truth found" in r.output
