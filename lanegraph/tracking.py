"""Experiment tracking: the runs of a command sent to a tracker (MLflow, ...), ``--track NAME[:URI]``.

A tracker comes from a plugin through the ``lanegraph_trackers`` hook, as a third party would
provide one for W&B or TensorBoard; the built-in plugin ``lanegraph_mlflow`` provides ``mlflow``
(``pip install "lanegraph[mlflow]"``). The core never imports a tracker's library.

A command holds one :class:`Tracking` session and calls it at three points:

- :meth:`Tracking.start` before any frame: the parent run of the command. A tracker that cannot
  start (its library missing, its server unreachable) is a :class:`~lanegraph.errors.UsageError`:
  exit 2 before any frame, nothing written.
- :meth:`Tracking.log_run` once per variant and sequence, once it is evaluated: a child run with
  the graph's params flattened (``node.param``), the metrics (:func:`run_metrics`) and the run's
  files (:func:`run_artifacts`).
- :meth:`Tracking.end` with the command's own files (``results.csv``, the plots, the report).

After the start a tracker that fails never loses a result: the failure is a warning (on the
console and in ``run.log``), the results stay on disk, and :attr:`Tracking.ok` turns False (the
command then exits 1).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from .errors import UsageError, did_you_mean
from .runlog import get_logger

log = get_logger("tracking")

#: metrics of a results row (``lanegraph ablate``'s columns) a tracker receives, by the same names
ROW_METRICS = (
    "detection_ratio",
    "precision",
    "ego_recall",
    "mean_abs_dx_px",
    "culane_f1",
    "frames",
    "frames_not_run",
    "frames_run",
    "failed_frames",
    "ms_per_frame",
    "wall_s",
)
#: the files of a run folder a tracker receives (those that exist)
RUN_FILES = ("graph.yaml", "run.json", "timings.json", "run.log")
#: a param value longer than this is cut (MLflow keeps at most 6000 characters)
MAX_PARAM_CHARS = 6000


@dataclass
class CommandRecord:
    """What a tracker's parent run says about the command: ``command`` ("run", "ablate"), a
    ``name`` for the run, the output folder, the command line, and params and tags of its own
    (the input or dataset, ``--frames`` ...)."""

    command: str
    name: str
    out_dir: Path
    argv: list[str] = field(default_factory=list)
    params: dict[str, str] = field(default_factory=dict)
    tags: dict[str, str] = field(default_factory=dict)


@dataclass
class TrackedRun:
    """One variant on one sequence, evaluated: a tracker's child run.

    ``params``: the resolved graph's params flattened (:func:`flatten_params`) and the run's own
    (``--set``, frames); ``metrics``: :func:`run_metrics`; ``artifacts``: files and folders to
    keep with it; ``status``: the run's ``ok``, ``failed frames`` or ``stopped``."""

    variant: str
    sequence: str
    params: dict[str, str] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)
    artifacts: list[Path] = field(default_factory=list)
    tags: dict[str, str] = field(default_factory=dict)
    status: str = "ok"


class Tracker:
    """The methods a tracker implements (a plugin's class may subclass this one or not).

    ``name`` is what ``--track`` calls it; the instance is made with the URI after the colon of
    ``--track NAME:URI`` (None without one: the tracker's own default). Every method may raise:
    :class:`Tracking` turns a failure of :meth:`start` into a usage error and a later one into a
    warning.
    """

    name: ClassVar[str] = ""

    def __init__(self, uri: str | None = None) -> None:
        self.uri = uri

    def start(self, command: CommandRecord) -> None:
        """Open the parent run of the command (before any frame runs)."""
        raise NotImplementedError

    def log_run(self, run: TrackedRun) -> None:
        """Record one variant on one sequence as a child run of the command's."""
        raise NotImplementedError

    def end(self, status: str, artifacts: Sequence[Path]) -> None:
        """Close the command's run: ``status`` is ``ok``, ``failed`` or ``interrupted``;
        ``artifacts`` the command's own files and folders."""
        raise NotImplementedError

    def where(self) -> str:
        """Where the runs went, for the command's last line (a URI, a folder)."""
        return self.uri or self.name


