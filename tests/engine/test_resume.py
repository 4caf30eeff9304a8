"""Kill a real run mid-way, resume it: the output equals an uninterrupted run's."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

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
