"""The options matrix of the one run path: every run option works on each of ``run`` (one input),
``run --dataset`` and ``ablate`` -- or is refused with its one reason -- because all three are
plan -> runner -> finish over the same tasks (lanes byte for byte those of a plain run)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
from click.testing import CliRunner

from lanegraph import hookimpl
from lanegraph.cli import main
from lanegraph.plugins import get_plugin_manager
from lanegraph.run.task import execute_task

ROOT = Path(__file__).resolve().parents[2]
PAPER = str(ROOT / "graphs" / "paper.yaml")
FRAMES = "0:3"
KINDS = ("run", "dataset", "ablate")


def command(kind: str, ds: Path, out: Path, *more: str) -> list[str]:
    """The command of ``kind`` on the synthetic dataset (``run``: its first sequence) into ``out``."""
    base = {
        "run": ["run", PAPER, "--input", str(ds.parent / "a")],
        "dataset": ["run", PAPER, "--dataset", str(ds)],
        "ablate": ["ablate", PAPER, "--dataset", str(ds), "--no-cache"],
    }[kind]
    return [*base, "--out", str(out), "-q", *more]


def lanes(kind: str, out: Path) -> dict[str, bytes]:
    """Each run's lanes.jsonl, by sequence."""
    folder = {"run": None, "dataset": out, "ablate": out / "runs" / "paper"}[kind]
    if folder is None:
        return {"straight": (out / "lanes.jsonl").read_bytes()}
    return {p.parent.name: p.read_bytes() for p in sorted(folder.glob("*/lanes.jsonl"))}


def lanegraph(args: list[str]):
    return CliRunner().invoke(main, args)


@pytest.fixture(scope="module")
def reference(synthetic_dataset, tmp_path_factory) -> dict[str, bytes]:
    """The lanes of a plain dataset run of FRAMES, by sequence."""
    out = tmp_path_factory.mktemp("reference") / "out"
    r = lanegraph(command("dataset", synthetic_dataset, out, "--frames", FRAMES))
    assert r.exit_code == 0, r.output
    return lanes("dataset", out)


def expected(kind: str, reference: dict[str, bytes]) -> dict[str, bytes]:
    return {"straight": reference["straight"]} if kind == "run" else reference


@pytest.mark.parametrize("kind", KINDS)
def test_frames_and_overwrite(kind, synthetic_dataset, reference, tmp_path):
    out = tmp_path / "out"
    r = lanegraph(command(kind, synthetic_dataset, out, "--frames", FRAMES))
    assert r.exit_code == 0, r.output
    assert lanes(kind, out) == expected(kind, reference)
    # another selection into the same folder: refused, the results left as they are ...
    r = lanegraph(command(kind, synthetic_dataset, out, "--frames", "0:2"))
    assert r.exit_code == 2 and "holds the results of another" in r.output, r.output
    assert lanes(kind, out) == expected(kind, reference)
    # ... unless --overwrite
    r = lanegraph(command(kind, synthetic_dataset, out, "--frames", "0:2", "--overwrite"))
    assert r.exit_code == 0, r.output
    assert all(len(b.splitlines()) == 2 for b in lanes(kind, out).values())


@pytest.mark.parametrize("kind", KINDS)
def test_chunk_frames(kind, synthetic_dataset, reference, tmp_path):
    """Chunks of one frame after two warm-up frames: every chunk starts from the whole run's state."""
    out = tmp_path / "out"
    r = lanegraph(
        command(kind, synthetic_dataset, out, "--frames", FRAMES, "--chunk-frames", "1", "--warmup", "2")
    )
    assert r.exit_code == 0, r.output
    assert lanes(kind, out) == expected(kind, reference)
    assert not [p for p in out.rglob(".*") if p.is_dir()]  # no chunk or temporary folder left
    runs = [p.parent for p in out.rglob("lanes.jsonl")]
    assert runs and all((p / "graph.yaml").is_file() and (p / "run.json").is_file() for p in runs)


class Ordered:
    """A third party's runner (``--scheduler ordered:LABEL``): the tasks in order, every call recorded."""

    name = "ordered"
    calls: list[list[str]] = []

    @classmethod
    def from_spec(cls, text: str):
        return cls() if text.partition(":")[0] == cls.name else None

    def run(self, tasks, progress=True, echo=None, done=None):
        outcomes = done if done is not None else {}
        Ordered.calls.append([t.label for t in tasks])
        for task in tasks:
            outcomes[task.index] = execute_task(task)
        return outcomes


