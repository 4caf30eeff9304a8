"""One run per output folder: another run's results refused (saying what differs, the folder left as
it was), an unfinished run refused without --resume, --overwrite removing only lanegraph's files."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from lanegraph.errors import UsageError
from lanegraph.run.folder import claim, command_identity, run_identity

RESOLVED = {"name": "g", "nodes": {"fit": {"type": "fit.irls", "params": {"roi_width": 40}}}}
ME = run_identity("a" * 64, "/data/drive", "0:20")


def snapshot(folder: Path) -> dict[str, bytes | None]:
    return {
        str(p.relative_to(folder)): (p.read_bytes() if p.is_file() and not p.is_symlink() else None)
        for p in sorted(folder.rglob("*"))
    }


def a_run(folder: Path, identity=ME, status="ok", **extra) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "lanes.jsonl").write_text('{"frame": "0", "lanes": []}\n')
    (folder / "timings.json").write_text("{}\n")
    (folder / "graph.yaml").write_text(yaml.safe_dump(RESOLVED))
    record = {"status": status, "identity": identity, "results": {"lanes": "lanes.jsonl"}, **extra}
    (folder / "run.json").write_text(json.dumps(record))
    return folder


def test_a_new_or_foreign_folder_is_taken(tmp_path):
    assert claim(tmp_path / "new", ME) == []
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("the user's")
    assert claim(tmp_path / "mine", ME) == []


def test_the_same_finished_run_runs_again(tmp_path):
    assert claim(a_run(tmp_path / "out"), ME) == []


@pytest.mark.parametrize(
    ("identity", "words"),
    [
        (
            run_identity("b" * 64, "/data/drive", "0:20"),
            "another graph or params (nodes.fit.params.roi_width: 40 there, 30 now)",
        ),
        (run_identity("a" * 64, "/data/other", "0:20"), "another input: /data/drive there, /data/other now"),
        (run_identity("a" * 64, "/data/drive", None), "other frames: 0:20 there, all now"),
        (
            command_identity("ablation", ["paper", "slt"], {"drive": "/data/drive"}, None),
            "it holds the results of a run, this is an ablation",
        ),
    ],
)
def test_another_runs_results_are_refused_and_left_as_they_are(tmp_path, identity, words):
    out = a_run(tmp_path / "out")
    (out / "notes.txt").write_text("the user's")
    before = snapshot(out)
    resolved = {"name": "g", "nodes": {"fit": {"type": "fit.irls", "params": {"roi_width": 30}}}}
    with pytest.raises(UsageError) as info:
        claim(out, identity, resolved=resolved)
    msg = str(info.value)
    assert msg.startswith(f"--out {out}: holds the results of another run: ") and words in msg, msg
    assert "--overwrite" in msg and "another output folder" in msg
    assert snapshot(out) == before


def test_an_unfinished_run_is_refused_without_resume(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "lanes.jsonl").write_text("{}\n" * 17)
    ckpt = {
        "graph_digest": "a" * 64,
        "input": "/data/drive",
        "frames": "0:20",
        "complete": False,
        "position": 17,
        "total": 20,
    }
    (out / "checkpoint.json").write_text(json.dumps(ckpt))  # killed: no run.json
    before = snapshot(out)
    with pytest.raises(
        UsageError, match=r"holds this run, unfinished \(17 of 20 frame\(s\) done; it was killed .*--resume"
    ):
        claim(out, ME)
    assert snapshot(out) == before
    assert claim(out, ME, resume=True) == []
    # interrupted with Ctrl-C: its record says where it stopped
    (out / "run.json").write_text(
        json.dumps({"status": "stopped", "identity": ME, "stopped": {"error": "interrupted (Ctrl-C)"}})
    )
    with pytest.raises(
        UsageError,
        match=r"17 of 20 frame\(s\) done; stopped: interrupted \(Ctrl-C\)\); continue it with --resume",
    ):
        claim(out, ME)
    # a different run into it is refused as another run's (with --resume its checkpoint says so)
    with pytest.raises(UsageError, match="another input"):
        claim(out, run_identity("a" * 64, "/data/other", "0:20"))


def test_overwrite_removes_only_what_lanegraph_wrote(tmp_path):
    out = a_run(
        tmp_path / "out", run_identity("b" * 64, "/x", None), debug_dir="pictures", written=["overlays"]
    )
    for name in ("checkpoint.json", "run.log"):
        (out / name).write_text("{}")
    (out / "pictures" / "0001").mkdir(parents=True)
    (out / "pictures" / "0001" / "mosaic.png").write_bytes(b"png")
    (out / "overlays").mkdir()
    (out / "report" / "assets").mkdir(parents=True)
    (out / "report" / "assets" / ".lanegraph-report").write_text("mark")
    (out / "report" / "index.html").write_text("<html>")
    (out / "runs" / "paper" / "seq").mkdir(parents=True)
    outside = tmp_path / "keep.txt"
    outside.write_text("keep")
    (out / "notes.txt").write_text("the user's")
    (out / "data").mkdir()
    (out / "data" / "lanes.jsonl").write_text("the user's")
    removed = claim(out, ME, overwrite=True)
    assert {p.name for p in removed} >= {"run.json", "lanes.jsonl", "pictures", "report", "runs", "overlays"}
    assert sorted(p.name for p in out.iterdir()) == ["data", "notes.txt"]
    assert (out / "data" / "lanes.jsonl").read_text() == "the user's" and outside.read_text() == "keep"
    assert claim(out, ME) == []


def test_overwrite_never_follows_a_link_nor_leaves_the_folder(tmp_path):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "precious.txt").write_text("keep")
    out = a_run(tmp_path / "out", written=["../victim", "/etc", "runs"])
    (out / "runs").symlink_to(victim)
    claim(out, run_identity("c" * 64, None, None), overwrite=True)
    assert (victim / "precious.txt").read_text() == "keep" and not (out / "runs").exists()


def test_a_folder_of_an_older_lanegraph_is_replaced_with_a_warning(tmp_path, caplog):
    out = tmp_path / "out"
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"status": "ok", "results": {"lanes": "lanes.jsonl"}}))
    (out / "lanes.jsonl").write_text("{}\n")
    with caplog.at_level("WARNING", logger="lanegraph.run"):
        assert claim(out, ME) == []
    assert "holds a run of an older lanegraph" in caplog.text
    claim(out, ME, overwrite=True)
    assert list(out.iterdir()) == []


def test_loose_files_and_planted_links_are_not_a_run(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "lanes.jsonl").write_text("the user's\n")  # no record: not a run's
    other = a_run(tmp_path / "other")
    (out / "run.json").symlink_to(other / "run.json")  # a link is never lanegraph's record
    assert claim(out, run_identity("z" * 64, None, None)) == []


def test_a_run_writing_the_folder_now_is_said_first(tmp_path):
    from lanegraph.paths import OutputLock
    from lanegraph.run.folder import check

    out = a_run(tmp_path / "out")
    with OutputLock(out, "ablate"):
        with pytest.raises(UsageError, match=r"in use by another lanegraph ablate \(pid"):
            check(out, run_identity("z" * 64, None, None))
    check(out, ME)  # released: the same run may go on


def test_resume_is_left_to_the_checkpoint(tmp_path):
    out = a_run(tmp_path / "out")
    (out / "checkpoint.json").write_text("not json")  # --resume says what is wrong with it
    assert claim(out, run_identity("z" * 64, None, None), resume=True) == []


def test_an_ablation_folder_holds_one_ablation(tmp_path):
    out = tmp_path / "abl"
    out.mkdir()
    mine = command_identity("ablation", ["paper", "slt"], {"kerbs": "/data/kerbs"}, None)
    (out / "command.json").write_text(json.dumps({"identity": mine, "written": ["results.csv", "runs"]}))
    (out / "results.csv").write_text("variant\n")
    (out / "runs").mkdir()
    assert claim(out, mine) == []
    other = command_identity("ablation", ["paper", "paper_literal"], {"kerbs": "/data/kerbs"}, None)
    with pytest.raises(UsageError, match="other variants: paper, slt there, paper, paper_literal now"):
        claim(out, other)
    assert claim(out, other, overwrite=True) and list(out.iterdir()) == []
