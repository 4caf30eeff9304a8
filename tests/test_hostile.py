"""The CLI used as a hostile or careless user would (issue 20), by class of defect:

1. a checkpoint is data: nothing in OUT can run code, a malformed checkpoint is refused, located;
2. outputs stay inside --out and --debug-dir (sink paths, symbolic links, frame ids);
3. resumes that are refused (tests/engine/test_resume.py interrupts and resumes again and again);
4. one run at a time in an output folder;
5. calibrations checked before any frame;
6. lane points inside the image when the calibration has no image size;
7. located errors instead of tracebacks (output folders, full disks, symbolic link loops, ablate options);
8. inputs that would take too much memory (param bounds: tests/corpus/graphs);
9. ablate keeps finished work (tests/engine/test_ablate.py has more);
10. eval checks its input files;
11. smaller things (--frames -1, an empty selection, --debug-frames, a source's path, show --format dot).

Every case: the documented exit code, no traceback, the message naming file / node / param / frame,
and nothing already written lost. Inputs are tiny folders made here (64 x 48 pairs) or small
synthetic sequences.
"""

from __future__ import annotations

import errno
import json
import os
import pickle
import shutil
import signal
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from lanegraph import hookimpl, plugins
from lanegraph.cli import main
from lanegraph.paths import OutputLock, inside, relative_output, safe_name

from .test_bad_input import DEMO, P2, P3, SMALL, kitti_odometry, kitti_raw, pair_folder, texture

ROOT = Path(__file__).resolve().parents[1]
PAPER = str(ROOT / "graphs" / "paper.yaml")
SYNTH = ["--set", "src.type=io.synthetic", "--set", "src.scale=0.3", "--set", "src.frames=4"]


@pytest.fixture
def cli(installed_pm, monkeypatch, tmp_path):
    """``cli(*args)`` -> (exit code, output) of the lanegraph command, in tmp_path."""
    monkeypatch.setattr(plugins, "_default", installed_pm)
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("LANEGRAPH_GRAPH_ROOTS", raising=False)

    def invoke(*args: str):
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
        assert "Traceback" not in r.output, r.output
        return r.exit_code, r.output

    return invoke


def lines(path: Path) -> list[str]:
    return path.read_text().splitlines() if path.is_file() else []


# ============================================================================ 1. checkpoints are data
def _interrupted_run(cli, out: Path, installed_pm, at: int = 2, graph: str = DEMO) -> None:
    """A run of ``graph`` on a small synthetic sequence, stopped by Ctrl-C right before frame ``at``
    is written."""

    class CtrlC:
        @hookimpl
        def lanegraph_before_node(self, node_id, frame):
            if node_id == "write" and frame is not None and int(frame) == at:
                os.kill(
                    os.getpid(), signal.SIGINT
                )  # Ctrl-C (a plugin raising KeyboardInterrupt is its own failure)

    installed_pm.register(CtrlC(), name="ctrl-c")
    try:
        code, output = cli("run", graph, "--out", out, "--quiet", *SYNTH, "--set", "disp.num_disparities=32")
    finally:
        installed_pm.unregister(name="ctrl-c")
    assert code == 130 and "interrupted (Ctrl-C)" in output, output


def test_a_crafted_pickle_in_out_never_runs(cli, tmp_path, installed_pm):
    out = tmp_path / "out"
    out.mkdir()
    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    for name in ("checkpoint.pkl", "checkpoint.json"):
        (out / name).write_bytes(pickle.dumps(Evil()))
        code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH, "--resume")
        assert code == 2, output
        assert str(out / name) in output and "cannot resume" in output, output
        assert not marker.exists()
        (out / name).unlink()


@pytest.mark.parametrize(
    "content, words",
    [
        ("[]", ["expected a JSON object", "got list"]),
        ("{}", ["format: expected 'lanegraph-checkpoint'"]),
        ('{"format": "lanegraph-checkpoint", "version": 7}', ["version: expected 3, got 7"]),
        (
            '{"format": "lanegraph-checkpoint", "version": 2}',
            ["version: expected 3, got 2", "version 3 stores values by their port types", "start over"],
        ),
        ("not json at all", ["not a valid JSON checkpoint", "line 1"]),
        ("[" * 100000, ["not a valid JSON checkpoint"]),
        (b"\xff\xfe\x00garbage", ["cannot read the checkpoint"]),
    ],
)
def test_a_malformed_checkpoint_is_refused_and_located(cli, tmp_path, content, words):
    out = tmp_path / "out"
    out.mkdir()
    (out / "lanes.jsonl").write_text('{"frame":"x","lanes":[]}\n')
    path = out / "checkpoint.json"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH, "--resume")
    assert code == 2, output
    assert str(path) in output and "cannot resume" in output, output
    for w in words:
        assert w in output, output
    assert lines(out / "lanes.jsonl") == ['{"frame":"x","lanes":[]}'], "nothing already written is lost"


def _mutate(ckpt: dict, how: str, i: int = 0) -> dict:
    """``ckpt`` broken as ``how`` says; ``i``: the feedback entry that carries lanes."""
    if how == "position":
        ckpt["position"] = -3
    elif how == "missing key":
        del ckpt["states"]
    elif how == "unknown key":
        ckpt["exec"] = "os.system('x')"
    elif how == "unknown value type":
        ckpt["feedback"][i]["value"] = {"$t": "os.system", "v": {}}
    elif how == "object array":
        ckpt["feedback"][i]["value"] = {"$t": "ndarray", "dtype": "|O", "shape": [1], "data": "AA=="}
    elif how == "array of the wrong size":
        ckpt["feedback"][i]["value"] = {
            "$t": "ndarray",
            "dtype": "<f4",
            "shape": [10**6, 10**6],
            "data": "AAAAAA==",
        }
    elif how == "a lane with another field":
        fields = {"$t": "dict", "v": [["coeffs", [1, 2, 3]], ["__class__", "x"]]}
        ckpt["feedback"][i]["value"] = [{"$t": "port", "type": "lanes", "v": fields}]
    elif how == "feedback from another node":
        ckpt["feedback"][i]["node"] = "disp"
    elif how == "failures not a list":
        ckpt["failures"] = {"frame": 1}
    elif how == "position beyond total":
        ckpt["position"] = ckpt["total"] + 5
    return ckpt


