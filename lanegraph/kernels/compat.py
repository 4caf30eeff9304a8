"""The numba and llvmlite versions whose internals lanegraph's kernel machinery was tested with.

Three pieces reach past numba's public surface: the checked disk cache (:mod:`.disk`: a subclass of
numba's function cache, its locator and its cache file), the bundle (:mod:`.bundle`: a compiled
kernel rebuilt from what numba's cache keeps of it, and saved to the kernel folder as numba's cache
saves one) and the kept resolutions of :func:`kept_call_types` (``BaseFunction.get_call_type``). Each is used
only where :func:`internals_tested` holds; elsewhere lanegraph's kernels are plain numba kernels
without a disk cache (compiled in every process), and ``pyproject.toml`` pins numba and llvmlite to
these ranges.

numba's type inference resolves each call of a built-in function or operator (``a + b``, ``x[i]``,
``np.empty``) by trying that function's typing templates in turn, again at every pass and every call
site: over 9,500 resolutions on a first run of the default graph, all but about 380 of them repeats.
While lanegraph compiles its kernel lists (:func:`lanegraph.kernels.first_run.precompile`) each
successful resolution is kept, so a repeat costs a dictionary look-up: the same signatures, hence
the same machine code, for 1.2-1.5 s less CPU (issue 32; ``LANEGRAPH_NUMBA_CALL_MEMO=0`` turns it
off). Outside those compilations numba's own method is in place.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from importlib import metadata

#: [first, end) of the minor versions tested, per distribution
TESTED = {"numba": ((0, 68), (0, 69)), "llvmlite": ((0, 50), (0, 51))}


def _minor(dist: str) -> tuple[int, int] | None:
    try:
        parts = metadata.version(dist).split(".")
        return int(parts[0]), int("".join(c for c in parts[1] if c.isdigit()) or 0)
    except (metadata.PackageNotFoundError, ValueError, IndexError):
        return None


def internals_tested() -> bool:
    """Whether the installed numba and llvmlite are versions lanegraph's use of their internals was
    tested with (:data:`TESTED`)."""
    for dist, (low, high) in TESTED.items():
        v = _minor(dist)
        if v is None or not low <= v < high:
            return False
    return True


def untested_text() -> str:
    """What is installed against what was tested, for a warning."""
    have = ", ".join(f"{d} {dist_version(d)}" for d in TESTED)
    want = ", ".join(f"{d} {lo[0]}.{lo[1]}" for d, (lo, _) in TESTED.items())
    return f"{have} (lanegraph's kernel cache was tested with {want})"


def dist_version(dist: str) -> str:
    """The installed version of the distribution ``dist``, ``?`` when it is not installed."""
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "?"


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
    """Within the block, numba's resolutions of built-in calls are kept (the module's text); after
    it numba's own ``BaseFunction.get_call_type`` is back. Yields whether they are kept: not with
    ``LANEGRAPH_NUMBA_CALL_MEMO=0``, nor with an untested numba (:func:`internals_tested`). Blocks
    may nest, also on several threads (numba compiles one function at a time)."""
    if os.environ.get("LANEGRAPH_NUMBA_CALL_MEMO", "1") == "0" or not internals_tested():
        yield False
        return
    from numba.core.types import functions as _functions

    base = _functions.BaseFunction
    if not hasattr(base, "get_impl_key"):  # pragma: no cover - a numba of the tested range has it
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


__all__ = ["TESTED", "internals_tested", "kept_call_types", "untested_text"]
