"""`lanegraph ablate`: variants and sweeps evaluated, shared work computed once, unchanged runs reused."""

from __future__ import annotations

import csv
from pathlib import Path

from click.testing import CliRunner

from lanegraph.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_ablate_on_a_synthetic_sequence(tmp_path):
    from lanegraph_synthetic import preset, write_sequence

    seq = write_sequence(preset("straight"), tmp_path / "seq", 3)
    args = [
        "ablate",
        str(ROOT / "graphs/paper.yaml"),
        str(ROOT / "graphs/ablations/slt.yaml"),
        "--input",
        str(seq),
        "--gt",
        str(seq / "lanes_gt.jsonl"),
        "--out",
        str(tmp_path / "out"),
        "--cache-dir",
        str(tmp_path / "cache"),
        "--sweep",
        "fit.roi_width=20,60",
        "--quiet",
    ]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    all_rows = list(csv.DictReader((tmp_path / "out" / "results.csv").open()))
    # one row for the sequence (named after the input folder) and one pooled row per variant
    assert [row["sequence"] for row in all_rows] == ["seq", "all"] * 4
    rows = [row for row in all_rows if row["sequence"] == "seq"]
    assert [row["variant"] for row in rows] == [
        "paper",
        "slt",
        "paper[fit.roi_width=20]",
        "paper[fit.roi_width=60]",
    ]
    assert all(row["detection_ratio"] not in ("", None) for row in rows)
    # with one sequence the pooled row is that sequence's figures
    pooled = [row for row in all_rows if row["sequence"] == "all"]
    assert [row["detection_ratio"] for row in pooled] == [row["detection_ratio"] for row in rows]
    # slt and the sweep points share disparity, road and IPM with paper: 5 nodes x 3 frames
    assert int(rows[1]["cache_hits"]) >= 15 and int(rows[0]["cache_hits"]) == 0
    assert float(rows[0]["ms_disp"]) > 0
    assert (tmp_path / "out" / "runs" / "slt" / "seq" / "lanes.jsonl").is_file()
    for f in ("results.md", "accuracy.png", "accuracy_vs_ms.png"):
        assert (tmp_path / "out" / f).stat().st_size > 0
    # nothing changed: every run is reused
    r = CliRunner().invoke(main, args)
    rows2 = [
        row for row in csv.DictReader((tmp_path / "out" / "results.csv").open()) if row["sequence"] == "seq"
    ]
    assert all(row["reused"] == "True" for row in rows2)
    assert [row["detection_ratio"] for row in rows2] == [row["detection_ratio"] for row in rows]
    # --no-cache recomputes
    r = CliRunner().invoke(main, [*args, "--no-cache"])
    rows3 = [
        row for row in csv.DictReader((tmp_path / "out" / "results.csv").open()) if row["sequence"] == "seq"
    ]
    assert all(row["reused"] == "False" and row["cache_hits"] == "0" for row in rows3)


def test_ablate_over_a_dataset_reports_each_sequence_and_the_pooled_figures(tmp_path):
    from lanegraph_synthetic import preset, write_sequence

    from lanegraph.evaluation.metrics import evaluate, read_jsonl

    a = write_sequence(preset("straight"), tmp_path / "data" / "a", 2)
    b = write_sequence(preset("curved"), tmp_path / "data" / "b", 3)
    ds = tmp_path / "data" / "ds.yaml"
    ds.write_text(
        "name: two\nsequences:\n"
        "  - {name: straight, input: a, gt: a/lanes_gt.jsonl}\n"
        "  - {name: curve, input: b, gt: b/lanes_gt.jsonl, frames: '1:3'}\n"
    )
    out = tmp_path / "out"
    args = [
        "ablate",
        str(ROOT / "graphs/paper.yaml"),
        "--dataset",
        str(ds),
        "--out",
        str(out),
        "--no-cache",
        "--quiet",
    ]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert [(row["variant"], row["sequence"], row["frames"]) for row in rows] == [
        ("paper", "straight", "2"),
        ("paper", "curve", "2"),
        ("paper", "all", "4"),
    ]
    # the pooled detection ratio is over every frame of both sequences
    evs = [
        evaluate(
            read_jsonl(out / "runs" / "paper" / "straight" / "lanes.jsonl"), read_jsonl(a / "lanes_gt.jsonl")
        ),
        evaluate(
            read_jsonl(out / "runs" / "paper" / "curve" / "lanes.jsonl"),
            read_jsonl(b / "lanes_gt.jsonl")[1:3],
        ),
    ]
    correct = sum(round(e["detection_ratio"] * e["frames"]) for e in evs)
    assert abs(float(rows[2]["detection_ratio"]) - correct / 4) < 1e-9
    assert [
        json_frame(line)
        for line in (out / "runs" / "paper" / "curve" / "lanes.jsonl").read_text().splitlines()
    ] == [g["frame"] for g in read_jsonl(b / "lanes_gt.jsonl")[1:3]]
    md = (out / "results.md").read_text()
    assert "Sequence straight (2 frames)" in md and "Sequence curve (2 frames)" in md and "pooled" in md
    # --dataset with --input is a usage error, before anything runs
    r = CliRunner().invoke(main, [*args[:-2], "--input", str(a), "--out", str(tmp_path / "o2")])
    assert r.exit_code == 2 and "--dataset" in r.output and not (tmp_path / "o2").exists()


def json_frame(line: str) -> str:
    import json

    return json.loads(line)["frame"]


def test_ablate_rejects_an_invalid_variant_before_running(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"extends: {ROOT / 'graphs/paper.yaml'}\nnodes:\n  fit: {{params: {{iterations: 0}}}}\n")
    r = CliRunner().invoke(
        main, ["ablate", str(ROOT / "graphs/paper.yaml"), str(bad), "--out", str(tmp_path / "o"), "--quiet"]
    )
    assert r.exit_code == 2 and "bad.yaml: node 'fit' (fit.irls): params.iterations" in r.output
    assert not (tmp_path / "o" / "results.csv").exists()


def test_ablate_unusable_input_exits_2_like_run(tmp_path):
    import cv2
    import numpy as np

    for side in ("left", "right"):
        (tmp_path / "in" / side).mkdir(parents=True)
        cv2.imwrite(str(tmp_path / "in" / side / "000000.png"), np.zeros((48, 64), np.uint8))
    graph = str(Path(__file__).resolve().parents[2] / "graphs" / "paper.yaml")
    r = CliRunner().invoke(
        main,
        [
            "ablate",
            graph,
            "--input",
            str(tmp_path / "in"),
            "--out",
            str(tmp_path / "o"),
            "--quiet",
            "--no-cache",
        ],
    )
    assert r.exit_code == 2, r.output
    assert "calib.yaml" in r.output and "Traceback" not in r.output


def test_python_dash_m_lanegraph_is_the_cli():
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-m", "lanegraph", "--version"], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0 and "lanegraph, version" in out.stdout
