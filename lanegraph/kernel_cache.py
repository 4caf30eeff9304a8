"""Where the compiled numba kernels are kept, and the first run's notice that they are being compiled.

Numba kernels are compiled once per machine and kept on disk (``cache=True``). The folder is shared
by every lanegraph cache folder: ``$LANEGRAPH_KERNEL_CACHE``, else ``<user cache>/lanegraph/kernels``
(``$XDG_CACHE_HOME`` or ``~/.cache``), whatever ``$LANEGRAPH_CACHE_DIR`` says; where that folder cannot
be written, ``$LANEGRAPH_CACHE_DIR/numba``. ``NUMBA_CACHE_DIR`` wins when set. One folder serves every
machine and version: numba keeps each kernel per source file, Python version, CPU and numba version,
and drops entries of another numba or of a changed source file, lanegraph's kernels also when any
file of their package changed (:mod:`lanegraph._numba`: a kernel holds the code of the helpers it
calls) (so a new ``LANEGRAPH_CACHE_DIR`` no longer compiles again; a home folder shared by several
machines holds each machine's kernels).

This module does not import numba: :func:`first_run_notice` says, before anything is loaded, that
the kernels are about to be compiled (a stamp file in the kernel folder records that this lanegraph
and numba have compiled them on this machine), and, from then on, says so at the first compilation
of the process if the stamp was wrong (a plugin changed, the cache was emptied).

On that first run, with two CPUs or more, :func:`first_run_notice` also starts a second process
(``python -m lanegraph.kernel_cache LIST CLAIMS``) that compiles the kernels the default run needs
(``lanegraph/data/kernels.json``: module, name and argument types of each, written by
``benchmarks/record_kernels.py`` longest compilation first) into the same folder. Once the run has
read its graph (before its first frame), :func:`compile_share` has the run take its part of the same
list: the two processes take the kernels one at a time from the front of the list, each claiming one
(an exclusive file in the folder ``CLAIMS``, made by the run) before it compiles it, so no kernel is
compiled twice and both CPUs stay busy to the end (longest first: neither is left with a long one
at the end). The run then waits for the kernels the helper is still compiling, and loads those from
the kernel folder when it calls them. The run stops the helper and removes ``CLAIMS`` when it ends.
A list that no longer matches the code costs only the time: a kernel it does not name is compiled
by the run as before, a name or a type it cannot resolve is skipped.

Where lanegraph's shipped bitcode of the list's kernels fits this machine and these sources
(:mod:`lanegraph.kernel_bundle`), each process makes a claimed kernel's machine code of it instead of
compiling the kernel (about 1.7 s of CPU for the list instead of about 11); without a helper (one
CPU, ``LANEGRAPH_NUMBA_CACHE=0``) the run then does so for the whole list itself.
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from . import kernel_bundle
from .kernel_bundle import decode_type, encode_type, install
from .kernel_bundle import read_list as _read_list

_STATE: dict = {"said": False, "armed": False, "helper": None, "claims": None, "first": False}

#: the kernels of the default run (module, name, argument types), for the first run's helper
KERNEL_LIST = Path(__file__).resolve().parent / "data" / "kernels.json"
#: the folder that holds the ``lanegraph`` package (site-packages, or a checkout's root)
_PACKAGE_ROOT = Path(__file__).resolve().parent.parent
#: the packages whose kernels the helper may import: lanegraph's own and its built-in plugins
_KERNEL_PACKAGES = {
    "lanegraph",
    "lanegraph_disparity",
    "lanegraph_image",
    "lanegraph_io",
    "lanegraph_lanes",
    "lanegraph_road",
    "lanegraph_synthetic",
}


def cache_root() -> Path:
    """lanegraph's user cache directory (``$LANEGRAPH_CACHE_DIR``, default ``~/.cache/lanegraph``)."""
    return Path(os.environ.get("LANEGRAPH_CACHE_DIR") or _user_cache_home() / "lanegraph")


def _user_cache_home() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"))


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".lanegraph-write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
        return True
    except OSError:
        return False