class _Runners:
    @hookimpl
    def lanegraph_runners(self):
        return [Ordered]


@pytest.mark.parametrize("kind", KINDS)
def test_scheduler(kind, synthetic_dataset, reference, tmp_path):
    pm = get_plugin_manager()
    plugin = _Runners()
    pm.register(plugin, name="ordered-runner")
    Ordered.calls = []
    try:
        out = tmp_path / "out"
        r = lanegraph(command(kind, synthetic_dataset, out, "--frames", FRAMES, "--scheduler", "ordered:x"))
    finally:
        pm.unregister(plugin)
    assert r.exit_code == 0, r.output
    assert lanes(kind, out) == expected(kind, reference)
    labels = {
        "run": ["paper"],
        "dataset": ["straight", "curve"],
        "ablate": ["paper / straight", "paper / curve"],
    }
    assert Ordered.calls == [labels[kind]]


@pytest.mark.parametrize("kind", KINDS)
def test_debug_dir(kind, synthetic_dataset, tmp_path):
    out, dbg = tmp_path / "out", tmp_path / "dbg"
    r = lanegraph(
        command(
            kind, synthetic_dataset, out, "--frames", "0:2", "--debug-dir", str(dbg), "--debug-frames", "1"
        )
    )
    assert r.exit_code == 0, r.output
    mosaics = sorted(str(p.relative_to(dbg).parent.parent) for p in dbg.rglob("mosaic.png"))
    assert (
        mosaics
        == {"run": ["."], "dataset": ["curve", "straight"], "ablate": ["paper/curve", "paper/straight"]}[kind]
    )
    assert all(p.parent.name.endswith("1") for p in dbg.rglob("mosaic.png"))  # frame 1 only


class CtrlC:
    """Ctrl-C after the ``n``-th frame the sink wrote (the line written)."""

    def __init__(self, n: int):
        self.n, self.seen = n, 0

    @hookimpl
    def lanegraph_after_node(self, node_id, frame):
        if node_id == "write" and frame is not None:
            self.seen += 1
            if self.seen == self.n:
                os.kill(os.getpid(), signal.SIGINT)


@pytest.mark.parametrize("kind", KINDS)
def test_ctrl_c_keeps_the_finished_runs_and_resume_continues(kind, synthetic_dataset, reference, tmp_path):
    """Interrupted in its second frame of the second sequence (of the one run, for ``run``): what
    ended is kept, and ``--resume`` does only the rest; the lanes equal an uninterrupted run's."""
    out = tmp_path / "out"
    pm = get_plugin_manager()
    plugin = CtrlC(2 if kind == "run" else 5)
    pm.register(plugin, name="ctrl-c")
    try:
        r = lanegraph(command(kind, synthetic_dataset, out, "--frames", FRAMES))
    finally:
        pm.unregister(plugin)
    assert r.exit_code == 130 and "interrupted (Ctrl-C)" in r.output, r.output
    if kind == "run":
        assert '"status": "stopped"' in (out / "run.json").read_text()
        kept = {}
    else:
        done = out if kind == "dataset" else out / "runs" / "paper"
        assert (done / "straight" / "run.json").is_file() and not (done / "curve").exists()
        assert not [p for p in done.glob(".*") if p.is_dir()]  # the interrupted run left nothing
        kept = {p: p.stat().st_mtime_ns for p in (done / "straight").iterdir()}
    r = lanegraph(command(kind, synthetic_dataset, out, "--frames", FRAMES, "--resume"))
    assert r.exit_code == 0, r.output
    assert lanes(kind, out) == expected(kind, reference)
    assert all(p.stat().st_mtime_ns == t for p, t in kept.items())  # the finished run was not run again


def test_resume_is_refused_with_chunks_for_its_one_reason(synthetic_dataset, tmp_path):
    r = lanegraph(command("run", synthetic_dataset, tmp_path / "out", "--resume", "--chunk-frames", "2"))
    assert r.exit_code == 2
    assert (
        "--resume continues a run after its checkpoint; a run in chunks (--chunk-frames) keeps none"
        in r.output
    )
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "args, reason",
    [
        (["--input", "x"], "--input is for a run on one input; --dataset names the inputs"),
        (["--report"], "--report is for a run on one input or an ablation"),
    ],
)
def test_what_a_dataset_run_refuses_it_says_once(args, reason, synthetic_dataset, tmp_path):
    r = lanegraph(command("dataset", synthetic_dataset, tmp_path / "out", *args))
    assert r.exit_code == 2 and reason in r.output, r.output
    assert not (tmp_path / "out").exists()
