"""The first run of an installation on a machine: its notice, and its kernels made beside it.

Kernels belong to their plugins. A plugin distribution names its kernel list through the
``lanegraph_kernels`` hook: a JSON file beside its code (``kernels.json``: module, name and argument
types of each kernel, longest compilation first, written by ``benchmarks/record_kernels.py``), with
the kernels' machine code beside it (``kernels.bundle``, :mod:`.bundle`). A list is read only from
inside the package folder of the plugin that names it, and only its entries that name a module of
that package are used (:func:`kernel_sets`). The engine names no plugin.

:func:`first_run_notice`, called by the commands that run kernels before they load anything, looks
for a stamp in the kernel folder (:mod:`.folder`) that records that this installation (lanegraph's
folder and version, numba's, Python's and the CPU) has made its kernels on this machine. Once the
run has read its graph (before its first frame), :func:`compile_share` registers the plugins'
bundles: from then on a kernel not in the kernel folder is loaded from its plugin's bundle when it
is first called (:func:`lanegraph.kernels.bundle.load`: machine code linked, nothing compiled), so a
run pays only for the kernels it calls. On a first run it also says what will happen, with the
figure the lists give (their kernels' measured seconds, loaded or compiled), before any frame.

Where a bundle does not apply (another Python, numba or machine, ``LANEGRAPH_KERNEL_BUNDLE=0``) the
default run's kernels of its list (``"default": true``) are compiled ahead: with two CPUs or more
by the run and a helper process (``python -m lanegraph.kernels helper CLAIMS``) that loads the
plugins and compiles the same kernels into the kernel folder. The two processes take the kernels one
at a time from the front, each claiming one (an exclusive file named by the kernel in the folder
``CLAIMS``, made by the run) before it makes it, so none is made twice and both CPUs stay busy to
the end. The run then waits for the kernels the helper is still making, and loads those from the
kernel folder when it calls them; it stops the helper and removes ``CLAIMS`` when it ends. Without
a helper (one CPU, ``LANEGRAPH_PRECOMPILE=0``, ``LANEGRAPH_NUMBA_CACHE=0``) nothing is compiled
ahead. Other kernels (another graph's, another source's, types no bundle holds) are compiled when
called, with a notice.

Python's cyclic garbage collector is off while a list is compiled (numba's compiler makes millions
of objects; the collections took 5-17 % of the CPU), and numba's resolutions of built-in calls are
kept (:func:`lanegraph.kernels.compat.kept_call_types`).
"""

from __future__ import annotations

import atexit
import gc
import hashlib
import os
import platform
import shutil
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ..paths import write_bytes_atomic
from . import bundle
from .bundle import KernelSet, decode_type, encode_type, install, kernel_sets
from .compat import internals_tested, kept_call_types
from .folder import kernel_folder

_STATE: dict = {
    "said": False,
    "armed": False,
    "helper": None,
    "claims": None,
    "first": False,
    "folder": None,
    "compiling": False,
    "quiet": False,
}

#: the folder that holds the ``lanegraph`` package (site-packages, or a checkout's root)
_PACKAGE_ROOT = Path(__file__).resolve().parent.parent.parent


def _held(s: KernelSet) -> set[str]:
    """The keys of ``s``'s entries its plugin's bundle holds and may be used for here."""
    return bundle.keys(s.bundle_path) if bundle.applies(s.bundle_path) else set()


def _split(sets: list[KernelSet]) -> tuple[list[tuple[KernelSet, dict]], list[tuple[KernelSet, dict]]]:
    """(the entries loaded from a bundle when called, the default run's others: compiled ahead,
    longest first)."""
    lazy, ahead = [], []
    for s in sets:
        held = _held(s)
        for e in s.entries:
            if bundle.entry_key(e) in held:
                lazy.append((s, e))
            elif e.get("default"):
                ahead.append((s, e))
    return lazy, sorted(ahead, key=lambda item: -float(item[1].get("seconds") or 0.0))


def _planned(sets: list[KernelSet], compile_missing: bool = True) -> list[tuple[KernelSet, dict]]:
    """The kernels a first run compiles ahead (the helper's list): the default run's kernels no
    bundle holds, longest first (none unless ``compile_missing``)."""
    return _split(sets)[1] if compile_missing else []


def _install_key() -> str:
    """This installation on this machine: lanegraph's folder and version, numba's and Python's
    versions, and this CPU (the stamp's name)."""
    from importlib import metadata

    from .._version import __version__

    try:
        numba_version = metadata.version("numba")
    except metadata.PackageNotFoundError:  # pragma: no cover - numba is a dependency
        numba_version = "?"
    cpu = platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.startswith(("model name", "flags", "Features")):
                    cpu += line
                    if line.startswith(("flags", "Features")):
                        break
    except OSError:
        cpu += platform.processor()
    text = f"{__version__}|{numba_version}|{sys.version_info[:2]}|{cpu}|{_PACKAGE_ROOT}"
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _stamped(stamp: Path) -> bool:
    try:
        return stat.S_ISREG(os.lstat(stamp).st_mode)
    except OSError:
        return False


