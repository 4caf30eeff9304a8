"""The first run against a warm one: the default ``lanegraph run`` (the paper graph on the built-in
synthetic scene, output piped), as a new user meets it, the 54 frames of KITTI drive 0001 laid out
by ``lanegraph data kitti`` (``--kitti``: from ``../shared/data``, or the KITTI zips or folders
named), or any other run (``-- RUN ARGS``).

Kinds of run, measured in turns (``--rounds`` of each, so that the load of a shared machine falls on
all of them alike; ``--kinds`` picks some):

- **first on this machine**: an empty kernel folder and an empty cache folder: each kernel is loaded
  from its plugin's shipped machine code when first called, where that applies
  (:mod:`lanegraph.kernels.bundle`), or compiled;
- **first, bundle off**: the same with ``LANEGRAPH_KERNEL_BUNDLE=0``: every kernel compiles;
- **second install**: another installation of the same sources (a copy of ``lanegraph/`` and
  ``plugins/`` in another folder, as a wheel beside an editable checkout) whose first run finds the
  kernel folder filled by this one's (issue 47: it must make its own decision);
- **new cache folder**: an empty ``LANEGRAPH_CACHE_DIR``, the machine's kernel folder already filled
  (the kernels are shared by every cache folder);
- **warm**: the same cache folder again.

For each: the wall time, the CPU time (user + system, of the run and of every process it waited
for: the first run's helper included; on a shared machine the steadier figure, as the load
stretches the walls), the time to the first line the command prints (stdout or stderr), whether
that line is the first run's notice and comes before any frame's progress, and whether its
``lanes.jsonl`` is byte-identical to the warm run's. Prints the medians, the ratios to the warm run
(the median and each round's: a shared machine's load changes between rounds) and the load average
before and after, then one ``ratio`` line per kind: wall and CPU, median and spread.

``--baseline PYTHON`` measures another install in the same sitting, its runs interleaved with these
(``PYTHON -m lanegraph.cli run``: e.g. the Python an older checkout is installed in); its lanes must
be identical too.

    python benchmarks/bench_first_run.py --rounds 3 [--baseline /path/to/before/python]
    python benchmarks/bench_first_run.py --rounds 1 --kinds "second install,warm"
    python benchmarks/bench_first_run.py --rounds 3 --kitti --kinds "first on this machine,warm"
    python benchmarks/bench_first_run.py --rounds 1 --kinds "first on this machine,warm" -- \
        --input ../shared/data/kitti_raw/2011_09_26/2011_09_26_drive_0001_sync
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import selectors
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from statistics import median

ROOT = Path(__file__).resolve().parents[1]
SHARED_DRIVE = ROOT.parent / "shared" / "data" / "kitti_raw" / "2011_09_26"


def run_once(
    env: dict[str, str], out: Path, args: list[str], python: str = sys.executable
) -> tuple[float, float, bytes, float, str]:
    """(wall s, s to the first line, lanes.jsonl, CPU s, how the output starts) of one piped
    ``lanegraph run`` (of ``python``; the CPU of the run and of the processes it waited for, its
    helper included). How it starts: ``notice`` when its first line is the first run's notice and
    no frame's progress came before it, ``frames first`` when progress came before the notice,
    ``-`` without a notice."""
    cmd = [python, "-m", "lanegraph.cli", "run", "--out", str(out), *args]
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    # from the output's folder: ``-m`` imports from the working folder first (never this checkout's
    # lanegraph in place of the baseline's)
    proc = subprocess.Popen(cmd, env=env, cwd=out.parent, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = None
    sel = selectors.DefaultSelector()
    assert proc.stdout is not None and proc.stderr is not None
    sel.register(proc.stdout, selectors.EVENT_READ)
    sel.register(proc.stderr, selectors.EVENT_READ)
    tail = head = b""
    open_streams = 2
    while open_streams:
        for key, _ in sel.select():
            chunk = os.read(key.fileobj.fileno(), 65536)  # type: ignore[union-attr]
            if not chunk:
                sel.unregister(key.fileobj)
                open_streams -= 1
                continue
            tail = (tail + chunk)[-2000:]
            head = (head + chunk)[:4000] if len(head) < 4000 else head
            if first is None and (b"\n" in chunk or b"\r" in chunk):
                first = time.perf_counter() - t0
    code = proc.wait()
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    if code != 0:
        raise SystemExit(f"lanegraph run failed ({code}): {tail.decode(errors='replace')}")
    text = head.decode(errors="replace")
    notice, frames = text.find("lanegraph: first run of"), text.find(" frames")
    starts = "-" if notice < 0 else ("notice" if frames < 0 or notice < frames else "frames first")
    lanes = b"".join(p.read_bytes() for p in sorted(out.rglob("lanes.jsonl")))  # a dataset: one a sequence
    frame_ms.append(max(_median_ms(p) for p in out.rglob("timings.json")))
    return wall, first if first is not None else wall, lanes, cpu, starts


#: the median ms per frame of each run, in order (the run's timings.json; the kernels' own speed
#: shows here: a warm run's frames with the bundle's machine code against compiled kernels')
frame_ms: list[float] = []


def _median_ms(path: Path) -> float:
    try:
        return float(json.loads(path.read_text())["total"]["median_ms"])
    except (OSError, ValueError, KeyError, TypeError):
        return float("nan")


KINDS = ("first on this machine", "first, bundle off", "second install", "new cache folder", "warm")


def second_install(root: Path) -> dict[str, str]:
    """A copy of this checkout's ``lanegraph/``, ``plugins/`` and ``graphs/`` in ``root`` (another installation of
    the same sources), and the environment that imports it first."""
    for name in ("lanegraph", "plugins", "graphs"):
        shutil.copytree(ROOT / name, root / name)  # with the bytecode, as pip compiles it at install
    return {"PYTHONPATH": os.pathsep.join([str(root), str(root / "plugins")])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3, help="runs of each kind (default 3)")
    ap.add_argument(
        "--baseline", metavar="PYTHON", help="also measure the lanegraph of this Python, interleaved"
    )
    ap.add_argument("--kinds", help=f"the kinds to run, comma-separated (default all: {', '.join(KINDS)})")
    ap.add_argument(
        "--kitti",
        nargs="*",
        metavar="SOURCE",
        help="run on KITTI laid out by `lanegraph data kitti` from these zips or folders "
        f"(default {SHARED_DRIVE}): its kitti.yaml, 54 frames",
    )
    ap.add_argument("args", nargs="*", help="more arguments for lanegraph run (e.g. a graph)")
    opt = ap.parse_args()
    kinds = [k.strip() for k in opt.kinds.split(",")] if opt.kinds else list(KINDS)
    if "warm" not in kinds or any(k not in KINDS for k in kinds):
        ap.error(f"--kinds: among {', '.join(KINDS)}, warm included")
    base = {
        k: v
        for k, v in os.environ.items()
        if k not in ("NUMBA_CACHE_DIR", "LANEGRAPH_CACHE_DIR", "LANEGRAPH_KERNEL_CACHE")
    }
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())} ({os.cpu_count()} cores)")
    installs = {"this": sys.executable, **({"baseline": opt.baseline} if opt.baseline else {})}
    rows: dict[tuple[str, str], list[tuple[float, float, bool, float, str]]] = {
        (i, k): [] for i in installs for k in kinds
    }
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        if opt.kitti is not None:
            sources = opt.kitti or [str(SHARED_DRIVE)]
            subprocess.run(
                [sys.executable, "-m", "lanegraph.cli", "data", "kitti", "--quiet", "--out", str(root / "kitti"), *sources],
                check=True, env={**base, "LANEGRAPH_KERNEL_CACHE": str(root / "data-kernels")}, cwd=root,
            )  # fmt: skip
            opt.args = ["--dataset", str(root / "kitti" / "kitti.yaml"), *opt.args]
            print(f"KITTI laid out by `lanegraph data kitti` from {' '.join(sources)}", flush=True)
        warm_env, reference = {}, None
        for inst, python in installs.items():
            warm_env[inst] = {
                **base,
                "LANEGRAPH_CACHE_DIR": str(root / f"{inst}-warm-cache"),
                "LANEGRAPH_KERNEL_CACHE": str(root / f"{inst}-kernels-shared"),
            }
            _, _, lanes, _, _ = run_once(
                warm_env[inst], root / f"{inst}-out-prime", opt.args, python
            )  # the kernels
            reference = reference if reference is not None else lanes
            if lanes != reference:
                print(f"  {inst}: lanes DIFFERENT from this install's", flush=True)
        for k in range(opt.rounds):
            for inst, python in installs.items():
                for kind in kinds:
                    if kind.startswith("first"):
                        env = {
                            **base,
                            "LANEGRAPH_CACHE_DIR": str(root / f"{inst}-c{k}-{kind[7:10]}"),
                            "LANEGRAPH_KERNEL_CACHE": str(root / f"{inst}-k{k}-{kind[7:10]}"),
                        }
                        if kind == "first, bundle off":
                            env["LANEGRAPH_KERNEL_BUNDLE"] = "0"
                        else:
                            env.pop("LANEGRAPH_KERNEL_BUNDLE", None)
                    elif kind == "second install":
                        copy = root / f"{inst}-install-{k}"
                        env = {**warm_env[inst], "LANEGRAPH_CACHE_DIR": str(root / f"{inst}-s{k}")}
                        env.update(second_install(copy))
                    elif kind == "new cache folder":
                        env = {**warm_env[inst], "LANEGRAPH_CACHE_DIR": str(root / f"{inst}-n{k}")}
                    else:
                        env = warm_env[inst]
                    load = os.getloadavg()[0]
                    wall, first, lanes, cpu, starts = run_once(
                        env, root / f"{inst}-out-{kind[:3]}-{kind[-3:]}-{k}", opt.args, python
                    )
                    rows[inst, kind].append((wall, first, lanes == reference, cpu, starts))
                    print(
                        f"  round {k + 1} {inst:8s} {kind:22s} wall {wall:6.2f} s, CPU {cpu:6.2f} s, first line after "
                        f"{first:5.2f} s ({starts}), lanes {'identical' if lanes == reference else 'DIFFERENT'}, "
                        f"load {load:.2f}, {frame_ms[-1]:.1f} ms/frame (median)",
                        flush=True,
                    )
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(
        f"{'install':9s}{'run':24s} {'median wall':>12s} {'x warm':>7s} {'per round':>18s} {'median CPU':>11s} "
        f"{'first line':>11s}  {'starts with':12s} lanes"
    )
    for inst in installs:
        warm_walls = [r[0] for r in rows[inst, "warm"]]
        warm = median(warm_walls)
        for kind in kinds:
            rs = rows[inst, kind]
            wall = median(r[0] for r in rs)
            first = median(r[1] for r in rs)
            cpu = median(r[3] for r in rs)
            per_round = ", ".join(f"{r[0] / ww:.1f}" for r, ww in zip(rs, warm_walls))
            same = "identical" if all(r[2] for r in rs) else "DIFFERENT"
            print(
                f"{inst:9s}{kind:24s} {wall:10.2f} s {wall / warm:6.1f}x {per_round:>18s} {cpu:9.2f} s "
                f"{first:9.2f} s  {'/'.join(sorted({r[4] for r in rs})):12s} {same}"
            )
    what = " ".join(["lanegraph run", *opt.args]) if opt.args else "the default lanegraph run"
    for inst in installs:
        warm_rows = rows[inst, "warm"]
        for kind in kinds:
            if kind == "warm":
                continue
            walls = [r[0] / w[0] for r, w in zip(rows[inst, kind], warm_rows)]
            cpus = [r[3] / w[3] for r, w in zip(rows[inst, kind], warm_rows)]
            print(
                f"ratio {inst} {kind!r} / warm ({what}): wall {median(walls):.2f}x "
                f"(per round {min(walls):.2f}-{max(walls):.2f}), CPU {median(cpus):.2f}x "
                f"(per round {min(cpus):.2f}-{max(cpus):.2f})"
            )


if __name__ == "__main__":
    main()