def kernel_cache_dir(results_root: Path | None = None) -> Path:
    """The folder numba keeps lanegraph's compiled kernels in (see the module's text);
    ``results_root``: ``$LANEGRAPH_CACHE_DIR`` resolved (the fallback's parent)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    if os.environ.get("LANEGRAPH_KERNEL_CACHE"):
        return Path(os.environ["LANEGRAPH_KERNEL_CACHE"])
    shared = _user_cache_home() / "lanegraph" / "kernels"
    if _writable(shared):
        return shared
    return (results_root or cache_root()) / "numba"


def _machine_key() -> str:
    """lanegraph's and numba's versions, Python's, and this CPU: the stamp's name."""
    from importlib import metadata

    from ._version import __version__

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
    text = f"{__version__}|{numba_version}|{sys.version_info[:2]}|{cpu}"
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _say(where: Path | None) -> None:
    if _STATE["said"] or os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return
    _STATE["said"] = True
    kept = f"once: they are kept in {where}" if where else "LANEGRAPH_NUMBA_CACHE=0: in every process"
    if kernel_bundle.applies():
        cost = "from lanegraph's LLVM bitcode: about a second longer on 2 free cores"
    else:
        cost = "the first run takes about seven seconds longer on 2 free cores, more on a busy machine"
    print(
        f"lanegraph: compiling the numba kernels for this machine ({kept}; {cost}) ...",
        file=sys.stderr,
        flush=True,
    )


def first_run_notice(quiet: bool = False) -> None:
    """Called by the commands that run kernels, before they load anything: the notice (on stderr) at
    once when this machine has not compiled this lanegraph's kernels yet; else at the first
    compilation of the process, should one happen. Records the stamp at exit. ``quiet``: no notice."""
    if _STATE["armed"]:
        return
    _STATE["armed"] = True
    _STATE["said"] = _STATE["said"] or quiet
    where = kernel_cache_dir()  # the folder lanegraph._numba gives numba
    stamp = where / f".compiled-{_machine_key()}"
    cached = os.environ.get("LANEGRAPH_NUMBA_CACHE", "1") != "0"
    if not stamp.exists() or not cached:
        _say(where if cached else None)
        _STATE["first"] = True
        if cached:
            _start_helper()
    if cached:
        _listen(where)
        atexit.register(_write_stamp, stamp)


def _listen(where: Path) -> None:
    from numba.core import event

    class _FirstCompile(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            disp = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
            module = getattr(getattr(disp, "py_func", None), "__module__", "") or ""
            if not module.startswith("numba"):
                _say(where)

        def on_end(self, ev: event.Event) -> None:
            pass

    event.register("numba:compile", _FirstCompile())


def _write_stamp(stamp: Path) -> None:
    try:
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(f"{_machine_key()}\n", encoding="utf-8")
    except OSError:
        pass


def _start_helper() -> None:
    """Start the process that compiles the listed kernels beside the run (see the module's text);
    stopped at exit. Not with one CPU (it would take the run's), ``NUMBA_DISABLE_JIT`` or
    ``LANEGRAPH_PRECOMPILE=0``."""
    from ._runtime import available_cpus

    if (
        os.environ.get("LANEGRAPH_PRECOMPILE", "1") == "0"
        or os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0")
        or not KERNEL_LIST.is_file()
        or available_cpus() < 2
    ):
        return
    try:
        claims = tempfile.mkdtemp(prefix="lanegraph-claims-")
    except OSError:
        return
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "lanegraph.kernel_cache", str(KERNEL_LIST), claims],
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


def compile_share() -> int:
    """The run's part of the first run's compilation, once its graph is read: the kernels of the list
    that the helper has not claimed, then a wait for those it is still compiling (see the module's
    text). Without a helper (one CPU, or ``LANEGRAPH_NUMBA_CACHE=0``), a first run whose shipped
    bitcode applies (:mod:`lanegraph.kernel_bundle`) makes the whole list's machine code itself, at a
    sixth of compiling it. Returns how many the run compiled or made; 0 (at once) when there is
    nothing to do."""
    proc, claims = _STATE["helper"], _STATE["claims"]
    if proc is None or claims is None:
        first = _STATE.get("first") and os.environ.get("LANEGRAPH_PRECOMPILE", "1") != "0"
        if not (first and kernel_bundle.applies()):
            return 0
        _STATE["first"] = False  # once
        return precompile(_read_list(KERNEL_LIST))
    _STATE["helper"] = None  # once
    entries = _read_list(KERNEL_LIST)
    folder = Path(claims)
    done = precompile(entries, folder)
    while proc.poll() is None:  # the helper's kernels in progress: loaded from the folder when called
        if all((folder / f"{i}.done").exists() for i in range(len(entries))):
            break
        time.sleep(0.01)
    return done


def _claim(claims: Path | None, i: int) -> bool:
    """Whether this process takes the list's entry ``i`` (an exclusive file in ``claims``; always
    without a claims folder)."""
    if claims is None:
        return True
    try:
        os.close(os.open(claims / str(i), os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        return True
    except OSError:  # claimed by the other process, or the folder is gone (the run has ended)
        return False


def _done(claims: Path | None, i: int) -> None:
    if claims is not None:
        try:
            (claims / f"{i}.done").write_bytes(b"")
        except OSError:
            pass


#: numba's resolutions of built-in calls kept while lanegraph compiles its kernels (kept_call_types)
_KEPT: dict = {}
_KEEPING = {"depth": 0, "numba's": None}
_KEEPING_LOCK = threading.Lock()


def _kept_get_call_type(resolve):
    """numba's ``BaseFunction.get_call_type`` (``resolve``) with each successful resolution kept in
    :data:`_KEPT`, keyed by the function type, the typing context and its target, and the argument
    types: a repeat returns the kept signature and records its implementation key as the first
    resolution did. Failures are not kept (they are resolved again, as numba does)."""
    from numba.core.target_extension import get_local_target

    def get_call_type(self, context, args, kws):
        try:
            key = (self, context, get_local_target(context), tuple(args), tuple(kws.items()))
            found = _KEPT.get(key)
        except TypeError:  # an argument type that cannot be hashed: resolved as numba does
            return resolve(self, context, args, kws)
        if found is not None:
            sig, impl = found
            self._impl_keys[sig.args] = impl
            return sig
        sig = resolve(self, context, args, kws)
        if sig is not None and sig.args in self._impl_keys:
            _KEPT[key] = (sig, self._impl_keys[sig.args])
        return sig

    get_call_type._lanegraph_memo = True
    return get_call_type


@contextlib.contextmanager
def kept_call_types() -> Iterator[bool]:
    """Within the block, numba's resolutions of built-in calls are kept (:mod:`lanegraph._numba`'s text;
    the kernel list of a first run is compiled in one: :func:`precompile`); after
    it numba's own ``BaseFunction.get_call_type`` is back, so numba code outside lanegraph's
    compilations (a user's own kernels) never goes through it. Yields whether the resolutions are
    kept: not with ``LANEGRAPH_NUMBA_CALL_MEMO=0``, nor where numba's function types lack what it
    relies on. Blocks may nest, also on several threads (numba compiles one function at a time)."""
    from numba.core.types import functions as _functions

    base = _functions.BaseFunction
    if os.environ.get("LANEGRAPH_NUMBA_CALL_MEMO", "1") == "0" or not hasattr(base, "get_impl_key"):
        yield False
        return
    with _KEEPING_LOCK:
        if _KEEPING["depth"] == 0:
            _KEEPING["numba's"] = base.get_call_type
            base.get_call_type = _kept_get_call_type(base.get_call_type)
        _KEEPING["depth"] += 1
    try:
        yield True
    finally:
        with _KEEPING_LOCK:
            _KEEPING["depth"] -= 1
            if _KEEPING["depth"] == 0:
                base.get_call_type = _KEEPING["numba's"]


def precompile(entries: list[dict], claims: Path | None = None) -> int:
    """Compile (or load from the kernel folder) each ``{"module", "name", "args"}`` of ``entries`` in
    order, each one this process claims in the folder ``claims`` (every one without it); returns how
    many were compiled or loaded. An entry whose module, kernel or types cannot be resolved is
    skipped: the list is a hint, the run compiles what it needs.

    Python's cyclic garbage collector is off meanwhile: numba's compiler makes millions of objects
    (its IR, types, LLVM IR builders), and the collections they set off took 5-17 % of the
    compilation's CPU; what they would free (at most 60 MB per process for its part of the default
    run's kernels) is collected once it is back on. numba's resolutions of built-in calls are kept
    meanwhile (:func:`kept_call_types`)."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        with kept_call_types():
            return _precompile(entries, claims)
    finally:
        if collecting:
            gc.enable()


def _precompile(entries: list[dict], claims: Path | None) -> int:
    """:func:`precompile`'s loop."""
    import importlib  # the kernels' modules load lanegraph._numba: numba's cache folder, as the run's

    done = 0
    for i, entry in enumerate(entries):
        if not _claim(claims, i):
            continue
        try:
            if str(entry["module"]).split(".")[0] not in _KERNEL_PACKAGES:
                continue  # the list names lanegraph's own kernels only
            module = importlib.import_module(str(entry["module"]))
            kernel = getattr(module, str(entry["name"]))
            sig = tuple(decode_type(str(a)) for a in entry["args"])
            if not hasattr(kernel, "compile"):
                continue
            if not install(kernel, sig, entry):  # the shipped bitcode made machine code, else compiled
                kernel.compile(sig)
            done += 1
        except Exception:  # noqa: BLE001 - a stale entry: the run compiles it itself
            continue
        finally:
            _done(claims, i)
    return done


def _main(argv: list[str]) -> int:
    if len(argv) not in (1, 2):
        print("usage: python -m lanegraph.kernel_cache LIST [CLAIMS]", file=sys.stderr)
        return 2
    entries = _read_list(Path(argv[0]))
    if not entries:
        return 1
    precompile(entries, Path(argv[1]) if len(argv) == 2 else None)
    return 0


__all__ = [
    "cache_root",
    "compile_share",
    "decode_type",
    "encode_type",
    "first_run_notice",
    "kernel_cache_dir",
    "precompile",
]

if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