@pytest.mark.parametrize(
    "how, words",
    [
        ("position", ["position:", "greater than or equal to 0", "-3"]),
        ("missing key", ["states:", "Field required"]),
        ("unknown key", ["exec:", "Extra inputs are not permitted"]),
        ("unknown value type", ["feedback[0] (verify.lanes)", "unknown value type 'os.system'"]),
        ("object array", ["feedback[0] (verify.lanes)", "dtype '|O'", "only numbers and booleans"]),
        ("array of the wrong size", ["feedback[0] (verify.lanes)", "do not make an array of shape"]),
        ("a lane with another field", ["feedback[0] (verify.lanes)[0]", "a Lane has the fields"]),
        (
            "feedback from another node",
            ["feedback[0]", "no feedback edge of the graph comes from disp.lanes"],
        ),
        ("failures not a list", ["failures:", "valid list"]),
        ("position beyond total", ["do not fit together"]),
    ],
)
def test_a_tampered_checkpoint_is_refused(cli, tmp_path, installed_pm, how, words):
    out = tmp_path / "out"
    _interrupted_run(cli, out, installed_pm, graph=PAPER)  # the paper graph's feedback edges carry lanes
    before = (out / "lanes.jsonl").read_bytes()
    path = out / "checkpoint.json"
    ckpt = json.loads(path.read_text())
    edges = [(f["node"], f["port"]) for f in ckpt["feedback"]]
    assert edges == [("road", "road"), ("verify", "lanes")]  # the disparity's road profile, the lanes
    i = edges.index(("verify", "lanes"))
    words = [w.replace("feedback[0]", f"feedback[{i}]") for w in words]
    path.write_text(json.dumps(_mutate(ckpt, how, i)))
    code, output = cli(
        "run", PAPER, "--out", out, "--quiet", *SYNTH, "--set", "disp.num_disparities=32", "--resume"
    )
    assert code == 2, output
    assert str(path) in output, output
    for w in words:
        assert w in output, output
    assert (out / "lanes.jsonl").read_bytes() == before


def test_torn_and_changed_lanes_files(cli, tmp_path, installed_pm):
    """A torn line after the frames done is cut; a line of the frames done that changed is refused."""
    args = ["run", DEMO, "--quiet", *SYNTH, "--set", "disp.num_disparities=32"]
    full = tmp_path / "full"
    assert cli(*args, "--out", full)[0] == 0
    out = tmp_path / "out"
    _interrupted_run(cli, out, installed_pm)
    lanes = out / "lanes.jsonl"
    done = lanes.read_text()
    lanes.write_text(done + "[1, 2]\n" + '{"frame": "00')  # garbage after the frames the checkpoint has done
    code, output = cli(*args, "--out", out, "--resume")
    assert code == 0, output
    assert lanes.read_text() == (full / "lanes.jsonl").read_text()

    _interrupted_run(cli, out, installed_pm)
    lanes.write_text("[1, 2]\n" + lanes.read_text()[7:])  # a line of a frame done, replaced
    changed = lanes.read_text()
    code, output = cli(*args, "--out", out, "--resume")
    assert code == 2 and str(lanes) in output and "not those the checkpoint recorded" in output, output
    assert lanes.read_text() == changed


def test_checkpoint_values_round_trip_exactly():
    from lanegraph.port_types import PORT_TYPES
    from lanegraph.records.resume import CheckpointValueError
    from lanegraph.storage import decode_value as _decode
    from lanegraph.storage import encode_value as _encode
    from lanegraph.types import BevGeometry, FeatureMap, Lane, Line, RoadModel

    def encode_value(v, where="value"):  # what a checkpoint stores: lanegraph's port types registered
        return _encode(v, where, PORT_TYPES)

    def decode_value(d, where="value"):
        return _decode(d, where, PORT_TYPES)

    lane = Lane(
        (np.float64(1.5), 2.0, -3e-7),
        (3, 90),
        "left",
        np.float32(0.25),
        np.arange(8, dtype=np.float32).reshape(4, 2),
        {"k": [1, None]},
    )
    values = [
        [lane, Line(1.0, 2.0, 3.0, "right")],
        RoadModel(1.0, 2.0, 0.5, valid=False, profile=np.array([-1, 3], np.int16)),
        BevGeometry(-10.0, 10.0, 5.0, 45.0, 0.05, np.eye(3)),
        {1: (float("nan"), float("-inf")), "a": np.bool_(True)},
        np.zeros((2, 3), np.uint8),
    ]
    for v in values:
        back = decode_value(json.loads(json.dumps(encode_value(v))))
        assert repr(back) == repr(v)
    back = decode_value(encode_value([lane]))[0]
    assert (
        type(back.coeffs[0]) is np.float64
        and back.points.dtype == np.float32
        and type(back.score) is np.float32
    )
    fm = FeatureMap.from_points((4, 5), np.array([0, 3]), np.array([1, 4]), np.array([0.5, 1.0], np.float32))
    fm2 = decode_value(encode_value(fm))
    assert np.array_equal(fm2.mask, fm.mask) and np.array_equal(fm2.orientation, fm.orientation)
    with pytest.raises(CheckpointValueError, match="cannot be stored"):
        encode_value(object())
    with pytest.raises(CheckpointValueError, match="dtype"):
        encode_value(np.array([object()]))


# ============================================================================ 2. outputs stay inside their folders
def test_path_helpers():
    for bad in ("../x", "/etc/x", "a/../../b", "a\\b", "", "C:/x", "a\x00b", ".", "./"):
        with pytest.raises(ValueError):
            relative_output(bad)
    assert relative_output("./a//b/./c.jsonl") == "a/b/c.jsonl"
    assert [safe_name(x) for x in ("..", ".", "", "a/b", ".hidden", "0000000001", "x" * 300)] == [
        "_..",
        "_.",
        "_",
        "a_b",
        "_.hidden",
        "0000000001",
        "x" * 200,
    ]
    # longer than 200 characters and hidden: prefixed, then cut (it was 201 characters)
    assert safe_name("." + "x" * 300) == "_." + "x" * 198


