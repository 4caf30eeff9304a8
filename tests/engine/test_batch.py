"""Batch runs in this process (`run --dataset`, `ablate`): units of work, chunks with warm-up, folders
put in place whole, failures reported with variant, sequence and frame, and no Dask imported."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from lanegraph.batches.batch import chunk_selections, clean_leftovers
from lanegraph.cli import main
from lanegraph.run.task import place_dir

ROOT = Path(__file__).resolve().parents[2]
PAPER = str(ROOT / "graphs" / "paper.yaml")


def lanes_files(out: Path) -> dict[str, bytes]:
    """Every lanes.jsonl under ``out``, by path relative to it."""
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("lanes.jsonl"))}


def test_chunk_selections_cover_every_frame_once():
    # 10 input frames, all selected, chunks of 4 after 2 warm-up frames
    assert chunk_selections(10, None, 4, 2) == [
        (slice(0, 4, 1), 0, 0, 4), (slice(2, 8, 1), 2, 4, 4), (slice(6, 10, 1), 2, 8, 2)
    ]  # fmt: skip
    for n, sel, k, w in [
        (23, slice(3, 20, 2), 3, 2),
        (9, slice(None, None, -1), 4, 1),
        (7, slice(-5, None), 2, 5),
    ]:
        picked = list(range(n))[sel]
        reported = []
        for s, warm, start, count in chunk_selections(n, sel, k, w):
            run = list(range(n))[s]
            assert run[warm:] == picked[start : start + count]  # the chunk, after its warm-up
            assert run[:warm] == picked[max(0, start - warm) : start]  # the frames just before it
            reported += run[warm:]
        assert reported == picked


def test_place_dir_replaces_a_folder_whole_and_leftovers_go(tmp_path):
    dest = tmp_path / "runs" / "seq"
    dest.mkdir(parents=True)
    (dest / "stale.txt").write_text("old run")
    new = tmp_path / "runs" / ".seq.tmp-1-abc"
    new.mkdir()
    (new / "lanes.jsonl").write_text("{}\n")
    place_dir(new, dest)
    assert sorted(p.name for p in dest.iterdir()) == ["lanes.jsonl"] and not new.exists()
    for left in (".seq.tmp-99-deadbeef", ".seq.old-00000001", ".seq.chunks", ".other.tmp-1-abcdef01"):
        (tmp_path / "runs" / left).mkdir()
    clean_leftovers(dest)
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == [".other.tmp-1-abcdef01", "seq"]


def test_run_dataset_writes_each_sequence_like_a_single_run(tmp_path, synthetic_dataset):
    out = tmp_path / "out"
    r = CliRunner().invoke(
        main, ["run", PAPER, "--dataset", str(synthetic_dataset), "--out", str(out), "--quiet"]
    )
    assert r.exit_code == 0, r.output
    assert "straight: 5 frame(s)" in r.output and "curve: 7 frame(s)" in r.output
    for name, folder in (("straight", "a"), ("curve", "b")):
        single = tmp_path / f"single_{name}"
        r = CliRunner().invoke(
            main,
            [
                "run",
                PAPER,
                "--input",
                str(synthetic_dataset.parent / folder),
                "--out",
                str(single),
                "--quiet",
            ],
        )
        assert r.exit_code == 0, r.output
        assert (out / name / "lanes.jsonl").read_bytes() == (single / "lanes.jsonl").read_bytes()
        record = json.loads((out / name / "run.json").read_text())
        assert (
            record["frames_ok"] == json.loads((single / "run.json").read_text())["frames_ok"]
            and record["failures"] == []
        )
        assert (
            json.loads((out / name / "timings.json").read_text())["nodes"]["disp"]["calls"]
            == record["frames_ok"]
        )
    assert not [p for p in out.iterdir() if p.name.startswith(".") and p.is_dir()]  # no temporary folder left


def test_chunks_are_the_runs_after_their_warmup(tmp_path, synthetic_dataset):
    ds = tmp_path / "one.yaml"
    ds.write_text(f"sequences:\n  - {{name: curve, input: {synthetic_dataset.parent / 'b'}}}\n")
    out = tmp_path / "chunked"
    r = CliRunner().invoke(
        main,
        [
            "run",
            PAPER,
            "--dataset",
            str(ds),
            "--out",
            str(out),
            "--chunk-frames",
            "3",
            "--warmup",
            "2",
            "--quiet",
        ],
    )
    assert r.exit_code == 0, r.output
    # issue 31, item 10: the graph's state outlives the warm-up: said before it starts and in run.json
    said = "the graph carries state from frame to frame (feedback edge(s) "
    assert said in r.output and "verify.lanes@prev" in r.output, r.output
    assert r.output.index(said) < r.output.index("curve: 7 frame(s)"), r.output
    assert any(said in w for w in json.loads((out / "curve" / "run.json").read_text())["warnings"])
    # 7 frames: [0, 3) alone, [3, 6) after frames 1-2, [6, 7) after frames 4-5
    expected = []
    for frames, warm in (("0:3", 0), ("1:6", 2), ("4:7", 2)):
        part = tmp_path / f"part_{frames}"
        r = CliRunner().invoke(
            main,
            [
                "run",
                PAPER,
                "--input",
                str(synthetic_dataset.parent / "b"),
                "--frames",
                frames,
                "--out",
                str(part),
                "--quiet",
            ],
        )
        assert r.exit_code == 0, r.output
        expected += (part / "lanes.jsonl").read_text().splitlines(keepends=True)[warm:]
    assert (out / "curve" / "lanes.jsonl").read_text() == "".join(expected)
    frames = [json.loads(line)["frame"] for line in expected]
    assert frames == [f"{i:010d}" for i in range(7)]
    timings = json.loads((out / "curve" / "timings.json").read_text())
    assert timings["frames"] == 7 and timings["nodes"]["disp"]["calls"] == 7  # warm-up frames are not timed
    assert not (out / ".curve.chunks").exists()


def _corrupt_copy(synthetic_dataset: Path, tmp_path: Path) -> Path:
    """The dataset with frame 0000000002 of ``curve`` truncated."""
    data = tmp_path / "data"
    shutil.copytree(synthetic_dataset.parent, data)
    bad = data / "b" / "left" / "0000000002.png"
    bad.write_bytes(bad.read_bytes()[:100])
    return data / synthetic_dataset.name


def test_a_failed_run_is_reported_and_the_others_finish(tmp_path, synthetic_dataset):
    ds = _corrupt_copy(synthetic_dataset, tmp_path)
    out = tmp_path / "out"
    slt = str(ROOT / "graphs" / "ablations" / "slt.yaml")
    r = CliRunner().invoke(
        main, ["ablate", PAPER, slt, "--dataset", str(ds), "--out", str(out), "--no-cache", "--quiet"]
    )
    assert r.exit_code == 1, r.output
    for variant in ("paper", "slt"):
        assert (
            f"error: run {variant} / curve failed: node 'src' (io.folder) failed on frame 0000000002"
            in r.stderr
        )
        assert "cannot decode image" in r.stderr
        assert len((out / "runs" / variant / "straight" / "lanes.jsonl").read_text().splitlines()) == 5
        # the failed run keeps what it wrote before the bad frame, and says where it stopped
        assert len((out / "runs" / variant / "curve" / "lanes.jsonl").read_text().splitlines()) == 2
        stopped = json.loads((out / "runs" / variant / "curve" / "run.json").read_text())["stopped"]
        assert stopped["frame"] == "0000000002" and stopped["node"] == "src"
        assert not (out / "runs" / variant / "curve" / "run_key.txt").exists()  # never reused
    rows = {(row["variant"], row["sequence"]): row for row in csv.DictReader((out / "results.csv").open())}
    assert rows[("paper", "straight")]["error"] == "" and rows[("paper", "straight")]["detection_ratio"] != ""
    assert (
        "frame 0000000002" in rows[("slt", "curve")]["error"]
        and rows[("slt", "curve")]["detection_ratio"] == ""
    )
    assert (
        rows[("slt", "all")]["error"] == "failed on sequence(s) curve"
        and rows[("slt", "all")]["detection_ratio"] == ""
    )
    assert (
        "- slt / curve: node 'src' (io.folder) failed on frame 0000000002" in (out / "results.md").read_text()
    )

    r = CliRunner().invoke(
        main, ["run", PAPER, "--dataset", str(ds), "--out", str(tmp_path / "run"), "--quiet"]
    )
    assert r.exit_code == 1 and "error: curve: node 'src' (io.folder) failed on frame 0000000002" in r.stderr
    assert len((tmp_path / "run" / "straight" / "lanes.jsonl").read_text().splitlines()) == 5


@pytest.mark.parametrize(
    "args, message",
    [
        (["run", "paper", "--resume", "--chunk-frames", "3"], "a run in chunks (--chunk-frames) keeps none"),
        (
            ["run", "paper", "--scheduler", "local:0"],
            "expected local:N with N a number of worker processes >= 1",
        ),
        (["run", "paper", "--dataset", "{ds}", "--input", "x"], "--input is for a run on one input"),
        (
            ["run", "paper", "--dataset", "{ds}", "--scheduler", "local:0"],
            "expected local:N with N a number of worker processes >= 1",
        ),
        (
            ["run", "paper", "--dataset", "{ds}", "--warmup", "2"],
            "--warmup is the number of frames run before each chunk",
        ),
        (
            ["run", "paper", "--dataset", "{ds}", "--chunk-frames", "0"],
            "--chunk-frames: expected an integer >= 1",
        ),
        (["ablate", "paper", "--dataset", "{ds}", "--scheduler", "local:x"], "expected local:N"),
        (
            ["ablate", "paper", "--dataset", "{ds}", "--chunk-frames", "2", "--warmup", "-1"],
            "--warmup: expected an integer >= 0",
        ),
    ],
)
def test_usage_errors_exit_2_before_anything_runs(tmp_path, synthetic_dataset, args, message):
    out = tmp_path / "out"
    args = [a.replace("{ds}", str(synthetic_dataset)) for a in args] + ["--out", str(out)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2, r.output
    assert message in r.output
    assert not list(out.rglob("lanes.jsonl")) if out.exists() else True


_NO_DASK = """
import sys
from lanegraph.cli import main
for args in (sys.argv[1:5], sys.argv[5:]):
    try:
        main(args, standalone_mode=False)
    except SystemExit as exc:
        assert not exc.code, exc.code
