"""Process settings: the allocator tuning a run applies (lanegraph._runtime) and the OpenMP wait policy (lanegraph.kernels.decorator)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

CODE = (
    "from lanegraph._runtime import tune_allocator; a = tune_allocator(); b = tune_allocator(); print(a, b)"
)


def _run(env_value: str | None) -> str:
    env = dict(os.environ)
    env.pop("LANEGRAPH_MALLOC_TUNING", None)
    if env_value is not None:
        env["LANEGRAPH_MALLOC_TUNING"] = env_value
    return subprocess.run(
        [sys.executable, "-c", CODE], capture_output=True, text=True, env=env, check=True
    ).stdout.split()


def test_turned_off_by_the_environment():
    assert _run("0") == ["False", "False"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_applied_once_on_glibc():
    import ctypes
    import ctypes.util

    try:
        ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt  # noqa: B018
    except (OSError, AttributeError):
        pytest.skip("not glibc (no mallopt)")
    assert _run(None) == ["True", "True"]  # the second call returns the first call's outcome


def test_a_run_applies_it(tmp_path, pm, monkeypatch):
    """The executor calls it when a run starts."""
    from lanegraph.run import executor

    from .test_executor import load

    calls = []
    monkeypatch.setattr(executor, "tune_allocator", lambda: calls.append(1) or True)
    executor.Executor(load(tmp_path, pm), executor.RunContext(), pm).run()
    assert calls == [1]


@pytest.mark.parametrize("preset, expected", [(None, "PASSIVE"), ("ACTIVE", "ACTIVE")])
def test_openmp_threads_sleep_unless_the_environment_says(preset, expected):
    """Importing the kernels' module makes numba's OpenMP threads sleep after a kernel (before the
    OpenMP runtime loads), and leaves a policy the user set alone."""
    env = dict(os.environ)
    env.pop("OMP_WAIT_POLICY", None)
    if preset is not None:
        env["OMP_WAIT_POLICY"] = preset
    code = "import os, lanegraph.kernels.decorator; print(os.environ['OMP_WAIT_POLICY'])"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    ).stdout.split()
    assert out == [expected]


def _cgroup(tmp_path, v2: str | None = None, v1: tuple[str, str] | None = None):
    if v2 is not None:
        (tmp_path / "cpu.max").write_text(v2 + "\n")
    if v1 is not None:
        (tmp_path / "cpu").mkdir()
        (tmp_path / "cpu" / "cpu.cfs_quota_us").write_text(v1[0] + "\n")
        (tmp_path / "cpu" / "cpu.cfs_period_us").write_text(v1[1] + "\n")
    return str(tmp_path)


@pytest.mark.parametrize(
    "v2, v1, cap",
    [
        ("150000 100000", None, 2),  # 1.5 CPUs: two threads make progress
        ("50000 100000", None, 1),
        ("400000 100000", None, 4),
        ("max 100000", None, None),  # no quota
        (None, ("200000", "100000"), 2),  # cgroup v1
        (None, ("-1", "100000"), None),  # v1 without a quota
        ("garbage", None, None),  # unreadable: no cap
        (None, None, None),  # no cgroup files at all
    ],
)
def test_available_cpus_is_the_affinity_capped_by_the_cgroup_quota(tmp_path, v2, v1, cap):
    from lanegraph._runtime import available_cpus

    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        affinity = os.cpu_count() or 1
    got = available_cpus(_cgroup(tmp_path, v2, v1))
    assert got == (affinity if cap is None else min(affinity, cap)) and got >= 1


def test_worker_pool_is_one_per_name_and_size_and_its_threads_leave_signals_to_the_main_thread():
    import signal
    import threading

    from lanegraph._runtime import worker_pool

    pool = worker_pool("test", 2)
    assert worker_pool("test", 2) is pool
    assert worker_pool("test", 3) is not pool and worker_pool("other", 2) is not pool
    blocked, name = pool.submit(
        lambda: (signal.pthread_sigmask(signal.SIG_BLOCK, set()), threading.current_thread().name)
    ).result()
    assert {signal.SIGINT, signal.SIGTERM, signal.SIGHUP} <= set(blocked)
    assert name.startswith("lanegraph-test")
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())  # the main thread's


def test_a_forked_child_gets_new_pools():
    import os

    from lanegraph._runtime import worker_pool

    worker_pool("fork", 1).submit(lambda: None).result()  # the parent's pool has a live thread
    pid = os.fork()
    if pid == 0:  # the child: the parent's pool has no thread here; a new one must run the task
        try:
            ok = worker_pool("fork", 1).submit(lambda: 42).result(timeout=10) == 42
        except Exception:  # noqa: BLE001
            ok = False
        os._exit(0 if ok else 1)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0


def test_lower_thread_priority_lowers_the_calling_thread_only():
    import os
    import threading

    from lanegraph._runtime import lower_thread_priority

    base = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    got = {}

    def work():
        got["changed"] = lower_thread_priority(5)
        got["nice"] = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
        got["zero"] = lower_thread_priority(0)

    th = threading.Thread(target=work)
    th.start()
    th.join()
    if sys.platform.startswith("linux"):
        assert got == {"changed": True, "nice": min(19, base + 5), "zero": False}
    else:  # nothing changed where a thread's priority cannot be set alone
        assert got == {"changed": False, "nice": base, "zero": False}
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == base
