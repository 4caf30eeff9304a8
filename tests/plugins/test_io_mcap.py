"""``io.write_mcap``: an MCAP file Foxglove opens, read back with the ``mcap`` reader -- its
schemas, message counts, the lanes in pixels and in metres, and a resumed run's copy."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("mcap", reason='the io extra is not installed: pip install -e ".[io]"')
pytest.importorskip("foxglove")

from lanegraph_io._mcap_sink import WriteMcap, lane_metres  # noqa: E402
from mcap.reader import make_reader  # noqa: E402

from lanegraph.errors import InputError  # noqa: E402
from lanegraph.nodes import RunContext, node_type_of  # noqa: E402
from lanegraph.types import BevGeometry, Lane  # noqa: E402

GEOM = BevGeometry(x_min=-10.0, x_max=10.0, z_min=5.0, z_max=45.0, resolution=0.05, H_img_from_bev=np.eye(3))


def lanes():
    # a straight line 1.8 m left of the camera: BEV column (x - x_min) / res - 0.5, the same on every row
    col = (-1.8 + 10.0) / 0.05 - 0.5
    pts = np.array([[100.0, 370.0], [300.0, 200.0]])
    return [Lane((col, 0.0, 0.0), (0, 799), "left", 0.9, pts)]


def sink(tmp_path, resume=False, **params):
    return WriteMcap(
        node_type_of(WriteMcap).params(**params), RunContext(out_dir=tmp_path, extra={"resume": resume})
    )


def read(path):
    with open(path, "rb") as fh:
        r = make_reader(fh)
        summary = r.get_summary()
        topics = {
            ch.topic: (
                summary.schemas[ch.schema_id].name,
                summary.statistics.channel_message_counts.get(cid, 0),
            )
            for cid, ch in summary.channels.items()
        }
        timings = [json.loads(m.data) for _, ch, m in r.iter_messages(topics=["/lanegraph/timings"])]
    return topics, timings


def test_the_file_holds_foxglove_schemas_one_message_a_frame(tmp_path):
    image = np.full((375, 1242, 3), 90, np.uint8)
    w = sink(tmp_path)
    for k in range(3):
        w(frame=f"{k:010d}", image=image, lanes=lanes() if k != 1 else [], geometry=GEOM)
    w.close()
    topics, timings = read(tmp_path / "lanes.mcap")
    assert topics == {
        "/camera/left/image": ("foxglove.CompressedImage", 3),
        "/lanes/annotations": ("foxglove.ImageAnnotations", 3),
        "/lanes/scene": ("foxglove.SceneUpdate", 3),
        "/lanegraph/timings": ("lanegraph.FrameTiming", 3),
    }
    assert [t["lanes"] for t in timings] == [1, 0, 1]
    assert [t["frame"] for t in timings] == ["0000000000", "0000000001", "0000000002"]
    assert timings[0]["frame_ms"] is None and timings[2]["frame_ms"] >= 0


def decode(path):
    """Every protobuf message of the file, decoded with the schema the file holds: (topic, message, log time)."""
    pytest.importorskip("google.protobuf")
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    out = []
    with open(path, "rb") as fh:
        for schema, ch, m in make_reader(fh).iter_messages():
            if schema.encoding != "protobuf":
                continue
            fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
            pool = descriptor_pool.DescriptorPool()
            for fd in fds.file:
                pool.Add(fd)
            cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
            out.append((ch.topic, cls.FromString(m.data), m.log_time))
    return out


def test_the_annotations_and_scene_decode_with_their_schemas(tmp_path):
    from foxglove.messages import ImageAnnotations, SceneUpdate

    w = sink(tmp_path, image="raw")
    w(frame="1700000000000000000", image=np.zeros((40, 60), np.uint8), lanes=lanes(), geometry=GEOM)
    w.close()
    decoded = {topic: (msg, t) for topic, msg, t in decode(tmp_path / "lanes.mcap")}
    assert (
        decoded["/camera/left/image"][0].encoding == "mono8" and decoded["/camera/left/image"][0].width == 60
    )
    assert decoded["/camera/left/image"][1] == 1_700_000_000_000_000_000  # a bag's stamp is the file's time
    pts = decoded["/lanes/annotations"][0].points[0].points
    assert [(p.x, p.y) for p in pts] == [(100.0, 370.0), (300.0, 200.0)]
    line = decoded["/lanes/scene"][0].entities[0].lines[0]
    ys = {round(p.y, 6) for p in line.points}
    assert ys == {1.8}  # 1.8 m left (y left in the road frame)
    xs = [p.x for p in line.points]
    assert min(xs) == pytest.approx(5.025) and max(xs) == pytest.approx(44.975)
    assert ImageAnnotations.get_schema().name == "foxglove.ImageAnnotations"
    assert SceneUpdate.get_schema().name == "foxglove.SceneUpdate"


def test_every_frames_annotations_carry_the_images_stamp(tmp_path):
    # Foxglove's Image panel, in its "sync annotations" mode, shows an image only with annotations
    # of the same stamp: a frame without lanes still gets one (its label), or the panel would wait
    image = np.full((375, 1242, 3), 90, np.uint8)
    w = sink(tmp_path)
    for k in range(3):
        w(frame=f"{k:010d}", image=image, lanes=lanes() if k != 1 else [], geometry=GEOM)
    w.close()
    msgs = decode(tmp_path / "lanes.mcap")
    images = [
        (m.timestamp.seconds, m.timestamp.nanos, t) for topic, m, t in msgs if topic == "/camera/left/image"
    ]
    notes = [m for topic, m, _ in msgs if topic == "/lanes/annotations"]
    assert [t for _, _, t in images] == [0, 100_000_000, 200_000_000]  # 10 frames/s from 0
    assert [len(a.points) for a in notes] == [1, 0, 1]
    for (sec, nanos, _), a in zip(images, notes, strict=True):
        stamps = {(x.timestamp.seconds, x.timestamp.nanos) for x in [*a.points, *a.texts]}
        assert stamps == {(sec, nanos)}
    assert [a.texts[0].text for a in notes] == [
        "0000000000: 1 lane",
        "0000000001: 0 lanes",
        "0000000002: 1 lane",
    ]
    label = notes[0].texts[0]
    assert 0 < label.position.x < 1242 and 0 < label.position.y < 375 and label.font_size > 0


def test_lane_metres_is_the_bev_model_on_the_road():
    xz = lane_metres(lanes()[0], GEOM)
    np.testing.assert_allclose(xz[:, 0], -1.8, atol=1e-9)
    assert xz[0, 1] == pytest.approx(44.975) and xz[-1, 1] == pytest.approx(5.025)


def test_a_resumed_run_keeps_the_frames_done_and_goes_on(tmp_path):
    image = np.full((40, 60, 3), 90, np.uint8)
    w = sink(tmp_path)
    for k in range(3):
        w(frame=f"{k:010d}", image=image, lanes=lanes(), geometry=GEOM)
        if k == 1:
            state = json.loads(json.dumps(w.state()))  # what the checkpoint records after frame 1
    w.close()  # the run stopped after frame 2, its checkpoint after frame 1
    r = sink(tmp_path, resume=True)
    r.restore(state)
    r(frame="0000000002", image=image, lanes=[], geometry=GEOM)
    r.close()
    topics, timings = read(tmp_path / "lanes.mcap")
    assert all(n == 3 for _, n in topics.values())
    assert [(t["frame"], t["lanes"]) for t in timings] == [
        ("0000000000", 1),
        ("0000000001", 1),
        ("0000000002", 0),
    ]
    with pytest.raises(InputError, match=r"holds 3 whole frame\(s\), the checkpoint recorded 5"):
        sink(tmp_path, resume=True).restore({"frames": 5, "last_time": 10**12})


def test_a_link_planted_at_the_name_is_not_written_through(tmp_path):
    from lanegraph.errors import UsageError

    elsewhere = tmp_path / "elsewhere.txt"
    elsewhere.write_text("not the run's")
    out = tmp_path / "out"
    out.mkdir()
    (out / "lanes.mcap").symlink_to(elsewhere)
    with pytest.raises(UsageError, match="outside .*outputs stay inside the output folder"):
        sink(out)
    (out / "lanes.mcap").unlink()
    (out / "lanes.mcap").symlink_to(out / "inner.txt")  # a link inside the folder: replaced, not followed
    (out / "inner.txt").write_text("the user's")
    w = sink(out)
    w(frame="0", image=np.zeros((8, 8, 3), np.uint8), lanes=[], geometry=None)
    w.close()
    assert elsewhere.read_text() == "not the run's" and (out / "inner.txt").read_text() == "the user's"
    assert not (out / "lanes.mcap").is_symlink() and read(out / "lanes.mcap")[0]["/lanes/scene"][1] == 1
