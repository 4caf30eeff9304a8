"""The first run of an installation on a machine: its notice, and its kernels made beside it.

Kernels belong to their plugins. A plugin distribution names its kernel list through the
``lanegraph_kernels`` hook: a JSON file beside its code (``kernels.json``: module, name and argument
types of each kernel, longest compilation first, written by ``benchmarks/record_kernels.py``), with
the kernels' LLVM bitcode beside it (``kernels.bundle``, :mod:`.bundle`). A list is read only from
inside the package folder of the plugin that names it, and only its entries that name a module of
that package are used (:func:`kernel_sets`). The engine names no plugin.

:func:`first_run_notice`, called by the commands that run kernels before they load anything, looks
for a stamp in the kernel folder (:mod:`.folder`) that records that this installation (lanegraph's
folder and version, numba's, Python's and the CPU) has made its kernels on this machine. Without
one, with two CPUs or more, it starts a helper process (``python -m lanegraph.kernels helper
CLAIMS``) that loads the plugins and makes their listed kernels into the kernel folder. Once the run
has read its graph (before its first frame), :func:`compile_share` says what will happen, with the
figure the lists give (their kernels' measured seconds, from bitcode or compiled), and has the run
take its part of the same lists: the two processes take the kernels one at a time from the front,
each claiming one (an exclusive file named by the kernel in the folder ``CLAIMS``, made by the run)
before it makes it, so none is made twice and both CPUs stay busy to the end. The run then waits for
the kernels the helper is still making, and loads those from the kernel folder when it calls them;
it stops the helper and removes ``CLAIMS`` when it ends. A kernel is made from its plugin's bitcode
where that fits (:func:`lanegraph.kernels.bundle.install`), else compiled -- then only the kernels
the default run needs (``"default": true`` in the list), as the others (another graph's, another
source's) may never be called. Without a helper (one CPU, ``LANEGRAPH_PRECOMPILE=0``,
``LANEGRAPH_NUMBA_CACHE=0``) the run makes from bitcode what fits and compiles nothing ahead.

Should the stamp be wrong (the kernel folder emptied, a plugin changed), the notice comes at the
first compilation of the process instead. Python's cyclic garbage collector is off while a list is
made (numba's compiler makes millions of objects; the collections took 5-17 % of the CPU), and
numba's resolutions of built-in calls are kept (:func:`lanegraph.kernels.compat.kept_call_types`).
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from . import bundle
from .bundle import decode_type, encode_type, install, read_list
from .compat import internals_tested, kept_call_types
from .folder import kernel_folder, write_private

_STATE: dict = {"said": False, "armed": False, "helper": None, "claims": None, "first": False, "folder": None}

#: the folder that holds the ``lanegraph`` package (site-packages, or a checkout's root)
_PACKAGE_ROOT = Path(__file__).resolve().parent.parent.parent


@dataclass(frozen=True)
class KernelSet:
    """A plugin's kernel list: the top-level package its entries may name, the list file, and its
    entries (those of other packages left out)."""

    package: str
    list_path: Path
    entries: tuple[dict, ...]

    @property
    def bundle_path(self) -> Path:
        """The bitcode of the list's kernels, beside it."""
        return self.list_path.with_suffix(".bundle")


def kernel_sets(pm: Any = None) -> list[KernelSet]:
    """The kernel lists the plugins of ``pm`` (the process's plugin manager by default) name through
    ``lanegraph_kernels``, each read from inside its plugin's package folder only; a plugin whose
    hook raises or names a file elsewhere is passed over (its kernels compile when called)."""
    if pm is None:
        from ..plugins import get_plugin_manager

        pm = get_plugin_manager()
    hook = getattr(pm.hook, "lanegraph_kernels", None)
    sets = []
    for impl in reversed(hook.get_hookimpls() if hook is not None else []):
        name = getattr(impl.plugin, "__name__", None) or type(impl.plugin).__module__
        package = str(name).split(".")[0]
        module = sys.modules.get(package)
        home = getattr(module, "__file__", None)
        try:
            named = impl.function()
        except Exception:  # noqa: BLE001 - a hint only: the plugin's kernels compile when called
            continue
        if named is None or home is None:
            continue
        path = Path(named).resolve()
        if Path(home).resolve().parent not in path.parents:
            continue  # beside the plugin's code only
        entries = tuple(e for e in read_list(path) if str(e.get("module", "")).split(".")[0] == package)
        sets.append(KernelSet(package, path, entries))
    return sets


def _planned(sets: list[KernelSet], compile_missing: bool) -> list[tuple[KernelSet, dict]]:
    """The kernels a first run makes ahead, longest first: those its plugin's bitcode holds, and,
    when ``compile_missing``, the default run's others (compiled)."""
    items = []
    for s in sets:
        fits = bundle.applies(s.bundle_path)
        held = bundle.keys(s.bundle_path) if fits else set()
        for e in s.entries:
            if bundle.entry_key(e) in held or (compile_missing and e.get("default")):
                items.append((s, e))
    return sorted(items, key=lambda item: -float(item[1].get("seconds") or 0.0))


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


