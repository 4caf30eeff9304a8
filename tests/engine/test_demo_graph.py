"""The engine demo graph end to end: on the built-in synthetic scene, and on the real KITTI drive."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from lanegraph.cli import main

DEMO = str(Path(__file__).resolve().parents[2] / "graphs" / "demo_sgbm.yaml")


def test_demo_graph_on_synthetic_scene(tmp_path):
    r = CliRunner().invoke(main, ["run", DEMO, "--out", str(tmp_path), "--frames", "0:2", "--quiet"])
    assert r.exit_code == 0, r.output
    lines = (tmp_path / "lanes.jsonl").read_text().splitlines()
    assert [json.loads(x)["frame"] for x in lines] == ["0000000000", "0000000001"]
    t = json.loads((tmp_path / "timings.json").read_text())
    assert (
        t["frames"] == 2
        and t["nodes"]["src"]["type"] == "io.synthetic"
        and t["nodes"]["disp"]["type"] == "disparity.sgbm"
    )


def test_demo_graph_on_kitti(kitti_drive, tmp_path):
    r = CliRunner().invoke(
        main, ["run", DEMO, "--input", str(kitti_drive), "--out", str(tmp_path), "--quiet"]
    )
    assert r.exit_code == 0, r.output
    assert len((tmp_path / "lanes.jsonl").read_text().splitlines()) == 54
    t = json.loads((tmp_path / "timings.json").read_text())
    assert t["frames"] == 54 and t["nodes"]["src"]["type"] == "io.kitti_raw"


def test_unknown_input_layout_is_a_located_error(tmp_path):
    (tmp_path / "empty").mkdir()
    r = CliRunner().invoke(main, ["run", DEMO, "--input", str(tmp_path / "empty"), "--out", str(tmp_path)])
    assert r.exit_code == 2
    assert "node 'src'" in r.output and "no installed source node type recognises the input" in r.output
