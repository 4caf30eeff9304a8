"""benchmarks/sweep_kitti.py: the changed drives it writes (on a tiny KITTI raw layout made here)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from lanegraph_io._sources import KittiRawSource

from lanegraph.nodes import RunContext

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))  # as when the script runs: its folder first (benchmarks/_sweep.py)
_spec = importlib.util.spec_from_file_location("sweep_kitti", ROOT / "benchmarks" / "sweep_kitti.py")
sweep_kitti = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sweep_kitti)

# KITTI's colour pair with the principal point moved into the 320 x 60 images of these tests
P2 = "7.215377e+02 0 1.605593e+02 4.485728e+01 0 7.215377e+02 3.02854e+01 2.163791e-01 0 0 1 2.745884e-03"
P3 = "7.215377e+02 0 1.605593e+02 -3.395242e+02 0 7.215377e+02 3.02854e+01 2.199936e+00 0 0 1 2.729905e-03"
W, H, SHIFT = 320, 60, 8


def tiny_drive(tmp_path: Path) -> Path:
    """Two frames of a random texture seen with disparity SHIFT everywhere, and a ground truth."""
    drive = tmp_path / "2011_09_26" / "2011_09_26_drive_0001_sync"
    rng = np.random.default_rng(0)
    gt = []
    for k in range(2):
        tex = cv2.GaussianBlur(rng.integers(0, 256, (H, W + SHIFT)).astype(np.uint8), (0, 0), 1.0)
        left, right = tex[:, :W], tex[:, SHIFT:]  # left(x) = right(x - SHIFT): disparity SHIFT
        for cam, im in (("image_02", left), ("image_03", right)):
            (drive / cam / "data").mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(drive / cam / "data" / f"{k:010d}.png"), np.dstack([im] * 3))
        gt.append(
            {"frame": f"{k:010d}", "image_size": [W, H], "markings": [{"id": 2, "kind": "dashed", "points": [[200.0, 20], [210.0, 40]]}],
             "ego": {"left": 2, "right": None}}
        )
    (drive / "lanes_gt.jsonl").write_text("\n".join(json.dumps(g) for g in gt) + "\n")
    (drive.parent / "calib_cam_to_cam.txt").write_text(f"S_rect_02: {W} {H}\nP_rect_02: {P2}\nP_rect_03: {P3}\n")
    return drive


def calib_of(drive: Path):
    return KittiRawSource.func(KittiRawSource.params(), RunContext(input_path=drive)).constants()["calib"]


@pytest.mark.parametrize(
    "spec, expected",
    [("recorded", ("recorded", None)), ("gain:0.5", ("gain", 0.5)), ("crop:1224x368", ("crop", (1224, 368))), ("step:3", ("step", 3.0)), ("noise:4", ("noise", 4.0))],
)
def test_parse_variant(spec, expected):
    assert sweep_kitti.parse_variant(spec) == expected


@pytest.mark.parametrize("spec, words", [("gain", "gain:NUMBER"), ("step:1.5", "integer"), ("crop:12", "WIDTHxHEIGHT"), ("fog:2", "unknown"), ("mirror:1", "no argument"), ("gain:-1", "positive")])
def test_parse_variant_errors(spec, words):
    with pytest.raises(ValueError, match=words):
        sweep_kitti.parse_variant(spec)


def test_mirror_swaps_the_cameras_and_moves_the_ground_truth(tmp_path):
    drive = tiny_drive(tmp_path)
    out = sweep_kitti.write_variant(drive, tmp_path / "m", "mirror", None)
    old, new = calib_of(drive), calib_of(out)
    assert new.cx == pytest.approx(W - 1 - old.cx, abs=1e-3) and new.cy == pytest.approx(old.cy, abs=1e-3)
    assert new.f == pytest.approx(old.f, rel=1e-6) and new.baseline == pytest.approx(old.baseline, rel=1e-5)
    old_right = cv2.imread(str(drive / "image_03" / "data" / "0000000001.png"))
    np.testing.assert_array_equal(cv2.imread(str(out / "image_02" / "data" / "0000000001.png")), cv2.flip(old_right, 1))
    rec = json.loads((out / "lanes_gt.jsonl").read_text().splitlines()[1])
    # (x, y) of the left image is (x - SHIFT, y) in the right one, mirrored
    np.testing.assert_allclose(rec["markings"][0]["points"], [[W - 1 - (200 - SHIFT), 20], [W - 1 - (210 - SHIFT), 40]], atol=0.6)
    assert rec["ego"] == {"left": None, "right": 2}


def test_gain_and_crop_variants(tmp_path):
    drive = tiny_drive(tmp_path)
    src = cv2.imread(str(drive / "image_03" / "data" / "0000000000.png"))
    dark = sweep_kitti.write_variant(drive, tmp_path / "g", "gain", 0.5)
    np.testing.assert_array_equal(cv2.imread(str(dark / "image_03" / "data" / "0000000000.png")), (src * 0.5).astype(np.uint8))
    crop = sweep_kitti.write_variant(drive, tmp_path / "c", "crop", (300, 50))
    assert cv2.imread(str(crop / "image_02" / "data" / "0000000000.png")).shape == (50, 300, 3)
    c = calib_of(crop)
    assert (c.width, c.height) == (300, 50) and c.cx == pytest.approx(calib_of(drive).cx)
    assert (crop / "lanes_gt.jsonl").read_text() == (drive / "lanes_gt.jsonl").read_text()


def test_a_missing_frame_is_named(tmp_path):
    drive = tiny_drive(tmp_path)
    (drive / "image_03" / "data" / "0000000001.png").unlink()
    with pytest.raises(FileNotFoundError, match="image_03/data/0000000001.png: no readable image"):
        sweep_kitti.write_variant(drive, tmp_path / "g", "gain", 0.5)


def test_unpainted_inpaints_along_the_markings_only(tmp_path):
    drive = tiny_drive(tmp_path)
    left = cv2.imread(str(drive / "image_02" / "data" / "0000000000.png"))
    bright = left.copy()
    cv2.line(bright, (200, 20), (210, 40), (255, 255, 255), 3)  # paint on the annotated polyline
    cv2.imwrite(str(drive / "image_02" / "data" / "0000000000.png"), bright)
    out = sweep_kitti.write_variant(drive, tmp_path / "u", "unpainted", None)
    got = cv2.imread(str(out / "image_02" / "data" / "0000000000.png")).astype(int)
    assert got[30, 205].max() < 230  # the paint is gone
    np.testing.assert_array_equal(got[:, :150], left[:, :150])  # far from the marking: untouched
    rec = json.loads((out / "lanes_gt.jsonl").read_text().splitlines()[0])
    assert rec["markings"] == [] and rec["ego"] == {"left": None, "right": None}
