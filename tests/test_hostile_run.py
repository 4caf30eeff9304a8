"""The second hostile round (issue 31): runs that nothing can fool.

1. checkpoints checked as a whole: position, frames done, writer state, lanes file; bounded shapes;
2. plugins that raise BaseException (SystemExit, KeyboardInterrupt) at import or in a hook, hooks
   that misbehave: located plugin errors;
3. inputs refused or warned: calibrations, ONNX models, report outputs, ``--scheduler``, ablation
   names, ``extends`` chains, plugins printing at import.

Every case: the documented exit code, no traceback, a message that says where, nothing lost.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

import pytest
from pydantic import Field

from lanegraph import NodeParams, Port, hookimpl, node_type

from . import test_hostile as hostile
from .test_bad_input import DEMO, P2, SMALL, kitti_raw, pair_folder
from .test_hostile import PAPER, SYNTH, _interrupted_run, lines

cli = hostile.cli  # the fixture: ``cli(*args)`` -> (exit code, output)

RESUME = ["--set", "disp.num_disparities=32", "--resume"]


# ============================================================================ 1. checkpoints agree
def _lanes_feedback(ckpt: dict) -> dict:
    """The checkpoint's feedback entry of the lanes (``verify.lanes``; the entries are in node
    order, the road profile's ``road.road`` before it since issue 33)."""
    return next(e for e in ckpt["feedback"] if (e["node"], e["port"]) == ("verify", "lanes"))


def _tamper(ckpt: dict, how: str) -> dict:
    write = ckpt["states"]["write"]
    if how == "writer state of nothing":
        ckpt["states"]["write"] = {"bytes": 0, "sha256": hashlib.sha256(b"").hexdigest()}
    elif how == "writer state of nothing, counted":
        ckpt["states"]["write"] = {
            **write,
            "bytes": 0,
            "sha256": hashlib.sha256(b"").hexdigest(),
            "frames": 0,
        }
    elif how == "writer state of nothing, frames kept":
        ckpt["states"]["write"] = {**write, "bytes": 0, "sha256": hashlib.sha256(b"").hexdigest()}
    elif how == "complete too early":
        ckpt["complete"] = True
    elif how == "frames done without failures":
        ckpt["frames_ok"] = 0
    elif how == "a failure after the position":
        ckpt["failures"] = [
            {"frame": "x", "index": 9, "node": "disp", "type": "disparity.sgbm", "error": "e"}
        ]
    elif how == "a huge shape":
        _lanes_feedback(ckpt)["value"] = {"$t": "ndarray", "dtype": "<f4", "shape": [2**70], "data": ""}
    elif how == "a negative product":
        _lanes_feedback(ckpt)["value"] = {
            "$t": "ndarray",
            "dtype": "<f8",
            "shape": [2**31] * 8,
            "data": "AA==",
        }
    elif how == "a huge feature map":
        empty = {"$t": "ndarray", "dtype": "<i8", "shape": [0], "data": ""}
        fields = [["shape", [2**30, 2**30]], ["rows", empty], ["cols", empty], ["values", None]]
        _lanes_feedback(ckpt)["value"] = {"$t": "port", "type": "features", "v": {"$t": "dict", "v": fields}}
    elif how == "a string where lanes belong":
        _lanes_feedback(ckpt)["value"] = "lanes"
    elif how == "invalid counts":
        ckpt["invalid_outputs"] = {"profile.road": [5, 3]}
    return ckpt


TAMPERED = [
    ("writer state of nothing", ["lanes.jsonl", "expected {bytes, sha256, start, frames}"]),
    (
        "writer state of nothing, counted",
        ["states.write.frames: 0, but frames_ok 2", "does not agree with itself"],
    ),
    (
        "writer state of nothing, frames kept",
        ["lanes.jsonl", "does not agree with itself (2 frame(s) in bytes 0..0)"],
    ),
    ("complete too early", ["complete: true, but position 2 of 4 frame(s)"]),
    ("frames done without failures", ["2 frame(s) not done, but 0 failure(s) recorded"]),
    ("a failure after the position", ["frame index 9 is not before position 2"]),
    ("a huge shape", ["] (verify.lanes)", "shape: expected a list of at most 32 integers"]),
    ("a negative product", ["] (verify.lanes)", "do not make an array of shape"]),
    ("a huge feature map", ["] (verify.lanes)", "expected [rows, cols] of at most"]),
    ("invalid counts", ["invalid_outputs.profile.road", "[5, 3]"]),
    (
        "a string where lanes belong",
        [
            "feedback (verify.lanes) of frame 0000000001: not a value of port type 'lanes' "
            "(expected a list of lanegraph.types.Lane, got str)"
        ],
    ),
]