def _estimate(items: list[tuple[KernelSet, dict]], workers: int) -> tuple[int, int, float]:
    """(kernels made from bitcode, kernels compiled, seconds) of a first run's kernels."""
    made = compiled = 0
    seconds = 0.0
    fits: dict[Path, set[str]] = {}
    for s, e in items:
        if s.bundle_path not in fits:
            fits[s.bundle_path] = bundle.keys(s.bundle_path) if bundle.applies(s.bundle_path) else set()
        if bundle.entry_key(e) in fits[s.bundle_path]:
            made += 1
            seconds += float(e.get("bitcode_seconds") or 0.2 * float(e.get("seconds") or 0.0))
        else:
            compiled += 1
            seconds += float(e.get("seconds") or 0.0)
    return made, compiled, seconds / max(1, workers)


def _say(text: str) -> None:
    if _STATE["said"] or os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return
    _STATE["said"] = True
    print(f"lanegraph: {text} ...", file=sys.stderr, flush=True)


def _say_plan(items: list[tuple[KernelSet, dict]], helper: bool) -> None:
    folder = _STATE["folder"]
    kept = f"kept in {folder} for later runs" if folder else "not kept: compiled again in every run"
    made, compiled, seconds = _estimate(items, 2 if helper else 1)
    cores = "on 2 cores" if helper else "on 1 core"
    figure = f"about {max(1, round(seconds))} s {cores}, longer on a busy machine"
    if made and not compiled:
        what = f"making the machine code of {made} numba kernels from the plugins' LLVM bitcode"
    elif compiled:
        what = f"compiling {compiled} numba kernels" + (
            f" and making {made} from LLVM bitcode" if made else ""
        )
    else:
        what = "compiling the numba kernels as they are called"
        figure = "a few seconds each"
    _say(f"first run of this installation on this machine: {what} ({figure}; {kept})")


def first_run_notice(quiet: bool = False) -> None:
    """Called by the commands that run kernels, before they load anything: decides whether this is
    the first run of this installation on this machine and, if so, starts the helper; the notice
    itself comes from :func:`compile_share`, before the first frame (or at the first compilation of
    the process should the stamp be wrong). Records the stamp at exit. ``quiet``: no notice."""
    if _STATE["armed"]:
        return
    _STATE["armed"] = True
    _STATE["said"] = _STATE["said"] or quiet
    cached = os.environ.get("LANEGRAPH_NUMBA_CACHE", "1") != "0" and internals_tested()
    folder = kernel_folder() if cached else None
    _STATE["folder"] = folder
    stamp = folder / f".compiled-{_install_key()}" if folder is not None else None
    if stamp is None or not _stamped(stamp):
        _STATE["first"] = True
        if stamp is not None:
            _start_helper()
    if stamp is not None:
        _listen(folder)
        atexit.register(_write_stamp, stamp)


def _listen(where: Path) -> None:
    from numba.core import event

    class _FirstCompile(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            disp = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
            module = getattr(getattr(disp, "py_func", None), "__module__", "") or ""
            if not module.startswith("numba"):
                _say(f"compiling numba kernels not kept in {where} (a plugin or its sources changed)")

        def on_end(self, ev: event.Event) -> None:
            pass

    event.register("numba:compile", _FirstCompile())


def _write_stamp(stamp: Path) -> None:
    try:
        write_private(stamp, f"{_install_key()} {_PACKAGE_ROOT}\n".encode())
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
    """The first run's part of making its kernels, once its graph is read (before its first frame):
    the notice, with its figure, then the kernels of the plugins' lists that the helper has not
    claimed, then a wait for those it is still making (see the module's text). Returns how many the
    run made; 0 (at once) on a later run."""
    if not _STATE["first"]:
        return 0
    _STATE["first"] = False  # once
    proc, claims = _STATE["helper"], _STATE["claims"]
    _STATE["helper"] = None
    ahead = os.environ.get("LANEGRAPH_PRECOMPILE", "1") != "0"
    sets = kernel_sets(pm)
    _say_plan(_planned(sets, compile_missing=True), helper=proc is not None)
    items = _planned(sets, compile_missing=proc is not None)
    if proc is None or claims is None:
        return precompile(items, compile_missing=False) if ahead and items else 0
    folder = Path(claims)
    done = precompile(items, folder)
    names = [claim_name(e) for _, e in items]
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
    ``claims`` (every one without it): from its plugin's bitcode where that fits, else compiled
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
    items = _planned(kernel_sets(), compile_missing=True)
    precompile(items, Path(argv[0]))
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
