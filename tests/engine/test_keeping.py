"""Runs a researcher can trust months later, end to end through the command line: one run per
output folder, the resolved graph and the record beside the results, exactly the frames run scored,
a run's log, the verbosity flags, tracking with MLflow."""

from __future__ import annotations

import copy
import csv
import json
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from lanegraph import plugins
from lanegraph.cli import main

from .test_graph import VALID

ROOT = Path(__file__).resolve().parents[2]
PAPER = str(ROOT / "graphs" / "paper.yaml")


def snapshot(folder: Path) -> dict[str, tuple[bytes | None, int]]:
    return {
        str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None, p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
    }


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    """A synthetic sequence of 5 frames with its ground truth."""
    from lanegraph_synthetic import preset, write_sequence

    return write_sequence(preset("straight"), tmp_path_factory.mktemp("seq") / "straight", 5)


def lanegraph(*args: str) -> object:
    return CliRunner().invoke(main, [str(a) for a in args])


def test_a_folder_holding_another_runs_results_is_refused_before_any_frame(seq, tmp_path):
    out = tmp_path / "out"
    r = lanegraph("run", PAPER, "--input", seq, "--out", out, "--frames", "0:2", "-q")
    assert r.exit_code == 0, r.output
    before = snapshot(out)
    for other in (["--set", "fit.roi_width=30"], ["--frames", "0:3"], ["--input", seq.parent]):
        args = ["run", PAPER, "--input", seq, "--out", out, "--frames", "0:2", "-q", *other]
        r = lanegraph(*args)
        assert r.exit_code == 2, r.output
        assert r.output.startswith(f"error: --out {out}: holds the results of another run: ")
        assert "--overwrite" in r.output and "another output folder" in r.output
        assert "frame(s) processed" not in r.output
        assert snapshot(out) == before  # not a byte, not a time stamp changed
    # the same run again is fine; with --overwrite another one replaces it
    assert lanegraph("run", PAPER, "--input", seq, "--out", out, "--frames", "0:2", "-q").exit_code == 0
    (out / "notes.txt").write_text("the user's")
    r = lanegraph("run", PAPER, "--input", seq, "--out", out, "--frames", "0:3", "-q", "--overwrite")
    assert r.exit_code == 0, r.output
    record = json.loads((out / "run.json").read_text())
    assert record["selection"]["frames"] == "0:3" and (out / "notes.txt").read_text() == "the user's"


def test_an_interrupted_run_is_refused_without_resume(seq, tmp_path):
    out = tmp_path / "out"
    assert lanegraph("run", PAPER, "--input", seq, "--out", out, "--frames", "0:3", "-q").exit_code == 0
    # as a killed run leaves it: a checkpoint one frame short of the end, no record
    ckpt = json.loads((out / "checkpoint.json").read_text())
    (out / "run.json").unlink()
    ckpt.update(complete=False)
    (out / "checkpoint.json").write_text(json.dumps(ckpt))
    before = snapshot(out)
    r = lanegraph("run", PAPER, "--input", seq, "--out", out, "--frames", "0:3", "-q")
    assert r.exit_code == 2 and "holds this run, unfinished (3 of 3 frame(s) done" in r.output
    assert "continue it with --resume" in r.output and snapshot(out) == before


def test_the_resolved_graph_beside_the_results_runs_as_it_is(seq, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    r = lanegraph("run", ROOT / "graphs/ablations/slt.yaml", "--input", seq, "--out", a, "-q",
                  "--set", "fit.roi_width=30", "--set", "hough.select=paper")  # fmt: skip
    assert r.exit_code == 0, r.output
    graph = yaml.safe_load((a / "graph.yaml").read_text())
    assert graph["nodes"]["fit"]["params"]["roi_width"] == 30 and "extends" not in graph
    r = lanegraph("run", a / "graph.yaml", "--input", seq, "--out", b, "-q")
    assert r.exit_code == 0, r.output
    assert (b / "lanes.jsonl").read_bytes() == (a / "lanes.jsonl").read_bytes()
    assert (b / "lanes.jsonl").stat().st_size > 100
    record = json.loads((a / "run.json").read_text())
    assert record["overrides"] == ["fit.roi_width=30", "hough.select=paper"]
    assert record["command"][:2] == ["lanegraph", "run"] and "fit.roi_width=30" in record["command"]
    assert record["selection"] == {"frames": "", "ids": [f"{i:010d}" for i in range(5)]}
    assert record["identity"]["input"] == str(seq.resolve())
    v = record["versions"]
    assert {"python", "lanegraph", "numpy", "opencv", "numba"} <= set(v) and v["plugins"]["lanegraph"] == v[
        "lanegraph"
    ]
    if (ROOT / ".git").exists():  # a checkout (a worktree's .git is a file)
        assert len(record["git"]["commit"]) == 40


def test_eval_and_report_score_exactly_the_frames_the_run_selected(seq, tmp_path):
    out = tmp_path / "out"
    assert lanegraph("run", PAPER, "--input", seq, "--out", out, "--frames", "0:3", "-q").exit_code == 0
    gt = seq / "lanes_gt.jsonl"
    r = lanegraph("eval", out, gt, "--json")
    res = json.loads(r.output)
    assert res["frames"] == 3 and res["frames_not_run"] == 2
    assert all(f["frame"] < "0000000003" for f in res["failed_frames"])
    r = lanegraph("eval", out / "lanes.jsonl", gt)
    assert r.output.splitlines()[0].startswith(
        "frames:          3 (2 frame(s) of the ground truth not run, not scored"
    )
    r = lanegraph("eval", out / "lanes.jsonl", gt, "--frames", "1:2", "--json")
    assert json.loads(r.output)["frames"] == 1 and json.loads(r.output)["frames_not_run"] == 4
    # a lanes file away from its run: no record, every frame of the ground truth
    lone = tmp_path / "lone.jsonl"
    lone.write_bytes((out / "lanes.jsonl").read_bytes())
    assert json.loads(lanegraph("eval", lone, gt, "--json").output)["frames"] == 5
    r = lanegraph("report", out, "--quiet")
    assert r.exit_code == 0, r.output
    assert "(3 frame(s)," in r.output
    page = (out / "report" / "index.html").read_text()
    assert "2 frame(s) of the ground truth not run" in page


def test_run_log_holds_warnings_and_every_frame_error(pm, monkeypatch, tmp_path):
    monkeypatch.setattr(plugins, "_default", pm)
    d = copy.deepcopy(VALID)
    d["nodes"]["double"]["on_error"] = "skip"
    g = tmp_path / "g.yaml"
    g.write_text(yaml.safe_dump(d))
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["run", str(g), "--out", str(out), "-q", "--set", "double.fail_on=2"])
    assert r.exit_code == 1
    log = (out / "run.log").read_text()
    assert "frame 0002: node 'double' (toy.scale) raised ValueError: boom on 2" in log
    assert "1 frame(s) failed" in log and "WARNING" in log
    assert "INFO lanegraph.run: run of" in log  # what was run, in the log only
    assert "run of" not in r.output  # -q: warnings and errors only on the terminal
    assert "1 frame(s) failed" in r.output
    r = CliRunner().invoke(main, ["run", str(g), "--out", str(tmp_path / "v"), "-v"])
    assert r.exit_code == 0 and "debug: frame 0001 (#1) done" in r.output
    assert "DEBUG lanegraph.run: frame 0001 (#1) done" in (tmp_path / "v" / "run.log").read_text()
    r = CliRunner().invoke(main, ["run", str(g), "--out", str(tmp_path / "qq"), "-qq"])
    assert r.exit_code == 0 and r.output.strip().startswith("4 frame(s) processed")  # no notes, no bar


