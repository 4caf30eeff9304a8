"""``io.rosbag``: ROS 1 and ROS 2 (MCAP, sqlite3) bags written by the tests, every encoding, the
pairing by stamp, and the bad bags the issue lists -- each refused naming the bag and what was expected."""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest

pytest.importorskip("rosbags", reason='the io extra is not installed: pip install -e ".[io]"')

from lanegraph_io import detect_source  # noqa: E402
from lanegraph_io._calibfiles import from_rectified  # noqa: E402
from lanegraph_io._rosbag import RosbagSource  # noqa: E402
from lanegraph_io._stereo import example_rig, unrectify  # noqa: E402
from lanegraph_io.recordings import write_bag, write_camera_info  # noqa: E402

from lanegraph.errors import InputError  # noqa: E402
from lanegraph.nodes import RunContext, node_type_of  # noqa: E402
from lanegraph.types import Calibration  # noqa: E402

RECT = Calibration(f=200.0, cx=159.5, cy=59.5, baseline=0.3, width=320, height=120)
FLAT = from_rectified(RECT, "test", {})


def texture(seed, h=120, w=320):
    rng = np.random.default_rng(seed)
    return cv2.resize(
        rng.integers(0, 255, (h // 4, w // 4, 3), dtype=np.uint8), (w, h), interpolation=cv2.INTER_CUBIC
    )


def pairs(n=4):
    # the right image is the left one shifted by 8 px: a positive disparity everywhere
    out = []
    for k in range(n):
        left = texture(k)
        right = np.roll(left, -8, axis=1)
        out.append((left, right))
    return out


def open_bag(path, frames=None, skip=0, **params):
    return RosbagSource(
        node_type_of(RosbagSource).params(**params), RunContext(input_path=path, frames=frames, skip=skip)
    )


@pytest.mark.parametrize(("storage", "name"), [("mcap", "rec.mcap"), ("sqlite3", "rec"), ("ros1", "rec.bag")])
def test_each_bag_format_reads_the_pairs_and_the_camera_info(tmp_path, storage, name):
    data = pairs()
    bag = write_bag(tmp_path / name, data, stereo=FLAT, storage=storage)
    assert detect_source(bag) == "io.rosbag"
    src = open_bag(bag)
    assert src.topics == ("/stereo/left/image_raw", "/stereo/right/image_raw")
    c = src.constants()["calib"]
    assert (c.f, c.cx, c.baseline, c.width) == pytest.approx((200.0, 159.5, 0.3, 320))
    got = list(src)
    assert [g["frame"] for g in got] == [str(1_700_000_000_000_000_000 + k * 100_000_000) for k in range(4)]
    for g, (left, right) in zip(got, data):
        np.testing.assert_array_equal(g["left"], left)
        np.testing.assert_array_equal(g["right"], right)
        assert g["left"].flags.writeable and g["right"].flags.writeable  # as a decoded PNG's pixels
    src.close()


@pytest.mark.parametrize("encoding", ["rgb8", "mono8", "bayer_rggb8", "png", "jpeg"])
def test_every_encoding(tmp_path, encoding):
    data = pairs(2)
    bag = write_bag(tmp_path / "rec.mcap", data, stereo=FLAT, encoding=encoding)
    got = list(open_bag(bag))
    for g, (left, _) in zip(got, data):
        if encoding in ("rgb8", "png"):
            np.testing.assert_array_equal(g["left"], left)
        elif encoding == "mono8":
            np.testing.assert_array_equal(g["left"], cv2.cvtColor(left, cv2.COLOR_BGR2GRAY))
        else:  # demosaicked or JPEG: close, and in BGR order (the red channel where red is)
            assert g["left"].shape == left.shape
            diff = np.abs(g["left"][4:-4, 4:-4].astype(int) - left[4:-4, 4:-4])
            assert diff.mean() < 12, (encoding, diff.mean())


def test_frames_and_a_resumed_run_seek_into_the_bag(tmp_path):
    data = pairs(6)
    bag = write_bag(tmp_path / "rec.mcap", data, stereo=FLAT)
    src = open_bag(bag, frames=slice(2, 6), skip=1)
    got = list(src)
    assert len(src) == 3 and src.skipped == 1
    for g, (left, _) in zip(got, data[3:]):
        np.testing.assert_array_equal(g["left"], left)


def test_an_unrectified_bag_is_rectified_in_the_source(tmp_path):
    rig = example_rig(RECT)
    data = pairs(2)
    raw = [unrectify(rig, RECT, a, b) for a, b in data]
    bag = write_bag(tmp_path / "rec.mcap", raw, stereo=rig)
    src = open_bag(bag)
    assert not src.rectifier.identity
    c = src.constants()["calib"]
    assert (c.f, c.baseline) == pytest.approx((RECT.f, RECT.baseline))
    got = list(src)
    inner = (slice(15, -15), slice(25, -25))
    assert np.abs(got[0]["left"][inner].astype(int) - data[0][0][inner]).mean() < 6
    as_recorded = list(open_bag(bag, rectify=False))
    np.testing.assert_array_equal(as_recorded[0]["left"], raw[0][0])
    # the calibration files given instead of the bag's CameraInfo
    write_camera_info(rig, tmp_path / "left.yaml", tmp_path / "right.yaml")
    nocam = write_bag(tmp_path / "nocam.mcap", raw)
    with pytest.raises(InputError, match="no calibration: the input carries none; give the calibration file"):
        open_bag(nocam)
    src = open_bag(nocam, calib=f"{tmp_path / 'left.yaml'},{tmp_path / 'right.yaml'}")
    np.testing.assert_array_equal(list(src)[0]["left"], got[0]["left"])


def test_pairs_by_stamp_within_the_tolerance_and_reports_the_rest(tmp_path, caplog):
    data = pairs(3)
    bag = write_bag(tmp_path / "late.mcap", data, stereo=FLAT, right_delay_ns=2_000_000)
    assert len(open_bag(bag)) == 3  # 2 ms apart: within 5 ms
    with pytest.raises(
        InputError, match=r"no left image of /stereo/left/image_raw has a right image .* within 1 ms"
    ):
        open_bag(bag, stamp_tolerance_ms=1.0)
    # a right image missing: its left one is left out, and said so
    from rosbags.rosbag2 import Reader  # noqa: F401 - the writer below drops one message

    missing = tmp_path / "missing.mcap"
    write_bag(missing, data, stereo=FLAT, topics=("/stereo/left/image_raw", "/stereo/right/image_raw"))
    src_full = open_bag(missing)
    assert src_full.pairing["left_unpaired"] == 0
    one_right = tmp_path / "onemissing.mcap"
    _write_raw(one_right, [("/stereo/left/image_raw", k, data[k][0]) for k in range(3)]
               + [("/stereo/right/image_raw", k, data[k][1]) for k in (0, 2)])  # fmt: skip
    with caplog.at_level(logging.WARNING, logger="lanegraph"):
        src = open_bag(one_right, calib=_flat_calib(tmp_path))
    assert len(src) == 2 and src.pairing == {
        "pairs": 2,
        "left_unpaired": 1,
        "right_unpaired": 0,
        "max_dt_ms": 0.0,
    }
    assert "left out: 1 left and 0 right image(s) without a partner" in caplog.text


def _flat_calib(tmp_path):
    (tmp_path / "calib.yaml").write_text("f: 200\ncx: 159.5\ncy: 59.5\nbaseline: 0.3\n")
    return str(tmp_path / "calib.yaml")


def _write_raw(path, messages, stamps=None, encoding="bgr8", fmt=None):
    """A ROS 2 MCAP bag of ``(topic, k, image)`` messages; ``stamps[i]`` overrides message i's stamp."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    folder = path.with_suffix("")
    conns = {}
    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for i, (topic, k, img) in enumerate(messages):
            stamp = (stamps or {}).get(i, 1_700_000_000_000_000_000 + k * 100_000_000)
            hdr = T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9),
                frame_id="x",
            )
            if img is None:  # not an image: a std_msgs/String
                msgtype = "std_msgs/msg/String"
                msg = T[msgtype](data="hello")
            elif fmt is not None:
                msgtype = "sensor_msgs/msg/CompressedImage"
                msg = T[msgtype](
                    header=hdr,
                    format=fmt,
                    data=np.frombuffer(cv2.imencode(".png", img)[1].tobytes(), np.uint8),
                )
            else:
                msgtype = "sensor_msgs/msg/Image"
                msg = T[msgtype](header=hdr, height=img.shape[0], width=img.shape[1], encoding=encoding, is_bigendian=0,
                                 step=img.shape[1] * 3, data=np.ascontiguousarray(img).reshape(-1))  # fmt: skip
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
            w.write(
                conns[topic],
                1_700_000_000_000_000_000 + k * 100_000_000 + i,
                bytes(ts.serialize_cdr(msg, msgtype)),
            )
    next(folder.glob("*.mcap")).replace(path)
    for rest in folder.iterdir():
        rest.unlink()
    folder.rmdir()
    return path


def test_bad_bags_are_refused_naming_the_bag_and_what_was_expected(tmp_path):
    data = pairs(3)
    calib = _flat_calib(tmp_path)
    # no image topics at all
    none = _write_raw(tmp_path / "none.mcap", [("/chatter", 0, None)])
    with pytest.raises(
        InputError, match=r"none.mcap: no sensor_msgs/Image or CompressedImage topic in the bag"
    ):
        open_bag(none, calib=calib)
    with pytest.raises(
        InputError, match=r"topic '/cam/left': no image messages in the bag \(its image topics: none\)"
    ):
        open_bag(none, calib=calib, left_topic="/cam/left", right_topic="/cam/right")
    # one camera only
    one = _write_raw(tmp_path / "one.mcap", [("/stereo/left/image_raw", k, data[k][0]) for k in range(3)])
    with pytest.raises(
        InputError, match=r"one.mcap: one camera only: the bag's one image topic is /stereo/left/image_raw"
    ):
        open_bag(one, calib=calib)
    # duplicate and unsorted stamps
    msgs = [("/stereo/left/image_raw", k, data[k][0]) for k in range(3)] + [
        ("/stereo/right/image_raw", k, data[k][1]) for k in range(3)
    ]
    dup = _write_raw(tmp_path / "dup.mcap", msgs, stamps={1: 1_700_000_000_000_000_000})
    with pytest.raises(
        InputError, match=r"dup.mcap: topic /stereo/left/image_raw: messages 0 and 1 have the same stamp"
    ):
        open_bag(dup, calib=calib)
    unsorted = _write_raw(tmp_path / "unsorted.mcap", msgs, stamps={2: 1_600_000_000_000_000_000})
    with pytest.raises(
        InputError, match=r"unsorted.mcap: topic /stereo/left/image_raw: stamps not in order: message 2"
    ):
        open_bag(unsorted, calib=calib)
    assert len(open_bag(dup, calib=calib, stamps="log")) == 3  # the bag's log times pair them
    # an unknown codec: that frame fails, named, the others are read
    odd = _write_raw(tmp_path / "odd.mcap", msgs, fmt="h265")
    with pytest.raises(
        InputError, match=r"CompressedImage format 'h265' is not read \(expected jpeg or png\)"
    ):
        open_bag(odd, calib=calib)
    # truncated
    good = write_bag(tmp_path / "good.mcap", data, stereo=FLAT)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(InputError, match=r"cut.mcap: cannot read the bag.*truncated"):
        open_bag(cut)
    ros1 = write_bag(tmp_path / "good.bag", data, stereo=FLAT, storage="ros1")
    cut1 = tmp_path / "cut.bag"
    cut1.write_bytes(ros1.read_bytes()[: ros1.stat().st_size // 2])
    with pytest.raises(InputError, match=r"cut.bag: cannot read the bag"):
        open_bag(cut1)


def test_topics_found_from_camera_info_when_the_names_do_not_tell(tmp_path):
    data = pairs(2)
    bag = write_bag(tmp_path / "cams.mcap", data, stereo=FLAT, topics=("/cam0/image_raw", "/cam1/image_raw"))
    src = open_bag(bag)
    assert src.topics == ("/cam0/image_raw", "/cam1/image_raw")  # cam1's P[0,3] holds the baseline
    swapped = write_bag(tmp_path / "swapped.mcap", data, stereo=FLAT,
                        topics=("/cam1/image_raw", "/cam0/image_raw"))  # fmt: skip
    assert open_bag(swapped).topics == ("/cam1/image_raw", "/cam0/image_raw")
    with pytest.raises(InputError, match="left_topic and right_topic are both '/cam0/image_raw'"):
        open_bag(bag, left_topic="/cam0/image_raw", right_topic="/cam0/image_raw")


def test_compressed_topics_find_their_camera_info_above_them(tmp_path):
    data = pairs(2)
    bag = write_bag(tmp_path / "c.mcap", data, stereo=FLAT, encoding="png",
                    topics=("/stereo/left/image_raw/compressed", "/stereo/right/image_raw/compressed"))  # fmt: skip
    src = open_bag(bag)
    assert src.info_of["/stereo/left/image_raw/compressed"] is None or src.constants()[
        "calib"
    ].baseline == pytest.approx(0.3)
    np.testing.assert_array_equal(list(src)[1]["left"], data[1][0])
