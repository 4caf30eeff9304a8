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
from pathlib import Path

import pytest

from . import test_hostile as hostile
from .test_bad_input import DEMO, P2, SMALL, kitti_raw, pair_folder
from .test_hostile import PAPER, SYNTH, _interrupted_run, lines

cli = hostile.cli  # the fixture: ``cli(*args)`` -> (exit code, output)

RESUME = ["--set", "disp.num_disparities=32", "--resume"]


# ============================================================================ 1. checkpoints agree
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
        ckpt["feedback"][0]["value"] = {"$t": "ndarray", "dtype": "<f4", "shape": [2**70], "data": ""}
    elif how == "a negative product":
        ckpt["feedback"][0]["value"] = {"$t": "ndarray", "dtype": "<f8", "shape": [2**31] * 8, "data": "AA=="}
    elif how == "a huge feature map":
        empty = {"$t": "ndarray", "dtype": "<i8", "shape": [0], "data": ""}
        ckpt["feedback"][0]["value"] = {
            "$t": "FeatureMap",
            "shape": [2**30, 2**30],
            "rows": empty,
            "cols": empty,
            "values": None,
        }
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
    ("a huge shape", ["feedback[0] (verify.lanes)", "shape: expected a list of at most 32 integers"]),
    ("a negative product", ["feedback[0] (verify.lanes)", "do not make an array of shape"]),
    ("a huge feature map", ["feedback[0] (verify.lanes)", "expected [rows, cols] of at most"]),
    ("invalid counts", ["invalid_outputs.profile.road", "[5, 3]"]),
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
    from lanegraph.graph import load_graph
    from lanegraph.resume import check_feedback_types
    from lanegraph.types import Lane

    g = load_graph(PAPER, pm=installed_pm)
    path = tmp_path / "checkpoint.json"
    check_feedback_types(
        {("verify", "lanes"): [Lane(coeffs=(0.0, 0.0, 1.0), bev_rows=(0, 10), side="left", score=1.0)]},
        g,
        path,
    )
    check_feedback_types({("verify", "lanes"): None}, g, path)  # a node that failed under on_error: empty
    for wrong in ("lanes", [1, 2], {"a": 1}):
        with pytest.raises(
            UsageError, match=r"feedback \(verify.lanes\): expected a value of port type 'lanes'"
        ):
            check_feedback_types({("verify", "lanes"): wrong}, g, path)


# ============================================================================ 3. inputs refused
def test_a_scheduler_that_cannot_work_is_refused_at_once(monkeypatch):
    """Issue 31, item 7: ``local:1000`` on a 2-core machine was still starting workers after 120 s;
    ``ftp://x`` waited 30 s before it was refused."""
    pytest.importorskip("distributed")
    from lanegraph import distributed
    from lanegraph.batch import parse_scheduler
    from lanegraph.errors import UsageError

    monkeypatch.setattr(distributed, "_cores", lambda: 2)
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
            distributed.check_spec(parse_scheduler(text))
        with pytest.raises(UsageError, match=words.replace("(", r"\(").replace(")", r"\)")):
            distributed.run_tasks([], parse_scheduler(text), progress=False, echo=lambda s: None)
    for text in ("local", "local:2", "tcp://127.0.0.1:8786", "127.0.0.1:8786", "tls://h:1", "sched.json"):
        distributed.check_spec(parse_scheduler(text))


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
    from lanegraph.ablate import Variant, distinct_folders
    from lanegraph.errors import UsageError

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
    from lanegraph.graph import MAX_EXTENDS, load_graph

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
