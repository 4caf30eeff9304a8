"""Batch runs on a Dask cluster (``pip install "lanegraph[distributed]"``): ``--scheduler local``,
``local:N`` or the address of an existing ``dask scheduler``.

The tasks (:class:`lanegraph.api.RunTask`) are submitted as they are, one Dask task each, and run
by ``task.execute()`` in the workers: outputs equal the in-process run's byte for
byte. Dask runs a task again on another worker when its worker dies (up to
``distributed.scheduler.allowed-failures`` times); a task's folder is put in place only when the
task ends, so a re-run never duplicates frames. A task that fails because of its input returns its
error (variant, sequence, frame) like any other outcome; the other tasks go on.

Threads: a worker runs one task at a time (one Dask thread), and the task's OpenCV and numba
threads are limited to the worker's share of its machine's cores (cores / Dask threads on that
host, at least 1; ``LANEGRAPH_WORKER_THREADS`` overrides), so that workers do not oversubscribe
the cores. A local cluster also sets ``NUMBA_NUM_THREADS``, ``OMP_NUM_THREADS``,
``OPENBLAS_NUM_THREADS`` and ``MKL_NUM_THREADS`` in its workers' environment. A graph's own threads
(``disparity.*.strips``) are part of its params and stay as they are.

Progress: the tasks report frames done as Dask events (topic ``lanegraph-progress-<job>``), at most
twice a second each, to one progress bar in the client.

Only :class:`lanegraph_dask.runner.DaskRunner` imports this module, and only with a scheduler: a
run without one never imports Dask.
"""

from __future__ import annotations

import importlib.util
import os
import time
import uuid
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import lanegraph
from lanegraph.errors import UsageError
from lanegraph.plugins import get_plugin_manager

if TYPE_CHECKING:  # a worker imports this module: only what it runs
    from lanegraph.api import Progress, RunTask, TaskOutcome

    from .runner import SchedulerSpec

try:
    from distributed import WorkerPlugin as _WorkerPlugin
except ImportError:  # reported as a usage error by _import_distributed when a scheduler is asked for
    _WorkerPlugin = object  # type: ignore[assignment,misc]

#: seconds to wait for a scheduler to answer, and for a first worker to join it
CONNECT_TIMEOUT_S = float(os.environ.get("LANEGRAPH_DASK_TIMEOUT", "30"))
#: seconds between two progress events of one task
PROGRESS_EVERY_S = 0.5

_THREADS: int | None = None  # set in a worker by _ThreadShare


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise UsageError('--scheduler needs Dask: pip install "lanegraph[distributed]"') from None
    return distributed


def _worker_threads() -> int | None:
    env = os.environ.get("LANEGRAPH_WORKER_THREADS")
    if env and env.isdigit() and int(env) >= 1:
        return int(env)
    return _THREADS


def _limit_threads() -> None:
    """Apply the worker's thread share to OpenCV (process-wide) and numba (the calling thread)."""
    n = _worker_threads()
    if n is None:
        return
    import cv2
    import numba

    cv2.setNumThreads(n)
    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))


def _run_on_worker(task: RunTask, topic: str) -> TaskOutcome:
    """A task in a Dask worker: limit threads, report progress as events, run."""
    from distributed import get_worker

    worker = get_worker()
    _limit_threads()
    attempt = uuid.uuid4().hex[:8]  # a task run again after its worker died counts anew
    last = 0.0

    def progress(done: int) -> None:
        nonlocal last
        now = time.monotonic()
        if now - last >= PROGRESS_EVERY_S or done == task.total:
            last = now
            worker.log_event(topic, [task.index, attempt, done])

    out = task.execute(progress=progress)
    out.worker = worker.address
    return out


