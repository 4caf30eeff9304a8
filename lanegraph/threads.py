"""Threads for the nodes and sources that run work on them -- part of what a plugin may import.

:func:`available_cpus` tells them how many CPUs the process may use at once (its affinity mask and
cgroup CPU quota), instead of assuming the machine's count; :func:`worker_pool` gives them a
process-wide pool of threads that leave signals (Ctrl-C, SIGTERM, SIGHUP) to the main thread
(:func:`leave_signals_to_the_main_thread`, for a pool of their own); :func:`lower_thread_priority`
lets a read-ahead thread yield to the run.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

__all__ = ["available_cpus", "leave_signals_to_the_main_thread", "lower_thread_priority", "worker_pool"]


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