def _say(text: str) -> None:
    if _STATE["said"] or os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return
    _STATE["said"] = True
    print(f"lanegraph: {text} ...", file=sys.stderr, flush=True)


def _plan_text(lazy: list[tuple[KernelSet, dict]], ahead: list[tuple[KernelSet, dict]], workers: int) -> str:
    """What a first run will do with its kernels, with the lists' figures."""
    parts = []
    if lazy:
        # the CPU of linking each kernel's machine code, measured by record_kernels.py; a run links
        # only those it calls
        load = sum(float(e.get("load_seconds") or 0.02) for _, e in lazy)
        parts.append(
            f"loading each of its numba kernels from the plugins' machine code when first called "
            f"({len(lazy)} kernels, {load:.1f} s at most)"
        )
    if ahead:
        seconds = sum(float(e.get("seconds") or 0.0) for _, e in ahead) / max(1, workers)
        cores = "on 2 cores" if workers > 1 else "on 1 core"
        parts.append(
            f"compiling {len(ahead)} numba kernels (about {max(1, round(seconds))} s {cores}, "
            "longer on a busy machine)"
        )
    if not parts:
        parts.append("compiling the numba kernels as they are called (a few seconds each)")
    return " and ".join(parts)


def _say_plan(lazy: list[tuple[KernelSet, dict]], ahead: list[tuple[KernelSet, dict]], helper: bool) -> None:
    folder = _STATE["folder"]
    kept = f"kept in {folder} for later runs" if folder else "not kept: compiled again in every run"
    what = _plan_text(lazy, ahead, 2 if helper else 1)
    _say(f"first run of this installation on this machine: {what}; {kept}")


def first_run_notice(quiet: bool = False) -> None:
    """Called by the commands that run kernels, before they load anything: decides whether this is
    the first run of this installation on this machine; the notice itself comes from
    :func:`compile_share`, before the first frame (a compilation says so when it starts). Records
    the stamp at exit. ``quiet``: no notice."""
    if _STATE["armed"]:
        return
    _STATE["armed"] = True
    _STATE["said"] = _STATE["said"] or quiet
    _STATE["quiet"] = quiet
    cached = os.environ.get("LANEGRAPH_NUMBA_CACHE", "1") != "0" and internals_tested()
    folder = kernel_folder() if cached else None
    _STATE["folder"] = folder
    stamp = folder / f".compiled-{_install_key()}" if folder is not None else None
    if stamp is None or not _stamped(stamp):
        _STATE["first"] = True
    if stamp is not None:
        _listen(folder)
        atexit.register(_write_stamp, stamp)


def _listen(where: Path) -> None:
    from numba.core import event

    class _Compile(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            disp = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
            func = getattr(disp, "py_func", None)
            module = getattr(func, "__module__", "") or ""
            if func is None or module.startswith("numba") or _STATE["compiling"] or _STATE["quiet"]:
                return
            if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
                return
            _STATE["compiling"] = True  # once per process
            print(
                f"lanegraph: compiling numba kernel {module}.{func.__qualname__} for types no plugin "
                f"ships machine code for (a few seconds; kept in {where} for later runs) ...",
                file=sys.stderr,
                flush=True,
            )

        def on_end(self, ev: event.Event) -> None:
            pass

    event.register("numba:compile", _Compile())


def _write_stamp(stamp: Path) -> None:
    try:
        write_bytes_atomic(stamp, f"{_install_key()} {_PACKAGE_ROOT}\n".encode(), mode=0o600)
    except OSError:
        pass


def _start_helper() -> None:
    """Start the process that makes the plugins' listed kernels beside the run (see the module's
    text); stopped at exit. Not with one CPU (it would take the run's), ``NUMBA_DISABLE_JIT`` or
    ``LANEGRAPH_PRECOMPILE=0``."""
    from .._runtime import available_cpus

    if (
        os.environ.get("LANEGRAPH_PRECOMPILE", "1") == "0"
        or os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0")
        or available_cpus() < 2
    ):
        return
    try:
        claims = tempfile.mkdtemp(prefix="lanegraph-claims-")
    except OSError:
        return
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "lanegraph.kernels", "helper", claims],
            # ``-m`` puts the working folder first on the child's import path: started from the
            # folder lanegraph is installed in, a module lying in the user's folder (an input or
            # output folder, say) can never be imported in its place
            cwd=str(_PACKAGE_ROOT),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    except OSError:
        shutil.rmtree(claims, ignore_errors=True)
        return
    _STATE["helper"], _STATE["claims"] = proc, claims
    atexit.register(_stop_helper, proc, claims)