def test_a_symbolic_link_out_of_out_is_refused(cli, tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    (out / "lanes.jsonl").symlink_to(elsewhere / "stolen.jsonl")
    code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
    assert code == 2, output  # a link is never lanegraph's (issue 46): refused before any check of the sink
    assert "lanes.jsonl is there and not lanegraph's" in output, output
    assert list(elsewhere.iterdir()) == [] and (out / "lanes.jsonl").is_symlink()
    with pytest.raises(Exception, match="outside"):
        inside(out, "lanes.jsonl", "x")


def test_links_planted_in_out_are_never_written_through(cli, tmp_path):
    """Links at the names a run writes (its own files, a sink's, a picture's) point elsewhere: the
    run replaces the link, the file it pointed to is untouched."""
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    hard = tmp_path / "hard.txt"
    hard.write_text("precious too\n")
    out, dbg = tmp_path / "out", tmp_path / "dbg"
    (out / "overlay").mkdir(parents=True)
    (dbg / "0000000001").mkdir(parents=True)
    for name in ("run.json", "timings.json", "checkpoint.json", "overlay/0000000000.png"):
        (out / name).symlink_to(victim)
    (dbg / "0000000001" / "mosaic.png").symlink_to(victim)
    os.link(hard, out / "lanes.jsonl")  # a hard link: truncating the file would change hard.txt
    graph = tmp_path / "overlay.yaml"
    graph.write_text(
        f"extends: {DEMO}\nnodes:\n  overlay: {{type: io.write_overlay, inputs: {{frame: src.frame, image: src.left}}}}\n"
    )
    args = ["run", graph, "--out", out, "--debug-dir", dbg, "--debug-frames", "1", "--quiet", *SYNTH]
    code, output = cli(*args)
    # links and a hard link at the names it writes are not lanegraph's (issue 46): refused, kept
    assert code == 2 and "is there and not lanegraph's" in output, output
    assert victim.read_text() == "precious\n" and hard.read_text() == "precious too\n"
    assert all((out / n).is_symlink() for n in ("run.json", "timings.json", "checkpoint.json"))
    for name in ("run.json", "timings.json", "checkpoint.json", "lanes.jsonl"):
        (out / name).unlink()
    code, output = cli(*args)  # a link in OUT's overlay folder and in --debug-dir: replaced
    assert code == 2 and "overlay is there and not lanegraph's" in output, output
    shutil.rmtree(out / "overlay")
    os.link(hard, out / "overlay.png")  # beside the run's files: left alone
    code, output = cli(*args)
    assert code == 0, output
    assert victim.read_text() == "precious\n" and hard.read_text() == "precious too\n"
    assert (
        not (out / "run.json").is_symlink() and json.loads((out / "run.json").read_text())["frames_ok"] == 4
    )
    assert cv2.imread(str(out / "overlay" / "0000000000.png")) is not None
    assert len(lines(out / "lanes.jsonl")) == 4
    assert not (dbg / "0000000001" / "mosaic.png").is_symlink()
    # a link at the lock's name: refused, not truncated
    (out / ".lanegraph.lock").unlink(missing_ok=True)
    (out / ".lanegraph.lock").symlink_to(victim)
    code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
    assert code == 2 and "cannot create the lock file" in output, output
    assert victim.read_text() == "precious\n"


def test_frame_ids_never_climb_out_of_the_debug_dir_or_the_overlay_folder(cli, tmp_path):
    """A frame file named '...png' has the stem '..'."""
    d = pair_folder(tmp_path / "in", n=1)
    for side in ("left", "right"):
        shutil.copy(d / side / "000000.png", d / side / "...png")
    graph = tmp_path / "overlay.yaml"
    graph.write_text(
        f"extends: {DEMO}\nnodes:\n  overlay: {{type: io.write_overlay, inputs: {{frame: src.frame, image: src.left}}}}\n"
    )
    dbg = tmp_path / "nest" / "dbg"
    code, output = cli(
        "run", graph, "--input", d, "--out", tmp_path / "nest" / "out", "--debug-dir", dbg, "--quiet", *SMALL
    )
    assert code == 0, output
    assert sorted(p.name for p in (tmp_path / "nest").iterdir()) == ["dbg", "out"]
    assert (dbg / "_.." / "mosaic.png").is_file() and (dbg / "000000" / "mosaic.png").is_file()
    assert sorted(p.name for p in (tmp_path / "nest" / "out" / "overlay").iterdir()) == [
        "000000.png",
        "_...png",
    ]


# ============================================================================ 3. resumes that are refused
@pytest.mark.parametrize(
    "change, words",
    [
        (
            ["--set", "disp.block_size=7"],
            ["another graph or params", "disp.params.block_size: 5 in the checkpoint, 7 now"],
        ),
        (["--frames", "0:3"], ["--frames differs", "(all)", "0:3"]),
        (
            ["--set", "src.frames=5"],
            ["another graph or params", "src.params.frames: 4 in the checkpoint, 5 now"],
        ),
    ],
)
def test_resume_with_other_params_or_frames_is_refused(cli, tmp_path, installed_pm, change, words):
    out = tmp_path / "out"
    _interrupted_run(cli, out, installed_pm)
    before = (out / "lanes.jsonl").read_bytes()
    code, output = cli(
        "run", DEMO, "--out", out, "--quiet", *SYNTH, "--set", "disp.num_disparities=32", *change, "--resume"
    )
    assert code == 2, output
    for w in [str(out / "checkpoint.json"), "cannot resume", *words]:
        assert w in output, output
    assert (out / "lanes.jsonl").read_bytes() == before


def test_resume_with_another_input_or_deleted_lanes_is_refused(cli, tmp_path, installed_pm):
    d = pair_folder(tmp_path / "in", n=4)
    args = ["run", DEMO, "--out", tmp_path / "out", "--quiet", *SMALL]

    class CtrlC:
        @hookimpl
        def lanegraph_after_node(self, node_id, frame):
            if node_id == "write" and frame == "000001":
                os.kill(
                    os.getpid(), signal.SIGINT
                )  # Ctrl-C (a plugin raising KeyboardInterrupt is its own failure)

    installed_pm.register(CtrlC(), name="ctrl-c")
    try:
        assert cli(*args, "--input", d)[0] == 130
    finally:
        installed_pm.unregister(name="ctrl-c")
    lanes = tmp_path / "out" / "lanes.jsonl"
    assert len(lines(lanes)) == 2
    # no --input: the synthetic scene's frames must not be appended to the folder's
    code, output = cli(*args, "--resume")
    assert code == 2 and "--input differs" in output and "(none: the synthetic scene)" in output, output
    other = pair_folder(tmp_path / "other", n=4)
    code, output = cli(*args, "--input", other, "--resume")
    assert code == 2 and "--input differs" in output and str(other.resolve()) in output, output
    # the same folder, a changed file
    cv2.imwrite(str(d / "left" / "000003.png"), texture(42))
    code, output = cli(*args, "--input", d, "--resume")
    assert code == 2 and "the input files changed since the checkpoint" in output, output
    assert len(lines(lanes)) == 2


def test_a_deleted_lanes_file_is_refused(cli, tmp_path, installed_pm):
    out = tmp_path / "out"
    _interrupted_run(cli, out, installed_pm)
    (out / "lanes.jsonl").unlink()
    code, output = cli(
        "run", DEMO, "--out", out, "--quiet", *SYNTH, "--set", "disp.num_disparities=32", "--resume"
    )
    assert code == 2, output
    assert str(out / "lanes.jsonl") in output and "missing: the checkpoint recorded" in output, output
    assert not (out / "lanes.jsonl").exists()


def test_a_complete_run_whose_lanes_were_deleted(cli, tmp_path):
    out = tmp_path / "out"
    assert cli("run", DEMO, "--out", out, "--quiet", *SYNTH)[0] == 0
    (out / "lanes.jsonl").unlink()
    code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH, "--resume")
    assert code == 2 and "missing: the checkpoint recorded" in output, output
    (out / "checkpoint.json").unlink()
    (out / "checkpoint.json").mkdir()
    code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
    assert code == 2 and "checkpoint.json is there and not lanegraph's" in output, output


