"""Runners are an open set: a third party registers one through the ``lanegraph_runners`` hook and
``--scheduler`` picks it; its results equal the in-process runner's byte for byte."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from click.testing import CliRunner
from lanegraph_dask.runner import DaskRunner

from lanegraph import hookimpl
from lanegraph.batches.runners import InProcessRunner, Runner, runner_types, select_runner
from lanegraph.cli import main
from lanegraph.errors import UsageError
from lanegraph.plugins import PluginManager, get_plugin_manager
from lanegraph.run.task import RunTask, describe_error, execute_task

ROOT = Path(__file__).resolve().parents[2]
PAPER = str(ROOT / "graphs" / "paper.yaml")
SLT = str(ROOT / "graphs" / "ablations" / "slt.yaml")


class ReversedRunner:
    """A third party's engine: the tasks last first (a queue of its own), every call recorded."""

    name = "reversed"
    calls: list[list[str]] = []

    def __init__(self, label: str):
        self.label = label

    @classmethod
    def from_spec(cls, text: str):
        name, _, label = text.partition(":")
        return cls(label) if name == cls.name else None

    def run(self, tasks, progress=True, echo=None, done=None):
        outcomes = done if done is not None else {}
        ReversedRunner.calls.append([t.label for t in tasks])
        for task in reversed(tasks):
            outcomes[task.index] = execute_task(task)
        return outcomes


class ThirdParty:
    @hookimpl
    def lanegraph_runners(self):
        return [ReversedRunner]


@pytest.fixture
def third_party():
    pm = get_plugin_manager()
    plugin = ThirdParty()
    assert pm.register(plugin, name="third-party-runner") is not None, pm.plugin_errors
    ReversedRunner.calls = []
    yield pm
    pm.unregister(plugin)


def test_runner_selection(third_party):
    assert isinstance(select_runner(None, third_party), InProcessRunner)
    assert isinstance(select_runner("inprocess", third_party), InProcessRunner)
    assert isinstance(select_runner("local:2", third_party), DaskRunner)
    assert isinstance(select_runner("tcp://127.0.0.1:8786", third_party), DaskRunner)
    picked = select_runner("reversed:batch-7", third_party)
    assert isinstance(picked, ReversedRunner) and picked.label == "batch-7" and isinstance(picked, Runner)
    # the fallback runner (Dask takes any address) comes after every other one
    assert runner_types(third_party)[-1] is DaskRunner
    with pytest.raises(UsageError, match="local:N"):
        select_runner("local:0", third_party)


def test_a_task_its_runner_could_not_run_fails_with_the_runners_reason():
    task = RunTask(3, "slt", "curve", None, None, None, "out/runs/slt/curve")
    out = task.failed("the task failed on the cluster: KilledWorker: gone")
    assert out.index == 3 and out.result.frames == 0 and out.record is None
    assert out.error == {
        "variant": "slt", "sequence": "curve", "frame": None, "node": None,
        "message": "the task failed on the cluster: KilledWorker: gone", "input": False,
        "before_any_frame": False, "stage": "run", "exit_code": 1,
    }  # fmt: skip
    assert describe_error(out.error) == "slt / curve: the task failed on the cluster: KilledWorker: gone"


def test_a_fresh_plugin_manager_has_the_builtin_runners():
    # lanegraph's own runner is there without any plugin; Dask's comes with its plugin's entry point
    assert {rt.name for rt in runner_types(PluginManager())} == {"inprocess"}
    with pytest.raises(UsageError, match=r"--scheduler local:2: no runner takes it \(runners: inprocess\)"):
        select_runner("local:2", PluginManager())
    pm = PluginManager()
    pm.load_entrypoints()
    assert pm.get_plugin("lanegraph_dask") is not None, pm.plugin_errors
    assert {rt.name for rt in runner_types(pm)} == {"inprocess", "dask"}


def test_an_ablation_on_a_third_party_runner(tmp_path, synthetic_dataset, third_party):
    outs = {}
    for label, extra in (("inprocess", []), ("reversed", ["--scheduler", "reversed:test"])):
        out = tmp_path / label
        r = CliRunner().invoke(
            main,
            ["ablate", PAPER, SLT, "--dataset", str(synthetic_dataset), "--frames", "0:3", "--out", str(out),
             "--no-cache", "--quiet", *extra],
        )  # fmt: skip
        assert r.exit_code == 0, r.output
        outs[label] = out
    # the third party's runner ran every run of the ablation (2 variants x 2 sequences), once
    assert len(ReversedRunner.calls) == 1 and sorted(ReversedRunner.calls[0]) == sorted(
        f"{v} / {s}" for v in ("paper", "slt") for s in ("straight", "curve")
    )
    a, b = outs["inprocess"], outs["reversed"]
    lanes = sorted(p.relative_to(a) for p in a.rglob("lanes.jsonl"))
    assert len(lanes) == 4
    for rel in lanes:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    rows = [list(csv.DictReader((o / "results.csv").open())) for o in (a, b)]
    keys = ("variant", "sequence", "frames", "detection_ratio", "precision", "ego_recall", "mean_abs_dx_px")
    assert [[r[k] for k in keys] for r in rows[0]] == [[r[k] for k in keys] for r in rows[1]]