def _stop_helper(proc: subprocess.Popen, claims: str | None = None) -> None:
    if proc.poll() is None:
        proc.terminate()  # numba writes a cache entry to a temporary file first: none is left half-written
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:  # pragma: no cover - terminate is honoured
            proc.kill()
    if claims:
        shutil.rmtree(claims, ignore_errors=True)


def compile_share(pm: Any = None) -> int:
    """Once the run's graph is read (before its first frame): the plugins' bundles registered (a
    kernel is loaded from its bundle when first called); on a first run the notice, with its figure,
    then the default run's kernels no bundle holds compiled ahead, shared with the helper (see the
    module's text). Returns how many the run compiled ahead; 0 on a later run."""
    sets = kernel_sets(pm)
    bundle.register(sets)
    if not _STATE["first"]:
        return 0
    _STATE["first"] = False  # once
    if _STATE["folder"] is None:  # no kernel folder: no bundle either (read by the folder's cache)
        _say_plan([], [], helper=False)
        return 0
    lazy, ahead = _split(sets)
    if not ahead or os.environ.get("LANEGRAPH_PRECOMPILE", "1") == "0":
        _say_plan(lazy, ahead, helper=False)  # those compiled when called
        return 0
    _start_helper()
    proc, claims = _STATE["helper"], _STATE["claims"]
    _STATE["helper"] = None
    _say_plan(lazy, ahead, helper=proc is not None)
    if proc is None or claims is None:
        return 0  # one CPU: compiled when called
    folder = Path(claims)
    done = precompile(ahead, folder)
    names = [claim_name(e) for _, e in ahead]
    while proc.poll() is None:  # the helper's kernels in progress: loaded from the folder when called
        if all((folder / f"{n}.done").exists() for n in names):
            break
        time.sleep(0.01)
    return done


def claim_name(entry: dict) -> str:
    """The claim file of a list entry (by its kernel and types: the same in both processes)."""
    return hashlib.sha256(bundle.entry_key(entry).encode()).hexdigest()[:24]


def _claim(claims: Path | None, name: str) -> bool:
    """Whether this process takes the entry (an exclusive file in ``claims``; always without one)."""
    if claims is None:
        return True
    try:
        os.close(os.open(claims / name, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        return True
    except OSError:  # claimed by the other process, or the folder is gone (the run has ended)
        return False


def _done(claims: Path | None, name: str) -> None:
    if claims is not None:
        try:
            (claims / f"{name}.done").write_bytes(b"")
        except OSError:
            pass


def precompile(
    items: list[tuple[KernelSet, dict]], claims: Path | None = None, compile_missing: bool = True
) -> int:
    """Make each ``(set, entry)`` of ``items`` in order, each one this process claims in the folder
    ``claims`` (every one without it): from its plugin's bundle where that fits, else compiled
    (when ``compile_missing``; else passed over); returns how many were made. An entry whose module
    is not its plugin's, or whose kernel or types cannot be resolved, is passed over: a list is a
    hint, the run compiles what it needs. The cyclic garbage collector is off meanwhile and numba's
    resolutions are kept (the module's text)."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        with kept_call_types():
            return _precompile(items, claims, compile_missing)
    finally:
        if collecting:
            gc.enable()


def _precompile(items: list[tuple[KernelSet, dict]], claims: Path | None, compile_missing: bool) -> int:
    """:func:`precompile`'s loop."""
    import importlib

    done = 0
    for s, entry in items:
        name = claim_name(entry)
        if not _claim(claims, name):
            continue
        try:
            module_name = str(entry["module"])
            if module_name.split(".")[0] != s.package:
                continue  # a list names its own plugin's kernels only
            kernel = getattr(importlib.import_module(module_name), str(entry["name"]))
            sig = tuple(decode_type(str(a)) for a in entry["args"])
            if not hasattr(kernel, "compile"):
                continue
            if install(kernel, sig, entry, s.bundle_path):
                done += 1
            elif compile_missing:
                kernel.compile(sig)
                done += 1
        except Exception:  # noqa: BLE001 - a stale entry: the run compiles it itself
            continue
        finally:
            _done(claims, name)
    return done


def _main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m lanegraph.kernels helper CLAIMS", file=sys.stderr)
        return 2
    precompile(_planned(kernel_sets()), Path(argv[0]))
    return 0


__all__ = [
    "KernelSet",
    "claim_name",
    "compile_share",
    "decode_type",
    "encode_type",
    "first_run_notice",
    "kernel_sets",
    "precompile",
]
