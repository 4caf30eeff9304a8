"""Wall time of an ablation over a dataset in this process and on a local Dask cluster.

    python benchmarks/bench_distributed.py [--dataset graphs/datasets/dev.yaml] [--workers 2]
        [--graphs graphs/paper.yaml graphs/ablations/*.yaml] [--chunk-sweep 10 --warmups 0,2,5,10]

Runs ``lanegraph ablate GRAPHS --dataset DATASET --no-cache`` twice as a user would (a fresh
process each, no result cache, so both compute everything): in this process and with
``--scheduler local:N``. Prints for each the wall time of the command, the CPU time it used (all
its processes) and so the cores it kept busy on average; for the cluster also the time to start it
and the workers' utilisation (the runs' wall times summed over N x the command's wall time); the
ratio; whether every lanes.jsonl is the same byte for byte; and the per-frame cost on one worker,
from which the wall time of N workers on the whole of KITTI raw (40,000 frames x the graphs) is
projected (perfect balance, no cluster start: a lower bound).

``--chunk-sweep K``: instead, the pooled figures of the first graph (paper.yaml) on the dataset
unchunked and with ``--chunk-frames K --warmup W`` for each W of ``--warmups``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KITTI_RAW_FRAMES = 40_000


def lanegraph(*args: str) -> list[str]:
    return [sys.executable, "-m", "lanegraph", *args]


def timed(cmd: list[str], marker: str | None = None) -> tuple[float, float, float | None, str]:
    """(wall s, CPU s of the command and its children, seconds until a stderr line containing
    ``marker`` appeared, stderr)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT)
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
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("lanes.jsonl"))}


def rows(out: Path) -> list[dict[str, str]]:
    return list(csv.DictReader((out / "results.csv").open()))


def compare(graphs: list[str], dataset: str, workers: int) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="bench_distributed_"))
    base = ["ablate", *graphs, "--dataset", dataset, "--no-cache", "--quiet"]
    print(f"{len(graphs)} graph(s) x {dataset}; {os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f} at the start")
    # numba kernels compiled and cached before either timing
    subprocess.run(lanegraph("run", graphs[0], "--frames", "0:1", "--out", str(tmp / "warm"), "--quiet"), cwd=ROOT, check=True, capture_output=True)
    wall_1, cpu_1, _, _ = timed(lanegraph(*base, "--out", str(tmp / "here")))
    frames = sum(json.loads(p.read_text())["frames"] for p in (tmp / "here").rglob("timings.json"))
    print(f"in this process:   {wall_1:7.1f} s wall, {cpu_1:7.1f} s CPU = {cpu_1 / wall_1:.2f} cores busy; {frames} frames, {1000 * wall_1 / frames:.1f} ms/frame")
    wall_n, cpu_n, start, _ = timed(lanegraph(*base, "--out", str(tmp / "cluster"), "--scheduler", f"local:{workers}"), marker="Dask dashboard")
    busy = sum(float(r["wall_s"]) for r in rows(tmp / "cluster") if r["sequence"] != "all")
    print(
        f"local:{workers}:          {wall_n:7.1f} s wall, {cpu_n:7.1f} s CPU = {cpu_n / wall_n:.2f} cores busy; cluster up after "
        f"{start or float('nan'):.1f} s; workers busy {100 * busy / (workers * wall_n):.0f} % of the wall time"
    )
    print(f"ratio:             {wall_1 / wall_n:.2f}x faster with {workers} workers")
    same = lanes(tmp / "here") == lanes(tmp / "cluster")
    print(f"lanes.jsonl:       {'identical' if same else 'DIFFERENT'} ({len(lanes(tmp / 'here'))} files)")
    per_frame = workers * busy / frames  # seconds of one worker per frame
    print(f"one worker:        {1000 * per_frame:.1f} ms per frame and graph (the runs' wall times summed / frames)")
    total = KITTI_RAW_FRAMES * len(graphs)
    print(f"KITTI raw ({KITTI_RAW_FRAMES} frames x {len(graphs)} graphs = {total} frame runs), projected:")
    for n in (1, 2, 8, 32, 128):
        print(f"  {n:4d} workers: {total * per_frame / n / 3600:7.2f} h")
    print(f"(in this process: {total * wall_1 / frames / 3600:.2f} h)")


def chunk_sweep(graph: str, dataset: str, chunk: int, warmups: list[int]) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="bench_chunks_"))
    keys = ("frames", "detection_ratio", "precision", "ego_recall", "mean_abs_dx_px")
    print(f"{graph} on {dataset}, pooled over its sequences")
    print("| run | frames | detection ratio | precision | ego recall | mean abs dx (px) | lanes.jsonl lines equal to unchunked |")
    print("|---|---|---|---|---|---|---|")
    ref = None
    for label, extra in [("unchunked", [])] + [(f"chunks of {chunk}, warm-up {w}", ["--chunk-frames", str(chunk), "--warmup", str(w)]) for w in warmups]:
        out = tmp / label.replace(" ", "_").replace(",", "")
        timed(lanegraph("ablate", graph, "--dataset", dataset, "--no-cache", "--quiet", "--out", str(out), *extra))
        pooled = next(r for r in rows(out) if r["sequence"] == "all")
        got = [line for f in sorted(out.rglob("lanes.jsonl")) for line in f.read_text().splitlines()]
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
    ap.add_argument("--graphs", nargs="+", default=["graphs/paper.yaml", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "graphs" / "ablations").glob("*.yaml"))])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--chunk-sweep", type=int, metavar="K", help="the figures of the first graph with chunks of K frames instead")
    ap.add_argument("--warmups", default="0,2,5,10", help="warm-up frames for --chunk-sweep, comma-separated")
    args = ap.parse_args()
    if not (ROOT / args.dataset).is_file() and not Path(args.dataset).is_file():
        sys.exit(f"{args.dataset}: no such dataset file")
    if args.chunk_sweep:
        chunk_sweep(args.graphs[0], args.dataset, args.chunk_sweep, [int(w) for w in args.warmups.split(",")])
    else:
        compare(args.graphs, args.dataset, args.workers)


if __name__ == "__main__":
    main()
