"""The ``mlflow`` tracker (plugin ``lanegraph_mlflow``) against a real ``mlflow server`` started on
127.0.0.1 by the test, and against a ``file://`` store: nested runs readable with
``mlflow.search_runs``, params ``node.param``, metrics, artifacts. Skipped with a reason when MLflow
(the ``mlflow`` extra) is not installed."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from lanegraph.errors import UsageError
from lanegraph.tracking import CommandRecord, TrackedRun, Tracking

pytestmark = pytest.mark.mlflow

#: how long the server may take to answer /health (it creates its database first)
SERVER_START_S = 180


def _mlflow():
    return pytest.importorskip("mlflow", reason='MLflow is not installed: pip install -e ".[mlflow]"')


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def mlflow_server(tmp_path_factory):
    """A real ``mlflow server`` on 127.0.0.1 (a free port; its database and artifacts in a
    temporary folder), stopped at the end; its URI."""
    _mlflow()
    root = tmp_path_factory.mktemp("mlflow_server")
    port = _free_port()
    log = (root / "server.log").open("wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", "mlflow", "server", "--host", "127.0.0.1", "--port", str(port)]
        + [
            "--backend-store-uri",
            f"sqlite:///{root / 'mlflow.db'}",
            "--artifacts-destination",
            str(root / "artifacts"),
        ]
        + ["--workers", "1"],
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=root,
        start_new_session=True,  # its workers are stopped with it
    )
    uri = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + SERVER_START_S
        while True:
            if proc.poll() is not None:
                pytest.fail(
                    f"mlflow server exited ({proc.returncode}): {(root / 'server.log').read_text()[-2000:]}"
                )
            try:
                with urllib.request.urlopen(f"{uri}/health", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline:
                pytest.fail(
                    f"mlflow server did not answer in {SERVER_START_S} s: {(root / 'server.log').read_text()[-2000:]}"
                )
            time.sleep(0.5)
        yield uri
    finally:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=20)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait(timeout=10)
        log.close()


@pytest.fixture
def experiment(monkeypatch, request):
    """An experiment of the test's own (MLFLOW_EXPERIMENT_NAME, which the tracker honours)."""
    name = f"lanegraph-{request.node.name}-{os.getpid()}"
    monkeypatch.setenv("MLFLOW_EXPERIMENT_NAME", name)
    return name


def _record(folder: Path, variant: str, ratio: float) -> TrackedRun:
    run_dir = folder / "runs" / variant / "seq"
    run_dir.mkdir(parents=True)
    (run_dir / "run.json").write_text('{"status": "ok"}\n')
    (run_dir / "graph.yaml").write_text(f"name: {variant}\n")
    (run_dir / "report").mkdir()
    (run_dir / "report" / "index.html").write_text("<html></html>")
    return TrackedRun(
        variant=variant,
        sequence="seq",
        params={"disp.num_disparities": "96", "fit.roi_width": "40" if variant == "paper" else "20"},
        metrics={"detection_ratio": ratio, "precision": 1.0, "ms_per_frame": 120.5, "ms.disp": 30.25},
        artifacts=[run_dir / "run.json", run_dir / "graph.yaml", run_dir / "report"],
        tags={"lanegraph.graph": f"graphs/{variant}.yaml"},
    )


def _track_an_ablation(uri: str, folder: Path) -> str:
    from lanegraph_mlflow import MlflowTracker

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "results.csv").write_text("variant,sequence,detection_ratio\n")
    tracking = Tracking(MlflowTracker(uri))
    tracking.start(CommandRecord("ablate", "ablate out", folder, ["lanegraph", "ablate"], {"frames": "0:2"}))
    for variant, ratio in (("paper", 1.0), ("slt", 0.5)):
        tracking.log_run(_record(folder, variant, ratio))
    tracking.end("ok", [folder / "results.csv"])
    assert tracking.ok, tracking.failures
    return tracking.tracker._parent


