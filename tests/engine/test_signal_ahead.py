"""Signals always end a run within seconds, whatever a node computed ahead (``ahead=True``, on a
thread: lanegraph.run.ahead) is doing: a node that never returns there is abandoned on its thread,
``run.json`` says so, and the exit code is the signal's (143 for SIGTERM, 130 for Ctrl-C)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

PLUGIN = '''
import os, threading
from lanegraph import NodeParams, hookimpl, node_type

CALLS = {"n": 0}


class P(NodeParams):
    pass


@node_type("hang.match", inputs={"image": "image"}, outputs={"y": "number"}, ahead=True)
def match(params: P, image):
    """Hangs from its second frame on (computed ahead, on a thread), for ever."""
    CALLS["n"] += 1
    if CALLS["n"] >= 2:
        open(os.environ["HANG_MARK"], "w").close()
        threading.Event().wait()
    return {"y": 1.0}


@node_type("hang.tail", inputs={"y": "number"}, outputs={"z": "number"})
def tail(params: P, y):
    return {"z": y}


class Hang:
    @hookimpl
    def lanegraph_node_types(self):
        return [match, tail]
'''

DRIVER = (
    "import sys; sys.path.insert(0, sys.argv.pop(1)); import hangplugin; "
    "from lanegraph.plugins import get_plugin_manager; get_plugin_manager().register(hangplugin.Hang()); "
    "from lanegraph.cli import main; main(prog_name='lanegraph')"
)

GRAPH = {
    "name": "hang",
    "nodes": {
        "src": {"type": "io.synthetic", "params": {"scale": 0.2, "frames": 6}},
        "match": {"type": "hang.match", "inputs": {"image": "src.left"}},
        "tail": {"type": "hang.tail", "inputs": {"y": "match.y"}},
        "write": {"type": "io.write_lanes", "inputs": {"frame": "src.frame"}},
    },
}


@pytest.mark.parametrize(
    ("sig", "code", "label"), [(signal.SIGTERM, 143, "SIGTERM"), (signal.SIGINT, 130, "Ctrl-C")]
)
def test_a_signal_ends_a_run_whose_node_computed_ahead_hangs(tmp_path, sig, code, label):
    (tmp_path / "hangplugin.py").write_text(PLUGIN)
    graph = tmp_path / "hang.yaml"
    graph.write_text(yaml.safe_dump(GRAPH))
    out, mark = tmp_path / "out", tmp_path / "hung"
    env = {**os.environ, "HANG_MARK": str(mark), "LANEGRAPH_OVERLAP": "1"}
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[2]), env.get("PYTHONPATH", "")])
    proc = subprocess.Popen(
        [sys.executable, "-c", DRIVER, str(tmp_path), "run", str(graph), "--out", str(out), "-q"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not mark.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert mark.exists(), proc.communicate(timeout=5)[0] if proc.poll() is not None else "never hung"
        time.sleep(0.3)
        proc.send_signal(sig)
        output, _ = proc.communicate(timeout=30)  # within seconds, not never
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == code, output
    record = json.loads((out / "run.json").read_text())
    assert record["status"] == "stopped" and f"interrupted ({label})" in record["stopped"]["error"]
    assert any("abandoned on their thread" in w and "match" in w for w in record["warnings"]), (
        record["warnings"],
        output,
    )
