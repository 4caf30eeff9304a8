"""Calibration files of a user's rig (OpenCV FileStorage, ROS camera_info, calib.yaml, KITTI) and
their rectification (``lanegraph_io._stereo``): read, checked, named when wrong."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from lanegraph_io import Rectifier, read_stereo_calibration
from lanegraph_io._stereo import example_rig, unrectify
from lanegraph_io.recordings import write_camera_info, write_opencv

from lanegraph.errors import InputError
from lanegraph.types import Calibration

RECT = Calibration(f=200.0, cx=159.5, cy=59.5, baseline=0.3, width=320, height=120)


def texture(h=120, w=320, seed=0):
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (h // 4, w // 4, 3), dtype=np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


@pytest.fixture
def rig():
    return example_rig(RECT)


def test_opencv_yaml_with_rectification_gives_the_rectified_calibration(tmp_path, rig):
    write_opencv(rig, tmp_path / "opencv.yaml")
    st = read_stereo_calibration([tmp_path / "opencv.yaml"])
    assert (st.width, st.height) == (320, 120)
    np.testing.assert_allclose(st.K1, rig.K1)
    np.testing.assert_allclose(st.D2, rig.D2)
    np.testing.assert_allclose(st.T, rig.T)
    assert not st.is_rectified()
    c = Rectifier(st.check((320, 120))).calib
    assert (c.f, c.cx, c.cy) == pytest.approx((RECT.f, RECT.cx, RECT.cy))
    assert c.baseline == pytest.approx(RECT.baseline)


def test_opencv_xml_and_stereo_rectify_from_r_t(tmp_path, rig):
    write_opencv(rig, tmp_path / "opencv.xml", rectification=False)
    assert "<opencv_storage>" in (tmp_path / "opencv.xml").read_text()
    st = read_stereo_calibration([tmp_path / "opencv.xml"])
    assert st.P1 is None and st.R is not None
    rect = Rectifier(st.check((320, 120)))
    # stereoRectify chooses its own rectified camera; the baseline is the rig's |T|
    assert rect.calib.baseline == pytest.approx(np.linalg.norm(rig.T), rel=1e-6)
    assert rect.calib.f > 0 and 0 <= rect.calib.cx < 320


def test_ros_camera_info_pair(tmp_path, rig):
    write_camera_info(rig, tmp_path / "left.yaml", tmp_path / "right.yaml")
    st = read_stereo_calibration([tmp_path / "left.yaml", tmp_path / "right.yaml"])
    c = Rectifier(st.check((320, 120))).calib
    assert (c.f, c.baseline) == pytest.approx((RECT.f, RECT.baseline))
    with pytest.raises(InputError, match="left and right swapped"):
        read_stereo_calibration([tmp_path / "right.yaml", tmp_path / "left.yaml"])
    with pytest.raises(InputError, match="describes one camera: give both"):
        read_stereo_calibration([tmp_path / "left.yaml"])


def test_calib_yaml_and_kitti_are_rectified_rigs(tmp_path):
    (tmp_path / "calib.yaml").write_text("f: 200\ncx: 159.5\ncy: 59.5\nbaseline: 0.3\n")
    st = read_stereo_calibration([tmp_path / "calib.yaml"])
    assert st.is_rectified()
    rect = Rectifier(st.check((320, 120)))
    assert rect.identity and rect.calib.baseline == pytest.approx(0.3)
    left = texture()
    a, b = rect(left, left)
    assert a is left and b is left  # a rectified pair passes as it is
    p2 = "200 0 159.5 0 0 200 59.5 0 0 0 1 0"
    p3 = "200 0 159.5 -60 0 200 59.5 0 0 0 1 0"
    (tmp_path / "calib.txt").write_text(f"P0: {p2}\nP1: {p3}\nP2: {p2}\nP3: {p3}\n")
    st = read_stereo_calibration([tmp_path / "calib.txt"])
    assert Rectifier(st.check((320, 120))).calib.baseline == pytest.approx(0.3)


def test_rectifier_undoes_the_rigs_distortion_and_rotation(rig):
    left, right = texture(seed=1), texture(seed=2)
    raw_l, raw_r = unrectify(rig, RECT, left, right)
    assert np.abs(raw_l.astype(int) - left).mean() > 10  # the raw images differ from the rectified ones
    a, b = Rectifier(rig.check((320, 120)))(raw_l, raw_r)
    inner = (slice(15, -15), slice(25, -25))
    assert np.abs(a[inner].astype(int) - left[inner]).mean() < 6
    assert np.abs(b[inner].astype(int) - right[inner]).mean() < 6


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"T": np.zeros(3)}, r"key 'T': the baseline \(\|T\|\) is zero, expected a plausible 0.05-2.0 m"),
        ({"T": np.array([-300.0, 0, 0])}, r"millimetres\? T is in metres: 0.3"),
        (
            {"K1": np.diag([-200.0, 200.0, 1.0])},
            r"key 'K1': focal length fx \(K1\[0,0\]\) must be > 0 pixels, got -200",
        ),
    ],
)
def test_implausible_opencv_calibration_is_named(tmp_path, rig, change, message):
    write_opencv(replace(rig, **change), tmp_path / "bad.yaml", rectification=False)
    st = read_stereo_calibration([tmp_path / "bad.yaml"])
    with pytest.raises(InputError, match=message) as err:
        st.check((320, 120))
    assert str(tmp_path / "bad.yaml") in str(err.value)


def test_a_size_that_disagrees_with_the_frames(tmp_path, rig):
    write_opencv(rig, tmp_path / "opencv.yaml")
    st = read_stereo_calibration([tmp_path / "opencv.yaml"])
    with pytest.raises(
        InputError,
        match=r"keys 'image_width'/'image_height': the calibration is for 320x120 images, the frames are 640x240",
    ):
        st.check((640, 240))
    write_camera_info(rig, tmp_path / "l.yaml", tmp_path / "r.yaml")
    st = read_stereo_calibration([tmp_path / "l.yaml", tmp_path / "r.yaml"])
    with pytest.raises(InputError, match=r"l.yaml: image_width/image_height: the calibration is for 320x120"):
        st.check((640, 240))


def test_bad_files_are_named(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_bytes(b"%YAML:1.0\n" + b"#" * 1_000_001)
    with pytest.raises(InputError, match="not a calibration file"):
        read_stereo_calibration([big])
    missing = tmp_path / "k.yaml"
    fs = cv2.FileStorage(str(missing), cv2.FILE_STORAGE_WRITE)
    fs.write("K1", np.eye(3))
    fs.release()
    with pytest.raises(InputError, match=r"missing key\(s\) \['D1', 'K2', 'D2'\]"):
        read_stereo_calibration([missing])
    info = tmp_path / "fish.yaml"
    info.write_text("image_width: 320\nimage_height: 120\ncamera_matrix: {rows: 3, cols: 3, data: [1,0,0,0,1,0,0,0,1]}\n"
                    "distortion_model: equidistant\n")  # fmt: skip
    with pytest.raises(
        InputError, match=r"fish.yaml: key 'distortion_model': 'equidistant' is not rectified"
    ):
        read_stereo_calibration([info, info])
    with pytest.raises(InputError, match="calibration file not found"):
        read_stereo_calibration([tmp_path / "none.yaml"])


def test_the_read_calibration_hook_reads_opencv_files(tmp_path, rig):
    import lanegraph_io

    write_opencv(rig, tmp_path / "opencv.yaml")
    c = lanegraph_io.lanegraph_read_calibration(Path(tmp_path / "opencv.yaml"))
    assert c.baseline == pytest.approx(RECT.baseline) and c.width == 320


def test_match_stamps_against_a_plain_search():
    from lanegraph_io._streams import match_stamps

    def naive(lefts, rights, tol):
        used, out = set(), []
        for i, s in enumerate(lefts):
            free = [k for k in range(len(rights)) if k not in used and abs(rights[k] - s) <= tol]
            if free:
                best = min(free, key=lambda k: (abs(rights[k] - s), k))
                used.add(best)
                out.append((i, best))
        return out

    rng = np.random.default_rng(3)
    for _ in range(200):
        lefts = np.cumsum(rng.integers(1, 20, rng.integers(0, 30))).tolist()
        rights = sorted(
            set(
                (np.asarray(lefts, int) + rng.integers(-6, 7, len(lefts))).tolist()
                + rng.integers(0, 400, 5).tolist()
            )
        )
        tol = int(rng.integers(0, 8))
        assert match_stamps(lefts, rights, tol) == naive(lefts, rights, tol)
