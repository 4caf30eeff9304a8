"""Process settings for running graphs.

Every frame allocates the same large arrays again (images, disparity maps, BEV images and masks,
kernel outputs: 0.1-3 MB each). glibc's ``malloc`` serves such blocks by mapping fresh pages and
returns them to the system on ``free``, so every frame pays a page fault per 4 KiB it touches:
about a quarter of the time after disparity on the 2-core reference machine (18.5 -> 13.7 ms per
frame, measured with ``benchmarks/bench_pipeline.py``). :func:`tune_allocator` makes ``malloc``
serve blocks below 32 MiB from its heap and keep up to 256 MiB of freed heap memory for reuse.

It changes a process-wide setting, so :class:`lanegraph.run.executor.Executor` applies it once when a
run starts; ``LANEGRAPH_MALLOC_TUNING=0`` leaves the allocator alone. Elsewhere than glibc (macOS,
Windows, musl) it does nothing.

:func:`available_cpus`, :func:`worker_pool` and the other helpers for threads are public, in
:mod:`lanegraph.threads` (imported here for the engine).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

from .threads import (  # noqa: F401 - the engine's names for them (and the tests')
    _cgroup_cpu_limit,
    available_cpus,
    leave_signals_to_the_main_thread,
    lower_thread_priority,
    worker_pool,
)

#: ``mallopt`` parameters (glibc's malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 << 20  # glibc's upper limit on 64-bit systems
TRIM_THRESHOLD = 256 << 20

_applied: bool | None = None


def tune_allocator() -> bool:
    """Apply the allocator settings once per process; returns whether they are in effect."""
    global _applied
    if _applied is not None:
        return _applied
    _applied = False
    if os.environ.get("LANEGRAPH_MALLOC_TUNING", "1") == "0" or not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    _applied = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )
    return _applied
