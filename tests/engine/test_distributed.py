"""Batch runs on real Dask clusters on 127.0.0.1 (`--scheduler`): a `dask scheduler` with two `dask
worker` processes, and a LocalCluster. Every lanes.jsonl equals the in-process run's byte for byte,
also when a worker process is killed in the middle of a task."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from lanegraph.cli import main

from .test_batch import PAPER, ROOT, _corrupt_copy, lanes_files

distributed = pytest.importorskip(
    "distributed", reason='the Dask tests need the distributed extra: pip install -e ".[distributed]"'
)

pytestmark = pytest.mark.cluster

GRAPHS = [
    PAPER,
    str(ROOT / "graphs" / "ablations" / "slt.yaml"),
    str(ROOT / "graphs" / "ablations" / "no_temporal_mask.yaml"),
]
START_TIMEOUT_S = 90


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """``dask scheduler`` and two ``dask worker`` processes (one task at a time each) on 127.0.0.1;
    yields ``(address, scheduler file)``. Torn down however the tests end; the processes also end on
    their own if this one dies (idle and death time-outs)."""
    folder = tmp_path_factory.mktemp("dask")
    sched_file = folder / "scheduler.json"
    procs: list[subprocess.Popen] = []

    def start(module: str, *args: str, log: str) -> None:
        with (folder / log).open("w") as fh:
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", module, *args],
                    stdout=fh,
                    stderr=subprocess.STDOUT,
                    cwd=folder,
                    start_new_session=True,
                )
            )

    try:
        start("distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--dashboard-address",
              "127.0.0.1:0", "--scheduler-file", str(sched_file), "--idle-timeout", "600", log="scheduler.log")  # fmt: skip
        t0 = time.monotonic()
        while not sched_file.is_file():
            assert time.monotonic() - t0 < START_TIMEOUT_S, (folder / "scheduler.log").read_text()
            assert procs[0].poll() is None, (folder / "scheduler.log").read_text()
            time.sleep(0.1)
        time.sleep(0.2)  # the file is written whole, but give it a moment
        address = json.loads(sched_file.read_text())["address"]
        for i in range(2):
            start("distributed.cli.dask_worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard",
                  "--dashboard-address", "127.0.0.1:0", "--host", "127.0.0.1", "--death-timeout", "60", "--local-directory", str(folder / f"w{i}"), log=f"worker{i}.log")  # fmt: skip
        with distributed.Client(address, timeout=START_TIMEOUT_S) as client:
            client.wait_for_workers(2, timeout=START_TIMEOUT_S)
        yield address, sched_file
    finally:
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        for p in procs:
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=15)


@pytest.fixture(scope="module")
def reference(tmp_path_factory, synthetic_dataset):
    """The in-process ablation of three graphs over the two sequences, without a cache."""
    out = tmp_path_factory.mktemp("reference")
    r = CliRunner().invoke(
        main,
        ["ablate", *GRAPHS, "--dataset", str(synthetic_dataset), "--out", str(out), "--no-cache", "--quiet"],
    )
    assert r.exit_code == 0, r.output
    files = lanes_files(out)
    assert len(files) == 6 and all(files.values())
    return out


def same_results(out: Path, ref: Path) -> None:
    """Every lanes.jsonl byte for byte, and the same figures in results.csv."""
    assert lanes_files(out) == lanes_files(ref)
    figures = (
        "variant",
        "sequence",
        "frames",
        "detection_ratio",
        "precision",
        "ego_recall",
        "mean_abs_dx_px",
        "culane_f1",
        "error",
    )
    rows = [{k: row[k] for k in figures} for row in csv.DictReader((out / "results.csv").open())]
    assert rows == [{k: row[k] for k in figures} for row in csv.DictReader((ref / "results.csv").open())]
    assert not [p for p in out.rglob(".*") if p.is_dir()]  # no temporary, replaced or chunk folder left


def test_ablation_on_a_scheduler_and_two_workers_equals_the_in_process_run(
    tmp_path, dask_cluster, reference, synthetic_dataset
):
    address, _ = dask_cluster
    out = tmp_path / "out"
    args = [
        "ablate",
        *GRAPHS,
        "--dataset",
        str(synthetic_dataset),
        "--out",
        str(out),
        "--cache-dir",
        str(tmp_path / "cache"),
        "--scheduler",
        address,
        "--quiet",
    ]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert f"connecting to the Dask scheduler at {address}" in r.stderr and "2 Dask worker(s)" in r.stderr
    same_results(out, reference)
    # the workers shared one cache folder: the variants after paper reused its disparity (each
    # frame's that paper had computed when they reached it)
    for variant in ("slt", "no_temporal_mask"):
        hits = [
            json.loads((out / "runs" / variant / s / "timings.json").read_text())["cache"]["hits"]
            for s in ("straight", "curve")
        ]
        assert sum(h.get("disp", 0) for h in hits) > 0
    # unchanged: every run reused, nothing submitted
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0 and all(
        row["reused"] == "True" for row in csv.DictReader((out / "results.csv").open())
    )
    same_results(out, reference)


def test_run_on_the_cluster_equals_the_in_process_run_also_in_chunks(
    tmp_path, dask_cluster, synthetic_dataset
):
    _, sched_file = dask_cluster  # --scheduler also takes the scheduler's --scheduler-file
    for extra in ([], ["--chunk-frames", "3", "--warmup", "2"]):
        outs = {}
        for where in ("here", "cluster"):
            outs[where] = tmp_path / f"{where}{len(extra)}"
            sched = ["--scheduler", str(sched_file)] if where == "cluster" else []
            r = CliRunner().invoke(
                main,
                [
                    "run",
                    PAPER,
                    "--dataset",
                    str(synthetic_dataset),
                    "--out",
                    str(outs[where]),
                    "--quiet",
                    *extra,
                    *sched,
                ],
            )
            assert r.exit_code == 0, r.output
        assert (
            lanes_files(outs["cluster"]) == lanes_files(outs["here"]) and len(lanes_files(outs["here"])) == 2
        )


def test_a_killed_worker_loses_and_duplicates_no_frame(tmp_path, dask_cluster, reference, synthetic_dataset):
    address, _ = dask_cluster
    out = tmp_path / "out"
    killed: list[int] = []

    def kill_a_worker_mid_task() -> None:
        # a task writes into .<sequence>.tmp-<pid>-<id>/ until it ends: kill that process once it
        # has written a frame and not yet its last
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120 and not killed:
            for lanes in out.glob("runs/*/.*.tmp-*/lanes.jsonl"):
                lines = lanes.read_bytes().count(b"\n")
                if 1 <= lines < 4:
                    pid = int(lanes.parent.name.split(".tmp-")[1].split("-")[0])
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
                    return
            time.sleep(0.005)

    killer = threading.Thread(target=kill_a_worker_mid_task, daemon=True)
    killer.start()
    r = CliRunner().invoke(
        main,
        [
            "ablate",
            *GRAPHS,
            "--dataset",
            str(synthetic_dataset),
            "--out",
            str(out),
            "--no-cache",
            "--scheduler",
            address,
            "--quiet",
        ],
    )
    killer.join(timeout=10)
    assert killed, "no worker was killed mid-task"
    assert r.exit_code == 0, r.output
    same_results(out, reference)
    with distributed.Client(address) as client:  # the worker's nanny started a new one
        client.wait_for_workers(2, timeout=START_TIMEOUT_S)
        assert killed[0] not in client.run(os.getpid).values()


def test_a_failed_task_on_the_cluster_is_reported_and_the_others_finish(
    tmp_path, dask_cluster, synthetic_dataset
):
    address, _ = dask_cluster
    ds = _corrupt_copy(synthetic_dataset, tmp_path)
    outs = {}
    for where in ("here", "cluster"):
        outs[where] = tmp_path / where
        sched = ["--scheduler", address] if where == "cluster" else []
        r = CliRunner().invoke(
            main,
            [
                "ablate",
                PAPER,
                "--dataset",
                str(ds),
                "--out",
                str(outs[where]),
                "--no-cache",
                "--quiet",
                *sched,
            ],
        )
        assert r.exit_code == 1, r.output
        assert (
            "error: run paper / curve failed: node 'src' (io.folder) failed on frame 0000000002" in r.stderr
        )
    assert lanes_files(outs["cluster"]) == lanes_files(outs["here"])
    assert (
        len((outs["cluster"] / "runs" / "paper" / "straight" / "lanes.jsonl").read_text().splitlines()) == 5
    )


def test_a_local_cluster_equals_the_in_process_run(tmp_path, reference, synthetic_dataset):
    out = tmp_path / "out"
    r = CliRunner().invoke(
        main,
        [
            "ablate",
            *GRAPHS,
            "--dataset",
            str(synthetic_dataset),
            "--out",
            str(out),
            "--cache-dir",
            str(tmp_path / "cache"),
            "--scheduler",
            "local:2",
            "--quiet",
        ],
    )
    assert r.exit_code == 0, r.output
    assert "starting a local Dask cluster: 2 worker process(es)" in r.stderr
    assert "Dask dashboard: http://" in r.stderr or "Dask dashboard: none" in r.stderr
    same_results(out, reference)


def test_an_unreachable_scheduler_is_a_usage_error(tmp_path, synthetic_dataset, monkeypatch):
    import socket

    from lanegraph_dask import cluster

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 2.0)
    out = tmp_path / "out"
    r = CliRunner().invoke(
        main,
        [
            "run",
            PAPER,
            "--dataset",
            str(synthetic_dataset),
            "--out",
            str(out),
            "--scheduler",
            f"tcp://127.0.0.1:{port}",
            "--quiet",
        ],
    )
    assert r.exit_code == 2, r.output
    assert (
        f"--scheduler tcp://127.0.0.1:{port}: could not reach a Dask scheduler there within 2 s" in r.stderr
    )
    assert not list(out.rglob("lanes.jsonl"))


def test_workers_on_one_host_share_its_cores(dask_cluster):
    from lanegraph_dask import cluster as d
    from lanegraph_dask.runner import parse_scheduler

    def _thread_share():  # a local function: sent by value (the workers cannot import tests/)
        import cv2
        from lanegraph_dask import cluster as d

        d._limit_threads()
        return d._THREADS, cv2.getNumThreads()

    address, _ = dask_cluster
    messages = []
    with d._Cluster(parse_scheduler(address), messages.append) as c:
        share = max(1, len(os.sched_getaffinity(0)) // 2)  # two workers, one task each, on this host
        assert set(c.client.run(_thread_share).values()) == {(share, share)}
    assert messages[-1] == "2 Dask worker(s), 2 task(s) at a time"


def test_thread_shares_divide_a_hosts_cores_among_the_tasks_that_share_them():
    from lanegraph_dask.cluster import thread_shares

    w = lambda host, port, n=1: (f"tcp://{host}:{port}", {"nthreads": n})  # noqa: E731
    # two workers of one task each on a 2-core host, as the tests' cluster: one thread each
    assert thread_shares(dict([w("10.0.0.1", 1), w("10.0.0.1", 2)]), {"tcp://10.0.0.1:1": [0, 1], "tcp://10.0.0.1:2": [0, 1]}) == {
        "tcp://10.0.0.1:1": 1, "tcp://10.0.0.1:2": 1
    }  # fmt: skip
    # a 16-core node with 4 one-task workers and one 2-task worker (6 tasks): 2 threads each;
    # another node is counted apart
    workers = dict([w("a", 1), w("a", 2), w("a", 3), w("a", 4), w("a", 5, 2), w("b", 1)])
    cpus = {addr: list(range(16)) for addr in workers} | {"tcp://b:1": list(range(8))}
    shares = thread_shares(workers, cpus)
    assert shares == {
        "tcp://a:1": 2,
        "tcp://a:2": 2,
        "tcp://a:3": 2,
        "tcp://a:4": 2,
        "tcp://a:5": 2,
        "tcp://b:1": 8,
    }
    # SLURM jobs bound to their own cores on one node do not share them
    workers = dict([w("n1", 1), w("n1", 2)])
    assert thread_shares(workers, {"tcp://n1:1": [0, 1, 2, 3], "tcp://n1:2": [4, 5, 6, 7]}) == {
        "tcp://n1:1": 4,
        "tcp://n1:2": 4,
    }
