"""The one place numba flags come from: :func:`lanegraph.jit` and :data:`lanegraph.prange`.

Use :func:`jit` for every kernel. Kernels are kept on disk in the user's kernel folder
(:mod:`.folder`), in files checked before numba reads them (:mod:`.disk`), so only the first run of
an installation on a machine pays the compilation (:mod:`.first_run`), also when the install
folder is read-only. ``LANEGRAPH_NUMBA_CACHE=0`` turns the disk cache off; ``NUMBA_DISABLE_JIT=1``
turns every kernel into plain Python (for coverage and debugging). With a numba or llvmlite that
lanegraph was not tested with (:mod:`.compat`) kernels are plain numba kernels, compiled in every
process.

The parallel kernels' worker threads (numba's OpenMP layer) sleep as soon as a kernel ends
(``OMP_WAIT_POLICY=PASSIVE``, set unless the environment already sets it, before the OpenMP
runtime starts): spinning, they took a core from the next node's OpenCV threads and from the
thread that reads the next frame (docs/pipeline.md). Set ``OMP_WAIT_POLICY=ACTIVE`` to keep them
spinning.

This file's contents are part of every lanegraph kernel's cache stamp and bundle digest
(:func:`lanegraph.kernels.bundle.package_digest`): its flags shape the machine code.
"""

from __future__ import annotations

import os
import warnings

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # read when the OpenMP runtime loads: see above

# numba's error texts without colorama's escapes (its default theme has no colours anyway): numba
# formats such a text for each value it tries to type and cannot, about 8,000 times on a first run,
# and colorama's wrapping of the streams each time cost 0.3-0.5 s of CPU for the default run's
# kernels (read when numba loads)
os.environ.setdefault("NUMBA_DISABLE_ERROR_MESSAGE_HIGHLIGHTING", "1")

import numba  # noqa: E402

from . import compat  # noqa: E402
from .folder import KernelCacheWarning  # noqa: E402

#: flags shared by every lanegraph kernel
JIT_OPTIONS = {
    "nopython": True,
    "cache": os.environ.get("LANEGRAPH_NUMBA_CACHE", "1") != "0",
    "nogil": True,
    "fastmath": False,
    # no C-callable wrapper beside each function (only a function passed as a first-class value
    # would use it; lanegraph passes none): one function less to lower, optimise and turn into
    # machine code for every kernel and helper, and for every one of numba's own functions they call
    "no_cfunc_wrapper": True,
}

_WARNED = {"untested": False}


def _keep_on_disk(dispatcher) -> None:
    if not compat.internals_tested():
        if not _WARNED["untested"]:
            _WARNED["untested"] = True
            warnings.warn(
                f"no kernel cache with {compat.untested_text()}: the kernels are compiled in every run",
                KernelCacheWarning,
                stacklevel=3,
            )
        return
    from . import disk

    disk.attach(dispatcher)


def jit(*args, **overrides):
    """``numba.jit`` with the project's flags and its checked disk cache; use as ``@jit`` or
    ``@jit(parallel=True)``."""
    opts = {**JIT_OPTIONS, **overrides}
    cache = opts.pop("cache")

    def make(func, sig_args=()):
        dispatcher = numba.jit(*sig_args, **opts)(func)
        if cache and hasattr(dispatcher, "py_func"):  # not under NUMBA_DISABLE_JIT
            _keep_on_disk(dispatcher)
        return dispatcher

    if args and callable(args[0]):
        return make(args[0])
    return lambda func: make(func, args)


prange = numba.prange

__all__ = ["JIT_OPTIONS", "jit", "prange"]
