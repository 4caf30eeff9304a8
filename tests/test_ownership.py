"""``--overwrite`` and the runs into a folder, as a property (hypothesis): random trees of the
user's files and folders, links (inside OUT and out of it), lanegraph runs (the demo graph on two
frames of a small synthetic scene, with or without ``--overwrite`` and ``--debug-dir``) and forged
records. After any sequence of them, no path outside lanegraph's genuine records has changed: every
path the user had is there with the same bytes (a link with the same target), nothing is written
outside OUT, and what a run added is listed by the folder's ownership record."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lanegraph import plugins
from lanegraph.cli import main
from lanegraph.records import owned

ROOT = Path(__file__).resolve().parents[1]
DEMO = str(ROOT / "graphs" / "demo_sgbm.yaml")
SYNTH = ["--set", "src.type=io.synthetic", "--set", "src.scale=0.2", "--set", "src.frames=2"]
SMALL = ["--set", "disp.num_disparities=16", "--set", "disp.block_size=3"]

#: names a user's file or folder may take: lanegraph's own names among them
NAMES = [
    "run.json", "timings.json", "graph.yaml", "run.log", "lanes.jsonl", "checkpoint.json",
    "command.json", "results.csv", "results.md", "accuracy.png", "runs", "debug", "report",
    "notes.txt", "photos", ".lanegraph-owned.json",
]  # fmt: skip


def tree(base: Path) -> dict[str, tuple[str, str]]:
    """Every path under ``base`` (links not followed): (kind, its bytes' digest or link target)."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(base):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            rel = str(p.relative_to(base))
            if p.is_symlink():
                out[rel] = ("link", os.readlink(p))
            elif p.is_dir():
                out[rel] = ("dir", "")
            else:
                out[rel] = ("file", hashlib.sha256(p.read_bytes()).hexdigest())
    return out


def genuine(out: Path) -> set[str]:
    return {f"out/{rel}" for rel in owned.read(out)} if out.is_dir() else set()


# one step: ("file", name, sub), ("dir", name), ("link", name, target), ("forge", kind), ("run", ...)
user_file = st.tuples(st.just("file"), st.sampled_from(NAMES), st.sampled_from(["", "inner.txt"]))
user_dir = st.tuples(st.just("dir"), st.sampled_from(NAMES))
link = st.tuples(
    st.just("link"),
    st.sampled_from(["esc", "runs", "debug", "lanes.jsonl", "photos"]),
    st.sampled_from(["../outside", "../outside/victim.txt", "photos", "nowhere", "."]),
)
forge = st.tuples(st.just("forge"), st.sampled_from(["copy", "names", "record", "dot"]))
run = st.tuples(
    st.just("run"),
    st.booleans(),  # --overwrite
    st.sampled_from(["0:1", "0:2"]),  # --frames
    st.sampled_from([None, "debug", "photos"]),  # --debug-dir inside OUT
)
steps = st.lists(st.one_of(user_file, user_dir, link, forge, run, run), min_size=2, max_size=7)


@pytest.fixture(scope="module")
def donor(installed_pm, tmp_path_factory) -> Path:
    """A genuine run folder elsewhere (its record is copied into OUT by a forger)."""
    folder = tmp_path_factory.mktemp("donor") / "out"
    old = plugins._default
    plugins._default = installed_pm
    try:
        args = ["run", DEMO, "--out", folder, "-q", "--frames", "0:1", *SYNTH, *SMALL]
        r = CliRunner().invoke(main, [str(a) for a in args])
    finally:
        plugins._default = old
    assert r.exit_code == 0, r.output
    return folder


def apply(step: tuple, base: Path, donor: Path) -> None:
    """A user's (or a forger's) step, done as well as the tree allows."""
    out = base / "out"
    out.mkdir(exist_ok=True)
    kind = step[0]
    try:
        if kind == "file":
            p = out / step[1] / step[2] if step[2] else out / step[1]
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_text(f"the user's {step[1]} {step[2]}\n")
        elif kind == "dir":
            (out / step[1]).mkdir(exist_ok=True)
            (out / step[1] / "photo.jpg").write_bytes(b"the user's photo")
        elif kind == "link":
            (out / step[1]).symlink_to(step[2])
        elif kind == "forge":
            ledger = out / owned.LEDGER
            if step[1] == "copy":  # a genuine record of another folder, copied
                shutil.copyfile(donor / owned.LEDGER, ledger)
            elif step[1] == "names":  # the right format, the user's files listed by name
                st_ = os.lstat(out)
                entries = {n: {"kind": "file", "ino": 1, "size": 0, "sha256": "0" * 64} for n in NAMES}
                entries.update(
                    {".": {"kind": "dir", "ino": st_.st_ino}, "esc/victim.txt": {"kind": "open", "ino": 2}}
                )
                doc = {
                    "format": owned.FORMAT,
                    "version": owned.VERSION,
                    "self": {},
                    "folder": {},
                    "entries": entries,
                }
                ledger.write_text(json.dumps(doc))
            elif step[1] == "record":  # run.json naming what is outside
                (out / "run.json").write_text(
                    json.dumps({"version": 2, "status": "ok", "written": ["esc/victim.txt", "."],
                                "debug_dir": ".", "results": {"lanes": "esc/sub"}})
                )  # fmt: skip
            else:
                (out / "command.json").write_text(json.dumps({"written": [".", "..", "../outside"]}))
    except OSError:
        pass  # a name already taken by another kind of path: the step does nothing


@settings(
    max_examples=6,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(steps=steps)
def test_no_path_outside_lanegraphs_records_ever_changes(steps, installed_pm, donor, monkeypatch):
    monkeypatch.setattr(plugins, "_default", installed_pm)
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        (base / "outside" / "sub").mkdir(parents=True)
        (base / "outside" / "victim.txt").write_text("outside OUT")
        (base / "outside" / "sub" / "thesis.tex").write_text("outside OUT")
        (base / "out").mkdir()
        for step in steps:
            if step[0] != "run":
                apply(step, base, donor)
                continue
            _, overwrite, frames, debug = step
            if debug and (base / "out" / debug).is_symlink():
                debug = None  # a --debug-dir leading elsewhere is a folder the user named: written
            before, mine = tree(base), genuine(base / "out")
            args = ["run", DEMO, "--out", base / "out", "-q", "--frames", frames, *SYNTH, *SMALL]
            args += ["--overwrite"] * overwrite + (["--debug-dir", base / "out" / debug] if debug else [])
            r = CliRunner().invoke(main, [str(a) for a in args])
            assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
            assert r.exit_code in (0, 2), r.output
            after, now = tree(base), genuine(base / "out")
            for path, what in before.items():
                if path not in mine:
                    assert after.get(path) == what, (steps, path, r.output)
            for path, what in after.items():
                if before.get(path) != what:  # written or replaced by the run: lanegraph's own
                    assert path.startswith("out/"), (steps, path)
                    assert path in now or path == f"out/{owned.LEDGER}", (steps, path, r.output)


# ---------------------------------------------------------------- the cases of issue 46, one by one
@pytest.fixture
def cli(installed_pm, monkeypatch, tmp_path):
    """``cli(*args)`` -> (exit code, output) of ``lanegraph run`` of the demo graph, small and fast."""
    monkeypatch.setattr(plugins, "_default", installed_pm)
    monkeypatch.chdir(tmp_path)

    def invoke(*args: object, graph: str = DEMO) -> tuple[int, str]:
        argv = ["run", graph, "-q", *SYNTH, *SMALL, *[str(a) for a in args]]
        r = CliRunner().invoke(main, argv)
        assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
        assert "Traceback" not in r.output, r.output
        return r.exit_code, r.output

    return invoke


def users(folder: Path, *names: str) -> dict[str, tuple[str, str]]:
    """The user's files ``names`` (a name ending in ``/`` a folder with a file in it), made in
    ``folder``; returns the tree they make."""
    for name in names:
        p = folder / name.rstrip("/")
        p.parent.mkdir(parents=True, exist_ok=True)
        if name.endswith("/"):
            p.mkdir(exist_ok=True)
            (p / "thesis.tex").write_text("years of work")
        else:
            p.write_text(f"the user's {name}")
    return tree(folder)


def test_debug_dir_that_is_out_itself_is_refused(cli, tmp_path):
    out = tmp_path / "o"
    before = users(out, "notes.txt")
    code, output = cli("--out", out, "--debug-dir", out, "--frames", "0:1")
    assert code == 2 and "--debug-dir" in output and "is --out itself" in output, output
    assert tree(out) == before


def test_a_debug_dir_in_the_users_folder_keeps_the_users_photos(cli, tmp_path):
    out = tmp_path / "o"
    photos = users(out / "photos", "holiday.jpg", "family/")
    assert cli("--out", out, "--debug-dir", out / "photos", "--frames", "0:1")[0] == 0
    assert any(p.name.endswith(".png") for p in (out / "photos").rglob("*"))
    assert cli("--out", out, "--frames", "0:2", "--overwrite")[0] == 0
    assert tree(out / "photos") == photos  # the pictures gone, the user's photos kept


def test_overwrite_in_a_home_folder_without_a_record_removes_nothing(cli, tmp_path):
    home = tmp_path / "home"
    before = users(home, "runs/", "graph.yaml", "results.csv", "run.log", "notes.txt")
    code, output = cli("--out", home, "--overwrite", "--frames", "0:1")
    assert code == 2 and "is there and not lanegraph's" in output, output
    assert tree(home) == before


def test_without_overwrite_the_users_files_at_lanegraphs_names_are_not_replaced(cli, tmp_path):
    out = tmp_path / "o"
    before = users(out, "graph.yaml", "run.log", "lanes.jsonl")
    code, output = cli("--out", out, "--frames", "0:1")
    assert code == 2 and "is there and not lanegraph's" in output, output
    assert tree(out) == before


def test_overwrite_keeps_user_files_that_carry_lanegraphs_names(cli, tmp_path):
    out = tmp_path / "o"
    assert cli("--out", out, "--frames", "0:1")[0] == 0
    users(out, "results.csv", "results.md", "accuracy.png", "runs/")
    theirs = {
        k: v
        for k, v in tree(out).items()
        if k.split("/")[0] in ("results.csv", "results.md", "accuracy.png", "runs")
    }
    assert cli("--out", out, "--frames", "0:2", "--overwrite")[0] == 0
    assert {k: v for k, v in tree(out).items() if k in theirs} == theirs
    (out / "timings.json").unlink()
    users(out, "timings.json/")  # a folder at a name the run writes: refused, kept
    before = tree(out)
    code, output = cli("--out", out, "--frames", "0:1", "--overwrite")
    assert code == 2 and "timings.json is there and not lanegraph's" in output, output
    assert tree(out) == before


@pytest.mark.parametrize(
    "record",
    [
        {"written": ["esc/victim.txt"]},
        {"results": {"lanes": "esc/sub"}},
        {"written": ["."]},
        {"debug_dir": "."},
    ],
)
def test_a_forged_record_removes_nothing_outside_nor_out_itself(cli, tmp_path, record):
    victim = tmp_path / "victim"
    users(victim, "victim.txt", "sub/")
    out = tmp_path / "o"
    assert cli("--out", out, "--frames", "0:1")[0] == 0
    (out / "esc").symlink_to(victim)
    users(out, "notes.txt")
    rec = json.loads((out / "run.json").read_text())
    rec.update(record)
    (out / "run.json").write_text(json.dumps(rec))  # forged: no longer the file lanegraph wrote
    outside, inside = tree(victim), {k: v for k, v in tree(out).items() if k in ("notes.txt", "esc")}
    code, output = cli("--out", out, "--frames", "0:2", "--overwrite")
    assert code == 2 and "run.json is there and not lanegraph's" in output, output
    assert tree(victim) == outside
    assert {k: v for k, v in tree(out).items() if k in inside} == inside


def test_overwrite_is_all_or_nothing(cli, tmp_path, monkeypatch):
    out = tmp_path / "o"
    assert cli("--out", out, "--frames", "0:1")[0] == 0
    before = tree(out)
    real, calls = os.rename, {"n": 0}

    def immutable_third(src, dst, *a, **k):  # as `chattr +i` on the third file (EPERM)
        calls["n"] += 1
        if calls["n"] == 3:
            raise PermissionError(1, "Operation not permitted", str(src))
        return real(src, dst, *a, **k)

    monkeypatch.setattr(owned.os, "rename", immutable_third)
    code, output = cli("--out", out, "--frames", "0:2", "--overwrite")
    assert code == 2 and "Operation not permitted; nothing was removed" in output, output
    assert tree(out) == before  # not half cleared
    monkeypatch.setattr(owned.os, "rename", real)
    assert cli("--out", out, "--frames", "0:2", "--overwrite")[0] == 0


def test_a_folder_named_run_log_in_a_fresh_out_is_refused_before_anything_is_written(cli, tmp_path):
    out = tmp_path / "o"
    (out / "run.log").mkdir(parents=True)
    code, output = cli("--out", out, "--frames", "0:1")
    assert code == 2 and "run.log is there and not lanegraph's" in output, output
    assert sorted(p.name for p in out.iterdir()) == ["run.log"]


def test_no_lock_file_is_left_by_a_refused_or_a_finished_run(cli, tmp_path):
    out = tmp_path / "o"
    code, output = cli("--out", out, "--frames", "50:60")  # selects none of the 2 frames
    assert code == 2, output
    assert not (out / ".lanegraph.lock").exists()
    assert cli("--out", out, "--frames", "0:1")[0] == 0
    assert not (out / ".lanegraph.lock").exists()


# ---------------------------------------------------------------- issue 47's items about OUT
def test_a_tracker_that_cannot_start_leaves_no_record_that_blocks_a_retry(
    installed_pm, monkeypatch, tmp_path, synthetic_two
):
    from lanegraph import tracking
    from lanegraph.errors import UsageError

    monkeypatch.setattr(plugins, "_default", installed_pm)

    def no_mlflow(self, command):
        raise UsageError("--track mlflow: MLflow is not installed (pip install 'lanegraph[mlflow]')")

    out = tmp_path / "abl"
    graph = tmp_path / "small.yaml"
    graph.write_text(f"extends: {DEMO}\nnodes:\n  disp: {{params: {{num_disparities: 16, block_size: 3}}}}\n")
    args = ["ablate", graph, "--dataset", synthetic_two, "--out", out, "-q", "--no-cache", "--frames", "0:1"]
    with monkeypatch.context() as m:
        m.setattr(tracking.Tracking, "start", no_mlflow)
        r = CliRunner().invoke(main, [str(a) for a in [*args, "--track", "mlflow"]])
    assert r.exit_code == 2 and "MLflow is not installed" in r.output, r.output
    assert not (out / "command.json").exists()
    r = CliRunner().invoke(main, [str(a) for a in args])  # the retry, without --track
    assert r.exit_code == 0, r.output


def test_a_refused_resume_advises_what_works(cli, tmp_path):
    out = tmp_path / "o"
    assert cli("--out", out, "--frames", "0:1")[0] == 0
    code, output = cli("--out", out, "--frames", "0:1", "--resume", "--set", "disp.block_size=5")
    assert code == 2 and "cannot resume" in output and "--overwrite in place of --resume" in output, output
    code, output = cli("--out", out, "--frames", "0:1", "--overwrite", "--set", "disp.block_size=5")
    assert code == 0, output  # the advice works
    assert not (out / ".lanegraph.lock").exists()


@pytest.fixture
def synthetic_two(tmp_path):
    from lanegraph_synthetic import preset, write_sequence

    write_sequence(preset("straight"), tmp_path / "a", 2)
    ds = tmp_path / "two.yaml"
    ds.write_text("name: two\nsequences:\n  - {name: straight, input: a}\n")
    return ds


def test_report_never_replaces_the_users_page(cli, tmp_path):
    out = tmp_path / "o"
    before = users(out, "report/index.html")
    code, output = cli("--out", out, "--frames", "0:1", "--report")
    assert code == 2 and "report/index.html is there and not lanegraph's" in output, output
    assert tree(out) == before
    (out / "report" / "index.html").unlink()
    assert cli("--out", out, "--frames", "0:1", "--report")[0] == 0
    assert cli("--out", out, "--frames", "0:2", "--report", "--overwrite")[0] == 0  # its own: replaced
