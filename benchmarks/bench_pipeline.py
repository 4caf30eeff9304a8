"""Speed of a lane graph on real frames, per node and end to end.

    python benchmarks/bench_pipeline.py [GRAPH ...] [--input DRIVE] [--frames 0:54] [--cold-start]

``--input`` is any input a source reads: a KITTI drive (PNG pairs) or a bag of raw frames, e.g. the
same frames recorded as they are (``python -m lanegraph_io.recordings drive.mcap --from DRIVE
--frames 54``): reading raw frames against decoding PNGs, in the same sitting.

For each graph prints, over the selected frames (after one warm-up frame; each figure from the
best of ``--repeat`` runs, default 3: the machines are shared and the best run is the least
disturbed one):
- median ms per node (a run whose source reads each frame before the nodes run: no read-ahead
  thread decoding beside them, the source's own ``read_ahead`` set to 0);
- "after disparity": the median per-frame sum of every node downstream of the disparity node;
- frames/s counting every node but image reading (the source), from the same run;
- frames/s end to end, image reading included: a second run as ``lanegraph run`` does it (the
  executor reads the next frame while this one is computed, the source decodes ahead as its
  ``read_ahead`` says: ``--read-ahead N`` sets it; the next frame's ``ahead`` nodes, the disparity,
  run beside this frame's later nodes: :mod:`lanegraph.run.ahead`; the per-node run above
  computes one node at a time);
- the graph's compute per frame (the sum of the node medians, every node but ``io.*``: what a
  run's ``timings.json`` gives) over one plain full-frame ``cv2.StereoSGBM`` call with the disparity
  node's matching params (number of disparities, block size, uniqueness, penalties, mode), timed
  in the same process right after the runs (median of ``--sgbm-calls`` calls on the frames' grey
  pairs): the ratio the speed target is stated in;
- the process's CPU time per frame in those runs (every thread) and the frames/s the CPUs free to
  it would give at most if they were always busy: on a shared machine a steadier figure than the
  frames/s, and the ceiling the overlap of reading, matching and the nodes works towards; and that
  CPU time by thread in the first of those runs (Linux: the SGBM bands' pool, the decoders, the main
  thread, OpenCV's and numba's workers), to see which part of a frame is the longest;
- the floors: the CPU time a frame of reading (the decoding threads' in the first end-to-end run),
  and of the disparity node and of the nodes after it (the process's, every thread, while the node
  runs, in the run that computes one node at a time: :class:`NodeCpu`; medians per frame), and the
  frames/s the CPUs free to the process would give at most if they were always busy
  with reading and the disparity alone (every other node free), and with every node as it is;
- the load average beside the figures (the machines are shared: a figure taken under load is
  not an idle machine's);
- with --cold-start: the wall time of a fresh `lanegraph run --frames 0:1` process, twice (the
  second one must find the numba kernels in the on-disk cache).
"""

from __future__ import annotations

import argparse
import atexit
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from lanegraph import hookimpl
from lanegraph._runtime import available_cpus
from lanegraph.graph.validation import load_graph
from lanegraph.nodes import RunContext
from lanegraph.run.executor import Executor
from lanegraph.run.prefetch import Prefetch

ROOT = Path(__file__).resolve().parents[1]
DRIVE = ROOT.parent / "shared/data/kitti_raw/2011_09_26/2011_09_26_drive_0001_sync"


def downstream_of(graph, start: str) -> set[str]:
    out, frontier = set(), {start}
    while frontier:
        nxt = {e.dst_node for e in graph.edges if e.src_node in frontier and not e.previous} - out
        out |= nxt
        frontier = nxt
    return out


def load() -> str:
    """The 1, 5 and 15 minute load averages, as ``uptime`` prints them."""
    try:
        return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover - not on every platform
        return "load average unknown"


def plain_sgbm_ms(graph, drive: Path, sel: slice, calls: int) -> tuple[float, str]:
    """Median ms of one plain full-frame ``cv2.StereoSGBM`` call (one call, the whole grey frame,
    no crop, no strips) with the graph's disparity node's matching params, and a description."""
    from lanegraph_disparity import SgbmParams
    from lanegraph_disparity._opencv import _sgbm_matcher

    disp = [nd for nd in graph.nodes.values() if nd.type.family == "disparity"]
    values = disp[0].params.model_dump() if disp else {}
    keys = ("num_disparities", "min_disparity", "block_size", "uniqueness_ratio", "mode", "p1", "p2")
    keys += ("speckle_window_size", "speckle_range", "disp12_max_diff", "prefilter_cap")
    params = SgbmParams(**{k: values[k] for k in keys if k in values})
    pairs = grey_pairs(drive, sel, calls)
    matcher = _sgbm_matcher(params, params.num_disparities, params.min_disparity)
    matcher.compute(*pairs[0])  # warm-up
    times = []
    for left, right in pairs:
        t0 = time.perf_counter()
        matcher.compute(left, right)
        times.append((time.perf_counter() - t0) * 1000.0)
    what = (
        f"{params.num_disparities} disparities, block {params.block_size}, uniqueness {params.uniqueness_ratio}, "
        f"mode {params.mode}"
    )
    return float(np.median(times)), what


