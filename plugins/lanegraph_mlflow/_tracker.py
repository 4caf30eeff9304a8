"""The ``mlflow`` tracker: one MLflow run per command, a child run per variant and sequence.

Written with :class:`mlflow.tracking.MlflowClient` and explicit run ids (not MLflow's global
active run), so that it nests runs the same way in every process. ``mlflow`` is imported in
:meth:`MlflowTracker.start`, never when the plugin is loaded.
"""

from __future__ import annotations

import io
import logging
import os
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, redirect_stdout
from pathlib import Path
from typing import Any

from lanegraph import __version__
from lanegraph.errors import UsageError
from lanegraph.runlog import get_logger
from lanegraph.tracking import CommandRecord, TrackedRun, Tracker

log = get_logger("tracking")

#: the experiment runs go to, unless MLFLOW_EXPERIMENT_NAME names another (MLflow's own variable)
EXPERIMENT = "lanegraph"
#: MLflow's statuses of a command's end and of a run's
_END_STATUS = {"ok": "FINISHED", "failed": "FAILED", "interrupted": "KILLED"}
#: a batch of params MLflow takes in one request
_PARAMS_PER_BATCH = 100


@contextmanager
def _http_limits(retries: int, timeout: int) -> Iterator[None]:
    """MLflow's HTTP retries and timeout for the calls inside (unless the user set them): the start
    fails within seconds on a server that is not there, instead of retrying for minutes."""
    names = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": str(retries), "MLFLOW_HTTP_REQUEST_TIMEOUT": str(timeout)}
    set_here = [n for n in names if n not in os.environ]
    for n in set_here:
        os.environ[n] = names[n]
    try:
        yield
    finally:
        for n in set_here:
            os.environ.pop(n, None)


def tracking_uri(uri: str | None) -> str | None:
    """The MLflow tracking URI of ``--track mlflow:URI``: a URI as it is (``http://``, ``file://``,
    ``sqlite://``, ``databricks``), a plain folder as a ``file://`` store; None: MLflow's default
    (``MLFLOW_TRACKING_URI``, else a local store in the current folder)."""
    if uri is None:
        return None
    if "://" in uri or uri.split(":", 1)[0] in ("databricks", "file"):
        return uri
    return Path(uri).expanduser().resolve().as_uri()


