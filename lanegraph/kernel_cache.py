"""Where the compiled numba kernels are kept, and the first run's notice that they are being compiled.

Numba kernels are compiled once per machine and kept on disk (``cache=True``). The folder is shared
by every lanegraph cache folder: ``$LANEGRAPH_KERNEL_CACHE``, else ``<user cache>/lanegraph/kernels``
(``$XDG_CACHE_HOME`` or ``~/.cache``), whatever ``$LANEGRAPH_CACHE_DIR`` says; where that folder cannot
be written, ``$LANEGRAPH_CACHE_DIR/numba``. ``NUMBA_CACHE_DIR`` wins when set. One folder serves every
machine and version: numba keeps each kernel per source file, Python version, CPU and numba version,
and drops entries of another numba or of a changed source file (so a new ``LANEGRAPH_CACHE_DIR`` no
longer compiles again; a home folder shared by several machines holds each machine's kernels).

This module does not import numba: :func:`first_run_notice` says, before anything is loaded, that
the kernels are about to be compiled (a stamp file in the kernel folder records that this lanegraph
and numba have compiled them on this machine), and, from then on, says so at the first compilation
of the process if the stamp was wrong (a plugin changed, the cache was emptied).
"""

from __future__ import annotations

import atexit
import hashlib
import os
import platform
import sys
from pathlib import Path

_STATE = {"said": False, "armed": False}


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
    print(
        f"lanegraph: compiling the numba kernels for this machine ({kept}; "
        "the first run takes about a minute longer on 2 cores) ...",
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


__all__ = ["cache_root", "first_run_notice", "kernel_cache_dir"]
