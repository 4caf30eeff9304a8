"""Write the kernel list of the first run (lanegraph.kernel_cache): the kernels the default
``lanegraph run`` calls from Python, with their argument types, longest compilation first (the run
and its helper process take them from the front: the longest first balances the two). Each one's
compilation is timed alone (CPU seconds, a fresh process with an empty kernel folder, ``--rounds``
times, the least kept) and written beside it. Run it after changing a kernel, its signature or the
default graph's kernels (a stale list costs the first run time, never a result):

    python benchmarks/record_kernels.py [lanegraph/data/kernels.json] [--rounds N] [-- RUN ARGS]

It then writes the list's kernels as LLVM bitcode beside it (``kernels.bundle``,
:mod:`lanegraph.kernel_bundle`: a first run makes their machine code instead of compiling them),
compiled in a fresh process with an empty kernel folder. A bundle is used only for the sources it
was made from: after any change in ``plugins/lanegraph_lanes/``, ``plugins/lanegraph_road/`` or
``lanegraph/_numba.py`` (the kernels' signatures unchanged) remake it alone, in a few seconds
(``tests/engine/test_kernel_bundle.py`` fails until then):

    python benchmarks/record_kernels.py --bundle-only
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def record(argv: list[str]) -> list[dict]:
    """The top-level kernels ``lanegraph run ARGV`` compiles, in order (in this process, with an
    empty kernel folder)."""
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["NUMBA_CACHE_DIR"] = os.path.join(tmp, "kernels")
        os.environ["LANEGRAPH_CACHE_DIR"] = os.path.join(tmp, "cache")
        os.environ["LANEGRAPH_PRECOMPILE"] = "0"
        import numba
        from numba.core import event

        from lanegraph.kernel_cache import encode_type

        numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]
        entries: list[dict] = []
        depth = [0]

        class _Record(event.Listener):
            def on_start(self, ev: event.Event) -> None:
                depth[0] += 1
                func = ev.data["dispatcher"].py_func
                args = [encode_type(t) for t in ev.data["args"]]
                if depth[0] == 1 and func.__module__.split(".")[0] != "numba" and None not in args:
                    entries.append({"module": func.__module__, "name": func.__qualname__, "args": args})

            def on_end(self, ev: event.Event) -> None:
                depth[0] -= 1

        event.register("numba:compile", _Record())
        from lanegraph.cli import main

        try:
            main(["run", "--quiet", "--out", os.path.join(tmp, "out"), *argv], standalone_mode=False)
        except SystemExit:
            pass
    return entries


#: compiles one entry (argv[1], JSON) in a fresh process after a small kernel (numba's own start-up
#: is not the entry's), without cyclic garbage collection and with numba's resolutions kept, as the
#: first run's precompile does, and prints the CPU seconds of its compilation
_TIME_ONE = """
import gc, json, sys, time
import numpy as np
from lanegraph import jit
from lanegraph.kernel_cache import kept_call_types
from lanegraph.kernel_cache import decode_type
import importlib

@jit(cache=False)
def _first(a):
    return a[0]

_first(np.zeros(1))
e = json.loads(sys.argv[1])
kernel = getattr(importlib.import_module(e["module"]), e["name"])
sig = tuple(decode_type(a) for a in e["args"])
gc.disable()
with kept_call_types():
    t = time.process_time()
    kernel.compile(sig)
    print(time.process_time() - t)
"""


def compile_seconds(entry: dict, rounds: int) -> float:
    """The least CPU time of ``rounds`` compilations of ``entry`` alone (with what it calls), each in
    a fresh process with an empty kernel folder."""
    best = float("inf")
    for _ in range(rounds):
        with tempfile.TemporaryDirectory() as tmp:
            env = {**os.environ, "NUMBA_CACHE_DIR": tmp, "LANEGRAPH_PRECOMPILE": "0"}
            out = subprocess.run(
                [sys.executable, "-c", _TIME_ONE, json.dumps(entry)],
                env=env, capture_output=True, text=True, check=True, cwd=ROOT,
            )  # fmt: skip
            best = min(best, float(out.stdout.split()[-1]))
    return best


def write_bundle(kernel_list: Path) -> None:
    """Write ``kernels.bundle`` beside ``kernel_list`` from a fresh process with an empty kernel
    folder (:func:`lanegraph.kernel_bundle.write_bundle`)."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {
            **os.environ,
            "NUMBA_CACHE_DIR": tmp,
            "LANEGRAPH_PRECOMPILE": "0",
            "LANEGRAPH_KERNEL_BUNDLE": "0",
        }
        out = kernel_list.with_name("kernels.bundle")
        subprocess.run(
            [sys.executable, "-m", "lanegraph.kernel_bundle", str(kernel_list), str(out)],
            env=env, check=True, cwd=ROOT,
        )  # fmt: skip


def main() -> None:
    args = sys.argv[1:]
    if "--bundle-only" in args:
        args.remove("--bundle-only")
        write_bundle(Path(args[0]) if args else ROOT / "lanegraph" / "data" / "kernels.json")
        return
    run_args = args[args.index("--") + 1 :] if "--" in args else []
    args = args[: args.index("--")] if "--" in args else args
    rounds = 1
    if "--rounds" in args:
        k = args.index("--rounds")
        rounds = int(args[k + 1])
        del args[k : k + 2]
    out = Path(args[0]) if args else ROOT / "lanegraph" / "data" / "kernels.json"
    entries = record(run_args)
    for e in entries:
        e["seconds"] = round(compile_seconds(e, rounds), 2)
        print(f"{e['seconds']:6.2f} s  {e['module']}.{e['name']}", flush=True)
    entries.sort(key=lambda e: -e["seconds"])  # longest first; sort is stable: the run's order on a tie
    text = ",\n".join(json.dumps(e) for e in entries)  # one kernel a line
    out.write_text(f"[\n{text}\n]\n", encoding="utf-8")
    print(f"{len(entries)} kernels, {sum(e['seconds'] for e in entries):.1f} s of compilation -> {out}")
    write_bundle(out)


if __name__ == "__main__":
    main()