def test_an_ablation_folder_lists_only_its_own_variants(seq, tmp_path):
    out = tmp_path / "abl"
    base = ["ablate", PAPER]
    common = ["--input", seq, "--gt", seq / "lanes_gt.jsonl", "--out", out, "--frames", "0:2", "-q"]
    common += ["--cache-dir", tmp_path / "cache"]
    assert (
        lanegraph(
            *base, ROOT / "graphs/ablations/slt.yaml", ROOT / "graphs/ablations/bm.yaml", *common
        ).exit_code
        == 0
    )
    before = snapshot(out)
    r = lanegraph(*base, ROOT / "graphs/ablations/ransac.yaml", *common, "--report")
    assert r.exit_code == 2 and "other variants: paper, slt, bm there, paper, ransac now" in r.output
    assert snapshot(out) == before
    r = lanegraph(*base, ROOT / "graphs/ablations/ransac.yaml", *common, "--report", "--overwrite")
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert {row["variant"] for row in rows} == {"paper", "ransac"}
    assert sorted(p.name for p in (out / "runs").iterdir()) == ["paper", "ransac"]
    assert "slt" not in (out / "results.md").read_text()
    page = (out / "report" / "index.html").read_text()
    assert "ransac" in page and '"slt"' not in page and "ablation of 2 variants" in page
    command = json.loads((out / "command.json").read_text())
    assert [v["name"] for v in command["variants"]] == ["paper", "ransac"]
    run = json.loads((out / "runs" / "ransac" / "straight" / "run.json").read_text())
    assert (
        run["selection"]["ids"] == ["0000000000", "0000000001"]
        and (out / "runs/ransac/straight/graph.yaml").is_file()
    )


@pytest.mark.mlflow
def test_ablate_tracks_every_variant_in_an_mlflow_file_store(seq, tmp_path, monkeypatch):
    mlflow = pytest.importorskip("mlflow", reason='MLflow is not installed: pip install -e ".[mlflow]"')
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "true")
    monkeypatch.setenv("MLFLOW_EXPERIMENT_NAME", "lanegraph-ablate-test")
    store = (tmp_path / "mlruns").as_uri()
    r = lanegraph("ablate", PAPER, ROOT / "graphs/ablations/bm.yaml", "--input", seq, "--gt", seq / "lanes_gt.jsonl",
                  "--out", tmp_path / "abl", "--frames", "0:2", "-q", "--track", f"mlflow:{store}",
                  "--cache-dir", tmp_path / "cache")  # fmt: skip
    assert r.exit_code == 0, r.output
    mlflow.set_tracking_uri(store)
    runs = mlflow.search_runs(experiment_names=["lanegraph-ablate-test"], output_format="list")
    children = {r.data.tags["lanegraph.variant"]: r for r in runs if "mlflow.parentRunId" in r.data.tags}
    assert set(children) == {"paper", "bm"}
    rows = {
        row["variant"]: row
        for row in csv.DictReader((tmp_path / "abl" / "results.csv").open())
        if row["sequence"] == "straight"
    }
    for name, run in children.items():
        assert run.data.metrics["detection_ratio"] == pytest.approx(float(rows[name]["detection_ratio"]))
        assert run.data.params["disp.num_disparities"] and "ms.disp" in run.data.metrics
    parent = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    assert len(parent) == 1 and parent[0].info.status == "FINISHED"


def test_track_with_an_unknown_tracker_is_a_usage_error(seq, tmp_path):
    r = lanegraph("run", PAPER, "--input", seq, "--out", tmp_path / "o", "--track", "wandb")
    assert r.exit_code == 2 and "no tracker 'wandb' is installed (installed: mlflow)" in r.output
    assert not (tmp_path / "o").exists()
