"""Wall time of an ablation over a dataset in this process and on a local Dask cluster.

    python benchmarks/bench_distributed.py [--dataset graphs/datasets/dev.yaml] [--workers 2] [--repeat 1]
        [--graphs graphs/paper.yaml graphs/ablations/*.yaml] [--chunk-sweep 10 --warmups 0,2,5,10]

Runs ``lanegraph ablate GRAPHS --dataset DATASET --no-cache`` twice as a user would (a fresh
process each, no result cache, so both compute everything): in this process and with
``--scheduler local:N``. Prints for each the wall time of the command, the CPU time it used (all
its processes) and so the cores it kept busy on average; for the cluster also the time to start it
and the workers' utilisation (the runs' wall times summed over N x the command's wall time); the
ratio (the best run of each, ``--repeat`` runs alternating: the machines are shared and the best run
is the least disturbed one); whether every lanes.jsonl is the same byte for byte; and the per-frame
cost on one worker, from which the wall time of N workers on the whole of KITTI raw (40,000 frames
x the graphs) is projected (perfect balance, no cluster start: a lower bound). ``--one-core``: also
the in-process run pinned to one core, which says how many cores it keeps busy by itself (SGBM in
two row strips, numba's parallel kernels, the thread decoding the next frame) and so how much N
workers can gain over it.

``--chunk-sweep K``: instead, the pooled figures of the first graph (paper.yaml) on the dataset
unchunked and with ``--chunk-frames K --warmup W`` for each W of ``--warmups``.
"""

from __future__ import annotations

import argparse
import atexit
import csv
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from lanegraph.records.results import find_result

ROOT = Path(__file__).resolve().parents[1]
KITTI_RAW_FRAMES = 40_000


def lanegraph(*args: str) -> list[str]:
    return [sys.executable, "-m", "lanegraph", *args]


