"""Kill a real run mid-way, resume it: the output equals an uninterrupted run's."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAPER = str(ROOT / "graphs" / "paper.yaml")


def lanegraph(*args, **kw):
    return subprocess.run(
        [sys.executable, "-m", "lanegraph.cli", *args], capture_output=True, text=True, **kw
    )


def test_kill_and_resume_equals_uninterrupted(tmp_path):
    frames = "0:8"
    full = tmp_path / "full"
    r = lanegraph("run", PAPER, "--out", str(full), "--frames", frames, "--quiet")
    assert r.returncode == 0, r.stderr

    part = tmp_path / "part"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lanegraph.cli",
            "run",
            PAPER,
            "--out",
            str(part),
            "--frames",
            frames,
            "--quiet",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    lanes = part / "lanes.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline:
        if lanes.is_file() and lanes.read_text().count("\n") >= 3:
            break
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = lanes.read_text().count("\n")
    assert 3 <= done_before < 8, "the run should have been killed mid-way"
    # simulate a torn write as well: half a line at the end
    with lanes.open("a") as fh:
        fh.write('{"frame": "00000000')

    r = lanegraph("run", PAPER, "--out", str(part), "--frames", frames, "--quiet", "--resume")
    assert r.returncode == 0, r.stderr
    assert "resuming after frame" in r.stderr
    assert lanes.read_text() == (full / "lanes.jsonl").read_text()


def test_resume_without_checkpoint_starts_over(tmp_path):
    r = lanegraph("run", PAPER, "--out", str(tmp_path), "--frames", "0:2", "--quiet", "--resume")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "lanes.jsonl").read_text().count("\n") == 2


# ------------------------------------------------------------------ interrupted again and again
TESTS = Path(__file__).resolve().parent
SMALL = [
    "--set",
    "src.type=io.synthetic",
    "--set",
    "src.scale=0.4",
    "--set",
    "src.frames=9",
    "--set",
    "src.preset=curved",
]


def interrupted_run(out: Path, spec: str | None, *extra: str) -> subprocess.CompletedProcess:
    """`lanegraph run paper.yaml` on a small synthetic sequence, interrupted at ``spec`` (see interrupter.py)."""
    from .interrupter import DRIVER

    env = {**os.environ, "LANEGRAPH_TEST_INTERRUPT": spec or ""}
    args = [
        sys.executable,
        "-c",
        DRIVER,
        str(TESTS),
        "run",
        PAPER,
        "--out",
        str(out),
        "--quiet",
        *SMALL,
        *extra,
    ]
    # the run's own handlers: a test started under nohup would hand SIGHUP down ignored, and lanegraph
    # rightly keeps a signal the user asked to ignore (lanegraph.interrupts)
    return subprocess.run(
        args, capture_output=True, text=True, env=env, timeout=300, preexec_fn=_default_sighup
    )


def _default_sighup() -> None:
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> str:
    out = tmp_path_factory.mktemp("full")
    r = interrupted_run(out, None)
    assert r.returncode == 0, r.stderr
    text = (out / "lanes.jsonl").read_text()
    assert text.count("\n") == 9 and '"points":[[' in text, (
        "the sequence should have lanes to carry from frame to frame"
    )
    return text


POINTS = [("write", "after"), ("write", "before"), ("fit", "before"), ("verify", "after"), ("src", "after")]


@pytest.mark.parametrize("seed", range(3))
def test_interrupted_again_and_again_equals_uninterrupted(tmp_path, uninterrupted, seed):
    """SIGINT and SIGKILL at random nodes and frames, several times in a row, each followed by
    --resume: the final lanes.jsonl is the uninterrupted run's, byte for byte."""
    rng = random.Random(seed)
    out = tmp_path / "out"
    first = True
    stops = []
    for _ in range(rng.randint(2, 3)):
        sig = rng.choice(["INT", "KILL"])
        node, when = rng.choice(POINTS)
        spec = f"{sig}:{node}:{when}:{rng.randint(1, 3)}"
        r = interrupted_run(out, spec, *([] if first else ["--resume"]))
        first = False
        stops.append((spec, r.returncode))
        if r.returncode == 0:  # fewer frames left than the chosen one: the run finished
            break
        assert r.returncode == (130 if sig == "INT" else -signal.SIGKILL), (spec, r.stderr)
        if sig == "INT":
            assert "interrupted (Ctrl-C)" in r.stderr and "Traceback" not in r.stderr, r.stderr
            assert json.loads((out / "run.json").read_text())["status"] == "stopped"
    r = interrupted_run(out, None, "--resume")
    assert r.returncode == 0, (stops, r.stderr)
    assert (out / "lanes.jsonl").read_text() == uninterrupted, stops
    assert json.loads((out / "run.json").read_text())["frames_ok"] == 9
    if seed:
        return
    # resuming a complete run changes nothing
    r = interrupted_run(out, None, "--resume")
    assert r.returncode == 0 and "nothing to resume" in r.stderr, r.stderr
    assert (out / "lanes.jsonl").read_text() == uninterrupted


