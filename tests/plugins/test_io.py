"""Sources and sinks: tiny synthetic KITTI raw / odometry / folder layouts, bad input, writers."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from lanegraph_io import WriteLanes, WriteOverlay, detect_source, parse_frames, read_calibration_yaml
from lanegraph_io._sinks import OverlayParams, WriteLanesParams
from lanegraph_io._sources import FolderSource, KittiOdometrySource, KittiRawSource

from lanegraph.errors import InputError
from lanegraph.nodes import RunContext, node_type_of
from lanegraph.types import Lane

# KITTI's colour pair with the principal point moved into the 20 x 12 images of these tests
P2 = "7.215377e+02 0 9.5593 4.485728e+01 0 7.215377e+02 5.854 2.163791e-01 0 0 1 2.745884e-03"
P3 = "7.215377e+02 0 9.5593 -3.395242e+02 0 7.215377e+02 5.854 2.199936e+00 0 0 1 2.729905e-03"


def img(h=12, w=20, v=100, colour=True):
    a = np.full((h, w), v, np.uint8)
    return np.dstack([a] * 3) if colour else a


def kitti_raw(tmp_path: Path, n=3, calib_rows=None, w=20, h=12) -> Path:
    date = tmp_path / "2011_09_26"
    drive = date / "2011_09_26_drive_0001_sync"
    for cam in ("image_02", "image_03"):
        (drive / cam / "data").mkdir(parents=True)
        for i in range(n):
            cv2.imwrite(str(drive / cam / "data" / f"{i:010d}.png"), img(h, w, 10 * i))
    rows = (
        calib_rows
        if calib_rows is not None
        else [f"S_rect_02: {w} {h}", f"P_rect_02: {P2}", f"P_rect_03: {P3}"]
    )
    (date / "calib_cam_to_cam.txt").write_text("calib_time: 09-Jan-2012 13:57:47\n" + "\n".join(rows) + "\n")
    return drive


def open_source(cls, params, path, frames=None):
    return cls(node_type_of(cls).params(**params), RunContext(input_path=path, frames=frames))


def test_kitti_raw_layout(tmp_path):
    drive = kitti_raw(tmp_path)
    assert detect_source(drive) == "io.kitti_raw"
    src = open_source(KittiRawSource, {}, drive)
    c = src.constants()["calib"]
    assert c.f == pytest.approx(721.5377) and c.cx == pytest.approx(9.5593) and c.cy == pytest.approx(5.854)
    assert c.baseline == pytest.approx((44.85728 + 339.5242) / 721.5377, abs=1e-6)
    frames = list(src)
    assert [f["frame"] for f in frames] == ["0000000000", "0000000001", "0000000002"]
    assert frames[2]["left"][0, 0, 0] == 20 and frames[2]["left"].shape == (12, 20, 3)


def test_frame_selection(tmp_path):
    drive = kitti_raw(tmp_path, n=5)
    src = open_source(KittiRawSource, {"frames": "1:5:2"}, drive)
    assert len(src) == 2 and [f["frame"] for f in src] == ["0000000001", "0000000003"]
    src = open_source(KittiRawSource, {}, drive, frames=slice(3, None))
    assert [f["frame"] for f in src] == ["0000000003", "0000000004"]
    assert parse_frames("7") == slice(7, 8) and parse_frames("") is None
    with pytest.raises(ValueError):
        parse_frames("a:b")


def test_images_are_read_lazily(tmp_path):
    drive = kitti_raw(tmp_path, n=3)
    src = open_source(KittiRawSource, {}, drive)
    (drive / "image_02" / "data" / "0000000002.png").write_bytes(b"\x89PNG truncated")  # after opening
    it = iter(src)
    assert next(it)["frame"] == "0000000000"


@pytest.mark.parametrize(
    "breaker, words",
    [
        (
            lambda d: (d / "image_03" / "data" / "0000000001.png").unlink(),
            ["0000000001.png has no right partner"],
        ),
        (lambda d: [p.unlink() for p in (d / "image_02" / "data").iterdir()], ["no images in the folder"]),
        (lambda d: (d.parent / "calib_cam_to_cam.txt").unlink(), ["calibration file not found"]),
        (
            lambda d: (d.parent / "calib_cam_to_cam.txt").write_text(
                "P_rect_02: 1 2 3\nP_rect_03: " + P3 + "\n"
            ),
            ["line 1", "'P_rect_02' has 3 numbers, expected 12"],
        ),
        (
            lambda d: (d.parent / "calib_cam_to_cam.txt").write_text("P_rect_02: " + P2 + "\n"),
            ["row 'P_rect_03' missing"],
        ),
        (
            lambda d: (d.parent / "calib_cam_to_cam.txt").write_text("garbage line\n"),
            ["line 1", "expected 'KEY: values'"],
        ),
        (
            lambda d: [
                (d / c / "data" / "0000000002.png").rename(d / c / "data" / "frame_x.png")
                for c in ("image_02", "image_03")
            ],
            ["'frame_x' is not a frame number"],
        ),
    ],
)
def test_bad_kitti_folders_are_located(tmp_path, breaker, words):
    drive = kitti_raw(tmp_path)
    breaker(drive)
    with pytest.raises(InputError) as info:
        list(open_source(KittiRawSource, {}, drive))
    for w in words:
        assert w in str(info.value), str(info.value)


def test_non_monotonic_frames(tmp_path):
    drive = kitti_raw(tmp_path, n=2)
    # 0000000010 and 10 sort as strings in this order but are the same frame number
    for c in ("image_02", "image_03"):
        cv2.imwrite(str(drive / c / "data" / "10.png"), img())
        cv2.imwrite(str(drive / c / "data" / "0000000010.png"), img())
    with pytest.raises(InputError, match="not increasing"):
        open_source(KittiRawSource, {}, drive)


def test_bad_frames_are_yielded_as_errors_and_the_rest_read(tmp_path):
    drive = kitti_raw(tmp_path, n=4)
    (drive / "image_02" / "data" / "0000000001.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    cv2.imwrite(str(drive / "image_03" / "data" / "0000000002.png"), img(12, 18))
    items = list(open_source(KittiRawSource, {}, drive))
    assert (
        isinstance(items[1], InputError)
        and "cannot decode image" in str(items[1])
        and "0000000001" in str(items[1])
    )
    assert isinstance(items[2], InputError) and "size mismatch" in str(items[2])
    assert items[3]["frame"] == "0000000003"


def test_kitti_odometry(tmp_path):
    seq = tmp_path / "00"
    for cam in ("image_0", "image_1"):
        (seq / cam).mkdir(parents=True)
        for i in range(2):
            cv2.imwrite(str(seq / cam / f"{i:06d}.png"), img(colour=False))
    rows = [
        f"P{k}: "
        + " ".join(["700", "0", "10", str(-700 * 0.54 * (k % 2)), "0", "700", "6", "0", "0", "0", "1", "0"])
        for k in range(4)
    ]
    (seq / "calib.txt").write_text("\n".join(rows) + "\n")
    assert detect_source(seq) == "io.kitti_odometry"
    src = open_source(KittiOdometrySource, {}, seq)
    assert src.constants()["calib"].baseline == pytest.approx(0.54)
    f = next(iter(src))
    assert f["left"].ndim == 2 and f["frame"] == "000000"


def test_folder_source_and_calibration_yaml(tmp_path):
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        cv2.imwrite(str(tmp_path / side / "a.png"), img())
    (tmp_path / "calib.yaml").write_text("f: 500\ncx: 10\ncy: 6\nbaseline: 0.3\n")
    assert detect_source(tmp_path) == "io.folder"
    src = open_source(FolderSource, {}, tmp_path)
    assert src.constants()["calib"].baseline == 0.3 and next(iter(src))["frame"] == "a"
    (tmp_path / "calib.yaml").write_text("f: 500\ncx: 10\n")
    with pytest.raises(InputError, match=r"missing key\(s\) \['cy', 'baseline'\]"):
        read_calibration_yaml(tmp_path / "calib.yaml")
    (tmp_path / "calib.yaml").write_text("f: x\ncx: 10\ncy: 1\nbaseline: 1\n")
    with pytest.raises(InputError, match="must be numbers"):
        read_calibration_yaml(tmp_path / "calib.yaml")


def test_missing_input_folder(tmp_path):
    with pytest.raises(InputError, match="input folder not found"):
        open_source(KittiRawSource, {}, tmp_path / "nope")
    assert detect_source(tmp_path / "nope") is None


def test_write_lanes_flushes_every_frame(tmp_path):
    w = WriteLanes(WriteLanesParams(), RunContext(out_dir=tmp_path))
    lane = Lane(
        coeffs=(1.0, 0.0, 0.0),
        bev_rows=(0, 10),
        side="left",
        score=0.5,
        points=np.array([[10.0, 370.0], [12.0, 360.0]]),
    )
    w(frame="0001", lanes=[lane])
    w(frame="0002", lanes=None)
    lines = (tmp_path / "lanes.jsonl").read_text().splitlines()  # before close()
    assert [json.loads(x)["frame"] for x in lines] == ["0001", "0002"]
    rec = json.loads(lines[0])["lanes"][0]
    assert rec["points"] == [[10.0, 370.0], [12.0, 360.0]] and rec["side"] == "left" and rec["score"] == 0.5
    w.close()
    w2 = WriteLanes(WriteLanesParams(append=True), RunContext(out_dir=tmp_path))
    w2(frame="0003")
    w2.close()
    assert len((tmp_path / "lanes.jsonl").read_text().splitlines()) == 3


def test_write_overlay(tmp_path):
    w = WriteOverlay(OverlayParams(every=2), RunContext(out_dir=tmp_path))
    lane = Lane(
        coeffs=(1.0, 0.0, 0.0),
        bev_rows=(0, 10),
        side="left",
        score=0.5,
        points=np.array([[2.0, 11.0], [5.0, 1.0]]),
    )
    w(frame="a", image=img(), lanes=[lane], mask=np.ones((12, 20), bool))
    w(frame="b", image=img())
    assert (tmp_path / "overlay" / "a.png").is_file() and not (tmp_path / "overlay" / "b.png").exists()


def test_real_kitti_drive(kitti_drive):
    src = open_source(KittiRawSource, {}, kitti_drive)
    assert len(src) == 54
    c = src.constants()["calib"]
    assert (c.f, c.cx, c.cy) == pytest.approx((721.5377, 609.5593, 172.854))
    assert c.baseline == pytest.approx(0.5327, abs=1e-3) and (c.width, c.height) == (1242, 375)
    f = next(iter(src))
    assert f["left"].shape == (375, 1242, 3) and f["right"].shape == (375, 1242, 3)


def test_io_auto_selects_the_source_by_the_input(tmp_path):
    """io.auto is never instantiated: its select_source names the source for the input (the engine
    passes every plugin's lanegraph_detect_source as ``detect``)."""
    from lanegraph_io._auto import AutoParams, AutoSource

    odo = kitti_raw(tmp_path)
    assert AutoSource.select_source(AutoParams(), None, detect_source) == "io.synthetic"
    assert AutoSource.select_source(AutoParams(default="io.folder"), None, detect_source) == "io.folder"
    assert AutoSource.select_source(AutoParams(), odo, detect_source) == "io.kitti_raw"
    (tmp_path / "nothing").mkdir()
    with pytest.raises(ValueError, match="no installed source node type recognises the input"):
        AutoSource.select_source(AutoParams(), tmp_path / "nothing", detect_source)
    with pytest.raises(RuntimeError, match="never instantiated"):
        AutoSource(AutoParams(), RunContext())


@pytest.mark.parametrize("read_ahead", [0, 1, 3])
def test_read_ahead_gives_the_frames_in_order_with_their_errors(tmp_path, read_ahead):
    """Decoding ahead on threads (the pair's two images in parallel) changes nothing a run sees:
    the same frames in the same order, a bad frame's error at its place."""
    drive = kitti_raw(tmp_path, n=6)
    (drive / "image_03" / "data" / "0000000002.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    plain = list(open_source(KittiRawSource, {"read_ahead": 0}, drive))
    src = open_source(KittiRawSource, {"read_ahead": read_ahead}, drive)
    assert src.reading_plan()[0] == read_ahead
    items = list(src)
    assert len(items) == len(plain) == 6
    for a, b in zip(items, plain):
        if isinstance(b, InputError):
            assert isinstance(a, InputError) and str(a) == str(b) and "0000000002" in str(a)
        else:
            assert a["frame"] == b["frame"] and np.array_equal(a["left"], b["left"])
            assert np.array_equal(a["right"], b["right"])
    assert [i["frame"] for i in items if not isinstance(i, InputError)] == [
        f"{i:010d}" for i in (0, 1, 3, 4, 5)
    ]


def test_read_ahead_stops_with_the_run(tmp_path):
    """A run that stops early (the generator closed) leaves no decoding thread behind."""
    import threading

    drive = kitti_raw(tmp_path, n=8)
    it = iter(open_source(KittiRawSource, {"read_ahead": 4}, drive))
    assert next(it)["frame"] == "0000000000"
    it.close()
    for th in threading.enumerate():
        if th.name.startswith("lanegraph-read"):
            th.join(timeout=5)
            assert not th.is_alive()


def test_auto_read_ahead_follows_the_free_cpus(tmp_path, monkeypatch):
    from lanegraph_io import _sources

    drive = kitti_raw(tmp_path, n=2)
    src = open_source(KittiRawSource, {}, drive)
    monkeypatch.setattr(_sources, "available_cpus", lambda: 1)
    assert src.reading_plan() == (0, 0)  # one CPU: one image after the other, in the caller's thread
    monkeypatch.setattr(_sources, "available_cpus", lambda: 2)
    assert src.reading_plan() == (2, 1)  # the decoders beside the nodes' thread: one CPU left for them
    monkeypatch.setattr(_sources, "available_cpus", lambda: 4)
    assert src.reading_plan() == (2, 3)
    monkeypatch.setattr(_sources, "available_cpus", lambda: 16)
    assert src.reading_plan() == (2, 6)  # at most two a frame in flight
    src.params = src.params.model_copy(update={"read_ahead": 0})
    assert src.reading_plan() == (0, 2)  # nothing ahead: a pair's two images at once
    assert [i["frame"] for i in src] == ["0000000000", "0000000001"]


@pytest.mark.parametrize("read_ahead", [0, 2])
def test_read_ahead_decodes_that_many_frames_beyond_the_one_asked_for(tmp_path, monkeypatch, read_ahead):
    from lanegraph_io import _sources

    drive = kitti_raw(tmp_path, n=8)
    src = open_source(KittiRawSource, {"read_ahead": read_ahead}, drive)
    asked: list[str] = []
    real = _sources.read_image
    monkeypatch.setattr(
        _sources, "read_image", lambda path, *a, **k: asked.append(path.name) or real(path, *a, **k)
    )
    it = iter(src)
    next(it)
    import time

    time.sleep(0.2)  # let the threads take what was submitted
    assert len(set(asked)) == 1 + read_ahead  # this frame's pair and read_ahead more
    it.close()


@pytest.mark.parametrize("given", [None, 0, 3])
def test_io_auto_passes_read_ahead_to_the_source_it_chooses(tmp_path, given):
    """A graph sets read_ahead on io.auto: the chosen KITTI source runs with it (the default when
    not set); the synthetic scene, which has no such field, is chosen without it."""
    import yaml

    from lanegraph.graph.validation import load_graph
    from lanegraph.run.executor import Executor

    drive = kitti_raw(tmp_path, n=2)
    src: dict = {"type": "io.auto"}
    if given is not None:
        src["params"] = {"read_ahead": given}
    gp = tmp_path / "g.yaml"
    gp.write_text(yaml.safe_dump({"nodes": {"src": src}}))
    ex = Executor(load_graph(gp), RunContext(input_path=drive, out_dir=tmp_path / "out"))
    assert ex.graph.source.type.name == "io.kitti_raw"
    assert ex.graph.source.params.read_ahead == (-1 if given is None else given)
    assert ex.run().frames == 2
    ex = Executor(load_graph(gp), RunContext(out_dir=tmp_path / "out2", frames=slice(0, 1)))
    assert ex.graph.source.type.name == "io.synthetic"
    assert "read_ahead" not in type(ex.graph.source.params).model_fields


def test_a_value_the_chosen_source_refuses_is_a_located_graph_error():
    from lanegraph_io._auto import AutoParams
    from pydantic import Field

    from lanegraph import NodeParams
    from lanegraph.errors import GraphError
    from lanegraph.run.sources import chosen_params

    class Narrow(NodeParams):
        read_ahead: int = Field(0, le=2)

    chosen = type("NT", (), {"params": Narrow, "name": "toy.narrow"})
    assert chosen_params(chosen, AutoParams(read_ahead=2)).read_ahead == 2
    assert chosen_params(chosen, AutoParams()).read_ahead == 0  # not set in the graph: the chosen default
    with pytest.raises(GraphError) as info:
        chosen_params(chosen, AutoParams(read_ahead=3), file="g.yaml", node="src")
    assert str(info.value).startswith("g.yaml: node 'src' (toy.narrow): params.read_ahead: ")
    assert "less than or equal to 2" in str(info.value)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread priorities are Linux's")
@pytest.mark.parametrize(("read_ahead", "read_nice", "expected"), [(2, 7, 7), (2, 0, 0), (0, 7, 0)])
def test_reading_ahead_the_decoders_run_below_the_nodes_priority(
    tmp_path, monkeypatch, read_ahead, read_nice, expected
):
    """Reading ahead, each decoding thread runs ``read_nice`` steps below the run's priority (and
    leaves signals to the main thread); the caller's thread keeps its own. Without reading ahead
    the run waits for the decoders: they keep its priority."""
    import os
    import signal
    import threading

    from lanegraph_io import _sources

    seen = []
    real = _sources.read_image

    def spy(*args, **kwargs):
        if threading.current_thread() is not threading.main_thread():
            blocked = signal.pthread_sigmask(signal.SIG_BLOCK, set())
            seen.append(
                (os.getpriority(os.PRIO_PROCESS, threading.get_native_id()), signal.SIGINT in blocked)
            )
        return real(*args, **kwargs)

    monkeypatch.setattr(_sources, "read_image", spy)
    monkeypatch.setattr(_sources, "available_cpus", lambda: 2)
    base = os.getpriority(os.PRIO_PROCESS, 0)
    drive = kitti_raw(tmp_path, n=3)
    src = open_source(KittiRawSource, {"read_ahead": read_ahead, "read_nice": read_nice}, drive)
    assert [i["frame"] for i in src] == [f"{i:010d}" for i in range(3)]
    assert len(seen) == 6  # every image decoded on a pool thread (two CPUs)
    assert {p for p, _ in seen} == {min(19, base + expected)} and all(b for _, b in seen)
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == base  # the caller's thread
