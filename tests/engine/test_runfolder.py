"""One run per output folder: another run's results refused (saying what differs, the folder left as
it was), an unfinished run refused without --resume, --overwrite removing only lanegraph's files."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from lanegraph.errors import UsageError
from lanegraph.records.folder import claim, command_identity, run_identity
from lanegraph.records.owned import seal

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


WRITES = {
    "run.json": "file",
    "timings.json": "file",
    "graph.yaml": "file",
    "run.log": "file",
    "checkpoint.json": "file",
    "lanes.jsonl": "file",
    "overlays": "tree",
    "pictures": "dir",
    "runs": "dir",
}


def a_sealed_run(folder: Path, identity=ME, **extra) -> Path:
    """A run as lanegraph writes it: the folder claimed, its files written, then sealed (the
    ownership record lists each file by inode, size and digest)."""
    folder.mkdir(parents=True, exist_ok=True)
    claim(folder, identity, writes=WRITES)
    a_run(folder, identity, **extra)
    (folder / "run.log").write_text("log\n")
    (folder / "checkpoint.json").write_text('{"format":"lanegraph-checkpoint"}')
    (folder / "pictures" / "0001").mkdir(parents=True)
    (folder / "pictures" / "0001" / "mosaic.png").write_bytes(b"png")
    (folder / "overlays").mkdir()
    (folder / "overlays" / "0001.png").write_bytes(b"png")
    (folder / "runs" / "paper" / "seq").mkdir(parents=True)
    (folder / "runs" / "paper" / "seq" / "run.json").write_text("{}")
    seal(folder)
    return folder


def test_overwrite_removes_only_what_lanegraph_wrote(tmp_path):
    (tmp_path / "out" / "data").mkdir(parents=True)
    (tmp_path / "out" / "data" / "lanes.jsonl").write_text("the user's")
    (tmp_path / "out" / "pictures").mkdir()  # the user's folder, given as --debug-dir
    (tmp_path / "out" / "pictures" / "photo.jpg").write_bytes(b"the user's")
    out = a_sealed_run(tmp_path / "out", run_identity("b" * 64, "/x", None))
    outside = tmp_path / "keep.txt"
    outside.write_text("keep")
    (out / "notes.txt").write_text("the user's")
    (out / "runs" / "paper" / "thesis.tex").write_text("the user's, in lanegraph's folder")
    removed = claim(out, ME, overwrite=True, writes=WRITES)
    assert {str(p.relative_to(out)) for p in removed} >= {
        "run.json", "lanes.jsonl", "pictures/0001", "pictures/0001/mosaic.png", "overlays", "runs/paper/seq"
    }  # fmt: skip
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [
        "data", "data/lanes.jsonl", "notes.txt", "pictures", "pictures/photo.jpg", "runs", "runs/paper",
        "runs/paper/thesis.tex",
    ]  # fmt: skip
    assert (out / "data" / "lanes.jsonl").read_text() == "the user's" and outside.read_text() == "keep"
    assert claim(out, ME) == []


def test_a_file_changed_since_lanegraph_wrote_it_is_not_lanegraphs(tmp_path):
    out = a_sealed_run(tmp_path / "out")
    (out / "lanes.jsonl").write_text("edited by the user\n")
    with pytest.raises(UsageError, match=r"lanes.jsonl is there and not lanegraph's"):
        claim(out, run_identity("c" * 64, None, None), overwrite=True, writes=WRITES)
    assert (out / "lanes.jsonl").read_text() == "edited by the user\n" and (out / "run.json").exists()


def test_a_copied_or_moved_record_is_not_genuine(tmp_path):
    import shutil

    out = a_sealed_run(tmp_path / "out")
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)  # same names, same bytes: other inodes
    with pytest.raises(UsageError, match="is there and not lanegraph's"):
        claim(copy, run_identity("c" * 64, None, None), overwrite=True, writes=WRITES)
    assert (copy / "lanes.jsonl").exists()


def test_overwrite_never_follows_a_link_nor_leaves_the_folder(tmp_path):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "precious.txt").write_text("keep")
    out = a_sealed_run(tmp_path / "out", written=["../victim", "/etc", "runs", "."], debug_dir=".")
    import shutil

    shutil.rmtree(out / "runs")
    (out / "runs").symlink_to(victim)
    with pytest.raises(UsageError, match="runs is there and not lanegraph's"):
        claim(out, run_identity("c" * 64, None, None), overwrite=True, writes=WRITES)
    assert claim(out, run_identity("c" * 64, None, None), overwrite=True) != []
    assert (victim / "precious.txt").read_text() == "keep" and (out / "runs").is_symlink()


def test_a_folder_of_an_older_lanegraph_is_taken_not_replaced(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"status": "ok", "results": {"lanes": "lanes.jsonl"}}))
    (out / "lanes.jsonl").write_text("{}\n")
    for overwrite in (False, True):
        with pytest.raises(UsageError, match=r"(run.json|lanes.jsonl) is there and not lanegraph's"):
            claim(out, ME, overwrite=overwrite, writes=WRITES)
    assert sorted(p.name for p in out.iterdir()) == ["lanes.jsonl", "run.json"]


def test_loose_files_and_planted_links_are_not_a_run(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "lanes.jsonl").write_text("the user's\n")  # no record: not a run's
    other = a_run(tmp_path / "other")
    (out / "run.json").symlink_to(other / "run.json")  # a link is never lanegraph's record
    assert claim(out, run_identity("z" * 64, None, None)) == []


def test_a_run_writing_the_folder_now_is_said_first(tmp_path):
    from lanegraph.paths import OutputLock
    from lanegraph.records.folder import check

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
    writes = {"command.json": "file", "results.csv": "file", "runs": "dir"}
    assert claim(out, mine, writes=writes) == []
    (out / "command.json").write_text(json.dumps({"identity": mine, "written": ["results.csv", "runs"]}))
    (out / "results.csv").write_text("variant\n")
    (out / "runs").mkdir()
    seal(out)
    assert claim(out, mine, writes=writes) == []
    other = command_identity("ablation", ["paper", "paper_literal"], {"kerbs": "/data/kerbs"}, None)
    with pytest.raises(UsageError, match="other variants: paper, slt there, paper, paper_literal now"):
        claim(out, other, writes=writes)
    assert claim(out, other, overwrite=True, writes=writes) and list(out.iterdir()) == []
