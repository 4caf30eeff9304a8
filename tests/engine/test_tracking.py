"""Experiment tracking in the core (no tracker library needed): choosing a tracker with --track,
params flattened, metrics of a results row, a tracker that fails after the start is a warning."""

from __future__ import annotations

from pathlib import Path

import pytest

from lanegraph import hookimpl
from lanegraph.errors import UsageError
from lanegraph.plugins import PluginManager
from lanegraph.tracking import (
    CommandRecord,
    TrackedRun,
    Tracker,
    Tracking,
    available_trackers,
    flatten_params,
    parse_track,
    run_metrics,
    tracked_row,
)


class Memory(Tracker):
    """A tracker that keeps what it is given (and fails where told to)."""

    name = "memory"
    fail_on: set[str] = set()

    def __init__(self, uri=None):
        super().__init__(uri)
        self.calls: list[tuple] = []

    def start(self, command):
        if "start" in self.fail_on:
            raise ConnectionError("connection refused")
        self.calls.append(("start", command.name))

    def log_run(self, run):
        if "log_run" in self.fail_on:
            raise ConnectionError("server went away")
        self.calls.append(("run", run.variant, run.sequence, run.metrics.get("detection_ratio")))

    def end(self, status, artifacts):
        self.calls.append(("end", status, [p.name for p in artifacts]))


class MemoryPlugin:
    @hookimpl
    def lanegraph_trackers(self):
        return [Memory]


class Broken:
    @hookimpl
    def lanegraph_trackers(self):
        raise RuntimeError("bug")


@pytest.fixture
def tpm():
    pm = PluginManager()
    pm.register(Broken(), name="broken")
    pm.register(MemoryPlugin(), name="memory_plugin")
    return pm


def test_a_tracker_is_chosen_by_name_with_an_optional_uri(tpm):
    assert set(available_trackers(tpm)) == {"memory"}  # the broken plugin is skipped
    t = parse_track("memory", tpm)
    assert isinstance(t, Memory) and t.uri is None
    assert parse_track("memory:http://127.0.0.1:5000", tpm).uri == "http://127.0.0.1:5000"
    with pytest.raises(
        UsageError, match=r"no tracker 'memroy' is installed \(installed: memory\); did you mean 'memory'"
    ):
        parse_track("memroy", tpm)
    with pytest.raises(UsageError, match="with a URI after the colon"):
        parse_track("memory:", tpm)


def test_the_mlflow_tracker_is_installed_with_lanegraph(installed_pm):
    assert "mlflow" in available_trackers(installed_pm)


def test_params_are_flattened_as_node_dot_param():
    resolved = {
        "name": "g",
        "nodes": {
            "src": {"type": "io.auto", "params": {"default": "io.synthetic"}},
            "disp": {
                "type": "disparity.sgbm",
                "params": {"num_disparities": 96, "wls": False, "resize": [188, 622]},
            },
            "fit": {"type": "fit.irls", "params": {"weights": {"a": 1.5}}},
            "gray": {"type": "image.gray"},
        },
    }
    assert flatten_params(resolved) == {
        "src.default": "io.synthetic",
        "disp.num_disparities": "96",
        "disp.wls": "false",
        "disp.resize": "[188,622]",
        "fit.weights.a": "1.5",
    }
    long = flatten_params({"nodes": {"n": {"params": {"p": "x" * 7000}}}})["n.p"]
    assert len(long) == 6000 and long.endswith("…")


def test_metrics_of_a_results_row():
    row = {
        "variant": "paper",
        "sequence": "seq",
        "detection_ratio": 0.75,
        "precision": None,
        "ego_recall": "1.0",
        "mean_abs_dx_px": float("nan"),
        "ms_per_frame": 120.5,
        "failed_frames": 0,
        "stage_ms": {"disp": 30.0, "fit": None},
        "error": None,
    }
    assert run_metrics(row) == {
        "detection_ratio": 0.75,
        "ego_recall": 1.0,
        "ms_per_frame": 120.5,
        "failed_frames": 0.0,
        "ms.disp": 30.0,
    }
    run = tracked_row({**row, "error": "node 'fit' raised"}, {"a.b": "1"}, None)
    assert run.status == "stopped" and run.tags["lanegraph.error"] == "node 'fit' raised"
    assert tracked_row({**row, "failed_frames": 2}, {}, None).status == "failed frames"


def test_run_artifacts_are_the_files_that_exist(tmp_path):
    from lanegraph.tracking import run_artifacts

    (tmp_path / "run.json").write_text("{}")
    (tmp_path / "lanes.jsonl").write_text("")
    (tmp_path / "report").mkdir()
    assert [p.name for p in run_artifacts(tmp_path, ["lanes.jsonl"])] == ["run.json", "lanes.jsonl"]
    (tmp_path / "report" / "index.html").write_text("<html>")
    assert [p.name for p in run_artifacts(tmp_path)] == ["run.json", "report"]


def test_tracking_session_start_failure_is_a_usage_error_and_later_failures_are_warnings(caplog):
    Memory.fail_on = {"start"}
    try:
        with pytest.raises(
            UsageError, match="--track memory: cannot start tracking at memory: connection refused"
        ):
            Tracking(Memory()).start(CommandRecord("run", "r", Path("out")))
        Memory.fail_on = {"log_run"}
        t = Tracking(Memory())
        t.start(CommandRecord("ablate", "ablate out", Path("out")))
        with caplog.at_level("WARNING", logger="lanegraph.tracking"):
            t.log_run(TrackedRun("paper", "seq", metrics={"detection_ratio": 1.0}))
        assert not t.ok and "run paper / seq not recorded: server went away" in t.failures[0]
        assert any("server went away" in r.getMessage() for r in caplog.records)
        t.end("ok", [Path("results.csv")])
        assert t.tracker.calls == [("start", "ablate out"), ("end", "ok", ["results.csv"])]
    finally:
        Memory.fail_on = set()
    off = Tracking(None)  # no --track: nothing happens
    off.start(CommandRecord("run", "r", Path("out")))
    off.log_run(TrackedRun("a", "b"))
    off.end("ok")
    assert off.ok and not off.enabled
