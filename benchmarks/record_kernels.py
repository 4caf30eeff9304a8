"""Write the built-in plugins' kernel lists and machine code (lanegraph.kernels): the kernels that every
built-in graph and every built-in source call from Python, with their argument types, each plugin's
into its own folder (``plugins/<plugin>/kernels.json``, longest compilation first: the first run and
its helper process take them from the front, the longest first balances the two).

The kernels are found by running, in this process with an empty kernel folder: the default ``lanegraph
run`` (its kernels are marked ``"default": true``: the ones a first run compiles ahead where no
bundle holds), every built-in graph on the synthetic scene, and the paper graph on every built-in
source that reads files (a folder of pairs written here, and, when ``../shared/data`` is there, the
KITTI raw drive and a KITTI odometry sequence). A kernel's ``seconds`` is the CPU its compilation took
there (with what it calls, compiled the first time; ``--rounds N``: the least of N compilations of
it alone, each in a fresh process, much slower to measure). Run it after changing a kernel, its
signature or the graphs (a stale list costs the first run time, never a result):

    python benchmarks/record_kernels.py [--rounds N] [--default-only]

It then writes each list's kernels as machine code for x86-64-v3 CPUs beside it
(``kernels.bundle``, :mod:`lanegraph.kernels.bundle`), compiled in a fresh process with an empty
kernel folder and ``NUMBA_CPU_NAME=x86-64-v3``, and times loading each kernel of it
(``load_seconds``: the first run's notice adds these up).
A bundle is used only for the sources it was made from: after any change of a plugin with kernels or
of ``lanegraph/kernels/decorator.py`` (the signatures unchanged) remake the bundles alone
(``tests/engine/test_kernel_bundle.py`` fails until then):

    python benchmarks/record_kernels.py --bundle-only
"""

from __future__ import annotations

import gc
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("LANEGRAPH_SHARED_DATA", ROOT.parent / "shared" / "data"))
KITTI_RAW = SHARED / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"
KITTI_ODOMETRY = SHARED / "kitti_odometry" / "seq1"
FRAMES = ["--frames", "0:4"]


def runs(tmp: Path, default_only: bool) -> list[tuple[str, list[str]]]:
    """(label, ``lanegraph run`` arguments) of every run recorded; the default run first."""
    out: list[tuple[str, list[str]]] = [("default run", [])]
    if default_only:
        return out
    from lanegraph_synthetic import preset, write_sequence

    from lanegraph.builtin import graph_names

    out += [(name, [name, *FRAMES]) for name in graph_names() if name != "paper"]
    pairs = write_sequence(preset(), tmp / "pairs", 4)
    out.append(("io.folder", ["paper", "--input", str(pairs), *FRAMES]))
    for label, folder in (("io.kitti_raw", KITTI_RAW), ("io.kitti_odometry", KITTI_ODOMETRY)):
        if folder.is_dir():
            out.append((label, ["paper", "--input", str(folder), *FRAMES]))
        else:
            print(f"  {label}: {folder} not found: its kernels are not recorded", flush=True)
    return out


def record(default_only: bool) -> list[dict]:
    """The top-level kernels the runs compile, each once, in the order first compiled, with the CPU
    seconds of its compilation (in this process, with an empty kernel folder)."""
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["NUMBA_CACHE_DIR"] = os.path.join(tmp, "kernels")
        os.environ["LANEGRAPH_CACHE_DIR"] = os.path.join(tmp, "cache")
        os.environ["LANEGRAPH_PRECOMPILE"] = "0"
        os.environ["LANEGRAPH_KERNEL_BUNDLE"] = "0"
        from numba.core import event

        from lanegraph.cli import main
        from lanegraph.kernels.bundle import encode_type, entry_key
        from lanegraph.kernels.compat import kept_call_types

        entries: dict[str, dict] = {}
        state = {"depth": 0, "t0": 0.0, "default": True}

        class _Record(event.Listener):
            def on_start(self, ev: event.Event) -> None:
                state["depth"] += 1
                if state["depth"] == 1:
                    state["t0"] = time.process_time()

            def on_end(self, ev: event.Event) -> None:
                state["depth"] -= 1
                func = ev.data["dispatcher"].py_func
                args = [encode_type(t) for t in ev.data["args"]]
                if state["depth"] or func.__module__.split(".")[0] == "numba" or None in args:
                    return
                e = {"module": func.__module__, "name": func.__qualname__, "args": args}
                seconds = round(time.process_time() - state["t0"], 2)
                if entry_key(e) not in entries:
                    entries[entry_key(e)] = {**e, "seconds": seconds, "default": state["default"]}

        event.register("numba:compile", _Record())
        for k, (label, argv) in enumerate(runs(Path(tmp), default_only)):
            before = len(entries)
            gc.disable()  # as the first run's precompile compiles
            try:
                with kept_call_types():
                    main(
                        ["run", "--quiet", "--out", os.path.join(tmp, f"out{k}"), *argv],
                        standalone_mode=False,
                    )
            except (SystemExit, Exception) as exc:  # noqa: BLE001 - a graph that needs what is not here
                if not (isinstance(exc, SystemExit) and exc.code in (0, None)):
                    print(f"  {label}: failed ({exc!r}): what it compiled is kept", flush=True)
            finally:
                gc.enable()
            state["default"] = False
            print(f"  {label}: {len(entries) - before} new kernels", flush=True)
    return list(entries.values())


