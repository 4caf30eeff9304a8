"""The command line: exit codes, outputs, listings."""

from __future__ import annotations

import json

import pytest
import yaml
from click.testing import CliRunner

from lanegraph import plugins
from lanegraph.cli import main

from .test_graph import VALID


@pytest.fixture
def cli(pm, monkeypatch):
    monkeypatch.setattr(plugins, "_default", pm)
    return CliRunner()


@pytest.fixture
def graph_file(tmp_path):
    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump(VALID))
    return p


def test_validate_ok_and_invalid(cli, graph_file, tmp_path):
    r = cli.invoke(main, ["validate", str(graph_file)])
    assert r.exit_code == 0, r.output
    assert "ok (5 nodes, 1 feedback edge(s))" in r.output
    bad = tmp_path / "bad.yaml"
    d = json.loads(json.dumps(VALID))
    d["nodes"]["double"]["params"]["factor"] = 1000
    bad.write_text(yaml.safe_dump(d))
    r = cli.invoke(main, ["validate", str(bad)])
    assert r.exit_code == 2
    assert "bad.yaml: node 'double' (toy.scale): params.factor" in r.output


def test_missing_graph_file_exit_2(cli, tmp_path):
    r = cli.invoke(main, ["validate", str(tmp_path / "nope.yaml")])
    assert r.exit_code == 2 and "graph file not found" in r.output


def test_run_writes_timings_and_reports_failures(cli, graph_file, tmp_path):
    out = tmp_path / "out"
    r = cli.invoke(main, ["run", str(graph_file), "--out", str(out), "--quiet", "--frames", "0:3"])
    assert r.exit_code == 0, r.output
    t = json.loads((out / "timings.json").read_text())
    assert t["frames"] == 3 and t["nodes"]["double"]["type"] == "toy.scale"
    r = cli.invoke(
        main,
        ["run", str(graph_file), "--out", str(out), "--quiet", "--set", "double.fail_on=2", "--overwrite"],
    )
    assert r.exit_code == 1
    assert "node 'double' (toy.scale) failed on frame 0002" in r.output
    # the stopped run still records what it did and why it stopped
    rec = json.loads((out / "run.json").read_text())
    assert rec["frames_ok"] == 2 and rec["stopped"]["node"] == "double" and rec["stopped"]["frame"] == "0002"
    assert json.loads((out / "timings.json").read_text())["frames"] == 2
    r = cli.invoke(main, ["run", str(graph_file), "--out", str(out), "--quiet", "--set", "double.factor=x"])
    assert r.exit_code == 2


def test_show_formats(cli, graph_file):
    r = cli.invoke(main, ["show", str(graph_file)])
    assert r.exit_code == 0 and yaml.safe_load(r.output)["nodes"]["acc"]["inputs"]["b"] == "acc.y@prev"
    r = cli.invoke(main, ["show", str(graph_file), "--format", "dot"])
    assert "digraph" in r.output and "style=dashed" in r.output
    r = cli.invoke(main, ["show", str(graph_file), "--format", "mermaid"])
    assert r.output.startswith("flowchart TD") and "-.->" in r.output


def test_nodes_and_schema(cli):
    r = cli.invoke(main, ["nodes", "--json"])
    listing = json.loads(r.output)
    names = [n["name"] for n in listing["node_types"]]
    assert "toy.scale" in names
    scale = next(n for n in listing["node_types"] if n["name"] == "toy.scale")
    assert scale["inputs"]["x"]["type"] == "number" and "factor" in scale["params"]["properties"]
    count = next(n for n in listing["node_types"] if n["name"] == "toy.count")
    assert scale["implements"] == [] and count["implements"] == ["constants", "frame_key", "len"]
    stored = {p["name"] for p in listing["port_types"] if p["stored"]}
    assert "lanes" in stored and "image" not in stored
    r = cli.invoke(main, ["schema"])
    assert "node_toy_scale" in json.loads(r.output)["$defs"]


def test_eval_json(cli, tmp_path):
    gt = {
        "frame": "f0",
        "markings": [{"id": 1, "points": [[100, 300], [110, 290], [120, 280]]}],
        "ego": {"left": 1, "right": None},
    }
    (tmp_path / "gt.jsonl").write_text(json.dumps(gt) + "\n" + json.dumps({**gt, "frame": "f1"}) + "\n")
    pred = {"frame": "f0", "lanes": [{"points": [[101, 300], [121, 280]]}]}
    (tmp_path / "p.jsonl").write_text(json.dumps(pred) + "\n")
    r = cli.invoke(main, ["eval", str(tmp_path / "p.jsonl"), str(tmp_path / "gt.jsonl"), "--json"])
    res = json.loads(r.output)
    assert set(res) >= {
        "frames",
        "detection_ratio",
        "precision",
        "ego_recall",
        "mean_abs_dx_px",
        "failed_frames",
    }
    assert res["frames"] == 2 and res["detection_ratio"] == 0.5 and res["precision"] == 1.0
    assert res["failed_frames"][0]["frame"] == "f1"
    r = cli.invoke(main, ["eval", str(tmp_path / "p.jsonl"), str(tmp_path / "gt.jsonl")])
    assert "detection ratio: 50.0 %" in r.output and "f1: ego left boundary" in r.output


def test_extends_outside_allowed_roots_is_rejected_by_the_cli(cli, tmp_path, monkeypatch):
    outside = tmp_path / "outside"
    inside = tmp_path / "work" / "graphs"
    outside.mkdir()
    inside.mkdir(parents=True)
    (outside / "base.yaml").write_text(yaml.safe_dump(VALID))
    child = inside / "child.yaml"
    child.write_text("extends: ../../outside/base.yaml\n")
    monkeypatch.chdir(tmp_path / "work")
    r = cli.invoke(main, ["validate", str(child)])
    assert r.exit_code == 2 and "outside the allowed roots" in r.output
    monkeypatch.setenv("LANEGRAPH_GRAPH_ROOTS", str(outside))
    r = cli.invoke(main, ["validate", str(child)])
    assert r.exit_code == 0, r.output