def available_trackers(pm: Any) -> dict[str, type]:
    """``{name: tracker class}`` of every tracker the installed plugins provide (a plugin whose
    hook raises is skipped with a warning; the first plugin to name a tracker keeps it)."""
    out: dict[str, type] = {}
    for impl in pm.hook.lanegraph_trackers.get_hookimpls():
        try:
            provided = list(impl.function() or [])
        except Exception as exc:  # noqa: BLE001 - a plugin's bug: reported, the others go on
            log.warning(
                "plugin %r: its lanegraph_trackers hook raised %s: %s",
                impl.plugin_name,
                type(exc).__name__,
                exc,
            )
            continue
        for cls in provided:
            name = getattr(cls, "name", None)
            if isinstance(name, str) and name and name not in out:
                out[name] = cls
    return out


#: the schemes a ``--track NAME:URI`` may name (anything else, ``javascript:``, is refused; a
#: plain folder has none)
TRACKING_SCHEMES = ("http", "https", "file", "sqlite", "postgresql", "mysql", "mssql", "databricks")


def parse_track(spec: str, pm: Any) -> Tracker:
    """The tracker of ``--track NAME[:URI]`` (``mlflow``, ``mlflow:http://127.0.0.1:5000``,
    ``mlflow:file:///data/mlruns``): an unknown name is a usage error listing the installed ones."""
    name, sep, uri = spec.partition(":")
    name = name.strip()
    trackers = available_trackers(pm)
    if name not in trackers:
        close = did_you_mean(name, list(trackers))
        raise UsageError(
            f"--track {spec}: no tracker {name!r} is installed (installed: {', '.join(sorted(trackers)) or 'none'})"
            + (f"; {close}" if close else "")
            + "; write --track NAME or --track NAME:URI, e.g. --track mlflow:http://127.0.0.1:5000"
        )
    if sep and not uri.strip():
        raise UsageError(f"--track {spec}: expected {name}:URI with a URI after the colon, or {name} alone")
    scheme = re.match(r"^([A-Za-z][A-Za-z0-9+.-]+):", uri.strip())
    if sep and scheme and scheme.group(1).lower() not in TRACKING_SCHEMES:
        raise UsageError(
            f"--track {spec}: {scheme.group(1)!r} is not a tracking store's scheme; expected a folder or a URI "
            f"of {', '.join(s + ':' for s in TRACKING_SCHEMES)} (e.g. --track {name}:http://127.0.0.1:5000)"
        )
    return trackers[name](uri.strip() if sep else None)


def _param_value(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, separators=(",", ":"), sort_keys=True)
    return text if len(text) <= MAX_PARAM_CHARS else text[: MAX_PARAM_CHARS - 1] + "…"


def flatten_params(resolved: Mapping[str, Any]) -> dict[str, str]:
    """A resolved graph's params as ``{"node.param": value}`` (:meth:`lanegraph.graph.Graph.resolved_dict`;
    a param holding a mapping gives ``node.param.key``); values as text, lists as JSON."""
    out: dict[str, str] = {}

    def put(prefix: str, value: Any) -> None:
        if isinstance(value, Mapping) and value:
            for k, v in value.items():
                put(f"{prefix}.{k}", v)
        else:
            out[prefix] = _param_value(value)

    for nid, spec in (resolved.get("nodes") or {}).items():
        for pname, value in (spec.get("params") or {}).items():
            put(f"{nid}.{pname}", value)
    return out


def _number(x: Any) -> float | None:
    if isinstance(x, bool) or x is None or x == "":
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if v == v and abs(v) != float("inf") else None