loaded = sorted(m for m in sys.modules if m.split(".")[0] in ("dask", "distributed") or m == "lanegraph_dask.cluster")
print("LOADED", loaded)
"""


def test_no_dask_without_a_scheduler(tmp_path, synthetic_dataset):
    ds = tmp_path / "one.yaml"
    ds.write_text(f"sequences:\n  - {{name: s, input: {synthetic_dataset.parent / 'a'}, frames: '0:1'}}\n")
    run = ["run", "--dataset", str(ds), "--quiet"]
    ablate = ["ablate", PAPER, "--dataset", str(ds), "--out", str(tmp_path / "ab"), "--no-cache", "--quiet"]
    p = subprocess.run(
        [sys.executable, "-c", _NO_DASK, *run, *ablate],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "LOADED []" in p.stdout
    assert (tmp_path / "out" / "s" / "lanes.jsonl").is_file() and (
        tmp_path / "ab" / "runs" / "paper" / "s" / "lanes.jsonl"
    ).is_file()


def test_a_plain_run_imports_nothing_new():
    # `lanegraph run` on one input keeps its start-up: neither the batch module nor Dask
    code = "import sys, lanegraph.cli, lanegraph.run.executor; print(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed', 'lanegraph_dask') or m == 'lanegraph.batches.batch'))"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and p.stdout.strip() == "[]", p.stdout + p.stderr


_WITHOUT_DASK = """
import sys
sys.modules["distributed"] = None  # as if the distributed extra were not installed
from lanegraph.cli import main
main(sys.argv[1:])
"""


def test_a_scheduler_without_dask_installed_is_a_usage_error(tmp_path, synthetic_dataset):
    args = [
        "run",
        PAPER,
        "--dataset",
        str(synthetic_dataset),
        "--out",
        str(tmp_path / "out"),
        "--scheduler",
        "local:2",
        "--quiet",
    ]
    p = subprocess.run(
        [sys.executable, "-c", _WITHOUT_DASK, *args], capture_output=True, text=True, timeout=300
    )
    assert p.returncode == 2, p.stderr
    assert 'error: --scheduler needs Dask: pip install "lanegraph[distributed]"' in p.stderr
    assert not list((tmp_path / "out").rglob("lanes.jsonl")) if (tmp_path / "out").exists() else True


def test_a_sequence_that_cannot_start_does_not_stop_the_others(tmp_path, synthetic_dataset):
    empty = tmp_path / "empty"
    (empty / "left").mkdir(parents=True)
    (empty / "right").mkdir()
    ds = tmp_path / "ds.yaml"
    ds.write_text(
        f"sequences:\n  - {{name: good, input: {synthetic_dataset.parent / 'a'}, frames: '0:2'}}\n  - {{name: bad, input: {empty}}}\n"
    )
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["run", PAPER, "--dataset", str(ds), "--out", str(out), "--quiet"])
    assert r.exit_code == 1, r.output
    assert "error: bad: " in r.stderr and "good: 2 frame(s)" in r.output
    assert len((out / "good" / "lanes.jsonl").read_text().splitlines()) == 2
    record = json.loads((out / "bad" / "run.json").read_text())
    assert record["status"] == "stopped" and record["before_any_frame"] is True and record["error"]
    ds.write_text(f"sequences:\n  - {{name: bad, input: {empty}}}\n")  # nothing can start: exit 2
    r = CliRunner().invoke(
        main, ["run", PAPER, "--dataset", str(ds), "--out", str(tmp_path / "out2"), "--quiet"]
    )
    assert r.exit_code == 2, r.output


def test_the_carried_state_is_said_only_when_a_chunk_starts_from_another_state(tmp_path, synthetic_dataset):
    """A chunked run of a graph with feedback edges says its lanes may differ from a whole run's
    only when a chunk's warm-up does not reach back to the selection's first frame; one chunk, or
    a warm-up as long as the frames before every chunk, runs the whole run's frames from its state."""
    from lanegraph.batches.batch import Planner
    from lanegraph.graph.files import ResolvedGraph
    from lanegraph.plugins import get_plugin_manager

    pm, graph = get_plugin_manager(), ResolvedGraph.load(PAPER, [])
    curve = synthetic_dataset.parent / "b"  # 7 frames

    def said(chunk_frames, warmup, frames=None):
        planner = Planner(pm, chunk_frames, warmup)
        plan = planner.add(None, "curve", graph, curve, frames, tmp_path / "run")
        assert plan.tasks and plan.outcome is None
        notes = {n for t in plan.tasks for n in t.notes}
        assert notes == set(planner.warnings)
        return planner.warnings

    assert said(3, 2) and "verify.lanes@prev" in said(3, 2)[0]  # [3, 6) after frames 1-2 only
    assert said(3, 3)  # [6, 7) after frames 3-5 only
    assert said(None, 0) == []  # no chunks: the whole run
    assert said(10, 0) == [] and said(7, 0) == []  # one chunk
    assert said(3, 6) == [] and said(2, 100) == []  # every chunk's warm-up reaches frame 0
    assert said(2, 2, slice(4, 7)) == [] and said(1, 1, slice(4, 7))  # from the selection's first frame