#: compiles one entry (argv[1], JSON) in a fresh process after a small kernel (numba's own start-up
#: is not the entry's), without cyclic garbage collection and with numba's resolutions kept, as the
#: first run's precompile does, and prints the CPU seconds of its compilation
_TIME_ONE = """
import gc, json, sys, time, importlib
import numpy as np
from lanegraph import jit
from lanegraph.kernels.compat import kept_call_types
from lanegraph.kernels.bundle import decode_type

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

#: loads every entry of the lists (argv[1:]) from its bundle in a fresh process with an empty kernel
#: folder and prints {key: CPU seconds} as JSON
_TIME_LOAD = """
import gc, json, sys, time, importlib
from pathlib import Path
from lanegraph.kernels.bundle import decode_type, entry_key, install, read_list

gc.disable()
out = {}
for name in sys.argv[1:]:
    path = Path(name)
    for e in read_list(path):
        kernel = getattr(importlib.import_module(e["module"]), e["name"])
        sig = tuple(decode_type(a) for a in e["args"])
        t = time.process_time()
        if install(kernel, sig, e, path.with_suffix(".bundle")):
            out[entry_key(e)] = round(time.process_time() - t, 3)
print(json.dumps(out))
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


def lists() -> list[Path]:
    """The built-in plugins' kernel lists."""
    return sorted(ROOT.glob("plugins/*/kernels.json"))


def write_bundles(paths: list[Path]) -> None:
    """Write ``kernels.bundle`` beside each list from one fresh process with an empty kernel folder
    and x86-64-v3 as the CPU (:func:`lanegraph.kernels.bundle.write_bundle`), then time loading their
    kernels from it."""
    from lanegraph.kernels.bundle import CPU

    paths = [p for p in paths if json.loads(p.read_text(encoding="utf-8"))]
    with tempfile.TemporaryDirectory() as tmp:
        env = {
            **os.environ,
            "NUMBA_CACHE_DIR": os.path.join(tmp, "make"),
            "LANEGRAPH_PRECOMPILE": "0",
            "LANEGRAPH_KERNEL_BUNDLE": "0",
        }
        env.pop("NUMBA_CPU_FEATURES", None)
        argv = [str(a) for p in paths for a in (p, p.with_suffix(".bundle"))]
        subprocess.run(
            [sys.executable, "-m", "lanegraph.kernels", "bundle", *argv],
            env={**env, "NUMBA_CPU_NAME": CPU, "NUMBA_CPU_FEATURES": ""}, check=True, cwd=ROOT,
        )  # fmt: skip
        env = {**env, "NUMBA_CACHE_DIR": os.path.join(tmp, "use"), "LANEGRAPH_KERNEL_BUNDLE": "1"}
        env.pop("NUMBA_CPU_NAME", None)
        env.pop("NUMBA_CPU_FEATURES", None)
        out = subprocess.run(
            [sys.executable, "-c", _TIME_LOAD, *map(str, paths)],
            env=env, check=True, cwd=ROOT, capture_output=True, text=True,
        )  # fmt: skip
    timed = json.loads(out.stdout.splitlines()[-1])
    from lanegraph.kernels.bundle import entry_key

    for p in paths:
        entries = json.loads(p.read_text(encoding="utf-8"))
        for e in entries:
            e.pop("bitcode_seconds", None)
            e["load_seconds"] = timed.get(entry_key(e))
        _write_list(p, entries)
        made = sum(timed.get(entry_key(e)) or 0.0 for e in entries)
        print(
            f"{p.relative_to(ROOT)}: {len(entries)} kernels, {made:.1f} s of CPU to load them all", flush=True
        )


def _write_list(path: Path, entries: list[dict]) -> None:
    text = ",\n".join(json.dumps(e) for e in entries)  # one kernel a line
    path.write_text(f"[\n{text}\n]\n" if entries else "[]\n", encoding="utf-8")


def main() -> None:
    args = sys.argv[1:]
    os.environ.setdefault("PYTHONPATH", f"{ROOT}{os.pathsep}{ROOT / 'plugins'}")
    if "--bundle-only" in args:
        write_bundles(lists())
        return
    rounds = 0
    if "--rounds" in args:
        k = args.index("--rounds")
        rounds = int(args[k + 1])
        del args[k : k + 2]
    entries = record("--default-only" in args)
    if rounds:
        for e in entries:
            e["seconds"] = round(compile_seconds(e, rounds), 2)
    by_package: dict[str, list[dict]] = {}
    for e in entries:
        by_package.setdefault(e["module"].split(".")[0], []).append(e)
    for package, es in sorted(by_package.items()):
        folder = ROOT / "plugins" / package
        if not folder.is_dir():
            print(f"  {package}: not a built-in plugin: its {len(es)} kernels are not listed", flush=True)
            continue
        es.sort(key=lambda e: -e["seconds"])  # longest first; sort is stable: the run's order on a tie
        _write_list(folder / "kernels.json", es)
        total = sum(e["seconds"] for e in es)
        print(f"{package}: {len(es)} kernels, {total:.1f} s of compilation", flush=True)
    for path in lists():  # a plugin whose kernels no run compiles any more
        if path.parent.name not in by_package:
            _write_list(path, [])
            path.with_suffix(".bundle").unlink(missing_ok=True)
    write_bundles(lists())


if __name__ == "__main__":
    main()