def test_failures_accumulate_over_resumes(cli, tmp_path, installed_pm):
    """on_error skip, a bad frame, an interruption after it: the resumed run reports it and exits 1."""
    d = pair_folder(tmp_path / "in", n=5)
    (d / "left" / "000001.png").write_bytes(b"\x89PNG truncated")
    graph = tmp_path / "skip.yaml"
    graph.write_text(f"extends: {DEMO}\non_error: skip\n")
    args = ["run", graph, "--input", d, "--quiet", *SMALL]
    code, output = cli(*args, "--out", tmp_path / "full")
    assert code == 1, output
    full = json.loads((tmp_path / "full" / "run.json").read_text())

    class CtrlC:
        @hookimpl
        def lanegraph_after_node(self, node_id, frame):
            if node_id == "write" and frame == "000003":
                os.kill(
                    os.getpid(), signal.SIGINT
                )  # Ctrl-C (a plugin raising KeyboardInterrupt is its own failure)

    installed_pm.register(CtrlC(), name="ctrl-c")
    try:
        assert cli(*args, "--out", tmp_path / "out")[0] == 130
    finally:
        installed_pm.unregister(name="ctrl-c")
    code, output = cli(*args, "--out", tmp_path / "out", "--resume")
    assert code == 1, output
    assert "frame 000001 (#1): node 'src' (io.folder)" in output, output
    rec = json.loads((tmp_path / "out" / "run.json").read_text())
    assert rec["failures"] == full["failures"] and len(rec["failures"]) == 1
    assert rec["frames_ok"] == full["frames_ok"] == 4 and rec["resumed_frames"] == 2
    assert (tmp_path / "out" / "lanes.jsonl").read_text() == (tmp_path / "full" / "lanes.jsonl").read_text()
    # a complete run resumed again: nothing appended, the same exit code as the run
    code, output = cli(*args, "--out", tmp_path / "out", "--resume")
    assert code == 1 and "nothing to resume" in output, output
    assert (tmp_path / "out" / "lanes.jsonl").read_text() == (tmp_path / "full" / "lanes.jsonl").read_text()


# ============================================================================ 4. one run at a time
def test_a_second_run_into_a_locked_out_is_refused(cli, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "lanes.jsonl").write_text("the other run's\n")
    with OutputLock(out, "run"):
        code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
        assert code == 2, output
        assert f"{out}: in use by another lanegraph run (pid {os.getpid()}" in output, output
        code, output = cli("ablate", DEMO, "--out", out, "--quiet", "--no-cache")
        assert code == 2 and "in use by another lanegraph run" in output, output
    assert (out / "lanes.jsonl").read_text() == "the other run's\n"
    (out / "lanes.jsonl").unlink()  # not lanegraph's by its record: a run would refuse it
    code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)  # released: runs
    assert code == 0, output


def test_two_processes_into_one_out(cli, tmp_path):
    """A real second process while the first one writes: refused with the first one's pid; the
    first one's lines are its own."""
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-m",
        "lanegraph.cli",
        "run",
        DEMO,
        "--out",
        str(out),
        "--quiet",
        *SYNTH[:4],
        "--set",
        "src.frames=40",
    ]
    first = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 120
        while time.time() < deadline and not (out / "lanes.jsonl").is_file():
            time.sleep(0.05)
        code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
    finally:
        _, err = first.communicate(timeout=300)
    assert first.returncode == 0, err
    assert code == 2 and f"in use by another lanegraph run (pid {first.pid}" in output, output
    assert [json.loads(x)["frame"] for x in lines(out / "lanes.jsonl")] == [f"{i:010d}" for i in range(40)]


def test_the_summary_names_the_files_the_sinks_wrote(cli, tmp_path):
    code, output = cli(
        "run", DEMO, "--out", tmp_path / "out", "--quiet", *SYNTH, "--set", "write.filename=sub/my.jsonl"
    )
    assert code == 0, output
    assert f"-> {tmp_path / 'out' / 'sub' / 'my.jsonl'}, {tmp_path / 'out' / 'timings.json'}" in output, (
        output
    )
    assert (
        not (tmp_path / "out" / "lanes.jsonl").exists()
        and len(lines(tmp_path / "out" / "sub" / "my.jsonl")) == 4
    )


# ============================================================================ 5. calibrations
NAN_P2 = P2.replace("60 0 32", "nan 0 32", 1)


@pytest.mark.parametrize(
    "rows, words",
    [
        (
            [f"P_rect_02: {NAN_P2}", f"P_rect_03: {P3}"],
            ["line 2", "row 'P_rect_02'", "non-finite value (nan)"],
        ),
        (
            [f"P_rect_02: {P2}", "P_rect_03: 60 0 32 -inf 0 60 24 0 0 0 1 0"],
            ["row 'P_rect_03'", "non-finite value (-inf)"],
        ),
        (
            [f"P_rect_02: {P2}", "P_rect_03: 60 0 32 -31962 0 60 24 0 0 0 1 0"],
            ["baseline 532.7 m", "millimetres", "0.5327"],
        ),
        (
            [f"P_rect_02: {P2}", "P_rect_03: 61 0 32 -30 0 61 24 0 0 0 1 0"],
            ["rows 'P_rect_02' and 'P_rect_03' are not a rectified pair", "fx"],
        ),
        (
            ["P_rect_02: 60 0 3200 0 0 60 24 0 0 0 1 0", "P_rect_03: 60 0 3200 -30 0 60 24 0 0 0 1 0"],
            ["row 'P_rect_02' (cx, P[0,2])", "principal point x 3200", "outside the 64x48 image"],
        ),
        (
            [f"P_rect_02: {P2}", f"P_rect_03: {P3}", f"P_rect_02: {P2}"],
            ["line 4", "row 'P_rect_02' appears twice", "first at line 2"],
        ),
        (
            [f"P_rect_02: {P2}", "P_rect_03: 60 0 32 -0.6 0 60 24 0 0 0 1 0"],
            ["baseline 0.01 m is outside the plausible 0.05-2.0 m"],
        ),
    ],
    ids=[
        "nan f",
        "inf baseline",
        "baseline in mm",
        "not rectified",
        "principal point outside",
        "duplicate row",
        "baseline tiny",
    ],
)
def test_implausible_kitti_raw_calibration(cli, tmp_path, rows, words):
    drive = kitti_raw(tmp_path, calib_rows=rows)
    code, output = cli("run", DEMO, "--input", drive, "--out", tmp_path / "out", "--quiet", *SMALL)
    assert code == 2, output
    assert str(drive.parent / "calib_cam_to_cam.txt") in output, output
    for w in words:
        assert w in output, output
    assert lines(tmp_path / "out" / "lanes.jsonl") == []


