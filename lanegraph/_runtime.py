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

:func:`available_cpus` tells the nodes that run work on threads how many CPUs the process may use
at once (its affinity mask and cgroup CPU quota), instead of assuming the machine's count, and
:func:`worker_pool` gives them a process-wide pool of that many threads.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import os
import signal
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

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


def _cgroup_cpu_limit(root: str = "/sys/fs/cgroup") -> float | None:
    """The CPU quota of the process's cgroup in CPUs (cgroup v2 ``cpu.max``, or v1
    ``cpu.cfs_quota_us`` / ``cpu.cfs_period_us``); None when there is none or it cannot be read."""
    try:
        with open(os.path.join(root, "cpu.max")) as fh:
            quota, _, period = fh.read().strip().partition(" ")
        if quota != "max":
            return int(quota) / int(period or 100000)
        return None
    except (OSError, ValueError):
        pass
    try:
        with open(os.path.join(root, "cpu", "cpu.cfs_quota_us")) as fh:
            quota_us = int(fh.read().strip())
        with open(os.path.join(root, "cpu", "cpu.cfs_period_us")) as fh:
            period_us = int(fh.read().strip())
    except (OSError, ValueError):
        return None
    return quota_us / period_us if quota_us > 0 and period_us > 0 else None


def available_cpus(root: str = "/sys/fs/cgroup") -> int:
    """How many CPUs this process may run on at once: the CPUs of its affinity mask
    (``sched_getaffinity``; ``os.cpu_count()`` where there is none), capped by its cgroup's CPU
    quota rounded up (a quota of 1.5 CPUs lets two threads make progress). At least 1."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    limit = _cgroup_cpu_limit(root)
    if limit is not None and limit > 0:
        n = min(n, max(1, math.ceil(limit - 1e-9)))
    return max(1, n)


_pools: dict[tuple[str, int], ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()
if hasattr(os, "register_at_fork"):  # a forked child has none of the parent's threads: new pools
    os.register_at_fork(after_in_child=_pools.clear)


def leave_signals_to_the_main_thread() -> None:
    """A pool thread blocks Ctrl-C, SIGTERM and SIGHUP: the kernel then delivers a signal sent to
    the process to the main thread, where Python handles it, at once."""
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM, signal.SIGHUP})


def lower_thread_priority(increment: int) -> bool:
    """Lower the calling thread's scheduling priority by ``increment`` nice steps (at most to 19);
    returns whether the priority was set (True also for a thread already at 19, which stays
    there). On Linux only, where ``setpriority`` of a thread id applies to that thread alone
    (elsewhere it would lower the whole process: nothing is done). A process may always lower a
    priority, never raise it back: meant for a pool's threads (``initializer``), which end with
    the pool."""
    if increment <= 0 or not sys.platform.startswith("linux") or not hasattr(threading, "get_native_id"):
        return False
    tid = threading.get_native_id()
    try:
        now = os.getpriority(os.PRIO_PROCESS, tid)
        os.setpriority(os.PRIO_PROCESS, tid, min(19, now + int(increment)))
    except OSError:  # a sandbox that forbids it: the thread keeps the run's priority
        return False
    return True


def worker_pool(name: str, n: int) -> ThreadPoolExecutor:
    """A process-wide pool of ``n`` threads named ``lanegraph-<name>``, created once per name and
    size (and anew in a forked child); its threads leave signals to the main thread."""
    with _pools_lock:
        pool = _pools.get((name, n))
        if pool is None:
            pool = _pools[(name, n)] = ThreadPoolExecutor(
                max_workers=n,
                thread_name_prefix=f"lanegraph-{name}",
                initializer=leave_signals_to_the_main_thread,
            )
        return pool
