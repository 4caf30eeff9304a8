"""Broken input folders, built at test time: `lanegraph run` must name the file and/or frame and
what was expected, never print a traceback, and exit with

- 2 when the input is unusable before any frame runs (no images, no calibration, a bad frame list),
- 1 when frames fail while running; then lanes.jsonl holds only whole lines, for the frames that
  completed (every other good frame too, with ``on_error: skip``).

Tiny synthetic 64x48 pairs and the engine demo graph (OpenCV SGBM) keep the module fast.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from lanegraph import plugins
from lanegraph.cli import main

DEMO = Path(__file__).resolve().parents[1] / "graphs" / "demo_sgbm.yaml"
W, H = 64, 48
SMALL = ["--set", "disp.num_disparities=16"]  # the demo's 128 px range does not fit a 64 px image
P2 = "60 0 32 0 0 60 24 0 0 0 1 0"
P3 = "60 0 32 -30 0 60 24 0 0 0 1 0"  # baseline 30 / 60 = 0.5 m


def texture(seed: int, h: int = H, w: int = W, colour: bool = True) -> np.ndarray:
    img = np.random.default_rng(seed).integers(0, 256, (h, w), dtype=np.uint8)
    return np.dstack([img] * 3) if colour else img


def pair_folder(root: Path, n: int = 3) -> Path:
    """``io.folder`` layout: left/ and right/ with n pairs, and calib.yaml."""
    for side in ("left", "right"):
        (root / side).mkdir(parents=True)
        for i in range(n):
            cv2.imwrite(str(root / side / f"{i:06d}.png"), texture(i))
    (root / "calib.yaml").write_text("f: 60\ncx: 32\ncy: 24\nbaseline: 0.5\n")
    return root


def kitti_raw(root: Path, n: int = 3, calib_rows: list[str] | None = None) -> Path:
    date = root / "2011_09_26"
    drive = date / "2011_09_26_drive_0001_sync"
    for cam in ("image_02", "image_03"):
        (drive / cam / "data").mkdir(parents=True)
        for i in range(n):
            cv2.imwrite(str(drive / cam / "data" / f"{i:010d}.png"), texture(i))
    rows = (
        calib_rows
        if calib_rows is not None
        else [f"S_rect_02: {W} {H}", f"P_rect_02: {P2}", f"P_rect_03: {P3}"]
    )
    (date / "calib_cam_to_cam.txt").write_text("calib_time: 09-Jan-2012 13:57:47\n" + "\n".join(rows) + "\n")
    return drive


def kitti_odometry(root: Path, n: int = 3, stems: list[str] | None = None) -> Path:
    seq = root / "00"
    for cam in ("image_0", "image_1"):
        (seq / cam).mkdir(parents=True)
        for i, stem in enumerate(stems or [f"{k:06d}" for k in range(n)]):
            cv2.imwrite(str(seq / cam / f"{stem}.png"), texture(i, colour=False))
    (seq / "calib.txt").write_text("\n".join(f"P{k}: {P3 if k % 2 else P2}" for k in range(4)) + "\n")
    return seq


@pytest.fixture
def run(installed_pm, monkeypatch, tmp_path):
    """``run(graph, input, *args)`` -> (exit code, output, out folder) of `lanegraph run`."""
    monkeypatch.setattr(plugins, "_default", installed_pm)
    monkeypatch.chdir(tmp_path)

    calls = iter(range(1000))

    def invoke(graph: Path, input_dir: Path, *args: str):
        out = tmp_path / f"out{next(calls)}"  # one run per output folder
        r = CliRunner().invoke(
            main, ["run", str(graph), "--input", str(input_dir), "--out", str(out), "--quiet", *args]
        )
        assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
        assert "Traceback" not in r.output, r.output
        return r.exit_code, r.output, out

    return invoke


def lanes_frames(out: Path) -> list[str]:
    """The frames of OUT/lanes.jsonl; every line must be a whole JSON record."""
    text = (out / "lanes.jsonl").read_text()
    assert text == "" or text.endswith("\n"), "partial last line"
    return [json.loads(line)["frame"] for line in text.splitlines()]


def skip_graph(tmp_path: Path) -> Path:
    """The demo graph with the error policy ``skip``: a bad frame is dropped, the run goes on."""
    g = tmp_path / "demo_skip.yaml"
    g.write_text(f"extends: {DEMO}\nname: demo_skip\non_error: skip\n")
    return g


def disparity_file_graph(tmp_path: Path, disp_dir: Path, on_error: str = "fail") -> Path:
    """Disparity read from files; the writer does not depend on it, yet must not see a failed frame."""
    g = tmp_path / "dispfile.yaml"
    g.write_text(
        f"""name: dispfile