def _check_runs(mlflow, uri: str, experiment: str, parent: str) -> None:
    from mlflow.tracking import MlflowClient

    mlflow.set_tracking_uri(uri)
    runs = mlflow.search_runs(experiment_names=[experiment], output_format="list")
    by_name = {r.info.run_name: r for r in runs}
    assert set(by_name) == {"ablate out", "paper / seq", "slt / seq"}
    top = by_name["ablate out"]
    assert top.info.run_id == parent and top.info.status == "FINISHED"
    assert top.data.params == {"frames": "0:2"} and top.data.tags["lanegraph.command"] == "ablate"
    ratios = {}
    for name in ("paper / seq", "slt / seq"):
        r = by_name[name]
        assert r.data.tags["mlflow.parentRunId"] == parent and r.info.status == "FINISHED"
        assert r.data.params["disp.num_disparities"] == "96"
        assert r.data.metrics["ms.disp"] == 30.25
        ratios[r.data.tags["lanegraph.variant"]] = r.data.metrics["detection_ratio"]
    assert ratios == {"paper": 1.0, "slt": 0.5}
    client = MlflowClient(uri)
    child = by_name["slt / seq"].info.run_id
    assert {a.path for a in client.list_artifacts(child)} == {"run.json", "graph.yaml", "report"}
    assert [a.path for a in client.list_artifacts(child, "report")] == ["report/index.html"]
    assert [a.path for a in client.list_artifacts(parent)] == ["results.csv"]
    local = client.download_artifacts(child, "graph.yaml")
    assert Path(local).read_text() == "name: slt\n"


def test_runs_on_a_real_tracking_server(mlflow_server, experiment, tmp_path, capsys):
    mlflow = _mlflow()
    parent = _track_an_ablation(mlflow_server, tmp_path)
    assert "View run" not in capsys.readouterr().out  # MLflow's links do not mix with lanegraph's output
    _check_runs(mlflow, mlflow_server, experiment, parent)


def test_runs_in_a_file_store(experiment, tmp_path, monkeypatch):
    mlflow = _mlflow()
    store = tmp_path / "mlruns"
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "true")  # for the reader too (MLflow 3)
    parent = _track_an_ablation(store.as_uri(), tmp_path / "out")
    assert (store / "mlflow.db").exists() is False and any(store.iterdir())  # a file store, not a database
    _check_runs(mlflow, store.as_uri(), experiment, parent)


def test_a_server_that_is_not_there_is_refused_at_the_start(tmp_path):
    _mlflow()
    from lanegraph_mlflow import MlflowTracker

    uri = f"http://127.0.0.1:{_free_port()}"
    with pytest.raises(UsageError, match=rf"--track mlflow: cannot start tracking at {uri}"):
        Tracking(MlflowTracker(uri)).start(CommandRecord("run", "run out", tmp_path))


def test_without_mlflow_the_tracker_says_how_to_install_it(monkeypatch, tmp_path):
    from lanegraph_mlflow import MlflowTracker

    monkeypatch.setitem(sys.modules, "mlflow", None)  # import mlflow raises ImportError
    with pytest.raises(UsageError, match=r'MLflow is not installed .*pip install "lanegraph\[mlflow\]"'):
        Tracking(MlflowTracker()).start(CommandRecord("run", "run out", tmp_path))


def test_the_plugin_does_not_import_mlflow_until_asked():
    code = (
        "import sys\n"
        "from lanegraph.plugins import get_plugin_manager\n"
        "from lanegraph.tracking import parse_track\n"
        "pm = get_plugin_manager()\n"
        "assert pm.get_plugin('lanegraph_mlflow') is not None, pm.plugin_errors\n"
        "parse_track('mlflow:http://127.0.0.1:1', pm)\n"
        "assert 'mlflow' not in sys.modules\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


def test_plain_folder_is_a_file_store(tmp_path):
    from lanegraph_mlflow._tracker import tracking_uri

    assert tracking_uri(str(tmp_path / "runs")) == (tmp_path / "runs").as_uri()
    for uri in ("http://127.0.0.1:5000", "file:///data/mlruns", "sqlite:///mlflow.db", "databricks"):
        assert tracking_uri(uri) == uri
    assert tracking_uri(None) is None


@pytest.mark.mlflow
def test_mlflows_own_info_lines_stay_out_of_lanegraphs_output(tmp_path):
    """A run tracked into a new store: MLflow creates its tables, and says nothing of it (its INFO
    lines); lanegraph's own lines about tracking remain."""
    _mlflow()
    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_LOGGING_LEVEL"}
    proc = subprocess.run(
        [sys.executable, "-m", "lanegraph.cli", "run", "--frames", "0:1", "-q",
         "--track", f"mlflow:sqlite:///{tmp_path / 'm.db'}", "--out", str(tmp_path / "out")],
        capture_output=True, text=True, env=env, timeout=600, cwd=tmp_path,  # MLflow's mlruns/ goes there
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "runs recorded in sqlite" in proc.stderr
    assert " INFO " not in proc.stderr + proc.stdout, proc.stderr[-2000:]