@pytest.mark.parametrize(
    "rows, words",
    [
        (
            ["S_rect_02: 640 480", f"P_rect_02: {P2}", f"P_rect_03: {P3}"],
            ["row 'S_rect_02'", "the calibration is for 640x480 images, the frames are 64x48"],
        ),
        (
            ["P_rect_02: 60 3 32 0 0 60 24 0 0 0 1 0", "P_rect_03: 60 3 32 -30 0 60 24 0 0 0 1 0"],
            ["row 'P_rect_02' is not a rectified projection matrix"],
        ),
        (
            [f"P_rect_02: {P2}", "P_rect_03: 120 0 64 -60 0 120 48 0 0 0 2 0"],
            ["row 'P_rect_03' is not a rectified projection matrix"],
        ),
        (["S_rect_02: 64.5 48", f"P_rect_02: {P2}", f"P_rect_03: {P3}"], ["row 'S_rect_02'", "two integers"]),
    ],
    ids=["size not the frames'", "skew", "scaled matrix", "fractional size"],
)
def test_calibration_forms(cli, tmp_path, rows, words):
    drive = kitti_raw(tmp_path, calib_rows=rows)
    code, output = cli("run", DEMO, "--input", drive, "--out", tmp_path / "out", "--quiet", *SMALL)
    assert code == 2, output
    assert str(drive.parent / "calib_cam_to_cam.txt") in output, output
    for w in words:
        assert w in output, output


def test_a_huge_calibration_file_is_not_read(cli, tmp_path):
    d = pair_folder(tmp_path / "in")
    (d / "calib.yaml").write_text("f: 60\ncx: 32\ncy: 24\nbaseline: 0.5\n" + "#" * 2_000_000 + "\n")
    code, output = cli("run", DEMO, "--input", d, "--out", tmp_path / "out", "--quiet", *SMALL)
    assert code == 2 and str(d / "calib.yaml") in output and "not a calibration file" in output, output


def test_the_user_widens_the_baseline_range(cli, tmp_path):
    drive = kitti_raw(
        tmp_path, calib_rows=[f"P_rect_02: {P2}", "P_rect_03: 60 0 32 -31962 0 60 24 0 0 0 1 0"]
    )
    widen = ["--set", "src.type=io.kitti_raw", "--set", "src.max_baseline_m=1000"]
    code, output = cli("run", DEMO, "--input", drive, "--out", tmp_path / "out", "--quiet", *SMALL, *widen)
    assert code == 0, output


@pytest.mark.parametrize(
    "text, words",
    [
        ("f: .nan\ncx: 32\ncy: 24\nbaseline: 0.5\n", ["key 'f'", "finite number"]),
        ("f: 60\ncx: 32\ncy: 24\nbaseline: .inf\n", ["key 'baseline'", "finite number"]),
        ("f: 60\ncx: 32\ncy: 24\nbaseline: 532.7\n", ["key 'baseline'", "millimetres"]),
        ("f: 60\ncx: 32\ncy: -500\nbaseline: 0.5\n", ["key 'cy'", "principal point y -500", "64x48"]),
        ("f: 60\ncx: 32\ncy: 24\nbaseline: 0.5\nwidth: 64\n", ["'width', 'height'", "give both or neither"]),
        ("f: 60\ncx: 32\ncy: 24\nbaseline: true\n", ["key 'baseline'", "must be numbers"]),
        ("f: 60\ncx: 32\ncy: 24\nbaseline: 0.5\nfy: 1000\n", ["key 'fy'", "not within 4x"]),
    ],
)
def test_implausible_calib_yaml(cli, tmp_path, text, words):
    d = pair_folder(tmp_path / "in")
    (d / "calib.yaml").write_text(text)
    code, output = cli("run", DEMO, "--input", d, "--out", tmp_path / "out", "--quiet", *SMALL)
    assert code == 2, output
    assert str(d / "calib.yaml") in output, output
    for w in words:
        assert w in output, output


def test_odometry_nan_row(cli, tmp_path):
    seq = kitti_odometry(tmp_path)
    (seq / "calib.txt").write_text(f"P0: {P2}\nP1: 60 0 32 nan 0 60 24 0 0 0 1 0\n")
    code, output = cli("run", DEMO, "--input", seq, "--out", tmp_path / "out", "--quiet", *SMALL)
    assert (
        code == 2 and str(seq / "calib.txt") in output and "row 'P1'" in output and "non-finite" in output
    ), output


def test_left_and_right_swapped(cli, tmp_path):
    from lanegraph_synthetic import KITTI_CALIB, preset, write_sequence

    seq = write_sequence(preset("straight", calib=KITTI_CALIB.scaled(0.4)), tmp_path / "seq", 2)
    code, output = cli(
        "run", DEMO, "--input", seq, "--out", tmp_path / "ok", "--quiet", "--set", "disp.num_disparities=48"
    )
    assert code == 0, output
    (seq / "left").rename(seq / "tmp")
    (seq / "right").rename(seq / "left")
    (seq / "tmp").rename(seq / "right")
    code, output = cli(
        "run", DEMO, "--input", seq, "--out", tmp_path / "out", "--quiet", "--set", "disp.num_disparities=48"
    )
    assert code == 2, output
    assert (
        str(seq / "left") in output
        and "left and right images look swapped" in output
        and "frame 0000000000" in output
    ), output
    off = ["--set", "src.type=io.folder", "--set", "src.check_order=false"]
    code, output = cli(
        "run",
        DEMO,
        "--input",
        seq,
        "--out",
        tmp_path / "out",
        "--quiet",
        "--set",
        "disp.num_disparities=48",
        *off,
    )
    assert code == 0, output


def test_a_road_profile_invalid_on_every_frame_is_a_warning(cli, tmp_path):
    d = pair_folder(tmp_path / "in")  # identical left and right textures: disparity 0, no road
    code, output = cli(
        "run", PAPER, "--input", d, "--out", tmp_path / "out", "--quiet", "--set", "disp.num_disparities=16"
    )
    assert code == 0, output
    assert (
        "warning: node 'road' (road.profile): output 'road' was invalid on every frame (3 of 3)" in output
    ), output
    rec = json.loads((tmp_path / "out" / "run.json").read_text())
    assert any("invalid on every frame" in w for w in rec["warnings"])