def test_a_checkpoint_that_does_not_agree_with_itself_is_refused(cli, tmp_path, installed_pm):
    """Issue 31, item 5: a writer state of nothing at position 2 used to cut lanes.jsonl to the
    frames after it (exit 0); ``complete: true`` at 2 of 4 frames said "nothing to resume"; a
    shape of 2**70 gave an OverflowError traceback."""
    out = tmp_path / "out"
    _interrupted_run(cli, out, installed_pm, graph=PAPER)  # the paper graph's feedback edges carry lanes
    lanes, path = out / "lanes.jsonl", out / "checkpoint.json"
    before, good = lanes.read_bytes(), path.read_text()
    assert json.loads(good)["states"]["write"]["frames"] == 2 == len(lines(lanes))
    for how, words in TAMPERED:
        path.write_text(json.dumps(_tamper(json.loads(good), how)))
        code, output = cli("run", PAPER, "--out", out, "--quiet", *SYNTH, *RESUME)
        assert code == 2, (how, output)
        assert "cannot resume" in output, (how, output)
        for w in words:
            assert w in output, (how, output)
        assert lanes.read_bytes() == before, how
    path.write_text(good)  # the checkpoint as the run wrote it still resumes
    code, output = cli("run", PAPER, "--out", out, "--quiet", *SYNTH, *RESUME)
    assert code == 0, output
    assert len(lines(lanes)) == 4


def test_a_lanes_file_with_other_lines_than_frames_done(tmp_path):
    """The writer's own checks: its file must hold one whole line per frame done after ``start``."""
    from lanegraph_io._sinks import WriteLanes, WriteLanesParams

    from lanegraph.errors import InputError
    from lanegraph.nodes import RunContext

    ctx = RunContext(out_dir=tmp_path, extra={"resume": True})
    data = b'{"frame":"0","lanes":[]}\n{"frame":"1","lanes":[]}\n'
    (tmp_path / "lanes.jsonl").write_bytes(data + b'{"frame":"2"')
    state = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest(), "start": 0, "frames": 2}
    w = WriteLanes(WriteLanesParams(), ctx)
    w.restore(state)  # agrees: the torn third line is cut
    w.close()
    assert (tmp_path / "lanes.jsonl").read_bytes() == data
    for bad, words in [
        ({**state, "frames": 0}, "does not agree with itself"),
        ({**state, "frames": 3}, "hold 2 whole line(s), the checkpoint recorded 3"),
        ({**state, "frames": 1}, "hold 2 whole line(s), the checkpoint recorded 1"),
        ({**state, "start": len(data) + 1}, "does not agree with itself"),
        ({**state, "frames": True}, "no valid state"),
    ]:
        with pytest.raises(InputError, match=words.replace("(", r"\(").replace(")", r"\)")):
            WriteLanes(WriteLanesParams(), ctx).restore(bad)


def test_a_feedback_value_of_the_wrong_type_is_refused(tmp_path, installed_pm):
    """A string where lanes belong used to fail frame 3 with an AttributeError."""
    from lanegraph.errors import UsageError
    from lanegraph.graph.validation import load_graph
    from lanegraph.records.resume import check_feedback_types
    from lanegraph.types import Lane

    g = load_graph(PAPER, pm=installed_pm)
    path = tmp_path / "checkpoint.json"
    check_feedback_types(
        {("verify", "lanes"): [Lane(coeffs=(0.0, 0.0, 1.0), bev_rows=(0, 10), side="left", score=1.0)]},
        g,
        path,
        installed_pm.port_types,
    )
    types = installed_pm.port_types  # a node that failed under on_error: empty
    check_feedback_types({("verify", "lanes"): None}, g, path, types)
    for wrong in ("lanes", [1, 2], {"a": 1}):
        with pytest.raises(
            UsageError,
            match=r"feedback \(verify.lanes\) of frame 7: not a value of port type 'lanes' \(expected a list of lanegraph.types.Lane",
        ):
            check_feedback_types({("verify", "lanes"): wrong}, g, path, types, "7")