def grey_pairs(path: Path, sel: slice, calls: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The first ``calls`` grey pairs of the selection, as the source that reads ``path`` gives them
    (a KITTI drive's PNGs, a bag's raw frames)."""
    from lanegraph.plugins import get_plugin_manager
    from lanegraph.run.sources import close_source, detect_source, open_source

    nt = detect_source(get_plugin_manager(), path)
    src = open_source(nt, nt.params(), path, frames=sel)
    pairs = []
    try:
        for item in src:
            if isinstance(item, dict):
                pairs.append(
                    tuple(
                        g if g.ndim == 2 else cv2.cvtColor(g, cv2.COLOR_BGR2GRAY)
                        for g in (item["left"], item["right"])
                    )
                )
            if len(pairs) == calls:
                break
    finally:
        close_source(src)
    return pairs


#: the kind of a thread that is not Python's (OpenCV's and numba's workers)
OTHER = "other (OpenCV, numba)"


def thread_cpu() -> dict[int, tuple[str, float]]:
    """Each live thread of this process: native id -> (kind, CPU seconds so far). The kind is
    lanegraph's thread name without its number (``lanegraph-bands``, ``lanegraph-read``, ...),
    ``main``, or ``other (OpenCV, numba)`` for the native workers. Empty where ``/proc/self/task``
    is missing (not Linux)."""
    if not os.path.isdir("/proc/self/task"):
        return {}
    names = {th.native_id: re.sub(r"_\d+$", "", th.name) for th in threading.enumerate()}
    main = threading.main_thread().native_id
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        kind = "main" if int(tid) == main else names.get(int(tid), OTHER)
        out[int(tid)] = (kind, (int(fields[11]) + int(fields[12])) / tick)  # utime + stime
    return out


class ThreadClock:
    """The CPU time of a run by kind of thread (:func:`thread_cpu`), sampled after every frame
    (about 0.1 ms): a thread that ends before the run does (the reading pool's) keeps its last
    sample."""

    def __init__(self) -> None:
        self.before = thread_cpu()
        self.seen: dict[int, tuple[str, float]] = {}

    def __call__(self, index: int, frame: object) -> None:
        for tid, (kind, cpu) in thread_cpu().items():
            known = self.seen.get(tid)
            # a thread whose Python part has ended is still in /proc for a moment, nameless
            self.seen[tid] = (known[0] if known and kind == OTHER else kind, cpu)

    def by_kind(self) -> dict[str, float]:
        self(-1, None)
        out: dict[str, float] = {}
        for tid, (kind, cpu) in self.seen.items():
            out[kind] = out.get(kind, 0.0) + cpu - self.before.get(tid, (kind, 0.0))[1]
        return out


class NodeCpu:
    """The process's CPU time (every thread: OpenCV's and the nodes' own workers too) while each
    node runs, per frame, in ms: registered with a run that computes one node at a time (no
    reading ahead, no prefetch, nothing computed ahead), it is that node's CPU."""

    def __init__(self) -> None:
        self.started: dict[str, float] = {}
        self.ms: dict[str, list[float]] = {}

    @hookimpl
    def lanegraph_before_node(self, node_id: str, node_type: str, frame: str | None, inputs: dict) -> None:
        self.started[node_id] = time.process_time()

    @hookimpl
    def lanegraph_after_node(
        self,
        node_id: str,
        node_type: str,
        frame: str | None,
        outputs: object,
        elapsed_ms: float,
        error: object,
    ) -> None:
        t0 = self.started.pop(node_id, None)
        if t0 is not None and frame is not None:
            self.ms.setdefault(node_id, []).append(1000.0 * (time.process_time() - t0))

    def median_sum(self, ids, frames: int) -> float:
        """The median over the last ``frames`` frames of the per-frame sum of ``ids``' CPU."""
        rows = [self.ms[i][-frames:] for i in ids if len(self.ms.get(i, ())) >= frames]
        return float(np.median(np.sum(rows, axis=0))) if rows else 0.0


def bench(
    graph_path: str,
    drive: Path,
    frames: str,
    repeat: int = 3,
    sgbm_calls: int = 10,
    read_ahead: int | None = None,
) -> None:
    a, _, b = frames.partition(":")
    sel = slice(int(a or 0), int(b) if b else None)
    start_load = load()
    out_dir = Path(tempfile.mkdtemp())
    atexit.register(shutil.rmtree, out_dir, True)  # nothing left in the temporary folder
    # warm-up: compile kernels, fill caches
    Executor(load_graph(graph_path), RunContext(input_path=drive, out_dir=out_dir, frames=slice(0, 1))).run()
    g = load_graph(graph_path)
    src = g.source.id
    disp = [nid for nid, nd in g.nodes.items() if nd.type.family == "disparity"]
    after = downstream_of(g, disp[0]) if disp else set(g.nodes) - {src}

    def per_frame(res, ids):
        n = res.frames
        return np.sum(
            [
                np.asarray(res.timings_ms[i][-n:])
                for i in ids
                if i in res.timings_ms and len(res.timings_ms[i]) >= n
            ],
            axis=0,
        )

    # 1. the nodes' own times: the source reads each frame in the main thread before the nodes run
    #    (no prefetch thread decoding PNGs beside them on the 2 cores). The machines are shared:
    #    of `repeat` runs the one with the lowest median per-frame time is kept (the least
    #    disturbed one, as timeit's best of N)
    def no_read_ahead() -> Executor:
        ex = Executor(
            load_graph(graph_path),
            RunContext(input_path=drive, out_dir=out_dir, frames=sel),
            prefetcher=Prefetch(0),
        )
        src_node = ex.graph.source
        if "read_ahead" in type(src_node.params).model_fields:  # the source decodes no frame ahead either
            src_node.params = src_node.params.model_copy(update={"read_ahead": 0})
        return ex

    runs, clocks = [], []
    for _ in range(repeat):
        ex, clock = no_read_ahead(), NodeCpu()
        ex.pm.register(clock)  # the process-wide manager: taken off again before the end-to-end runs
        try:
            runs.append(ex.run())
        finally:
            ex.pm.unregister(clock)
        clocks.append(clock)
    best = min(
        range(repeat), key=lambda k: float(np.median(per_frame(runs[k], [i for i in g.nodes if i != src])))
    )
    res, node_cpu = runs[best], clocks[best]
    # 2. end to end, as `lanegraph run` does it: the next frame is read while this one is
    #    computed; best of `repeat` runs
    walls, cpus, threads = [], [], {}
    for k in range(repeat):
        ex = Executor(load_graph(graph_path), RunContext(input_path=drive, out_dir=out_dir, frames=sel))
        if read_ahead is not None and "read_ahead" in type(ex.graph.source.params).model_fields:
            ex.graph.source.params = ex.graph.source.params.model_copy(update={"read_ahead": read_ahead})
        # the CPU by thread in the first run only (sampled after every frame, about 0.1 ms): the
        # others are timed undisturbed
        clock = ThreadClock() if k == 0 else None
        t0, c0 = time.perf_counter(), time.process_time()
        e2e = ex.run(on_frame=clock)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
        if clock is not None:
            threads = clock.by_kind()
    wall = min(walls)
    n = res.frames
    print(f"\n== {graph_path}: {n} frames of {drive.name} (best of {repeat} runs; {start_load} at the start)")
    for nid in g.order:
        ts = res.timings_ms.get(nid)
        if ts:
            print(
                f"  {nid:14s} {g.nodes[nid].type.name:22s} median {np.median(ts):8.2f} ms   p90 {np.percentile(ts, 90):8.2f} ms"
            )
    no_src = per_frame(res, [i for i in g.nodes if i != src])
    print(f"  after disparity (median of per-frame sum): {np.median(per_frame(res, after)):.2f} ms")
    print(
        f"  every node but image reading: {1000.0 / np.median(no_src):.1f} frames/s ({np.median(no_src):.1f} ms median per frame)"
    )
    ahead = ", ".join(sorted(ex.ahead.nodes))
    print(
        f"  end to end, reading included: {e2e.frames / wall:.1f} frames/s ({1000 * wall / e2e.frames:.1f} ms/frame, next frame read ahead"
        + (f", its {ahead} computed ahead" if ahead else "")
        + f"); runs {', '.join(f'{e2e.frames / w:.1f}' for w in walls)}"
    )
    # the CPU time of the whole process (every thread: decoding, SGBM bands, nodes) per frame: a
    # figure other load on a shared machine changes little, and with the CPUs free to the process
    # the most frames/s they could give if every one were always busy
    cpu_ms = 1000.0 * min(cpus) / max(e2e.frames, 1)
    n_cpu = available_cpus()
    print(
        f"  CPU time per frame, end to end (all threads, least of the runs): {cpu_ms:.1f} ms; "
        f"{n_cpu} CPUs busy all the time would give at most {1000.0 * n_cpu / cpu_ms:.1f} frames/s"
    )
    if threads:
        parts = sorted(((v, k) for k, v in threads.items() if v > 0), reverse=True)
        print(
            "  CPU a frame by thread (the first run, sampled after each frame; clock ticks of 10 ms): "
            + ", ".join(f"{k} {1000.0 * v / max(e2e.frames, 1):.1f} ms" for v, k in parts)
        )
    # reading: the decoding threads' CPU in the end-to-end run (the source is not a hooked node call);
    # where the source decodes in the main thread (no reading thread), its median time in the
    # one-node-at-a-time run
    if threads.get("lanegraph-read", 0) > 0:
        reading = 1000.0 * threads["lanegraph-read"] / max(e2e.frames, 1)
    else:
        reading = float(np.median(res.timings_ms.get(src, [0.0])[-n:]))
    disparity = node_cpu.median_sum(disp[:1], n)
    after_cpu = node_cpu.median_sum(sorted(after), n)
    rest = node_cpu.median_sum(sorted(set(g.nodes) - {src} - set(disp[:1]) - after), n)
    least = reading + disparity
    if least > 0:
        print(
            f"  floors, CPU a frame (reading: its threads end to end; the nodes: every thread while the node "
            f"runs, one node at a time): reading {reading:.1f} ms, the disparity {disparity:.1f} ms, the "
            f"nodes after it {after_cpu:.1f} ms, the others {rest:.1f} ms; {n_cpu} CPUs always busy would "
            f"give at most {1000.0 * n_cpu / least:.1f} frames/s with reading and the disparity alone "
            f"(every other node free), {1000.0 * n_cpu / (least + after_cpu + rest):.1f} with every node "
            "as it is"
        )
    compute = sum(
        float(np.median(ts))
        for nid, ts in res.timings_ms.items()
        if ts and not g.nodes[nid].type.name.startswith("io.")
    )
    sgbm_ms, what = plain_sgbm_ms(g, drive, sel, sgbm_calls)
    print(
        f"  graph compute per frame (sum of node medians, io.* left out): {compute:.1f} ms; one plain "
        f"full-frame cv2.StereoSGBM call ({what}): {sgbm_ms:.1f} ms; ratio {compute / sgbm_ms:.2f}"
    )
    print(f"  {load()}")


def cold_start(graph_path: str, drive: Path) -> None:
    """A fresh kernel cache: the first process compiles every kernel, the second loads them."""
    import os

    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "LANEGRAPH_CACHE_DIR": cache}
        env.pop("NUMBA_CACHE_DIR", None)
        for label in ("first process, empty kernel cache", "second process, kernels cached"):
            with tempfile.TemporaryDirectory() as out:
                t0 = time.perf_counter()
                subprocess.run(
                    [
                        sys.executable,
                        "-m",
                        "lanegraph.cli",
                        "run",
                        graph_path,
                        "--input",
                        str(drive),
                        "--out",
                        out,
                        "--frames",
                        "0:1",
                        "--quiet",
                    ],
                    check=True,
                    capture_output=True,
                    env=env,
                )
                print(f"  cold start to first frame ({label}): {time.perf_counter() - t0:.2f} s")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("graphs", nargs="*", default=[str(ROOT / "graphs/paper.yaml")])
    ap.add_argument(
        "--input", type=Path, default=DRIVE, help="a KITTI drive (default: drive 0001), a bag, a video ..."
    )
    ap.add_argument("--frames", default="0:54")
    ap.add_argument("--cold-start", action="store_true")
    ap.add_argument(
        "--read-ahead",
        type=int,
        default=None,
        help="the source's read_ahead in the end-to-end runs (default: the source's own, auto)",
    )
    ap.add_argument(
        "--sgbm-calls", type=int, default=10, help="plain SGBM calls timed for the ratio (default 10)"
    )
    ap.add_argument(
        "--repeat", type=int, default=3, help="runs per figure; the best one is reported (default 3)"
    )
    a = ap.parse_args()
    if not a.input.exists():
        sys.exit(f"input not found: {a.input}")
    for gp in a.graphs:
        bench(gp, a.input, a.frames, a.repeat, a.sgbm_calls, a.read_ahead)
        if a.cold_start:
            cold_start(gp, a.input)


if __name__ == "__main__":
    main()