# ============================================================================ 6. lanes inside the image
def test_image_size_from_the_frames(tmp_path):
    from lanegraph_io._sources import FolderParams, FolderSource, KittiOdometryParams, KittiOdometrySource

    from lanegraph.nodes import RunContext

    seq = kitti_odometry(tmp_path)
    src = KittiOdometrySource(KittiOdometryParams(), RunContext(input_path=seq))
    assert (src.constants()["calib"].width, src.constants()["calib"].height) == (64, 48)
    d = pair_folder(tmp_path / "in")
    cv2.imwrite(str(d / "left" / "000001.png"), texture(5, h=40))
    cv2.imwrite(str(d / "right" / "000001.png"), texture(5, h=40))
    src = FolderSource(FolderParams(), RunContext(input_path=d))
    items = list(src)
    assert "image is 64x40, the calibration expects 64x48" in str(items[1]) and items[2]["frame"] == "000002"


def test_lanes_stay_inside_an_image_whose_size_the_calibration_does_not_give(cli, tmp_path):
    import yaml
    from lanegraph_synthetic import KITTI_CALIB, preset, write_sequence

    seq = write_sequence(preset("curved", calib=KITTI_CALIB.scaled(0.5)), tmp_path / "seq", 3)
    cal = yaml.safe_load((seq / "calib.yaml").read_text())
    w, h = cal.pop("width"), cal.pop("height")
    (seq / "calib.yaml").write_text(yaml.safe_dump(cal))
    code, output = cli("run", PAPER, "--input", seq, "--out", tmp_path / "out", "--quiet")
    assert code == 0, output
    pts = [
        p
        for line in lines(tmp_path / "out" / "lanes.jsonl")
        for ln in json.loads(line)["lanes"]
        for p in ln["points"]
    ]
    assert pts, "the scene has lanes"
    assert all(0 <= x <= w - 1 and 0 <= y <= h - 1 for x, y in pts), max(y for _, y in pts)


def test_real_odometry_lanes_inside_the_image(cli, kitti_odometry_seq2):
    code, output = cli(
        "run", PAPER, "--input", kitti_odometry_seq2, "--out", "out", "--quiet", "--frames", "0:4"
    )
    assert code == 0, output
    img = cv2.imread(str(sorted((kitti_odometry_seq2 / "image_0").iterdir())[0]), cv2.IMREAD_GRAYSCALE)
    pts = [
        p
        for line in lines(Path("out") / "lanes.jsonl")
        for ln in json.loads(line)["lanes"]
        for p in ln["points"]
    ]
    assert pts and max(y for _, y in pts) <= img.shape[0] - 1 and max(x for x, _ in pts) <= img.shape[1] - 1


@pytest.fixture
def kitti_odometry_seq2() -> Path:
    from .conftest import SHARED

    seq = SHARED / "kitti_odometry" / "seq2"
    if not (seq / "image_0").is_dir():
        pytest.skip(f"real KITTI odometry data not found at {seq} (a fresh clone has no ../shared/data)")
    return seq


# ============================================================================ 7. located errors, not tracebacks
def test_out_and_debug_dir_that_cannot_be_folders(cli, tmp_path):
    f = tmp_path / "afile"
    f.write_text("keep me\n")
    for opt, path, words in [
        ("--out", f, "exists and is not a folder"),
        ("--out", f / "sub", f"{f} is a file, not a folder"),
        ("--debug-dir", f, "exists and is not a folder"),
    ]:
        extra = ["--out", tmp_path / "o"] if opt == "--debug-dir" else []
        code, output = cli("run", DEMO, opt, path, *extra, "--quiet", *SYNTH)
        assert code == 2 and f"{opt} {path}" in output and words in output, output
    assert f.read_text() == "keep me\n"


def test_a_read_only_out(cli, tmp_path, monkeypatch):
    def refuse(self, *a, **k):
        raise OSError(errno.EROFS, "Read-only file system", str(self))

    monkeypatch.setattr(Path, "mkdir", refuse)
    code, output = cli("run", DEMO, "--out", tmp_path / "ro", "--quiet", *SYNTH)
    assert code == 2 and f"--out {tmp_path / 'ro'}: cannot write there: Read-only file system" in output, (
        output
    )


def test_a_full_disk_during_the_run(cli, tmp_path, monkeypatch):
    from lanegraph_io import _sinks

    writer = _sinks.WriteLanes  # the node type's class
    real = writer.__call__
    calls = {"n": 0}

    def full(self, frame, lanes=None):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, frame, lanes)

    monkeypatch.setattr(writer, "__call__", full)
    out = tmp_path / "out"
    code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
    assert code == 1, output
    assert (
        "node 'write' (io.write_lanes) failed on frame 0000000002" in output
        and "No space left on device" in output
    ), output
    assert len(lines(out / "lanes.jsonl")) == 2
    rec = json.loads((out / "run.json").read_text())
    assert rec["status"] == "stopped" and rec["stopped"]["frame"] == "0000000002"
    # and when run.json cannot be written either: said so, exit 1, the lines written kept
    from lanegraph import paths

    def no_space(path, text):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(paths, "write_text_atomic", no_space)
    calls["n"] = 0
    code, output = cli("run", DEMO, "--out", out, "--quiet", "--overwrite", *SYNTH)
    assert code == 1 and f"cannot write {out}/run.json and timings.json: No space left on device" in output, (
        output
    )
    assert len(lines(out / "lanes.jsonl")) == 2


def test_a_checkpoint_that_cannot_be_written(cli, tmp_path, monkeypatch):
    from lanegraph.records import checkpointing as executor

    calls = {"n": 0}
    real = executor.save_checkpoint

    def full(path, data):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, data)

    monkeypatch.setattr(executor, "save_checkpoint", full)
    out = tmp_path / "out"
    code, output = cli("run", DEMO, "--out", out, "--quiet", *SYNTH)
    assert code == 1 and f"{out / 'checkpoint.json'}: No space left on device" in output, output
    assert json.loads((out / "run.json").read_text())["status"] == "stopped"


def test_symbolic_link_loops(cli, tmp_path, monkeypatch):
    (tmp_path / "loop1").symlink_to(tmp_path / "loop2")
    (tmp_path / "loop2").symlink_to(tmp_path / "loop1")
    code, output = cli("validate", tmp_path / "loop1")
    assert code == 2 and f"cannot resolve '{tmp_path / 'loop1'}'" in output, output
    child = tmp_path / "child.yaml"
    child.write_text("extends: loop1\n")
    code, output = cli("validate", child)
    assert code == 2 and "child.yaml: extends: invalid path 'loop1'" in output, output
    monkeypatch.setenv("LANEGRAPH_GRAPH_ROOTS", str(tmp_path / "loop1"))
    code, output = cli("validate", PAPER)
    assert code == 2 and f"LANEGRAPH_GRAPH_ROOTS: {tmp_path / 'loop1'}" in output, output
    monkeypatch.delenv("LANEGRAPH_GRAPH_ROOTS")
    code, output = cli("run", DEMO, "--out", tmp_path / "loop1", "--quiet", *SYNTH)
    assert code == 2 and "--out" in output and "leads nowhere" in output, output