def test_a_dataset_run_on_a_pipe_says_it_has_started(tmp_path, synthetic_dataset):
    """stderr is not a terminal under CliRunner: the batch's progress is a line, not tqdm's bar."""
    r = CliRunner().invoke(
        main, ["run", PAPER, "--dataset", str(synthetic_dataset), "--out", str(tmp_path / "o")]
    )
    assert r.exit_code == 0, r.output
    assert "frames: 0/12 frames" in r.output.splitlines()
    assert "\r" not in r.output


def test_clean_leftovers_removes_only_the_names_lanegraph_gives(tmp_path):
    """A killed task's temporary folder, a replaced run and the chunk folder go; a user's folders
    whose names merely start the same way, and a link, stay (the ownership rule: never by pattern)."""
    from lanegraph.run.task import chunks_dir, tmp_dir

    run = tmp_path / "seq"
    ours = [tmp_dir(run), tmp_path / ".seq.old-0123abcd", chunks_dir(run)]
    users = [tmp_path / ".seq.tmp-notes", tmp_path / ".seq.old-backup", tmp_path / ".seq.chunks.bak"]
    for p in ours + users:
        p.mkdir()
        (p / "f.txt").write_text("x")
    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / "keep.txt").write_text("x")
    (tmp_path / ".seq.old-89abcdef").symlink_to(target)
    clean_leftovers(run)
    assert [p for p in ours if p.exists()] == []
    assert all((p / "f.txt").read_text() == "x" for p in users)
    assert (target / "keep.txt").exists() and (tmp_path / ".seq.old-89abcdef").is_symlink()
