"""``benchmarks/bench_pipeline.py``'s CPU time by thread: a thread that ends before the run keeps
its last sample, threads are grouped by lanegraph's names without their numbers."""

from __future__ import annotations

import importlib.util
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("bench_pipeline", ROOT / "benchmarks" / "bench_pipeline.py")
bench_pipeline = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_pipeline)


def _spin(seconds: float, then: threading.Event | None = None) -> None:
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass
    if then is not None:
        then.wait(30)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/task")
def test_thread_clock_keeps_an_ended_thread_and_groups_by_name():
    clock = bench_pipeline.ThreadClock()
    release = threading.Event()
    threads = [
        threading.Thread(target=_spin, args=(0.15, release), name=f"lanegraph-spin_{i}") for i in range(2)
    ]
    for th in threads:
        th.start()
    deadline = time.monotonic() + 30
    while (
        time.monotonic() < deadline
        and sum(cpu for kind, cpu in bench_pipeline.thread_cpu().values() if kind == "lanegraph-spin") < 0.26
    ):  # both have spun, or nearly (10 ms clock ticks), and wait
        time.sleep(0.01)
    time.sleep(0.05)
    clock(0, "0")  # sampled while they live, as a run samples after every frame
    release.set()
    for th in threads:
        th.join()
    _spin(0.05)
    clock(1, "1")  # they have ended: gone from /proc, their last samples kept
    got = clock.by_kind()
    assert 0.26 <= got["lanegraph-spin"] <= 0.4  # both threads' 0.15 s, as /proc counted them
    assert got["main"] >= 0.03
    assert not any(k.startswith("lanegraph-spin_") for k in got)