# ============================================================================ 3. inputs refused
def test_a_scheduler_that_cannot_work_is_refused_at_once(monkeypatch):
    """Issue 31, item 7: ``local:1000`` on a 2-core machine was still starting workers after 120 s;
    ``ftp://x`` waited 30 s before it was refused."""
    pytest.importorskip("distributed", reason='Dask is not installed: pip install -e ".[distributed]"')
    from lanegraph_dask import cluster
    from lanegraph_dask.runner import parse_scheduler

    from lanegraph.errors import UsageError

    monkeypatch.setattr(cluster, "_cores", lambda: 2)
    for text, words in [
        (
            "local:1000",
            "1000 worker processes, but this process may use 2 CPU(s): expected local:N with N <= 2",
        ),
        ("local:3", "expected local:N with N <= 2"),
        ("ftp://x", "unknown scheme 'ftp'"),
        ("FILE:///tmp/s.json", "unknown scheme 'file'"),
    ]:
        with pytest.raises(UsageError, match=words.replace("(", r"\(").replace(")", r"\)")):
            cluster.check_spec(parse_scheduler(text))
        with pytest.raises(UsageError, match=words.replace("(", r"\(").replace(")", r"\)")):
            cluster.connect(parse_scheduler(text), lambda s: None)  # where a cluster starts
    for text in ("local", "local:2", "tcp://127.0.0.1:8786", "127.0.0.1:8786", "tls://h:1", "sched.json"):
        cluster.check_spec(parse_scheduler(text))


@pytest.mark.parametrize(
    "text, words",
    [
        (
            "f: 60\ncx: 32\ncy: 24\nbaseline: 0.5\nf: 600\n",
            ["line 5", "key 'f' is given twice (first at line 1)"],
        ),
        (
            "f: 60\ncx: 32\ncy: 24\nbaseline: 0.5\nbaseline_mm: 500\n",
            ["unknown key 'baseline_mm'", "baseline"],
        ),
        ("f: 60\ncx: 32\ncy: 24\nbaseline: 0.5\nk1: 0.1\n", ["unknown key 'k1'", "known keys: f, fy, cx"]),
    ],
    ids=["duplicate key", "unknown key, near", "unknown key"],
)
def test_a_calib_yaml_with_a_key_twice_or_an_unknown_key(cli, tmp_path, text, words):
    """Issue 31, item 9: the last of two keys used to win silently, unknown keys were ignored."""
    d = pair_folder(tmp_path / "in")
    (d / "calib.yaml").write_text(text)
    code, output = cli("run", DEMO, "--input", d, "--out", tmp_path / "out", "--quiet", *SMALL)
    assert code == 2, output
    assert str(d / "calib.yaml") in output, output
    for w in words:
        assert w in output, output
    assert len(output.strip().splitlines()) == 1, output


@pytest.mark.parametrize(
    "rows, words",
    [
        (
            [f"P_rect_02: {P2}", "P_rect_03: 60 0 32 -30 0 60 24 -18000 0 0 1 0"],
            ["row 'P_rect_03'", "translation ty", "-300 m, more than 10 m"],
        ),
        (
            [f"P_rect_02: {P2}", "P_rect_03: 60 0 32 -30 0 60 24 -6 0 0 1 0"],
            ["rows 'P_rect_02'/'P_rect_03'", "0.1 m apart along y", "differ along x only"],
        ),
    ],
    ids=["ty -300 m", "right camera below the left"],
)
def test_a_kitti_camera_far_from_the_rig_is_refused(cli, tmp_path, rows, words):
    drive = kitti_raw(tmp_path, calib_rows=rows)
    code, output = cli("run", DEMO, "--input", drive, "--out", tmp_path / "out", "--quiet", *SMALL)
    assert code == 2, output
    assert str(drive.parent / "calib_cam_to_cam.txt") in output and "implausible calibration" in output, (
        output
    )
    for w in words:
        assert w in output, output


def test_two_ablation_variants_never_share_a_folder(cli, tmp_path):
    """Issue 31, item 11: two variants of one name shared runs/<variant>/ and gave identical rows."""
    from lanegraph.errors import UsageError
    from lanegraph.evaluation.ablate import Variant, distinct_folders

    a, b, c = tmp_path / "a.yaml", tmp_path / "b.yaml", tmp_path / "c.yaml"
    variants = [Variant("x", a), Variant("x", b), Variant("X", c), Variant("x-2", a, ["n.p=1"])]
    distinct_folders(variants)
    assert [v.name for v in variants] == ["x", "x-2", "X-3", "x-2-2"]
    with pytest.raises(UsageError, match=r"variant 'x' \(.*a.yaml with --set n.p=1\) is given twice"):
        distinct_folders([Variant("x", a, ["n.p=1"]), Variant("x", tmp_path / "." / "a.yaml", ["n.p=1"])])
    d = pair_folder(tmp_path / "in")
    g = tmp_path / "g.yaml"
    g.write_text(f"extends: {DEMO}\nnodes:\n  disp: {{params: {{num_disparities: 16}}}}\n")
    code, output = cli("ablate", g, g, "--input", d, "--out", tmp_path / "out", "--quiet")
    assert code == 2 and "is given twice" in output, output
    assert not (tmp_path / "out" / "runs").exists()