class MlflowTracker(Tracker):
    """``--track mlflow`` (MLflow's default store: ``MLFLOW_TRACKING_URI``, else ``./mlflow.db``
    with the artifacts in ``./mlruns``) or ``--track mlflow:URI`` (a tracking server, a
    ``file://`` store, a database)."""

    name = "mlflow"

    def __init__(self, uri: str | None = None) -> None:
        super().__init__(uri)
        self._uri = tracking_uri(uri)
        self._client: Any = None
        self._experiment: str | None = None
        self._parent: str | None = None
        self.run_url: str | None = None  # the command's run's web page, on a tracking server

    def where(self) -> str:
        if self._client is not None:
            uri = getattr(self._client, "tracking_uri", None) or self._uri or "MLflow's default store"
            return f"{uri} (experiment {self._experiment_name()!r})"
        return self._uri or "MLflow's default store"

    @staticmethod
    def _experiment_name() -> str:
        return os.environ.get("MLFLOW_EXPERIMENT_NAME") or EXPERIMENT

    def start(self, command: CommandRecord) -> None:
        log.info(
            "tracking: opening MLflow at %s ...", self._uri or "its default store (./mlflow.db, ./mlruns)"
        )
        # MLflow's own INFO lines (its store being created, migrations ...) stay out of lanegraph's
        # output; its warnings and errors still show (MLFLOW_LOGGING_LEVEL set by the user wins)
        quiet_mlflow = "MLFLOW_LOGGING_LEVEL" not in os.environ
        if quiet_mlflow:
            os.environ["MLFLOW_LOGGING_LEVEL"] = "WARNING"
        try:
            import mlflow  # noqa: F401 - the library the extra installs
            from mlflow.tracking import MlflowClient
        except ImportError as exc:
            raise UsageError(
                f'--track mlflow: MLflow is not installed ({exc}): pip install "lanegraph[mlflow]"'
            ) from None
        if quiet_mlflow:  # imported before (by a test, a notebook): its loggers are set already
            for name in ("mlflow", "alembic"):
                logging.getLogger(name).setLevel(max(logging.getLogger(name).level, logging.WARNING))
        if self._uri is not None and self._uri.startswith("file:"):
            # asked for by name: MLflow 3 keeps its file store but refuses it unless allowed
            os.environ.setdefault("MLFLOW_ALLOW_FILE_STORE", "true")
        with _http_limits(retries=0, timeout=15):
            client = MlflowClient(tracking_uri=self._uri)
            name = self._experiment_name()
            exp = client.get_experiment_by_name(name)
            self._experiment = exp.experiment_id if exp is not None else client.create_experiment(name)
            tags = {
                "lanegraph.command": command.command,
                "lanegraph.out": str(Path(command.out_dir).resolve()),
                "lanegraph.argv": " ".join(command.argv)[:5000],
                "lanegraph.version": __version__,
                **command.tags,
            }
            run = client.create_run(self._experiment, run_name=command.name, tags=tags)
        self._client, self._parent = client, run.info.run_id
        with _http_limits(retries=2, timeout=60):
            self._log(self._parent, command.params, {})

    def _log(self, run_id: str, params: dict[str, str], metrics: dict[str, float]) -> None:
        from mlflow.entities import Metric, Param

        now = int(time.time() * 1000)
        items = [Param(k, v) for k, v in params.items()]
        ms = [Metric(k, float(v), now, 0) for k, v in metrics.items()]
        for i in range(0, max(len(items), 1), _PARAMS_PER_BATCH):
            self._client.log_batch(
                run_id, metrics=ms if i == 0 else [], params=items[i : i + _PARAMS_PER_BATCH]
            )

    def _artifacts(self, run_id: str, paths: Sequence[Path]) -> None:
        for p in paths:
            if p.is_dir():
                self._client.log_artifacts(run_id, str(p), artifact_path=p.name)
            elif p.is_file():
                self._client.log_artifact(run_id, str(p))

    def log_run(self, run: TrackedRun) -> None:
        from mlflow.utils.mlflow_tags import MLFLOW_PARENT_RUN_ID

        tags = {
            MLFLOW_PARENT_RUN_ID: self._parent,
            "lanegraph.variant": run.variant,
            "lanegraph.sequence": run.sequence,
            "lanegraph.status": run.status,
            **run.tags,
        }
        with _http_limits(retries=2, timeout=60):
            child = self._client.create_run(
                self._experiment, run_name=f"{run.variant} / {run.sequence}", tags=tags
            )
            rid = child.info.run_id
            self._log(rid, run.params, run.metrics)
            self._artifacts(rid, run.artifacts)
            self._terminate(rid, "FAILED" if run.status == "stopped" else "FINISHED")

    def end(self, status: str, artifacts: Sequence[Path]) -> None:
        with _http_limits(retries=2, timeout=60):
            self._artifacts(self._parent, artifacts)
            said = self._terminate(self._parent, _END_STATUS.get(status, "FAILED"))
        url = next(
            (
                line.split(" at: ", 1)[1]
                for line in said.splitlines()
                if line.startswith("🏃") and " at: " in line
            ),
            None,
        )
        if url:
            self.run_url = url.strip()
            log.info("tracking: the command's MLflow run: %s", self.run_url)

    def _terminate(self, run_id: str, status: str) -> str:
        """End a run; what MLflow prints about it (links to its web page, on stdout, where they
        would mix with lanegraph's own output) is returned instead."""
        buf = io.StringIO()
        with redirect_stdout(buf):
            self._client.set_terminated(run_id, status)
        return buf.getvalue()
