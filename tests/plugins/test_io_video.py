"""``io.video``: side-by-side and two-file stereo videos written by the tests; seeking; the bad
videos the issue lists (odd width, variable frame rate, a corrupt packet)."""

from __future__ import annotations

from fractions import Fraction

import cv2
import numpy as np
import pytest

av = pytest.importorskip("av", reason='the io extra is not installed: pip install -e ".[io]"')

from lanegraph_io import detect_source  # noqa: E402
from lanegraph_io._video import VideoSource  # noqa: E402
from lanegraph_io.recordings import write_video  # noqa: E402

from lanegraph.errors import InputError  # noqa: E402
from lanegraph.nodes import RunContext, node_type_of  # noqa: E402


def texture(seed, h=120, w=320):
    rng = np.random.default_rng(seed)
    return cv2.resize(
        rng.integers(0, 255, (h // 4, w // 4, 3), dtype=np.uint8), (w, h), interpolation=cv2.INTER_CUBIC
    )


def pairs(n=6):
    return [(texture(k), np.roll(texture(k), -8, axis=1)) for k in range(n)]


@pytest.fixture
def calib(tmp_path):
    (tmp_path / "calib.yaml").write_text("f: 200\ncx: 159.5\ncy: 59.5\nbaseline: 0.3\n")
    return str(tmp_path / "calib.yaml")


def open_video(path, calib, frames=None, skip=0, **params):
    return VideoSource(
        node_type_of(VideoSource).params(calib=calib, **params),
        RunContext(input_path=path, frames=frames, skip=skip),
    )


def test_side_by_side_lossless_video_gives_the_pairs(tmp_path, calib):
    data = pairs()
    video = write_video(tmp_path / "stereo.mkv", data, codec="ffv1")
    assert detect_source(video) == "io.video"
    src = open_video(video, calib)
    got = list(src)
    assert [g["frame"] for g in got] == [f"{k:010d}" for k in range(6)]
    for g, (left, right) in zip(got, data):
        np.testing.assert_array_equal(g["left"], left)
        np.testing.assert_array_equal(g["right"], right)
    assert src.constants()["calib"].baseline == pytest.approx(0.3)


def test_frames_seek_and_a_resumed_run_continues_by_frame_index(tmp_path, calib):
    data = pairs(8)
    # H.264, a key frame every 3 frames: a seek lands on frame 3 and decodes 4 before the first wanted
    video = write_video(tmp_path / "stereo.mp4", data, options={"crf": "12", "g": "3", "bf": "2"})
    c = av.open(str(video))
    keys = [p.is_keyframe for p in c.demux(c.streams.video[0]) if p.size]
    c.close()
    assert keys.count(True) >= 2
    whole = list(open_video(video, calib))
    src = open_video(video, calib, frames=slice(3, 8), skip=2)
    part = list(src)
    assert [g["frame"] for g in part] == ["0000000005", "0000000006", "0000000007"]
    for g, w in zip(part, whole[5:]):
        np.testing.assert_array_equal(g["left"], w["left"])
    assert np.abs(whole[4]["left"].astype(int) - data[4][0]).mean() < 6  # crf 12: close to the input


def test_two_files_paired_by_timestamp(tmp_path, calib):
    data = pairs(4)
    folder = tmp_path / "rig"
    folder.mkdir()
    write_video(folder / "left.mkv", data, codec="ffv1", right_path=folder / "right.mkv")
    assert detect_source(folder) == "io.video"
    got = list(open_video(folder, calib))
    assert len(got) == 4
    np.testing.assert_array_equal(got[3]["right"], data[3][1])


def test_odd_width_side_by_side_is_refused(tmp_path, calib):
    frames = [(texture(k, w=161)[:, :161], texture(k, w=160)) for k in range(2)]
    video = write_video(tmp_path / "odd.mkv", [(a, b) for a, b in frames], codec="ffv1")
    with pytest.raises(
        InputError, match=r"odd.mkv: a side-by-side stereo video has an even width .* 321 px wide"
    ):
        open_video(video, calib)


def test_variable_frame_rate_is_refused(tmp_path, calib):
    path = tmp_path / "vfr.mkv"
    c = av.open(str(path), "w")
    s = c.add_stream("ffv1", rate=10)
    s.width, s.height, s.pix_fmt = 640, 120, "bgr0"
    s.codec_context.time_base = Fraction(1, 10)
    for k, pts in enumerate([0, 1, 2, 4, 5, 6]):
        f = av.VideoFrame.from_ndarray(np.hstack(pairs(6)[k]), format="bgr24")
        f.pts, f.time_base = pts, Fraction(1, 10)
        for p in s.encode(f):
            c.mux(p)
    for p in s.encode():
        c.mux(p)
    c.close()
    with pytest.raises(
        InputError,
        match=r"vfr.mkv: variable frame rate: frame intervals from 100.00 to 200.00 ms.*expected a constant frame rate",
    ):
        open_video(path, calib)


def test_a_corrupt_packet_fails_its_frame_only(tmp_path, calib):
    video = write_video(tmp_path / "mj.avi", pairs(5), codec="mjpeg")
    c = av.open(str(video))
    packets = [(p.pts, p.pos, p.size) for p in c.demux(c.streams.video[0]) if p.size]
    c.close()
    data = bytearray(video.read_bytes())
    _, pos, size = packets[2]
    data[pos + 8 : pos + size - 8] = bytes(size - 16)
    bad = tmp_path / "bad.avi"
    bad.write_bytes(bytes(data))
    got = list(open_video(bad, calib, check_order=False))
    assert isinstance(
        got[2], InputError
    ) and "bad.avi: frame 0000000002: the frame's packet does not decode" in str(got[2])
    assert [g["frame"] for k, g in enumerate(got) if k != 2] == [
        "0000000000",
        "0000000001",
        "0000000003",
        "0000000004",
    ]


def test_no_calibration_and_not_a_video(tmp_path):
    video = write_video(tmp_path / "stereo.mkv", pairs(2), codec="ffv1")
    with pytest.raises(InputError, match="no calibration: the input carries none; give the calibration file"):
        VideoSource(node_type_of(VideoSource).params(), RunContext(input_path=video))
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"not a video" * 100)
    with pytest.raises(InputError, match=r"junk.mp4: cannot open the video"):
        open_video(junk, str(tmp_path / "none.yaml"))