on_error: {on_error}
nodes:
  src: {{type: io.auto}}
  write: {{type: io.write_lanes, inputs: {{frame: src.frame}}}}   # before disp in the file, not in the run
  disp: {{type: disparity.file, params: {{dir: '{disp_dir}'}}, inputs: {{left: src.left, frame: src.frame}}}}
  vdisp: {{type: road.vdisparity, inputs: {{disparity: disp.disparity}}}}
"""
    )
    return g


def test_good_folder_runs(run, tmp_path):
    code, output, out = run(DEMO, pair_folder(tmp_path / "in"), *SMALL)
    assert code == 0, output
    assert lanes_frames(out) == ["000000", "000001", "000002"]


# ------------------------------------------------------------------ found before any frame runs: exit 2
def _drop_right(d: Path) -> None:
    (d / "right" / "000001.png").unlink()


def _empty(d: Path) -> None:
    for p in [*(d / "left").iterdir(), *(d / "right").iterdir()]:
        p.unlink()


@pytest.mark.parametrize(
    "name, breaker, where, words",
    [
        (
            "missing right image",
            _drop_right,
            "left/000001.png",
            ["frame 000001", "has no right partner", "right"],
        ),
        ("empty folder", _empty, "left", ["no images in the folder", "expected .png"]),
        (
            "no calibration",
            lambda d: (d / "calib.yaml").unlink(),
            "calib.yaml",
            ["calibration file not found", "f, cx, cy, baseline"],
        ),
        (
            "calibration without baseline",
            lambda d: (d / "calib.yaml").write_text("f: 60\ncx: 32\ncy: 24\n"),
            "calib.yaml",
            ["missing key(s) ['baseline']", "baseline in metres"],
        ),
        (
            "calibration not numbers",
            lambda d: (d / "calib.yaml").write_text("f: sixty\ncx: 32\ncy: 24\nbaseline: 0.5\n"),
            "calib.yaml",
            ["must be numbers", "sixty"],
        ),
    ],
)
def test_unusable_pair_folder_exit_2(run, tmp_path, name, breaker, where, words):
    d = pair_folder(tmp_path / "in")
    breaker(d)
    code, output, out = run(DEMO, d, *SMALL)
    assert code == 2, output
    assert str(d / where) in output, output
    for w in words:
        assert w in output, output
    assert not (out / "lanes.jsonl").exists() or lanes_frames(out) == []


@pytest.mark.parametrize(
    "name, rows, words",
    [
        (
            "row missing",
            [f"P_rect_02: {P2}"],
            ["row 'P_rect_03' missing", "3x4 projection matrix, 12 numbers"],
        ),
        (
            "row not numbers",
            [f"P_rect_02: {P2}", "P_rect_03: 60 0 32 minus30 0 60 24 0 0 0 1 0"],
            ["line 3", "row 'P_rect_03'", "non-numeric values", "minus30", "expected 12 numbers"],
        ),
        (
            "row too short",
            [f"P_rect_02: {P2}", "P_rect_03: 60 0 32 -30 0 60 24 0 0 0 1"],
            ["line 3", "row 'P_rect_03' has 11 numbers", "expected 12 numbers"],
        ),
        ("not KEY: values", [f"P_rect_02: {P2}", "P_rect_03 60 0 32"], ["line 3", "expected 'KEY: values'"]),
    ],
)
def test_broken_kitti_raw_calibration_exit_2(run, tmp_path, name, rows, words):
    drive = kitti_raw(tmp_path, calib_rows=rows)
    code, output, _ = run(DEMO, drive, *SMALL)
    assert code == 2, output
    assert str(drive.parent / "calib_cam_to_cam.txt") in output, output
    for w in words:
        assert w in output, output


def test_kitti_odometry_calib_without_the_right_cameras_row(run, tmp_path):
    seq = kitti_odometry(tmp_path)
    (seq / "calib.txt").write_text(f"P0: {P2}\nP2: {P2}\nP3: {P3}\n")  # the grey pair's P1 is missing
    code, output, _ = run(DEMO, seq, *SMALL)
    assert code == 2, output
    assert str(seq / "calib.txt") in output and "row 'P1' missing" in output, output


def test_duplicated_frame_numbers(run, tmp_path):
    # 000010 and 10 sort apart as names but are the same frame number
    seq = kitti_odometry(tmp_path, stems=["000000", "000010", "10"])
    code, output, _ = run(DEMO, seq, *SMALL)
    assert code == 2, output
    assert str(seq / "image_0") in output and "frame 10" in output, output
    assert "frame numbers not increasing: 10 after 10" in output, output


@pytest.mark.parametrize("frames", ["10:20", "5", "-1:0"])
def test_frame_selection_out_of_range(run, tmp_path, frames):
    d = pair_folder(tmp_path / "in")
    code, output, _ = run(DEMO, d, *SMALL, "--frames", frames)
    assert code == 2, output
    assert (
        str(d) in output
        and "select(s) no frame" in output
        and "the input has 3 frame(s), indices 0..2" in output
    ), output


def test_frame_selection_with_step_0_is_a_usage_error(run, tmp_path):
    code, output, _ = run(DEMO, pair_folder(tmp_path / "in"), *SMALL, "--frames", "0:3:0")
    assert code == 2, output
    assert "--frames" in output and "must not be 0" in output, output


def test_missing_input_folder(run, tmp_path):
    code, output, _ = run(DEMO, tmp_path / "nope", *SMALL)
    assert code == 2 and f"--input {tmp_path / 'nope'}: no such file or folder" in output, output


# ------------------------------------------------------------------ frames that fail while running: exit 1
def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:60])


def _wider_than_calibration(d: Path) -> None:
    (d / "calib.yaml").write_text("f: 60\ncx: 32\ncy: 24\nbaseline: 0.5\nwidth: 64\nheight: 48\n")
    for side in ("left", "right"):
        cv2.imwrite(str(d / side / "000001.png"), texture(9, w=80))


@pytest.mark.parametrize(
    "name, breaker, where, words",
    [
        (
            "size mismatch",
            lambda d: cv2.imwrite(str(d / "right" / "000001.png"), texture(9, h=40)),
            "right/000001.png",
            ["left/right size mismatch", "left 64x48, right 64x40"],
        ),
        (
            "truncated png",
            lambda d: _truncate(d / "left" / "000001.png"),
            "left/000001.png",
            ["cannot decode image", "truncated"],
        ),
        (
            "not an image",
            lambda d: (d / "right" / "000001.png").write_text("not a picture\n"),
            "right/000001.png",
            ["cannot decode image", "not an image file"],
        ),
        (
            "image size not the calibration's",
            _wider_than_calibration,
            "left/000001.png",
            ["image is 80x48", "the calibration expects 64x48"],
        ),
    ],
)
def test_bad_frame(run, tmp_path, name, breaker, where, words):
    d = pair_folder(tmp_path / "in")
    breaker(d)
    # on_error fail (the default): the run stops at the bad frame, the frames before it are kept
    code, output, out = run(DEMO, d, *SMALL)
    assert code == 1, output
    assert "node 'src' (io.folder) failed on frame 000001" in output, output
    assert str(d / where) in output, output
    for w in words:
        assert w in output, output
    assert lanes_frames(out) == ["000000"]
    assert json.loads((out / "run.json").read_text())["stopped"]["frame"] == "000001"
    # on_error skip: the bad frame is dropped and reported, every good frame is written
    code, output, out = run(skip_graph(tmp_path), d, *SMALL)
    assert code == 1, output
    assert "1 frame(s) failed" in output and "frame 000001 (#1): node 'src' (io.folder)" in output, output
    assert str(d / where) in output, output
    assert lanes_frames(out) == ["000000", "000002"]
    failures = json.loads((out / "run.json").read_text())["failures"]
    assert [(f["frame"], f["node"]) for f in failures] == [("000001", "src")]


def _disp_png(path: Path, shape: tuple[int, int] = (H, W), dtype=np.uint16) -> None:
    cv2.imwrite(str(path), np.full(shape, 8 * 256 if dtype == np.uint16 else 8, dtype))


@pytest.mark.parametrize(
    "name, bad, words",
    [
        (
            "wrong size",
            lambda p: _disp_png(p, (40, W)),
            ["disparity map is 40x64", "the left image is 48x64", "the same size"],
        ),
        (
            "8-bit",
            lambda p: _disp_png(p, dtype=np.uint8),
            ["expected a 16-bit KITTI disparity PNG", "got dtype uint8"],
        ),
        ("missing", lambda p: p.unlink(), ["no precomputed disparity", "no such file"]),
    ],
)
def test_bad_disparity_file(run, tmp_path, name, bad, words):
    d = pair_folder(tmp_path / "in")
    disp = tmp_path / "disp"
    disp.mkdir()
    for i in range(3):
        _disp_png(disp / f"{i:06d}.png")
    bad(disp / "000001.png")
    code, output, out = run(disparity_file_graph(tmp_path, disp), d)
    assert code == 1, output
    assert "node 'disp' (disparity.file) failed on frame 000001" in output, output
    assert str(disp / "000001.png") in output, output
    for w in words:
        assert w in output, output
    assert lanes_frames(out) == ["000000"]  # frame 000001 never reached the writer
    code, output, out = run(disparity_file_graph(tmp_path, disp, on_error="skip"), d)
    assert code == 1, output
    assert "frame 000001 (#1): node 'disp' (disparity.file)" in output, output
    assert lanes_frames(out) == ["000000", "000002"]
