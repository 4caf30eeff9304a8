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


def test_node_cpu_counts_every_thread_while_a_node_runs():
    """The CPU of a node's call, its worker threads' included; calls outside a frame (constant
    nodes) are left out; the per-frame sums of several nodes."""
    clock = bench_pipeline.NodeCpu()
    for frame in ("0", "1", "2"):
        clock.lanegraph_before_node(node_id="a", node_type="t", frame=frame, inputs={})
        worker = threading.Thread(target=_spin, args=(0.06,))
        worker.start()
        _spin(0.03)
        worker.join()
        clock.lanegraph_after_node(
            node_id="a", node_type="t", frame=frame, outputs={}, elapsed_ms=0.0, error=None
        )
        clock.lanegraph_before_node(node_id="b", node_type="t", frame=frame, inputs={})
        clock.lanegraph_after_node(
            node_id="b", node_type="t", frame=frame, outputs={}, elapsed_ms=0.0, error=None
        )
    clock.lanegraph_before_node(node_id="c", node_type="t", frame=None, inputs={})
    clock.lanegraph_after_node(node_id="c", node_type="t", frame=None, outputs={}, elapsed_ms=0.0, error=None)
    assert set(clock.ms) == {"a", "b"} and len(clock.ms["a"]) == 3
    assert all(85.0 <= ms <= 200.0 for ms in clock.ms["a"])  # 30 ms here, 60 ms in the worker
    assert clock.median_sum(["a", "b"], 3) >= clock.median_sum(["a"], 3) >= 85.0
    assert clock.median_sum(["a"], 4) == 0.0  # fewer frames than asked: nothing to sum


def test_node_cpu_sees_every_node_of_a_run(tmp_path):
    from lanegraph.graph.validation import load_graph
    from lanegraph.nodes import RunContext
    from lanegraph.run.executor import Executor
    from lanegraph.run.prefetch import Prefetch

    ex = Executor(
        load_graph(ROOT / "graphs" / "paper.yaml"),
        RunContext(input_path=None, out_dir=tmp_path, frames=slice(0, 2)),
        prefetcher=Prefetch(0),
    )
    clock = bench_pipeline.NodeCpu()
    ex.pm.register(clock)
    try:
        ex.run()
    finally:
        ex.pm.unregister(clock)
    frame_nodes = set(ex.graph.nodes) - {ex.graph.source.id}
    assert set(clock.ms) <= frame_nodes and {"disp", "road", "fit"} <= set(clock.ms)
    assert all(len(v) == 2 and min(v) >= 0.0 for v in clock.ms.values())
    assert clock.ms["disp"][0] > 0.0