def run_metrics(row: Mapping[str, Any]) -> dict[str, float]:
    """The metrics of one results row (a variant on a sequence, or pooled): :data:`ROW_METRICS`
    that have a value, and ``ms.<node>``, each node's median ms per frame."""
    out = {k: v for k in ROW_METRICS if (v := _number(row.get(k))) is not None}
    for nid, ms in (row.get("stage_ms") or {}).items():
        if (v := _number(ms)) is not None:
            out[f"ms.{nid}"] = v
    return out


def existing(folder: Path, names: Sequence[str]) -> list[Path]:
    """The files among ``folder/name`` that exist (and the ``report`` folder when it has a page)."""
    paths = [folder / n for n in names if (folder / n).is_file()]
    if (folder / "report" / "index.html").is_file():
        paths.append(folder / "report")
    return paths


def run_artifacts(run_dir: Path, extra: Sequence[str] = ()) -> list[Path]:
    """A run folder's files a tracker keeps: :data:`RUN_FILES` (the resolved graph, the record,
    the timings, the log), ``extra`` names (its result files), and its report."""
    return existing(run_dir, [*RUN_FILES, *extra])


class Tracking:
    """A command's tracking session (see the module's doc). ``tracker`` None: nothing is tracked
    and every method does nothing."""

    def __init__(self, tracker: Tracker | None) -> None:
        self.tracker = tracker
        self.failures: list[str] = []
        self.started = False

    @property
    def enabled(self) -> bool:
        return self.tracker is not None

    @property
    def ok(self) -> bool:
        """False once a tracker call after the start failed (the command exits 1)."""
        return not self.failures

    def start(self, command: CommandRecord) -> None:
        if self.tracker is None:
            return
        try:
            self.tracker.start(command)
        except UsageError:
            raise
        except Exception as exc:  # noqa: BLE001 - any library's error: a located usage error
            raise UsageError(
                f"--track {self.tracker.name}: cannot start tracking at {self.tracker.where()}: {_why(exc)}"
            ) from None
        self.started = True

    def _call(self, what: str, fn: Any, *args: Any) -> None:
        if self.tracker is None or not self.started:
            return
        try:
            fn(*args)
        except Exception as exc:  # noqa: BLE001 - the results are on disk: a warning, exit 1
            msg = (
                f"tracking ({self.tracker.name} at {self.tracker.where()}): {what} not recorded: {_why(exc)}"
            )
            self.failures.append(msg)
            log.warning(msg)

    def log_run(self, run: TrackedRun) -> None:
        """Record one variant on one sequence (a failure is a warning)."""
        if self.tracker is not None:
            self._call(f"run {run.variant} / {run.sequence}", self.tracker.log_run, run)

    def end(self, status: str, artifacts: Sequence[Path] = ()) -> None:
        """Close the command's run (a failure is a warning)."""
        if self.tracker is not None:
            self._call("the command's run", self.tracker.end, status, list(artifacts))
            if self.started and self.ok:
                log.info("tracking: runs recorded in %s", self.tracker.where())


def tracked_row(
    row: Mapping[str, Any],
    params: Mapping[str, str],
    run_dir: Path | None,
    result_files: Sequence[str] = (),
    tags: Mapping[str, str] | None = None,
) -> TrackedRun:
    """A :class:`TrackedRun` of one results row (``variant``, ``sequence``, metrics, ``error``),
    with the variant's flattened ``params`` and its run folder's files."""
    status = (
        "stopped" if row.get("error") else ("failed frames" if _number(row.get("failed_frames")) else "ok")
    )
    return TrackedRun(
        variant=str(row.get("variant")),
        sequence=str(row.get("sequence")),
        params=dict(params),
        metrics=run_metrics(row),
        artifacts=run_artifacts(run_dir, result_files) if run_dir is not None else [],
        tags={**(tags or {}), **({"lanegraph.error": str(row["error"])[:5000]} if row.get("error") else {})},
        status=status,
    )


def _why(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 400 else text[:399] + "…"
