"""The first run against a warm one: the default ``lanegraph run`` (the paper graph on the built-in
synthetic scene, output piped), as a new user meets it.

Three kinds of run, measured in turns (``--rounds`` of each, so that the load of a shared machine
falls on all of them alike):

- **first on this machine**: an empty kernel folder and an empty cache folder: every kernel compiles;
- **new cache folder**: an empty ``LANEGRAPH_CACHE_DIR``, the machine's kernel folder already filled
  (the kernels are shared by every cache folder: :mod:`lanegraph.kernel_cache`);
- **warm**: the same cache folder again.

For each: the wall time, the time to the first line the command prints (stdout or stderr), and
whether its ``lanes.jsonl`` is byte-identical to the warm run's. Prints the medians, the ratios to
the warm run and the load average before and after.

    python benchmarks/bench_first_run.py --rounds 3
"""

from __future__ import annotations

import argparse
import os
import selectors
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from statistics import median


def run_once(env: dict[str, str], out: Path, args: list[str]) -> tuple[float, float, bytes]:
    """(wall s, s to the first line, lanes.jsonl) of one piped ``lanegraph run``."""
    cmd = [sys.executable, "-m", "lanegraph.cli", "run", "--out", str(out), *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = None
    sel = selectors.DefaultSelector()
    assert proc.stdout is not None and proc.stderr is not None
    sel.register(proc.stdout, selectors.EVENT_READ)
    sel.register(proc.stderr, selectors.EVENT_READ)
    tail = b""
    open_streams = 2
    while open_streams:
        for key, _ in sel.select():
            chunk = os.read(key.fileobj.fileno(), 65536)  # type: ignore[union-attr]
            if not chunk:
                sel.unregister(key.fileobj)
                open_streams -= 1
                continue
            tail = (tail + chunk)[-2000:]
            if first is None and (b"\n" in chunk or b"\r" in chunk):
                first = time.perf_counter() - t0
    code = proc.wait()
    wall = time.perf_counter() - t0
    if code != 0:
        raise SystemExit(f"lanegraph run failed ({code}): {tail.decode(errors='replace')}")
    return wall, first if first is not None else wall, (out / "lanes.jsonl").read_bytes()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3, help="runs of each kind (default 3)")
    ap.add_argument("args", nargs="*", help="more arguments for lanegraph run (e.g. a graph)")
    opt = ap.parse_args()
    base = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "LANEGRAPH_CACHE_DIR")}
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())} ({os.cpu_count()} cores)")
    rows: dict[str, list[tuple[float, float, bool]]] = {
        "first on this machine": [],
        "new cache folder": [],
        "warm": [],
    }
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        shared_kernels = root / "kernels-shared"
        warm_env = {
            **base,
            "LANEGRAPH_CACHE_DIR": str(root / "warm-cache"),
            "LANEGRAPH_KERNEL_CACHE": str(shared_kernels),
        }
        _, _, reference = run_once(warm_env, root / "out-prime", opt.args)  # fills the shared kernels
        for k in range(opt.rounds):
            for kind in rows:
                if kind == "first on this machine":
                    env = {
                        **base,
                        "LANEGRAPH_CACHE_DIR": str(root / f"c{k}"),
                        "LANEGRAPH_KERNEL_CACHE": str(root / f"k{k}"),
                    }
                elif kind == "new cache folder":
                    env = {
                        **base,
                        "LANEGRAPH_CACHE_DIR": str(root / f"n{k}"),
                        "LANEGRAPH_KERNEL_CACHE": str(shared_kernels),
                    }
                else:
                    env = warm_env
                wall, first, lanes = run_once(env, root / f"out-{kind[:3]}-{k}", opt.args)
                rows[kind].append((wall, first, lanes == reference))
                print(
                    f"  round {k + 1} {kind:22s} wall {wall:6.2f} s, first line after {first:5.2f} s, "
                    f"lanes {'identical' if lanes == reference else 'DIFFERENT'}",
                    flush=True,
                )
    warm = median(w for w, _, _ in rows["warm"])
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'run':24s} {'median wall':>12s} {'x warm':>7s} {'first line':>11s}  lanes")
    for kind, rs in rows.items():
        wall = median(w for w, _, _ in rs)
        first = median(f for _, f, _ in rs)
        same = "identical" if all(s for _, _, s in rs) else "DIFFERENT"
        print(f"{kind:24s} {wall:10.2f} s {wall / warm:6.1f}x {first:9.2f} s  {same}")


if __name__ == "__main__":
    main()