@pytest.mark.parametrize(
    "args, words",
    [
        (["--cache-max-gb", "nan"], ["--cache-max-gb", "expected a size in GiB > 0", "nan"]),
        (["--cache-max-gb", "-1"], ["--cache-max-gb", "-1"]),
        (["--cache-dir", "FILE"], ["--cache-dir", "exists and is not a folder"]),
    ],
)
def test_ablate_options_checked_before_anything_runs(cli, tmp_path, args, words):
    (tmp_path / "FILE").write_text("x")
    args = [str(tmp_path / "FILE") if a == "FILE" else a for a in args]
    code, output = cli("ablate", DEMO, "--out", tmp_path / "abl", "--quiet", *args)
    assert code == 2, output
    for w in words:
        assert w in output, output
    assert not (tmp_path / "abl" / "runs").exists()


# ============================================================================ 8. an image above the size limit
def test_an_image_above_max_megapixels_fails_its_frame_before_it_is_decoded(cli, tmp_path):
    d = pair_folder(tmp_path / "in")
    # a PNG whose header claims 100000 x 100000 pixels (40 GB decoded) and holds almost nothing
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    bomb = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 100000, 100000, 8, 0, 0, 0, 0))
    bomb += chunk(b"IDAT", zlib.compress(b"\0" * 1000)) + chunk(b"IEND", b"")
    (d / "left" / "000001.png").write_bytes(bomb)
    graph = tmp_path / "skip.yaml"
    graph.write_text(f"extends: {DEMO}\non_error: skip\n")
    code, output = cli("run", graph, "--input", d, "--out", tmp_path / "out", "--quiet", *SMALL)
    assert code == 1, output
    assert (
        "frame 000001 (#1): node 'src' (io.folder)" in output
        and "100000x100000 (10000.0 Mpx), above the source's max_megapixels 8" in output
    ), output
    assert [json.loads(x)["frame"] for x in lines(tmp_path / "out" / "lanes.jsonl")] == ["000000", "000002"]


# ============================================================================ 9. ablate keeps finished work
def test_ablate_a_failing_variant_gets_its_row(cli, tmp_path):
    import csv

    d = pair_folder(tmp_path / "in", n=3)
    gt = tmp_path / "gt.jsonl"
    gt.write_text(
        "".join(
            json.dumps({"frame": f"{i:06d}", "markings": [], "ego": {"left": None, "right": None}}) + "\n"
            for i in range(3)
        )
    )
    disp = tmp_path / "disp"
    disp.mkdir()
    cv2.imwrite(
        str(disp / "000000.png"), np.full((48, 64), 8 * 256, np.uint16)
    )  # 000001 missing: that frame fails
    failing = tmp_path / "failing.yaml"
    failing.write_text(
        f"extends: {DEMO}\nnodes:\n  disp: {{type: disparity.file, params: {{dir: '{disp}'}}, inputs: {{left: blur.image, frame: src.frame}}}}\n"
    )
    small = tmp_path / "small.yaml"
    small.write_text(f"extends: {DEMO}\nnodes:\n  disp: {{params: {{num_disparities: 16}}}}\n")
    out = tmp_path / "abl"
    code, output = cli(
        "ablate", small, failing, "--input", d, "--gt", gt, "--out", out, "--quiet", "--no-cache"
    )
    assert code == 1, output
    assert "error: run failing / in failed: node 'disp' (disparity.file) failed on frame 000001" in output, (
        output
    )
    rows = {(r["variant"], r["sequence"]): r for r in csv.DictReader((out / "results.csv").open())}
    assert rows[("small", "in")]["detection_ratio"] == "1.0" and rows[("small", "in")]["error"] == ""
    assert (
        rows[("failing", "in")]["detection_ratio"] == ""
        and "frame 000001" in rows[("failing", "in")]["error"]
    )
    assert rows[("failing", "all")]["error"] == "failed on sequence(s) in"
    assert (
        "- failing / in: node 'disp' (disparity.file) failed on frame 000001"
        in (out / "results.md").read_text()
    )
    assert json.loads((out / "runs" / "failing" / "in" / "run.json").read_text())["status"] == "stopped"
    assert [json.loads(x)["frame"] for x in lines(out / "runs" / "failing" / "in" / "lanes.jsonl")] == [
        "000000"
    ]


def test_ablate_interrupted_keeps_the_finished_variants(cli, tmp_path, installed_pm):
    d = pair_folder(tmp_path / "in", n=2)
    second = tmp_path / "second.yaml"
    second.write_text(f"extends: {DEMO}\nnodes:\n  disp: {{params: {{num_disparities: 32}}}}\n")
    first = tmp_path / "first.yaml"
    first.write_text(f"extends: {DEMO}\nnodes:\n  disp: {{params: {{num_disparities: 16}}}}\n")

    class CtrlC:
        @hookimpl
        def lanegraph_before_node(self, node_id, node_type, frame):
            if node_type == "disparity.sgbm" and frame == "000001" and CtrlC.armed:
                os.kill(
                    os.getpid(), signal.SIGINT
                )  # Ctrl-C (a plugin raising KeyboardInterrupt is its own failure)

    CtrlC.armed = False
    runs = {"n": 0}

    class Arm:
        @hookimpl
        def lanegraph_run_start(self):
            runs["n"] += 1
            CtrlC.armed = runs["n"] == 2

    installed_pm.register(CtrlC(), name="ctrl-c")
    installed_pm.register(Arm(), name="arm")
    try:
        code, output = cli(
            "ablate", first, second, "--input", d, "--out", tmp_path / "abl", "--quiet", "--no-cache"
        )
    finally:
        installed_pm.unregister(name="ctrl-c")
        installed_pm.unregister(name="arm")
    assert code == 130 and "interrupted (Ctrl-C)" in output, output
    md = (tmp_path / "abl" / "results.md").read_text()
    assert "| first |" in md and "| second |" not in md
    assert len(lines(tmp_path / "abl" / "runs" / "first" / "in" / "lanes.jsonl")) == 2


