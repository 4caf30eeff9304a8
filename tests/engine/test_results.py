"""The engine finds a run's lanes through what its sinks declare (lanegraph.records.results), never by a
file name of its own: a lanes file the graph renames is found by eval, report and ablate; eval's
lateral error reads the calibration through the installed plugins."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from lanegraph import plugins
from lanegraph.cli import main
from lanegraph.records.results import LANES, default_names, find_result, recorded_result_files

ROOT = Path(__file__).resolve().parents[2]
DEMO = str(ROOT / "graphs" / "demo_sgbm.yaml")


@pytest.fixture
def cli(installed_pm, monkeypatch):
    monkeypatch.setattr(plugins, "_default", installed_pm)
    return CliRunner()


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    from lanegraph_synthetic import preset, write_sequence

    return write_sequence(preset("straight"), tmp_path_factory.mktemp("scene") / "seq", 3)


def test_the_lanes_writer_declares_its_file(installed_pm):
    assert default_names(LANES, installed_pm) == ["lanes.jsonl"]
    lanes = installed_pm.node_types["io.write_lanes"]
    assert lanes.result_files(lanes.params(filename="a/b.jsonl")) == {"lanes": "a/b.jsonl"}


def test_a_renamed_lanes_file_is_found_through_run_json(cli, scene, tmp_path):
    out = tmp_path / "out"
    r = cli.invoke(
        main,
        [
            "run",
            DEMO,
            "--input",
            str(scene),
            "--out",
            str(out),
            "--set",
            "write.filename=sub/mine.jsonl",
            "--quiet",
        ],
    )
    assert r.exit_code == 0, r.output
    assert recorded_result_files(out) == {"lanes": "sub/mine.jsonl"} and not (out / "lanes.jsonl").exists()
    assert find_result(out, LANES) == out / "sub" / "mine.jsonl"
    r = cli.invoke(main, ["eval", str(out), str(scene / "lanes_gt.jsonl"), "--json"])  # PRED: the run folder
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["frames"] == 3
    r = cli.invoke(main, ["report", str(out), "--quiet"])
    assert r.exit_code == 0, r.output
    assert "3 frame(s)" in r.output
    r = cli.invoke(main, ["eval", str(tmp_path), str(scene / "lanes_gt.jsonl")])
    assert (
        r.exit_code == 2 and f"{tmp_path}: no predictions (expected {tmp_path / 'lanes.jsonl'})" in r.output
    ), r.output


def test_run_dataset_says_where_each_sequence_s_lanes_are(cli, scene, tmp_path):
    ds = tmp_path / "ds.yaml"
    ds.write_text(f"sequences:\n  - {{name: one, input: {scene}, gt: {scene / 'lanes_gt.jsonl'}}}\n")
    r = cli.invoke(
        main,
        [
            "run",
            DEMO,
            "--dataset",
            str(ds),
            "--out",
            str(tmp_path / "runs"),
            "--set",
            "write.filename=l.jsonl",
            "--quiet",
        ],
    )
    assert r.exit_code == 0, r.output
    assert f"one: 3 frame(s) -> {tmp_path / 'runs' / 'one' / 'l.jsonl'}" in r.output
    r = cli.invoke(main, ["eval", str(tmp_path / "runs"), "--dataset", str(ds), "--json"])
    assert r.exit_code == 0 and json.loads(r.output)["sequences"]["one"]["frames"] == 3, r.output


def test_ablate_evaluates_a_renamed_lanes_file(cli, scene, tmp_path):
    variant = tmp_path / "renamed.yaml"
    variant.write_text(f"extends: {DEMO}\nnodes:\n  write: {{params: {{filename: other.jsonl}}}}\n")
    r = cli.invoke(
        main,
        [
            "ablate",
            DEMO,
            str(variant),
            "--input",
            str(scene),
            "--gt",
            str(scene / "lanes_gt.jsonl"),
            "--out",
            str(tmp_path / "abl"),
            "--no-cache",
            "--quiet",
        ],
    )
    assert r.exit_code == 0, r.output
    rows = {
        row.split(",")[0]: row.split(",")
        for row in (tmp_path / "abl" / "results.csv").read_text().splitlines()[1:]
        if ",all," not in row
    }
    assert rows["renamed"][2] == rows["demo_sgbm"][2] == "3"  # both evaluated over the 3 frames
    assert (tmp_path / "abl" / "runs" / "renamed" / "seq" / "other.jsonl").is_file()


def test_eval_lateral_reads_the_calibration_through_the_plugins(cli, scene, tmp_path):
    out = tmp_path / "out"
    assert cli.invoke(main, ["run", DEMO, "--input", str(scene), "--out", str(out), "--quiet"]).exit_code == 0
    args = [
        "eval",
        str(out / "lanes.jsonl"),
        str(scene / "lanes_gt.jsonl"),
        "--scene",
        str(scene / "scene.json"),
        "--json",
    ]
    r = cli.invoke(main, args)  # the calibration of the folder holding scene.json, read by its source
    assert r.exit_code == 0, r.output
    assert set(json.loads(r.output)["lateral_error_cm"]) == {"10", "20", "30"}
    r = cli.invoke(
        main, [*args, "--calib", str(scene / "calib.yaml")]
    )  # a calibration file, read by a plugin
    assert r.exit_code == 0, r.output
    (tmp_path / "calib.txt").write_text("not a format any plugin reads\n")
    r = cli.invoke(main, [*args, "--calib", str(tmp_path / "calib.txt")])
    assert r.exit_code == 2 and "no installed plugin reads this calibration file" in r.output


def test_the_frames_a_run_selected_are_read_from_its_record(tmp_path):
    import json

    from lanegraph.records.results import recorded_selection

    assert recorded_selection(tmp_path) is None
    (tmp_path / "run.json").write_text(json.dumps({"status": "ok"}))
    assert recorded_selection(tmp_path) is None  # an older record: every ground-truth frame is scored
    (tmp_path / "run.json").write_text(json.dumps({"selection": {"frames": "0:2", "ids": ["0000", "0001"]}}))
    assert recorded_selection(tmp_path) == ("0:2", ["0000", "0001"])
    (tmp_path / "run.json").write_text(json.dumps({"selection": {"frames": "", "ids": []}}))
    assert recorded_selection(tmp_path) == (None, [])