def timed(
    cmd: list[str], marker: str | None = None, cpus: set[int] | None = None
) -> tuple[float, float, float | None, str]:
    """(wall s, CPU s of the command and its children, seconds until a stderr line containing
    ``marker`` appeared, stderr); ``cpus``: the CPUs the command may run on (default: all)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    pin = (lambda: os.sched_setaffinity(0, cpus)) if cpus else None
    p = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT, preexec_fn=pin
    )
    seen: list[float] = []
    lines: list[str] = []

    def read() -> None:
        assert p.stderr is not None
        for line in p.stderr:
            lines.append(line)
            if marker and marker in line and not seen:
                seen.append(time.perf_counter() - t0)

    reader = threading.Thread(target=read)
    reader.start()
    p.wait()
    reader.join()
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if p.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({p.returncode}):\n{''.join(lines[-20:])}")
    return wall, cpu, (seen[0] if seen else None), "".join(lines)


def lanes(out: Path) -> dict[str, bytes]:
    files = (find_result(run.parent) for run in sorted(out.rglob("run.json")))
    return {str(p.relative_to(out)): p.read_bytes() for p in files if p is not None}


def rows(out: Path) -> list[dict[str, str]]:
    return list(csv.DictReader((out / "results.csv").open()))


def compare(graphs: list[str], dataset: str, workers: int, repeat: int, one_core: bool) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="bench_distributed_"))
    atexit.register(shutil.rmtree, tmp, True)  # nothing left in the temporary folder
    base = ["ablate", *graphs, "--dataset", dataset, "--no-cache", "--quiet"]
    print(f"{len(graphs)} graph(s) x {dataset}; {os.cpu_count()} cores; {repeat} run(s) of each, alternating")
    # numba kernels compiled and cached before any timing
    subprocess.run(
        lanegraph("run", graphs[0], "--frames", "0:1", "--out", str(tmp / "warm"), "--quiet"),
        cwd=ROOT,
        check=True,
        capture_output=True,
    )
    here, cluster = [], []
    for k in range(repeat):
        load = os.getloadavg()[0]
        wall, cpu, _, _ = timed(lanegraph(*base, "--out", str(tmp / f"here{k}")))
        frames = sum(json.loads(p.read_text())["frames"] for p in (tmp / f"here{k}").rglob("timings.json"))
        here.append(wall)
        print(
            f"in this process:  {wall:7.1f} s wall, {cpu:7.1f} s CPU = {cpu / wall:.2f} cores busy; {frames} frames; load average {load:.2f} before"
        )
        load = os.getloadavg()[0]
        wall, cpu, start, _ = timed(
            lanegraph(*base, "--out", str(tmp / f"cluster{k}"), "--scheduler", f"local:{workers}"),
            marker="Dask dashboard",
        )
        busy = sum(float(r["wall_s"]) for r in rows(tmp / f"cluster{k}") if r["sequence"] != "all")
        cluster.append((wall, busy))
        print(
            f"local:{workers}:          {wall:7.1f} s wall, {cpu:7.1f} s CPU = {cpu / wall:.2f} cores busy; cluster up after "
            f"{start or float('nan'):.1f} s; workers busy {100 * busy / (workers * wall):.0f} % of the wall time; load average {load:.2f} before"
        )
        same = lanes(tmp / f"here{k}") == lanes(tmp / f"cluster{k}")
        print(
            f"lanes.jsonl:      {'identical' if same else 'DIFFERENT'} ({len(lanes(tmp / f'here{k}'))} files)"
        )
    if one_core:  # how many cores the in-process run already keeps busy: its wall time on one core
        load = os.getloadavg()[0]
        wall, cpu, _, _ = timed(
            lanegraph(*base, "--out", str(tmp / "one_core")), cpus={min(os.sched_getaffinity(0))}
        )
        print(
            f"in this process on one core: {wall:7.1f} s wall, {cpu:7.1f} s CPU; load average {load:.2f} before"
        )
        print(
            f"  so on {os.cpu_count()} cores it ran {wall / min(here):.2f}x faster than on one: two workers can gain at most {workers / (wall / min(here)):.2f}x"
        )
    wall_1 = min(here)
    wall_n, busy = min(cluster)
    print(
        f"best of {repeat}:  in this process {wall_1:.1f} s, local:{workers} {wall_n:.1f} s: {wall_1 / wall_n:.2f}x faster with {workers} workers"
    )
    per_frame = busy / frames  # the runs' wall times summed: seconds of one worker per frame
    print(
        f"one worker:       {1000 * per_frame:.1f} ms per frame and graph (the best cluster run's run wall times summed / frames)"
    )
    total = KITTI_RAW_FRAMES * len(graphs)
    print(
        f"KITTI raw ({KITTI_RAW_FRAMES} frames x {len(graphs)} graphs = {total} frame runs), projected (perfect balance, no start-up):"
    )
    for n in (1, 2, 8, 32, 128):
        print(f"  {n:4d} workers: {total * per_frame / n / 3600:7.2f} h")
    print(f"  in this process: {total * wall_1 / frames / 3600:.2f} h")


def chunk_sweep(graph: str, dataset: str, chunk: int, warmups: list[int]) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="bench_chunks_"))
    atexit.register(shutil.rmtree, tmp, True)  # nothing left in the temporary folder
    keys = ("frames", "detection_ratio", "precision", "ego_recall", "mean_abs_dx_px")
    print(f"{graph} on {dataset}, pooled over its sequences")
    print(
        "| run | frames | detection ratio | precision | ego recall | mean abs dx (px) | lanes.jsonl lines equal to unchunked |"
    )
    print("|---|---|---|---|---|---|---|")
    ref = None
    for label, extra in [("unchunked", [])] + [
        (f"chunks of {chunk}, warm-up {w}", ["--chunk-frames", str(chunk), "--warmup", str(w)])
        for w in warmups
    ]:
        out = tmp / label.replace(" ", "_").replace(",", "")
        timed(
            lanegraph(
                "ablate", graph, "--dataset", dataset, "--no-cache", "--quiet", "--out", str(out), *extra
            )
        )
        pooled = next(r for r in rows(out) if r["sequence"] == "all")
        got = [line for f in lanes(out) for line in (out / f).read_text().splitlines()]
        if ref is None:
            ref = got
        equal = sum(a == b for a, b in zip(got, ref))
        vals = [pooled[k] for k in keys]
        pct = [f"{100 * float(v):.1f} %" if v else "n/a" for v in vals[1:4]]
        dx = f"{float(vals[4]):.2f}" if vals[4] else "n/a"
        print(f"| {label} | {vals[0]} | {' | '.join(pct)} | {dx} | {equal} / {len(ref)} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="graphs/datasets/dev.yaml")
    ap.add_argument(
        "--graphs",
        nargs="+",
        default=[
            "graphs/paper.yaml",
            *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "graphs" / "ablations").glob("*.yaml")),
        ],
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="runs of each, alternating; the best of each is compared (a shared machine)",
    )
    ap.add_argument(
        "--one-core",
        action="store_true",
        help="also time the in-process run on one core (how parallel it is already)",
    )
    ap.add_argument(
        "--chunk-sweep",
        type=int,
        metavar="K",
        help="the figures of the first graph with chunks of K frames instead",
    )
    ap.add_argument("--warmups", default="0,2,5,10", help="warm-up frames for --chunk-sweep, comma-separated")
    args = ap.parse_args()
    if not (ROOT / args.dataset).is_file() and not Path(args.dataset).is_file():
        sys.exit(f"{args.dataset}: no such dataset file")
    if args.chunk_sweep:
        chunk_sweep(args.graphs[0], args.dataset, args.chunk_sweep, [int(w) for w in args.warmups.split(",")])
    else:
        compare(args.graphs, args.dataset, args.workers, args.repeat, args.one_core)


if __name__ == "__main__":
    main()