def test_an_over_long_extends_chain_is_reported_as_one(tmp_path, installed_pm):
    """Issue 31, item 11: a chain of 2000 files was "nesting deeper than 32 levels" on an unrelated
    two-line file (the recursion ran out of stack in the YAML parser)."""
    from lanegraph.errors import GraphError
    from lanegraph.graph.model import MAX_EXTENDS
    from lanegraph.graph.validation import load_graph

    def chain(n: int) -> Path:
        (tmp_path / "g0.yaml").write_text(f"extends: {DEMO}\n")
        for i in range(1, n - 1):
            (tmp_path / f"g{i}.yaml").write_text(f"extends: g{i - 1}.yaml\nname: g{i}\n")
        return tmp_path / f"g{n - 2}.yaml"

    top = chain(MAX_EXTENDS)  # 32 files with the demo graph: fine
    assert load_graph(top, pm=installed_pm).nodes
    top = chain(2000)
    with pytest.raises(GraphError) as info:
        load_graph(top, pm=installed_pm)
    text = str(info.value)
    assert f"g1967.yaml: extends: an extends chain of more than {MAX_EXTENDS} files ({top} -> " in text, text
    assert "nesting" not in text and len(text.splitlines()) == 1, text


# ============================================================================ 2. plugins that end things
HOSTILE_PLUGINS = {
    "lg_exit": "import sys\nsys.exit(0)\n",
    "lg_ctrlc": "raise KeyboardInterrupt\n",
    "lg_base": "class Odd(BaseException):\n    pass\n\nraise Odd('from a plugin')\n",
    "lg_printer": (
        "import lanegraph\n"
        "print('hello from a plugin at import')\n\n"
        "class _P(lanegraph.NodeParams):\n    pass\n\n"
        "@lanegraph.node_type('printer.id', inputs={'x': 'number'}, outputs={'y': 'number'})\n"
        "def ident(params: _P, x):\n    '''Passes x on.'''\n    return {'y': x}\n\n"
        "@lanegraph.hookimpl\n"
        "def lanegraph_node_types():\n    print('hello from a registration hook')\n    return [ident]\n"
    ),
    "lg_exit_hook": (
        "import sys\nimport lanegraph\n\n@lanegraph.hookimpl\ndef lanegraph_node_types():\n    sys.exit(3)\n"
    ),
}


@pytest.fixture
def hostile_site(tmp_path, monkeypatch):
    """The installed plugins plus HOSTILE_PLUGINS, each a distribution on a temporary sys.path
    entry, in a fresh process-wide plugin manager."""
    from importlib import metadata

    from lanegraph import plugins

    site = tmp_path / "site"
    site.mkdir()
    for name, code in HOSTILE_PLUGINS.items():
        (site / f"{name}.py").write_text(code)
        dist = site / f"{name}-0.1.dist-info"
        dist.mkdir()
        (dist / "METADATA").write_text(
            f"Metadata-Version: 2.1\nName: {name.replace('_', '-')}\nVersion: 0.1\n"
        )
        (dist / "entry_points.txt").write_text(f"[lanegraph.plugins]\n{name} = {name}\n")
    monkeypatch.syspath_prepend(str(site))
    metadata.distributions  # noqa: B018 - the new path is searched from now on
    monkeypatch.setattr(plugins, "_default", None)
    yield site
    plugins.set_plugin_manager(None)
    for name in HOSTILE_PLUGINS:
        sys.modules.pop(name, None)


def test_a_plugin_that_exits_or_interrupts_at_import_is_unloaded(hostile_site):
    """Issue 31, item 2: a plugin calling sys.exit(0) while being imported made every command exit 0
    having done nothing; a KeyboardInterrupt or another BaseException alike."""
    from lanegraph.plugins import PluginManager

    pm = PluginManager()
    pm.load_entrypoints()
    errors = {e.plugin: str(e) for e in pm.plugin_errors}
    assert set(errors) == {"lg_exit", "lg_ctrlc", "lg_base", "lg_exit_hook"}, errors
    assert "failed to load: SystemExit: it called sys.exit(0)" in errors["lg_exit"]
    assert "failed to load: KeyboardInterrupt" in errors["lg_ctrlc"]
    assert "failed to load: Odd: from a plugin" in errors["lg_base"]
    assert "its lanegraph_node_types hook raised SystemExit: it called sys.exit(3)" in errors["lg_exit_hook"]
    assert all(pm.get_plugin(name) is None for name in errors)
    assert "printer.id" in pm.node_types and "image.gray" in pm.node_types


