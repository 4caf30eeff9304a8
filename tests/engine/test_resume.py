"""Kill a real run mid-way, resume it: the output equals an uninterrupted run's."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAPER = str(ROOT / "graphs" / "paper.yaml")


def lanegraph(*args, **kw):
    return subprocess.run([sys.executable, "-m", "lanegraph.cli", *args], capture_output=True, text=True, **kw)


def test_kill_and_resume_equals_uninterrupted(tmp_path):
    frames = "0:8"
    full = tmp_path / "full"
    r = lanegraph("run", PAPER, "--out", str(full), "--frames", frames, "--quiet")
    assert r.returncode == 0, r.stderr

    part = tmp_path / "part"
    proc = subprocess.Popen(
        [sys.executable, "-m", "lanegraph.cli", "run", PAPER, "--out", str(part), "--frames", frames, "--quiet"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    lanes = part / "lanes.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline:
        if lanes.is_file() and lanes.read_text().count("\n") >= 3:
            break
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = lanes.read_text().count("\n")
    assert 3 <= done_before < 8, "the run should have been killed mid-way"
    # simulate a torn write as well: half a line at the end
    with lanes.open("a") as fh:
        fh.write('{"frame": "00000000')

    r = lanegraph("run", PAPER, "--out", str(part), "--frames", frames, "--quiet", "--resume")
    assert r.returncode == 0, r.stderr
    assert "resuming after frame" in r.stderr
    assert lanes.read_text() == (full / "lanes.jsonl").read_text()


def test_resume_without_checkpoint_starts_over(tmp_path):
    r = lanegraph("run", PAPER, "--out", str(tmp_path), "--frames", "0:2", "--quiet", "--resume")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "lanes.jsonl").read_text().count("\n") == 2


# ------------------------------------------------------------------ interrupted again and again
TESTS = Path(__file__).resolve().parent
SMALL = ["--set", "src.type=io.synthetic", "--set", "src.scale=0.4", "--set", "src.frames=9", "--set", "src.preset=curved"]


def interrupted_run(out: Path, spec: str | None, *extra: str) -> subprocess.CompletedProcess:
    """`lanegraph run paper.yaml` on a small synthetic sequence, interrupted at ``spec`` (see interrupter.py)."""
    from .interrupter import DRIVER

    env = {**os.environ, "LANEGRAPH_TEST_INTERRUPT": spec or ""}
    args = [sys.executable, "-c", DRIVER, str(TESTS), "run", PAPER, "--out", str(out), "--quiet", *SMALL, *extra]
    return subprocess.run(args, capture_output=True, text=True, env=env, timeout=300)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> str:
    out = tmp_path_factory.mktemp("full")
    r = interrupted_run(out, None)
    assert r.returncode == 0, r.stderr
    text = (out / "lanes.jsonl").read_text()
    assert text.count("\n") == 9 and '"points":[[' in text, "the sequence should have lanes to carry from frame to frame"
    return text


POINTS = [("write", "after"), ("write", "before"), ("fit", "before"), ("verify", "after"), ("src", "after")]


@pytest.mark.parametrize("seed", range(3))
def test_interrupted_again_and_again_equals_uninterrupted(tmp_path, uninterrupted, seed):
    """SIGINT and SIGKILL at random nodes and frames, several times in a row, each followed by
    --resume: the final lanes.jsonl is the uninterrupted run's, byte for byte."""
    rng = random.Random(seed)
    out = tmp_path / "out"
    first = True
    stops = []
    for _ in range(rng.randint(2, 3)):
        sig = rng.choice(["INT", "KILL"])
        node, when = rng.choice(POINTS)
        spec = f"{sig}:{node}:{when}:{rng.randint(1, 3)}"
        r = interrupted_run(out, spec, *([] if first else ["--resume"]))
        first = False
        stops.append((spec, r.returncode))
        if r.returncode == 0:  # fewer frames left than the chosen one: the run finished
            break
        assert r.returncode == (130 if sig == "INT" else -signal.SIGKILL), (spec, r.stderr)
        if sig == "INT":
            assert "interrupted (Ctrl-C)" in r.stderr and "Traceback" not in r.stderr, r.stderr
            assert json.loads((out / "run.json").read_text())["status"] == "stopped"
    r = interrupted_run(out, None, "--resume")
    assert r.returncode == 0, (stops, r.stderr)
    assert (out / "lanes.jsonl").read_text() == uninterrupted, stops
    assert json.loads((out / "run.json").read_text())["frames_ok"] == 9
    if seed:
        return
    # resuming a complete run changes nothing
    r = interrupted_run(out, None, "--resume")
    assert r.returncode == 0 and "nothing to resume" in r.stderr, r.stderr
    assert (out / "lanes.jsonl").read_text() == uninterrupted