# ------------------------------------------------------------------ the executor's side, with the toy plugin
def _toy_graph(tmp_path, pm, extra: dict | None = None):
    import yaml

    from lanegraph.graph.validation import load_graph

    from .test_graph import VALID

    data = {**VALID, "nodes": {**VALID["nodes"], **(extra or {})}}
    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump(data))
    return load_graph(p, pm=pm)


def checkpointed(graph, context, pm, path, resume=None):
    """An executor keeping its checkpoint in ``path`` (resuming ``resume``), as ``lanegraph run`` does."""
    from lanegraph.records.checkpointing import Checkpointer
    from lanegraph.run.executor import Executor

    return Executor(
        graph, context, pm, checkpointer=Checkpointer(graph, context, path, resume, port_types=pm.port_types)
    )


def test_a_source_that_cannot_skip_is_read_past_the_frames_done(tmp_path, pm):
    """toy.count ignores context.skip: the executor drops the frames done itself, and the feedback
    value (a running sum) continues where the checkpoint left it."""
    from lanegraph.nodes import RunContext
    from lanegraph.records.resume import load_checkpoint

    from . import toyplugin

    ck = tmp_path / "checkpoint.json"

    from lanegraph import hookimpl

    class Stop:
        @hookimpl
        def lanegraph_before_node(self, node_id, frame):
            if node_id == "sink" and frame == "0002":
                raise KeyboardInterrupt

    pm.register(Stop(), name="stop")
    with pytest.raises(KeyboardInterrupt):
        checkpointed(_toy_graph(tmp_path, pm), RunContext(), pm, ck).run()
    pm.unregister(name="stop")
    assert toyplugin.Collect.out == [("0000", 0.0), ("0001", 2.0)]
    state = load_checkpoint(ck)
    assert state.position == 2 and state.total == 4 and state.feedback[0].value == 2.0
    ex = checkpointed(
        _toy_graph(tmp_path, pm),
        RunContext(skip=state.position, extra={"resume": True}),
        pm,
        ck,
        state,
    )
    res = ex.run()
    assert toyplugin.Collect.out == [("0002", 6.0), ("0003", 12.0)]  # as in the uninterrupted run
    assert res.frames == 4 and res.resumed_frames == 2 and load_checkpoint(ck).complete


def test_a_feedback_value_a_checkpoint_cannot_hold(tmp_path, pm):
    """A plugin's own type on a feedback edge: the run goes on and says that it cannot be resumed;
    --resume then refuses, saying why."""
    from lanegraph import NodeParams, Port, hookimpl, node_type
    from lanegraph.errors import UsageError
    from lanegraph.nodes import RunContext
    from lanegraph.records.resume import load_checkpoint

    class Opaque:
        pass

    @node_type("toy.opaque", inputs={"x": "number", "prev": Port("any", optional=True)}, outputs={"o": "any"})
    def opaque(params: NodeParams, x, prev=None):
        """Wraps x in an object of its own."""
        return {"o": Opaque()}

    class Plugin:
        @staticmethod
        @hookimpl
        def lanegraph_node_types():
            return [opaque]

    pm.register(Plugin, name="opaque")
    ck = tmp_path / "checkpoint.json"
    g = _toy_graph(
        tmp_path, pm, {"op": {"type": "toy.opaque", "inputs": {"x": "src.value", "prev": "op.o@prev"}}}
    )
    res = checkpointed(g, RunContext(), pm, ck).run()
    assert res.frames == 4
    assert any(
        "--resume will not be possible" in w and "Opaque cannot be stored" in w for w in res.warnings()
    )
    state = load_checkpoint(ck)
    assert state.unresumable and state.feedback == []
    g = _toy_graph(
        tmp_path, pm, {"op": {"type": "toy.opaque", "inputs": {"x": "src.value", "prev": "op.o@prev"}}}
    )
    with pytest.raises(UsageError, match="cannot be resumed: a feedback value cannot be stored"):
        checkpointed(g, RunContext(skip=state.position), pm, ck, state)


@pytest.mark.parametrize("sig, code, label", [("TERM", 143, "SIGTERM"), ("HUP", 129, "SIGHUP")])
def test_sigterm_and_sighup_stop_a_run_as_ctrl_c_does(tmp_path, uninterrupted, sig, code, label):
    """Issue 31, item 6: only Ctrl-C wrote run.json's stop; SIGTERM and SIGHUP are handled alike:
    the stop recorded, exit 128 + the signal, the lanes kept, --resume continues."""
    out = tmp_path / "out"
    r = interrupted_run(out, f"{sig}:write:after:3")
    assert r.returncode == code, r.stderr
    assert f"interrupted ({label}); continue with --resume" in r.stderr and "Traceback" not in r.stderr, (
        r.stderr
    )
    rec = json.loads((out / "run.json").read_text())
    assert rec["status"] == "stopped" and f"interrupted ({label})" in rec["stopped"]["error"], rec
    assert (out / "lanes.jsonl").read_text().count("\n") == 3
    r = interrupted_run(out, None, "--resume")
    assert r.returncode == 0, r.stderr
    assert (out / "lanes.jsonl").read_text() == uninterrupted