def test_plugins_printing_never_corrupt_a_commands_json(hostile_site):
    """Issue 31, item 11: a plugin printing at import (or in a registration hook) corrupted
    ``lanegraph schema``'s JSON on stdout; its prints now go to stderr."""
    from click.testing import CliRunner

    from lanegraph.cli import main

    for args in (["schema"], ["nodes", "--json"]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
        data = json.loads(r.stdout)
        assert data
        assert "hello from a plugin at import" in r.stderr and "hello from a registration hook" in r.stderr
        from lanegraph import plugins

        plugins.set_plugin_manager(None)
        sys.modules.pop("lg_printer", None)
    r = CliRunner().invoke(main, ["validate", str(DEMO)])
    assert r.exit_code == 0 and r.output.count("warning: plugin") == 4, r.output


class _Renders:
    """A plugin whose lanegraph_render returns ``what`` (or raises it)."""

    def __init__(self, what):
        self.what = what

    @hookimpl
    def lanegraph_render(self, node_type, port, value):
        if isinstance(self.what, BaseException):
            raise self.what
        return self.what


def test_call_hook_names_the_plugin_and_the_hook(installed_pm):
    """Issue 31, item 4: every way a hook can misbehave is a HookError naming the plugin and the
    hook; the user's own interruption goes through."""
    import numpy as np

    from lanegraph import interrupts
    from lanegraph.errors import HookError
    from lanegraph.plugins import PluginManager, call_hook

    pm = PluginManager()
    img = np.zeros((4, 4, 3), np.uint8)
    pm.register(_Renders(None), name="declines")
    pm.register(_Renders(img), name="draws")
    assert call_hook(pm, "lanegraph_render", node_type="t", port="p", value=1) is img
    assert call_hook(pm, "lanegraph_before_node", node_id="n", node_type="t", frame=None, inputs={}) == []
    for what, words in [
        ("a string", "returned str 'a string', expected an image (an HxW or HxWx3 array) or None"),
        (ValueError("bad value"), "raised ValueError: bad value"),
        (SystemExit(0), "raised SystemExit: it called sys.exit(0)"),
        (GeneratorExit(), "raised GeneratorExit"),
    ]:
        pm.register(_Renders(what), name="bad")  # registered last: called first
        with pytest.raises(HookError) as info:
            call_hook(pm, "lanegraph_render", node_type="t", port="p", value=1)
        assert str(info.value) == f"plugin 'bad': hook lanegraph_render: {words}", str(info.value)
        assert info.value.plugin == "bad" and info.value.hook == "lanegraph_render"
        pm.unregister(name="bad")
    pm.register(_Renders(KeyboardInterrupt()), name="ctrl-c")
    with pytest.raises(KeyboardInterrupt):  # without handlers installed: taken for the user's
        call_hook(pm, "lanegraph_render", node_type="t", port="p", value=1)
    with interrupts.handling():
        with pytest.raises(
            HookError, match="plugin 'ctrl-c': hook lanegraph_render: raised KeyboardInterrupt"
        ):
            call_hook(pm, "lanegraph_render", node_type="t", port="p", value=1)
        pm.unregister(name="ctrl-c")
        pm.register(_Renders(interrupts.Interrupted("SIGTERM")), name="signal")
        with pytest.raises(interrupts.Interrupted):  # a signal's stop is never a plugin's failure
            call_hook(pm, "lanegraph_render", node_type="t", port="p", value=1)
    pm.unregister(name="signal")

    class Wraps:
        @hookimpl(wrapper=True)
        def lanegraph_detect_source(self, path):
            return (yield)

    class Detects:
        @hookimpl
        def lanegraph_detect_source(self, path):
            raise OSError("cannot look")

    pm.register(Detects(), name="detects")
    pm.register(Wraps(), name="wraps")
    with pytest.raises(
        HookError, match="plugin 'detects': hook lanegraph_detect_source: raised OSError: cannot look"
    ):
        call_hook(pm, "lanegraph_detect_source", path=".")


def test_a_misbehaving_render_hook_with_debug_dir_is_located(cli, tmp_path, installed_pm):
    """Issue 31, item 4: lanegraph_render raising, or returning a string, with --debug-dir gave a
    raw traceback."""
    for what, words in [
        ("not an image", "returned str 'not an image', expected an image"),
        (RuntimeError("boom"), "raised RuntimeError: boom"),
    ]:
        installed_pm.register(_Renders(what), name="bad-render")
        try:
            out = tmp_path / f"out-{type(what).__name__}"
            code, output = cli("run", DEMO, "--out", out, "--debug-dir", tmp_path / "dbg", "--quiet", *SYNTH)
        finally:
            installed_pm.unregister(name="bad-render")
        assert code == 1, output
        assert f"plugin 'bad-render': hook lanegraph_render: {words}" in output, output


def test_a_raising_detect_source_hook_is_located(cli, tmp_path, installed_pm):
    class Detects:
        @hookimpl
        def lanegraph_detect_source(self, path):
            sys.exit(0)

    d = pair_folder(tmp_path / "in")
    installed_pm.register(Detects(), name="bad-detect")
    try:
        code, output = cli("run", DEMO, "--input", d, "--out", tmp_path / "out", "--quiet", *SMALL)
    finally:
        installed_pm.unregister(name="bad-detect")
    assert code == 2, output  # found before any frame
    assert (
        "plugin 'bad-detect': hook lanegraph_detect_source: raised SystemExit: it called sys.exit(0)"
        in output
    )


# ============================================================================ 4. one run at a time, whatever happens to the lock file
def test_deleting_the_lock_file_lets_no_second_run_in(cli, tmp_path, installed_pm):
    """Issue 31, item 1: the lock file deleted during a run let a second run into the folder; the
    first then exited 0 with the second one's lines in lanes.jsonl."""
    from click.testing import CliRunner

    from lanegraph.cli import main
    from lanegraph.paths import LOCK_NAME, OutputLock

    out = tmp_path / "out"
    out.mkdir()
    with OutputLock(out, "run"):
        (out / LOCK_NAME).unlink()
        code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
        assert code == 2, output
        assert f"{out}: in use by another lanegraph run (holder unknown: its lock file was removed)" in output
    second: list = []

    class Intruder:
        @hookimpl
        def lanegraph_before_node(self, node_id, frame):
            if node_id == "write" and frame == "0000000002" and not second:
                (out / LOCK_NAME).unlink()
                r = CliRunner().invoke(main, ["run", str(DEMO), "--out", str(out), "--quiet", *SYNTH])
                second.append(r)

    installed_pm.register(Intruder(), name="intruder")
    try:
        code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
    finally:
        installed_pm.unregister(name="intruder")
    assert code == 0, output
    assert second[0].exit_code == 2 and "in use by another lanegraph run" in second[0].output, second[
        0
    ].output
    assert [json.loads(x)["frame"] for x in lines(out / "lanes.jsonl")] == [f"{i:010d}" for i in range(4)]
    assert not (out / LOCK_NAME).exists()  # the refused run created nothing


def test_resource_fork_files_are_not_frames(cli, tmp_path):
    """Issue 31, item 3: an image folder holding macOS ``._*.png`` files failed on its first frame
    (and the process then aborted); they are not images."""
    d = pair_folder(tmp_path / "in", n=3)
    for side in ("left", "right"):
        (d / side / "._000000.png").write_bytes(b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X        ")
    code, output = cli("run", DEMO, "--input", d, "--out", tmp_path / "out", "--quiet", *SMALL)
    assert code == 0, output
    assert [json.loads(x)["frame"] for x in lines(tmp_path / "out" / "lanes.jsonl")] == [
        "000000",
        "000001",
        "000002",
    ]


# ============================================================================ 5. plugins that end a run
class EndsParams(NodeParams):
    frame: str = Field("", description="id of the frame on which to end things (empty: never)")
    how: str = Field(
        "exit", description="exit (sys.exit(0)), ctrl-c (KeyboardInterrupt) or base (a BaseException)"
    )


class _Odd(BaseException):
    pass


@node_type("hostile.ends", inputs={"frame": Port("frame_id")}, outputs={"y": "number"})
def ends(params: EndsParams, frame: str) -> dict:
    """Ends the process on frame ``params.frame``, the way ``params.how`` says."""
    if frame == params.frame:
        if params.how == "exit":
            sys.exit(0)
        if params.how == "ctrl-c":
            raise KeyboardInterrupt
        raise _Odd("a plugin's own BaseException")
    return {"y": 1.0}


class EndsPlugin:
    @staticmethod
    @hookimpl
    def lanegraph_node_types():
        return [ends]


def _ends_graph(tmp_path: Path, how: str, on_error: str = "fail") -> Path:
    g = tmp_path / f"ends_{how}_{on_error}.yaml"
    g.write_text(
        f"extends: {DEMO}\non_error: {on_error}\nnodes:\n"
        f"  boom: {{type: hostile.ends, params: {{frame: '0000000002', how: {how}}}, inputs: {{frame: src.frame}}}}\n"
    )
    return g


@pytest.mark.parametrize(
    "how, words",
    [("exit", "SystemExit: 0"), ("ctrl-c", "KeyboardInterrupt"), ("base", "_Odd: a plugin's own")],
)
def test_a_node_that_exits_is_a_located_failure(cli, tmp_path, installed_pm, how, words):
    """Issue 31, item 2: a node calling sys.exit(0) ended the run with exit 0, no error and no
    run.json. Now: the node's failure, located, recorded, exit 1; under on_error: skip the frame."""
    installed_pm.register(EndsPlugin, name="ends")
    try:
        out = tmp_path / "out"
        code, output = cli("run", _ends_graph(tmp_path, how), "--out", out, "--quiet", *SYNTH)
        assert code == 1, output
        assert f"node 'boom' (hostile.ends) failed on frame 0000000002: {words}" in output, output
        rec = json.loads((out / "run.json").read_text())
        assert rec["status"] == "stopped" and rec["stopped"]["node"] == "boom", rec
        assert rec["stopped"]["frame"] == "0000000002" and (out / "timings.json").is_file()
        assert len(lines(out / "lanes.jsonl")) == 2
        out = tmp_path / "skip"
        code, output = cli("run", _ends_graph(tmp_path, how, "skip"), "--out", out, "--quiet", *SYNTH)
        assert code == 1, output
        rec = json.loads((out / "run.json").read_text())
        assert [(f["frame"], f["node"]) for f in rec["failures"]] == [("0000000002", "boom")], rec
        assert words in rec["failures"][0]["error"] and len(lines(out / "lanes.jsonl")) == 3
    finally:
        installed_pm.unregister(name="ends")


class _HookEnds:
    """A plugin whose hook ``name`` calls sys.exit(0) (on frame 0000000002 for the node hooks)."""

    def __init__(self, name: str):
        self.name = name

    def _maybe(self, name: str, frame=None) -> None:
        if name == self.name and (frame is None or frame == "0000000002"):
            sys.exit(0)

    @hookimpl
    def lanegraph_run_start(self):
        self._maybe("lanegraph_run_start")

    @hookimpl
    def lanegraph_before_node(self, node_id, frame):
        if node_id == "write":
            self._maybe("lanegraph_before_node", frame or "-")

    @hookimpl
    def lanegraph_after_node(self, node_id, frame):
        if node_id == "write":
            self._maybe("lanegraph_after_node", frame or "-")

    @hookimpl
    def lanegraph_run_end(self):
        self._maybe("lanegraph_run_end")


@pytest.mark.parametrize(
    "hook, n_lines",
    [
        ("lanegraph_run_start", 0),
        ("lanegraph_before_node", 2),
        ("lanegraph_after_node", 3),
        ("lanegraph_run_end", 4),
    ],
)
def test_a_hook_that_exits_is_a_located_failure_and_the_record_is_written(
    cli, tmp_path, installed_pm, hook, n_lines
):
    """Issue 31, item 4: a raising lanegraph_run_end gave a traceback after the last frame and no
    run.json nor timings.json; the node hooks raw tracebacks."""
    installed_pm.register(_HookEnds(hook), name="hook-ends")
    try:
        out = tmp_path / "out"
        code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
    finally:
        installed_pm.unregister(name="hook-ends")
    assert code == 1, output
    assert f"plugin 'hook-ends': hook {hook}: raised SystemExit: it called sys.exit(0)" in output, output
    rec = json.loads((out / "run.json").read_text())
    assert rec["status"] == "stopped" and f"hook {hook}" in rec["stopped"]["error"], rec
    assert (out / "timings.json").is_file()
    assert len(lines(out / "lanes.jsonl")) == n_lines


def test_a_lanes_file_replaced_during_the_run_is_said_exit_1(cli, tmp_path, installed_pm):
    """Issue 31, item 1: the run checks at the end that the lanes file on disk is the one it wrote."""
    out = tmp_path / "out"

    class Replaces:
        @hookimpl
        def lanegraph_after_node(self, node_id, frame):
            if node_id == "write" and frame == "0000000001":
                (out / "other.jsonl").write_text('{"frame": "x", "lanes": []}\n')
                os.replace(out / "other.jsonl", out / "lanes.jsonl")

    installed_pm.register(Replaces(), name="replaces")
    try:
        code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
    finally:
        installed_pm.unregister(name="replaces")
    assert code == 1, output
    assert f"{out / 'lanes.jsonl'}: replaced during the run" in output, output
    rec = json.loads((out / "run.json").read_text())
    assert rec["status"] == "stopped" and "replaced during the run" in rec["stopped"]["error"]


def test_no_abort_when_the_first_frame_cannot_be_read(tmp_path):
    """Issue 31, item 3: a truncated first frame wrote the right error and run.json, then the
    process aborted ('terminate called without an active exception', exit 134) while the
    read-ahead thread was still decoding the next frame. Now it is stopped and joined first."""
    import subprocess

    import cv2
    import numpy as np

    d = tmp_path / "in"
    for side in ("left", "right"):
        (d / side).mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(3):
        img = rng.integers(0, 256, (1000, 1500), dtype=np.uint8)
        for side in ("left", "right"):
            cv2.imwrite(str(d / side / f"{i:06d}.png"), img)
    (d / "calib.yaml").write_text("f: 1200\ncx: 750\ncy: 500\nbaseline: 0.5\n")
    first = d / "left" / "000000.png"
    first.write_bytes(first.read_bytes()[:2000])
    for k in range(3):
        r = subprocess.run(
            [
                sys.executable,
                "-m",
                "lanegraph.cli",
                "run",
                str(DEMO),
                "--input",
                str(d),
                "--out",
                str(tmp_path / f"o{k}"),
                "--quiet",
            ],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert r.returncode == 1, (r.returncode, r.stderr)
        assert "terminate called" not in r.stderr and "cannot decode image" in r.stderr, r.stderr
        assert json.loads((tmp_path / f"o{k}" / "run.json").read_text())["status"] == "stopped"


def test_debug_frames_that_match_nothing_are_in_run_json(cli, tmp_path):
    """Issue 31, item 11: the warning was on stderr only; docs/errors.md says run.json holds it."""
    out = tmp_path / "out"
    code, output = cli(
        "run",
        DEMO,
        "--out",
        out,
        "--debug-dir",
        tmp_path / "dbg",
        "--debug-frames",
        "1,77",
        "--quiet",
        *SYNTH,
    )
    assert code == 0, output
    rec = json.loads((out / "run.json").read_text())
    assert any("--debug-frames 77 matched no frame" in w for w in rec["warnings"]), rec["warnings"]


def test_an_empty_out_and_an_unusable_scheduler_are_refused_at_once(cli, tmp_path):
    """Issue 31, items 7 and 9: ``--out ""`` wrote the run files into the current folder;
    ``--scheduler local:1000`` started workers for minutes, ``ftp://x`` waited 30 s."""
    pytest.importorskip("distributed", reason='Dask is not installed: pip install -e ".[distributed]"')
    for args in (["run", DEMO, *SYNTH], ["ablate", DEMO], ["report", tmp_path]):
        code, output = cli(*args, "--out", "")
        assert code == 2 and "expected a folder, got ''" in output, output
    assert not (tmp_path / "lanes.jsonl").exists() and not (tmp_path / "run.json").exists()
    ds = tmp_path / "ds.yaml"
    ds.write_text(f"name: d\nsequences:\n  - {{name: a, input: {pair_folder(tmp_path / 'in')}}}\n")
    for sched, words in (
        ("local:100000", "worker processes, but this process may use"),
        ("ftp://x", "unknown scheme 'ftp'"),
    ):
        code, output = cli(
            "run", DEMO, "--dataset", ds, "--scheduler", sched, "--out", tmp_path / "o", "--quiet"
        )
        assert code == 2 and words in output, output
        assert not (tmp_path / "o").exists()


def test_what_a_graph_carries_from_frame_to_frame(installed_pm):
    """Issue 31, item 10: a chunked run says when the graph's state may outlive the warm-up."""
    from lanegraph.graph.validation import load_graph

    assert load_graph(DEMO, pm=installed_pm).carried_state() is None
    assert "verify.lanes@prev" in load_graph(PAPER, pm=installed_pm).carried_state()


def test_a_plugin_registered_without_a_name_is_named_by_its_class():
    from lanegraph.errors import HookError
    from lanegraph.plugins import PluginManager, call_hook

    pm = PluginManager()
    pm.register(_Renders(ValueError("x")))  # pluggy names it by its id
    with pytest.raises(HookError, match=r"^plugin '_Renders': hook lanegraph_render: raised ValueError: x$"):
        call_hook(pm, "lanegraph_render", node_type="t", port="p", value=1)