def test_ablate_a_malformed_gt_is_found_before_any_run(cli, tmp_path):
    d = pair_folder(tmp_path / "in", n=2)
    gt = tmp_path / "gt.jsonl"
    gt.write_text('{"frame": "000000", "markings": "x"}\n')
    code, output = cli(
        "ablate", DEMO, "--input", d, "--gt", gt, "--out", tmp_path / "abl", "--quiet", "--no-cache"
    )
    assert code == 2 and f"{gt}: line 1: 'markings' must be a list" in output, output
    assert not (tmp_path / "abl" / "runs").exists()


# ============================================================================ 10. eval checks its input
GT_LINE = {
    "frame": "f0",
    "markings": [{"id": 1, "points": [[100, 300], [110, 290], [120, 280]]}],
    "ego": {"left": 1, "right": None},
}
PRED_LINE = {"frame": "f0", "lanes": [{"points": [[101, 300], [121, 280]]}]}


@pytest.mark.parametrize(
    "pred, gt, where, words",
    [
        ([GT_LINE], [PRED_LINE], "PRED", ["line 1", "no 'lanes' key", "PRED and GT swapped?"]),
        (
            [{"frame": "f0", "lanes": [{"points": [[1, 2, 3], [4, 5, 6]]}]}],
            [GT_LINE],
            "PRED",
            ["line 1", "lanes[0]: points[0]", "[x, y]"],
        ),
        ([PRED_LINE, PRED_LINE], [GT_LINE], "PRED", ["line 2", "frame 'f0' appears twice (first at line 1)"]),
        ([{"frame": "f0", "lanes": "none"}], [GT_LINE], "PRED", ["line 1", "'lanes' must be a list"]),
        ([PRED_LINE], [{**GT_LINE, "ego": "left"}], "GT", ["line 1", "'ego' must be an object"]),
        ([PRED_LINE], [{**GT_LINE, "markings": "x"}], "GT", ["line 1", "'markings' must be a list"]),
        (
            [PRED_LINE],
            [{**GT_LINE, "ego": {"left": 7, "right": None}}],
            "GT",
            ["line 1", "ego.left: 7 is not the id of a marking"],
        ),
        ([PRED_LINE], [GT_LINE, GT_LINE], "GT", ["line 2", "appears twice"]),
        (
            [{"frame": "f0", "lanes": [{"points": [[float("nan"), 1]]}]}],
            [GT_LINE],
            "PRED",
            ["line 1", "two finite numbers"],
        ),
        ([{"frame": True, "lanes": []}], [GT_LINE], "PRED", ["line 1", "'frame' must be a frame id"]),
        ([{**PRED_LINE, "frame": "0000000007"}], [GT_LINE], "PRED", ["no frame of", "different sequences?"]),
    ],
    ids=[
        "swapped",
        "three coordinates",
        "duplicate frame",
        "lanes none",
        "ego left",
        "markings x",
        "ego unknown id",
        "gt duplicate",
        "nan point",
        "frame bool",
        "no common frame",
    ],
)
def test_eval_checks_both_files(cli, tmp_path, pred, gt, where, words):
    p, g = tmp_path / "p.jsonl", tmp_path / "gt.jsonl"
    p.write_text("".join(json.dumps(x) + "\n" for x in pred))
    g.write_text("".join(json.dumps(x) + "\n" for x in gt))
    code, output = cli("eval", p, g)
    assert code == 2, output
    assert str(p if where == "PRED" else g) in output, output
    for w in words:
        assert w in output, output


# ============================================================================ 11. smaller things
def test_frames_minus_one_is_the_last_frame(cli, tmp_path):
    d = pair_folder(tmp_path / "in", n=4)
    for sel, expect in (("-1", ["000003"]), ("-2", ["000002"]), ("-2:", ["000002", "000003"])):
        out = tmp_path / f"out{sel}"  # one run per output folder
        code, output = cli("run", DEMO, "--input", d, "--out", out, "--quiet", *SMALL, "--frames", sel)
        assert code == 0, output
        assert [json.loads(x)["frame"] for x in lines(out / "lanes.jsonl")] == expect


@pytest.mark.parametrize("sel", ["10:20", "7", "-9"])
def test_an_empty_selection_of_the_synthetic_source(cli, tmp_path, sel):
    code, output = cli("run", DEMO, "--out", tmp_path / "out", "--quiet", *SYNTH, "--frames", sel)
    assert code == 2 and "select(s) no frame: the input has 4 frame(s), indices 0..3" in output, output


def test_debug_frames_that_match_nothing_are_named(cli, tmp_path):
    code, output = cli(
        "run",
        DEMO,
        "--out",
        tmp_path / "out",
        "--debug-dir",
        tmp_path / "dbg",
        "--debug-frames",
        "1,77,x",
        "--quiet",
        *SYNTH,
    )
    assert code == 0, output
    assert "warning: --debug-frames 77, x matched no frame of the run" in output, output
    assert (tmp_path / "dbg" / "0000000001" / "mosaic.png").is_file()


def test_a_source_path_and_another_input(cli, tmp_path):
    a, b = pair_folder(tmp_path / "a"), pair_folder(tmp_path / "b")
    graph = tmp_path / "g.yaml"
    graph.write_text(f"extends: {DEMO}\nnodes:\n  src: {{type: io.folder, params: {{path: '{a}'}}}}\n")
    code, output = cli("run", graph, "--input", b, "--out", tmp_path / "out", "--quiet", *SMALL)
    assert code == 2, output
    assert f"node 'src' params.path '{a}' and --input '{b}' both name the input" in output, output
    assert (
        cli("run", graph, "--input", a, "--out", tmp_path / "out", "--quiet", *SMALL)[0] == 0
    )  # the same folder: fine


def test_show_dot_escapes_names(cli, tmp_path):
    g = tmp_path / "q.yaml"
    g.write_text(
        'name: "say \\"hi\\" \\\\ there\\nnext"\nnodes:\n  src: {type: io.auto}\n  end: {type: io.write_lanes, inputs: {frame: src.frame}}\n'
    )
    code, output = cli("show", g, "--format", "dot")
    assert code == 0, output
    assert output.splitlines()[0] == 'digraph "say \\"hi\\" \\\\ there\\nnext" {', output
    code, output = cli("show", g, "--format", "mermaid")
    assert code == 0 and "n_end_1[" in output and "  end[" not in output, output


def test_ctrl_c_leaves_a_run_json(cli, tmp_path, installed_pm):
    out = tmp_path / "out"
    _interrupted_run(cli, out, installed_pm)  # Ctrl-C right before frame 2 is written
    rec = json.loads((out / "run.json").read_text())
    assert (
        rec["status"] == "stopped"
        and "interrupted (Ctrl-C)" in rec["stopped"]["error"]
        and rec["frames_ok"] == 2
    )
    assert len(lines(out / "lanes.jsonl")) == 2