def _probe() -> dict[str, Any]:
    """What a worker has: lanegraph's version, its plugins, its cores."""
    pm = get_plugin_manager()
    try:
        cpus = sorted(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        cpus = list(range(os.cpu_count() or 1))
    return {
        "lanegraph": lanegraph.__version__,
        "plugins": sorted({nt.plugin for nt in pm.node_types.values()}),
        "cpus": cpus,
    }


def _host(address: str) -> str:
    return address.split("://")[-1].rsplit(":", 1)[0].strip("[]")


class ThreadShare(_WorkerPlugin):
    """Sets a worker's thread share (see the module's doc) when it starts or joins: ``per_worker``
    maps a worker's address to the threads of each of its tasks; a worker that joined later gets
    the smallest share of its host (``per_host``), or on a new host its cores divided by its Dask
    threads."""

    name = "lanegraph-thread-share"

    def __init__(self, per_worker: dict[str, int], per_host: dict[str, int]):
        self.per_worker = dict(per_worker)
        self.per_host = dict(per_host)

    def setup(self, worker: Any) -> None:
        global _THREADS
        own = self.per_worker.get(worker.address) or self.per_host.get(_host(worker.address))
        _THREADS = own or max(1, _cores() // max(1, int(getattr(worker, "nthreads", 1))))


def thread_shares(workers: dict[str, dict[str, Any]], cpus: dict[str, list[int]]) -> dict[str, int]:
    """Each worker's threads per task: its cores divided by the Dask threads of the workers on its
    host whose cores overlap its own (all of them on a plain host; only itself in a SLURM job bound
    to its own cores), at least 1. ``workers``: ``scheduler_info()["workers"]``; ``cpus``: the CPU
    ids each worker may run on."""
    shares = {}
    for addr in workers:
        mine = set(cpus.get(addr, ()))
        sharing = sum(
            int(other["nthreads"])
            for a, other in workers.items()
            if _host(a) == _host(addr) and (a == addr or mine & set(cpus.get(a, ())))
        )
        shares[addr] = max(1, len(mine) // max(1, sharing))
    return shares


#: the address schemes a Dask client speaks (``HOST:PORT`` without one is tcp)
SCHEMES = ("tcp", "tls", "ws", "wss", "ucx", "inproc")


def check_spec(spec: SchedulerSpec) -> None:
    """Refuse at once (:class:`UsageError`) a ``--scheduler`` that cannot work: ``local:N`` with more
    worker processes than the CPUs this process may use (each worker runs one task on one core:
    more only add start-up time and memory), or an address of a scheme Dask does not speak
    (``ftp://x``). Called where ``--scheduler`` is parsed and again before a cluster is started or
    reached."""
    if spec.local:
        cores = _cores()
        if spec.workers is not None and spec.workers > cores:
            raise UsageError(
                f"--scheduler {spec.text}: {spec.workers} worker processes, but this process may use "
                f"{cores} CPU(s): expected local:N with N <= {cores} (local alone starts one per CPU)"
            )
        return
    address = spec.address or ""
    if "://" in address:
        scheme = address.split("://", 1)[0].lower()
        if scheme not in SCHEMES:
            raise UsageError(
                f"--scheduler {address}: unknown scheme {scheme!r}: expected local, local:N, a scheduler "
                f"address such as tcp://HOST:8786 (schemes: {', '.join(SCHEMES)}) or a scheduler file *.json"
            )


class _Cluster:
    """A client on a local cluster it started, or on an existing scheduler; closes what it opened."""

    def __init__(self, spec: SchedulerSpec, echo: Callable[[str], None]):
        check_spec(spec)  # also where --scheduler is parsed (DaskRunner.from_spec): before any work
        distributed = _import_distributed()
        import logging

        self.cluster = None
        self.client = None
        self._scratch: Any = None  # the local workers' scratch folder, removed when closed
        if spec.local:
            n = spec.workers or _cores()
            threads = max(1, _cores() // n)
            env = {
                k: str(threads)
                for k in (
                    "LANEGRAPH_WORKER_THREADS",
                    "NUMBA_NUM_THREADS",
                    "OMP_NUM_THREADS",
                    "OPENBLAS_NUM_THREADS",
                    "MKL_NUM_THREADS",
                )
            }
            echo(
                f"starting a local Dask cluster: {n} worker process(es), 1 task and {threads} OpenCV/numba thread(s) each ..."
            )
            import tempfile

            import dask

            self._scratch = tempfile.TemporaryDirectory(prefix="lanegraph-dask-")
            try:
                # a worker gets its next task when it is free, not one queued behind the running one:
                # the tasks are long and of unequal length
                # (the scheduler's and the workers' scratch folders in one temporary folder, removed at close)
                with dask.config.set(
                    {
                        "distributed.scheduler.worker-saturation": 1.0,
                        "temporary-directory": self._scratch.name,
                    }
                ):
                    self.cluster = distributed.LocalCluster(
                        n_workers=n,
                        threads_per_worker=1,
                        processes=True,
                        env=env,
                        silence_logs=logging.ERROR,
                        dashboard_address="127.0.0.1:8787",
                        local_directory=self._scratch.name,  # not left in the temporary folder
                    )
            except Exception as exc:  # noqa: BLE001 - e.g. no free port, a worker that cannot start
                self._scratch.cleanup()
                raise UsageError(
                    f"--scheduler {spec.text}: could not start a local Dask cluster: {type(exc).__name__}: {exc}"
                ) from None
            self.client = distributed.Client(self.cluster)
            self._echo_dashboard(echo)
        else:
            echo(f"connecting to the Dask scheduler at {spec.address} ...")
            try:
                if (
                    spec.address.endswith(".json") and "://" not in spec.address
                ):  # dask scheduler --scheduler-file
                    self.client = distributed.Client(scheduler_file=spec.address, timeout=CONNECT_TIMEOUT_S)
                else:
                    self.client = distributed.Client(spec.address, timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError, ValueError) as exc:
                raise UsageError(
                    f"--scheduler {spec.address}: could not reach a Dask scheduler there within {CONNECT_TIMEOUT_S:.0f} s ({exc})"
                ) from None
            self._echo_dashboard(echo)
        try:
            self._check_workers(spec, echo)
        except BaseException:
            self.close()
            raise

    def _echo_dashboard(self, echo: Callable[[str], None]) -> None:
        if "dashboard" not in self.client.scheduler_info().get("services", {}):
            return
        if self.cluster is not None and importlib.util.find_spec("bokeh") is None:
            echo(
                'Dask dashboard: none (pip install "lanegraph[distributed]" installs bokeh, which serves it)'
            )
            return
        echo(f"Dask dashboard: {self.client.dashboard_link}")

    def _check_workers(self, spec: SchedulerSpec, echo: Callable[[str], None]) -> None:
        client = self.client
        if not client.scheduler_info().get("workers"):
            echo(f"waiting up to {CONNECT_TIMEOUT_S:.0f} s for a Dask worker to join {spec.text} ...")
            try:
                client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
            except TimeoutError:
                raise UsageError(
                    f"--scheduler {spec.text}: no Dask worker joined within {CONNECT_TIMEOUT_S:.0f} s (start some with `dask worker {spec.text}`)"
                ) from None
        probes = client.run(_probe, on_error="return")
        bad = {addr: res for addr, res in probes.items() if isinstance(res, BaseException)}
        if bad:
            addr, exc = next(iter(bad.items()))
            raise UsageError(
                f"--scheduler {spec.text}: {len(bad)} Dask worker(s) cannot run lanegraph (e.g. {addr}: {type(exc).__name__}: {exc}); "
                "install lanegraph and the plugins of your graphs on every worker"
            )
        mine = {nt.plugin for nt in get_plugin_manager().node_types.values()}
        for addr, info in probes.items():
            missing = sorted(mine - set(info["plugins"]))
            if missing:
                echo(
                    f"warning: Dask worker {addr} lacks plugin(s) {', '.join(missing)}: graphs using them fail there"
                )
        workers = client.scheduler_info()["workers"]
        shares = thread_shares(workers, {a: info["cpus"] for a, info in probes.items()})
        per_host: dict[str, int] = {}
        for addr, n in shares.items():
            per_host[_host(addr)] = min(n, per_host.get(_host(addr), n))
        client.register_plugin(ThreadShare(shares, per_host))
        total = sum(int(w["nthreads"]) for w in workers.values())
        if not spec.local:
            echo(f"{len(workers)} Dask worker(s), {total} task(s) at a time")

    def __enter__(self) -> _Cluster:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self.client is not None:
            self.client.close(timeout=10)
        if self.cluster is not None:
            self.cluster.close(timeout=10)
        if self._scratch is not None:
            self._scratch.cleanup()
            self._scratch = None


def connect(spec: SchedulerSpec, echo: Callable[[str], None]) -> _Cluster:
    """A client on the cluster of ``spec`` (a local one started, or a scheduler reached), its
    workers checked; ``close()`` it when done (:class:`lanegraph_dask.runner.DaskRunner`)."""
    return _Cluster(spec, echo)


def submit_all(client: Any, tasks: list[RunTask], bar: Progress, outcomes: dict[int, TaskOutcome]) -> None:
    """Run ``tasks`` on the cluster of ``client``, putting every task's outcome into ``outcomes`` (a
    task Dask could not run -- its workers kept dying, or it could not be unpickled -- gets an
    outcome with the error)."""
    distributed = _import_distributed()
    topic = f"lanegraph-progress-{uuid.uuid4().hex[:12]}"
    client.subscribe_topic(topic, lambda event: bar.update(*event[1]))
    futures = {}
    try:
        # with a result cache in the planned order (a variant's runs before the next variant's: the
        # cache is filled first); without one the longest first, so that no long run is left last
        order = tasks if any(t.cache_dir for t in tasks) else sorted(tasks, key=lambda t: -(t.total or 0))
        for task in order:
            fut = client.submit(
                _run_on_worker, task, topic, key=f"lanegraph-{topic[-12:]}-{task.index}", pure=False
            )
            futures[fut] = task
        for fut in distributed.as_completed(list(futures)):
            task = futures[fut]
            try:
                out = fut.result()
            except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: reported, the others go on
                out = task.failed(f"the task failed on the cluster: {type(exc).__name__}: {exc}")
            outcomes[task.index] = out
            bar.finish(task.index, out.result.frames)
    finally:
        client.unsubscribe_topic(topic)
        for fut in futures:
            if not fut.done():
                fut.cancel()