def test_a_restored_feedback_value_passes_its_registered_port_types_check(tmp_path, pm):
    """The checkpointer checks a feedback value read back from a checkpoint with the ``check`` of
    its port type as the ``lanegraph_port_types`` hook registered it: a plugin's port type's too
    (a sub-type without a check of its own by its parent's), and lanegraph's own as strictly as a
    node's output is checked (a float64 array is no disparity map). A refusal names the file, the
    node, the port and the frame; a check that raises is a refusal too, never a traceback."""
    import json

    import numpy as np

    from lanegraph import NodeParams, Port, PortType, hookimpl, node_type
    from lanegraph.errors import UsageError
    from lanegraph.nodes import RunContext
    from lanegraph.records.resume import load_checkpoint
    from lanegraph.storage import encode_value

    def cloud_check(v):
        ok = isinstance(v, np.ndarray) and v.ndim == 2 and v.shape[1] == 3 and v.dtype == np.float64
        return None if ok else "expected N x 3 float64 points"

    calls = []

    @node_type(
        "toy.grow",
        inputs={
            "x": "number",
            "prev": Port("ground_cloud", optional=True),
            "disp": Port("disparity", optional=True),
        },
        outputs={"cloud": "ground_cloud", "disparity": "disparity"},
    )
    def grow(params: NodeParams, x, prev=None, disp=None):
        """Adds a point to the previous cloud."""
        calls.append(None if prev is None else prev.shape)
        pts = np.zeros((0, 3)) if prev is None else prev
        return {"cloud": np.vstack([pts, [[x, x, x]]]), "disparity": np.zeros((2, 2), np.float32)}

    class Clouds:
        @staticmethod
        @hookimpl
        def lanegraph_port_types():
            return [
                PortType("point_cloud", "N x 3 float64 metres", check=cloud_check),
                PortType("ground_cloud", "points on the road", parent="point_cloud"),
            ]

        @staticmethod
        @hookimpl
        def lanegraph_node_types():
            return [grow]

    pm.register(Clouds, name="clouds")
    ck = tmp_path / "checkpoint.json"
    extra = {
        "grow": {
            "type": "toy.grow",
            "inputs": {"x": "src.value", "prev": "grow.cloud@prev", "disp": "grow.disparity@prev"},
        }
    }
    checkpointed(_toy_graph(tmp_path, pm, extra), RunContext(), pm, ck).run()
    good = json.loads(ck.read_text())
    good.update(position=3, frames_ok=3, last_frame="0002", complete=False)
    good["states"] = {
        k: {**v, "frames": 3} if isinstance(v, dict) and "frames" in v else v
        for k, v in good["states"].items()
    }

    def resume(value, port="cloud"):
        data = json.loads(json.dumps(good))
        data["feedback"] = [{"node": "grow", "port": port, "value": encode_value(value), "key": None}]
        ck.write_text(json.dumps(data))
        state = load_checkpoint(ck)
        return checkpointed(
            _toy_graph(tmp_path, pm, extra),
            RunContext(skip=state.position, extra={"resume": True}),
            pm,
            ck,
            state,
        )

    resume(np.ones((3, 3)))  # a cloud: accepted
    for wrong in (np.ones((3, 2)), np.ones((3, 3), np.float32), [[1.0, 2.0, 3.0]], "points"):
        with pytest.raises(UsageError) as info:
            resume(wrong)
        assert str(info.value).startswith(
            f"{ck}: feedback (grow.cloud) of frame 0002: not a value of port type 'ground_cloud' "
            "(expected N x 3 float64 points); cannot resume"
        ), info.value
    resume(np.ones((2, 2), np.float32), "disparity")
    with pytest.raises(
        UsageError,
        match=r"\(grow.disparity\) of frame 0002: not a value of port type 'disparity' "
        r"\(expected an HxW float32 disparity map, got float64 array of shape \(2, 2\)\)",
    ):
        resume(np.ones((2, 2)), "disparity")  # PORT_VALUE_CHECKS took any 2-D array
    calls.clear()

    def broken(v):
        raise KeyError("x")

    pm.port_types["point_cloud"] = PortType("point_cloud", "N x 3", check=broken)
    with pytest.raises(UsageError, match=r"port type 'point_cloud''s check raised KeyError"):
        resume(np.ones((3, 3)))
    assert calls == []  # no node saw a value
    # a run whose node puts out a value its port type's check refuses says at once that --resume
    # will refuse it (not only when --resume reads it back)
    pm.port_types["point_cloud"] = PortType("point_cloud", "N x 3", check=lambda v: "expected a cloud")
    ck.unlink()
    res = checkpointed(_toy_graph(tmp_path, pm, extra), RunContext(), pm, ck).run()
    said = "frame 0000: feedback (grow.cloud): not a value of port type 'ground_cloud' (expected a cloud)"
    assert res.frames == 4 and f"--resume will not be possible for this run: {said}" in res.warnings()
    assert load_checkpoint(ck).unresumable == said and load_checkpoint(ck).feedback == []
