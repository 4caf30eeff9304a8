"""The record beside a result: the resolved graph as a runnable graph file, the versions, the git
commit of the graph's checkout (read from the .git files, git never run there)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from lanegraph.graph.validation import load_graph
from lanegraph.records.provenance import command_line, git_commit, versions, write_resolved_graph

ROOT = Path(__file__).resolve().parents[2]


def test_the_resolved_graph_file_loads_to_the_same_graph(tmp_path, installed_pm):
    g = load_graph(
        ROOT / "graphs/ablations/slt.yaml", ["hough.select=paper", "fit.roi_width=30"], installed_pm
    )
    path = write_resolved_graph(tmp_path, g.resolved_dict())
    assert path == tmp_path / "graph.yaml" and path.read_text().startswith("# The resolved graph")
    again = load_graph(path, [], installed_pm)
    assert again.resolved_dict() == g.resolved_dict()
    assert again.nodes["fit"].params.roi_width == 30 and "\nextends:" not in path.read_text()


def test_versions_name_the_libraries_and_the_plugins(installed_pm):
    v = versions(installed_pm)
    for key in ("python", "lanegraph", "numpy", "opencv", "numba"):
        assert isinstance(v[key], str) and v[key][0].isdigit(), key
    assert v["plugins"]["lanegraph"] == v["lanegraph"]
    assert "onnxruntime" not in versions() or "onnxruntime" in __import__("sys").modules


def test_command_line_names_the_program():
    assert command_line(["/usr/local/bin/lanegraph", "run", "g.yaml"]) == ["lanegraph", "run", "g.yaml"]


def _git(cwd: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-c", "user.name=t", "-c", "user.email=t@t", *args],
        cwd=cwd,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()


@pytest.mark.skipif(
    shutil.which("git") is None, reason="git is not installed (used to make the test's repository)"
)
def test_git_commit_of_the_graphs_checkout(tmp_path):
    repo = tmp_path / "repo"
    (repo / "graphs").mkdir(parents=True)
    graph = repo / "graphs" / "g.yaml"
    graph.write_text("name: g\n")
    _git(repo, "init", "-q", "-b", "main")
    _git(repo, "add", ".")
    _git(repo, "commit", "-qm", "one")
    sha = _git(repo, "rev-parse", "HEAD")
    assert git_commit(graph) == {"commit": sha, "branch": "main"}
    _git(repo, "pack-refs", "--all")  # the branch only in packed-refs
    assert not (repo / ".git/refs/heads/main").exists()
    assert git_commit(graph) == {"commit": sha, "branch": "main"}
    _git(repo, "worktree", "add", "-q", str(tmp_path / "wt"), "-b", "other")
    assert git_commit(tmp_path / "wt" / "graphs" / "g.yaml") == {"commit": sha, "branch": "other"}
    _git(repo, "checkout", "-q", "--detach")
    assert git_commit(graph) == {"commit": sha}
    # a configuration that would run a program if git were run there: it is never run
    (repo / ".git" / "config").write_text(f"[core]\n\tfsmonitor = touch {tmp_path / 'ran'}\n")
    assert git_commit(graph) == {"commit": sha} and not (tmp_path / "ran").exists()


def test_no_checkout_no_commit(tmp_path):
    (tmp_path / "g.yaml").write_text("name: g\n")
    assert git_commit(tmp_path / "g.yaml") is None or (tmp_path / ".git").exists()
    bad = tmp_path / "bad"
    (bad / ".git").mkdir(parents=True)
    (bad / ".git" / "HEAD").write_text("ref: ../../etc/passwd\n")
    assert git_commit(bad / "g.yaml") is None


def _in_time(fn, *args):
    """``fn(*args)`` on a thread, which must end within seconds (a FIFO must not block it)."""
    import threading

    out = {}
    th = threading.Thread(target=lambda: out.setdefault("v", fn(*args)), daemon=True)
    th.start()
    th.join(10)
    assert not th.is_alive(), "blocked"
    return out["v"]


@pytest.mark.parametrize(
    ("where", "what", "why"),
    [
        ("HEAD", "fifo", "a FIFO, not read"),
        ("HEAD", "zero", "a device, not read"),
        ("HEAD", b"ref: refs/heads/\xff\xfe\n", "not UTF-8 text"),
        ("commondir", b"\xff..\n", "not UTF-8 text"),
        ("refs/heads/main", "fifo", "a FIFO, not read"),
        ("HEAD", b"ref: refs/heads/main\n" * 10000, "more than the 65536"),
    ],
)
def test_git_files_are_read_only_when_small_regular_utf8_files(tmp_path, where, what, why):
    graph = tmp_path / "g.yaml"
    graph.write_text("name: g\n")
    git = tmp_path / ".git"
    (git / "refs" / "heads").mkdir(parents=True)
    (git / "HEAD").write_text("ref: refs/heads/main\n")
    (git / "refs" / "heads" / "main").write_text("a" * 40 + "\n")
    target = git / where
    target.unlink(missing_ok=True)
    if what == "fifo":
        os.mkfifo(target)
    elif what == "zero":
        target.symlink_to("/dev/zero")
    else:
        target.write_bytes(what)
    got = _in_time(git_commit, graph)
    assert set(got) == {"skipped"} and why in got["skipped"] and "not recorded" in got["skipped"], got


def test_a_run_whose_graph_lies_beside_a_fifo_head_runs_and_says_so(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from lanegraph.cli import main

    (tmp_path / "g").mkdir()
    graph = tmp_path / "g" / "demo.yaml"
    graph.write_text((Path(__file__).resolve().parents[2] / "graphs" / "demo_sgbm.yaml").read_text())
    (tmp_path / ".git").mkdir()
    os.mkfifo(tmp_path / ".git" / "HEAD")
    out = tmp_path / "out"
    args = ["run", str(graph), "--out", str(out), "-q", "--set", "src.type=io.synthetic", "--set",
            "src.scale=0.2", "--set", "src.frames=1", "--set", "disp.num_disparities=16"]  # fmt: skip
    r = _in_time(lambda: CliRunner().invoke(main, args))
    assert r.exit_code == 0, r.output
    record = json.loads((out / "run.json").read_text())
    assert "a FIFO, not read" in record["git"]["skipped"]
