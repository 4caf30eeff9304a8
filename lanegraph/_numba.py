"""The one place numba flags come from.

Use :func:`jit` for every kernel. Kernels are cached on disk (``cache=True``), so
only the first run on a machine pays the compilation. ``NUMBA_DISABLE_JIT=1`` turns
every kernel into plain Python (for coverage and debugging).
"""

from __future__ import annotations

import os

import numba

#: flags shared by every lanegraph kernel
JIT_OPTIONS = {
    "nopython": True,
    "cache": os.environ.get("LANEGRAPH_NUMBA_CACHE", "1") != "0",
    "nogil": True,
    "fastmath": False,
}


def jit(*args, **overrides):
    """``numba.jit`` with the project's flags; use as ``@jit`` or ``@jit(parallel=True)``."""
    opts = {**JIT_OPTIONS, **overrides}
    if args and callable(args[0]):
        return numba.jit(**opts)(args[0])
    return numba.jit(*args, **opts)


prange = numba.prange
