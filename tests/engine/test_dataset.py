"""Dataset files: validation located in the file and the sequence, paths relative to the file, the
pooled evaluation, and ``lanegraph eval --dataset``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from lanegraph.cli import main
from lanegraph.errors import InputError
from lanegraph.evaluation.dataset import (
    POOLED,
    evaluate_sequences,
    load_dataset,
    single_sequence,
)
from lanegraph.evaluation.metrics import evaluate
from lanegraph.frames import parse_frames

ROOT = Path(__file__).resolve().parents[2]


def _gt(frame: str, x: float | None) -> dict:
    marks = [] if x is None else [{"id": 0, "points": [[x, 300], [x, 200]]}]
    return {"frame": frame, "markings": marks, "ego": {"left": 0 if marks else None, "right": None}}


def _pred(frame: str, xs: list[float]) -> dict:
    return {"frame": frame, "lanes": [{"points": [[x, 300], [x, 200]]} for x in xs]}


def _layout(tmp_path: Path) -> Path:
    for name in ("a", "b"):
        (tmp_path / "data" / name).mkdir(parents=True)
        (tmp_path / "data" / name / "lanes_gt.jsonl").write_text("")
    ds = tmp_path / "sets" / "ds.yaml"
    ds.parent.mkdir()
    ds.write_text(
        "sequences:\n"
        "  - {name: first, input: ../data/a, gt: ../data/a/lanes_gt.jsonl}\n"
        "  - {name: second, input: ../data/b, frames: '2:8:2'}\n"
    )
    return ds


def test_paths_are_relative_to_the_file_and_frames_parsed(tmp_path):
    ds = load_dataset(_layout(tmp_path))
    assert ds.name == "ds" and [s.name for s in ds] == ["first", "second"]
    assert ds.sequences[0].input == (tmp_path / "data" / "a").resolve()
    assert ds.sequences[0].gt == (tmp_path / "data" / "a" / "lanes_gt.jsonl").resolve()
    assert ds.sequences[1].gt is None and ds.sequences[1].frames == slice(2, 8, 2)
    assert ds.has_gt


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("sequences: []\n", "sequences: List should have at least 1 item"),
        (
            "sequences:\n  - {name: x, input: ../data/a, colour: red}\n",
            "sequence 'x': colour: Extra inputs are not permitted",
        ),
        ("sequences:\n  - {name: ../up, input: ../data/a}\n", "expected a plain name"),
        ("sequences:\n  - {name: all, input: ../data/a}\n", "expected a plain name"),
        (
            "sequences:\n  - {name: x, input: ../data/a, frames: 'a:b'}\n",
            "sequence 'x': frames: Value error, expected A:B",
        ),
        (
            "sequences:\n  - {name: x, input: ../data/a}\n  - {name: x, input: ../data/b}\n",
            "sequence 'x': the name is used twice",
        ),
        ("sequences:\n  - {name: x, input: ../data/nope}\n", "sequence 'x': input:"),
        ("sequences:\n  - {name: x, input: ../data/a, gt: ../data/a/none.jsonl}\n", "sequence 'x': gt:"),
        ("sequences: [\n", "not valid YAML"),
        ("- just a list\n", "Input should be a valid dictionary"),
    ],
)
def test_a_broken_dataset_file_is_located(tmp_path, text, message):
    ds = _layout(tmp_path)
    ds.write_text(text)
    with pytest.raises(InputError) as info:
        load_dataset(ds)
    assert str(ds) in str(info.value) and message in str(info.value)


def test_selection_rules():
    assert parse_frames("3") == slice(3, 4) and parse_frames("-1") == slice(-1, None)  # the last frame
    assert [0, 1, 2][parse_frames("-1")] == [2] and [0, 1, 2][parse_frames("-2")] == [1]
    assert parse_frames(":5") == slice(None, 5) and parse_frames(None) is None
    for bad in ("1:2:0", "1:2:3:4", "x"):
        with pytest.raises(ValueError):
            parse_frames(bad)


def test_single_sequence_is_named_after_its_folder(tmp_path):
    assert [s.name for s in single_sequence(tmp_path / "my drive")] == ["my_drive"]
    assert [s.name for s in single_sequence(None)] == ["synthetic"]


def test_pooled_figures_count_every_frame_once():
    a_gt = [_gt("0", 100), _gt("1", 100)]
    a_pred = [_pred("0", [101]), _pred("1", [300])]  # frame 1: a false lane and a missed boundary
    b_gt = [_gt("0", None), _gt("1", None), _gt("2", 50)]
    b_pred = [_pred("0", []), _pred("1", [20]), _pred("2", [52])]  # frame 1: a false lane
    res = evaluate_sequences([("a", a_pred, a_gt), ("b", b_pred, b_gt)])
    assert res["a"]["detection_ratio"] == 0.5 and abs(res["b"]["detection_ratio"] - 2 / 3) < 1e-12
    pooled = res[POOLED]
    assert pooled["frames"] == 5 and pooled["detection_ratio"] == 3 / 5
    assert pooled["precision"] == 2 / 4 and pooled["ego_recall"] == 2 / 3
    # frames of the same name in two sequences do not mix: pooled = both evaluated side by side
    assert {f["frame"] for f in pooled["failed_frames"]} == {"a/1", "b/1"}
    assert res["a"] == {k: v for k, v in evaluate(a_pred, a_gt).items() if k != "per_frame"}


def test_eval_dataset_prints_each_sequence_and_the_pooled_row(tmp_path):
    ds = tmp_path / "ds.yaml"
    for name, gt, pred in (
        ("a", [_gt("0", 100)], [_pred("0", [100])]),
        ("b", [_gt("0", 100)], [_pred("0", [])]),
    ):
        (tmp_path / "gt" / name).mkdir(parents=True)
        (tmp_path / "gt" / name / "lanes_gt.jsonl").write_text("".join(json.dumps(r) + "\n" for r in gt))
        (tmp_path / "runs" / name).mkdir(parents=True)
        (tmp_path / "runs" / name / "lanes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in pred))
    ds.write_text(
        "sequences:\n  - {name: a, input: gt/a, gt: gt/a/lanes_gt.jsonl}\n  - {name: b, input: gt/b, gt: gt/b/lanes_gt.jsonl}\n"
    )
    r = CliRunner().invoke(main, ["eval", str(tmp_path / "runs"), "--dataset", str(ds)])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert any(line.startswith("| a | 1 | 100.0 %") for line in lines)
    assert any(line.startswith("| b | 1 | 0.0 %") for line in lines)
    assert any(line.startswith("| **all** (pooled) | 2 | 50.0 %") for line in lines)
    assert "b/0: ego left boundary" in r.output
    r = CliRunner().invoke(main, ["eval", str(tmp_path / "runs"), "--dataset", str(ds), "--json"])
    assert json.loads(r.output)["sequences"]["all"]["detection_ratio"] == 0.5
    # a sequence without predictions is named
    (tmp_path / "runs" / "b" / "lanes.jsonl").unlink()
    r = CliRunner().invoke(main, ["eval", str(tmp_path / "runs"), "--dataset", str(ds)])
    assert r.exit_code == 2 and "sequence 'b'" in r.output and "Traceback" not in r.output


def test_the_dev_dataset_names_the_eight_developer_sources():
    ds = load_dataset(ROOT / "graphs" / "datasets" / "dev.yaml", check_paths=False)
    assert [s.name for s in ds] == [
        "drive_0001",
        "seq1",
        "seq2",
        "seq2_ramp",
        "kitti15_000024",
        "kitti12_000070",
        "odom00",
        "kitti15_000005",
    ]
    assert all(s.gt is not None and s.gt.name == "lanes_gt.jsonl" for s in ds)
    assert ds.sequences[1].input == (ROOT.parent / "shared" / "data" / "kitti_odometry" / "seq1").resolve()
    assert ds.sequences[6].input == (ROOT.parent / "shared" / "data" / "kitti_singles" / "odom00").resolve()
