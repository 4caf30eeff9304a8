"""Writing recordings of a stereo rig: ROS bags (ROS 1, ROS 2 MCAP and sqlite3), stereo videos, and
their calibration files -- from any pairs, or from the synthetic scene seen through an unrectified
rig (distortion and a small rotation of each camera: :func:`~lanegraph_io._stereo.example_rig`).

The tests make their data with it, and so do the commands of docs/inputs.md::

    python -m lanegraph_io.recordings recording.mcap --frames 6     # + left.yaml, right.yaml, opencv.yaml

Needs the ``io`` extra (``rosbags`` for bags, ``av`` for videos).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Iterator
from pathlib import Path

import cv2
import numpy as np
import yaml

from lanegraph.types import Calibration

from ._stereo import StereoCalibration, example_rig, unrectify

TOPICS = ("/stereo/left/image_raw", "/stereo/right/image_raw")
STORAGES = ("mcap", "sqlite3", "ros1")
ENCODINGS = ("bgr8", "rgb8", "mono8", "bayer_rggb8", "jpeg", "png")


def _encode(img: np.ndarray, encoding: str) -> tuple[str, np.ndarray, int, int, int]:
    """``(encoding, bytes, height, width, step)`` of a BGR image as a ROS Image in ``encoding``."""
    h, w = img.shape[:2]
    if encoding == "bgr8":
        data = img
    elif encoding == "rgb8":
        data = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    elif encoding == "mono8":
        data = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif encoding == "bayer_rggb8":  # R at (0,0), G at (0,1) and (1,0), B at (1,1)
        data = np.empty((h, w), np.uint8)
        data[0::2, 0::2] = img[0::2, 0::2, 2]
        data[0::2, 1::2] = img[0::2, 1::2, 1]
        data[1::2, 0::2] = img[1::2, 0::2, 1]
        data[1::2, 1::2] = img[1::2, 1::2, 0]
    else:
        raise ValueError(f"encoding: expected one of {', '.join(ENCODINGS)}, got {encoding!r}")
    data = np.ascontiguousarray(data)
    return encoding, data.reshape(-1), h, w, data.strides[0]


def camera_info_dict(stereo: StereoCalibration, side: str) -> dict:
    """One camera of ``stereo`` as a ROS ``camera_info`` YAML mapping (``camera_calibration``'s)."""
    k, d, r, p = (
        (stereo.K1, stereo.D1, stereo.R1, stereo.P1)
        if side == "left"
        else (stereo.K2, stereo.D2, stereo.R2, stereo.P2)
    )

    def mat(a: np.ndarray, rows: int, cols: int) -> dict:
        return {"rows": rows, "cols": cols, "data": [float(x) for x in np.asarray(a).reshape(-1)]}

    return {
        "image_width": int(stereo.width),
        "image_height": int(stereo.height),
        "camera_name": side,
        "camera_matrix": mat(k, 3, 3),
        "distortion_model": "plumb_bob",
        "distortion_coefficients": mat(d, 1, len(d)),
        "rectification_matrix": mat(r if r is not None else np.eye(3), 3, 3),
        "projection_matrix": mat(p, 3, 4),
    }


def write_camera_info(stereo: StereoCalibration, left: str | Path, right: str | Path) -> None:
    """``left.yaml`` and ``right.yaml`` as ROS ``camera_calibration`` writes them."""
    for side, path in (("left", left), ("right", right)):
        Path(path).write_text(yaml.safe_dump(camera_info_dict(stereo, side), sort_keys=False))


def write_opencv(stereo: StereoCalibration, path: str | Path, rectification: bool = True) -> None:
    """An OpenCV FileStorage file (YAML, or XML for ``.xml``) with K1, D1, K2, D2, R, T, the image
    size and (``rectification``) R1, R2, P1, P2."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", int(stereo.width))
    fs.write("image_height", int(stereo.height))
    for key in ("K1", "D1", "K2", "D2", "R", "T") + (("R1", "R2", "P1", "P2") if rectification else ()):
        v = getattr(stereo, key)
        if v is not None:
            fs.write(
                key, np.asarray(v, np.float64).reshape(3, -1) if key == "T" else np.asarray(v, np.float64)
            )
    fs.release()


def write_bag(
    path: str | Path,
    pairs: Iterable[tuple[np.ndarray, np.ndarray]],
    *,
    stereo: StereoCalibration | None = None,
    storage: str = "mcap",
    encoding: str = "bgr8",
    fps: float = 10.0,
    start_ns: int = 1_700_000_000_000_000_000,
    topics: tuple[str, str] = TOPICS,
    right_delay_ns: int = 0,
) -> Path:
    """A bag of the stereo ``pairs`` (BGR): ``sensor_msgs/Image`` in ``encoding``, or
    ``CompressedImage`` for ``jpeg`` / ``png``, and ``CameraInfo`` of ``stereo`` beside each image
    topic (none without ``stereo``). ROS 2 (``mcap``: one ``.mcap`` file at ``path``; ``sqlite3``:
    a bag folder at ``path``) or ROS 1 (``ros1``: a ``.bag`` file). Returns ``path``."""
    from rosbags.typesys import Stores, get_typestore

    if storage not in STORAGES:
        raise ValueError(f"storage: expected one of {', '.join(STORAGES)}, got {storage!r}")
    path = Path(path)
    ros1 = storage == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    compressed = encoding in ("jpeg", "png")
    img_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr

    def header(stamp: int, frame_id: str):
        t = Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
        return Header(seq=0, stamp=t, frame_id=frame_id) if ros1 else Header(stamp=t, frame_id=frame_id)

    def info_msg(side: str, stamp: int):
        d = camera_info_dict(stereo, side)
        roi = T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        arrays = {
            k: np.asarray(d[src]["data"], np.float64)
            for k, src in (
                ("d", "distortion_coefficients"),
                ("k", "camera_matrix"),
                ("r", "rectification_matrix"),
                ("p", "projection_matrix"),
            )
        }
        if ros1:
            arrays = {k.upper(): v for k, v in arrays.items()}
        return T["sensor_msgs/msg/CameraInfo"](
            header=header(stamp, side), height=d["image_height"], width=d["image_width"],
            distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi, **arrays,
        )  # fmt: skip

    def image_msg(img: np.ndarray, stamp: int, side: str):
        if compressed:
            ok, buf = cv2.imencode(".jpg" if encoding == "jpeg" else ".png", img)
            assert ok
            return T[img_type](header=header(stamp, side), format=encoding, data=buf.reshape(-1))
        enc, data, h, w, step = _encode(img, encoding)
        return T[img_type](
            header=header(stamp, side), height=h, width=w, encoding=enc, is_bigendian=0, step=step, data=data
        )

    def messages() -> Iterator[tuple[str, str, int, object]]:
        for k, (left, right) in enumerate(pairs):
            stamp = start_ns + int(round(k * 1e9 / fps))
            for side, topic, img, delay in (
                ("left", topics[0], left, 0),
                ("right", topics[1], right, right_delay_ns),
            ):
                if stereo is not None:
                    yield (
                        topic.rsplit("/", 1)[0] + "/camera_info",
                        "sensor_msgs/msg/CameraInfo",
                        stamp + delay,
                        info_msg(side, stamp + delay),
                    )
                yield topic, img_type, stamp + delay, image_msg(img, stamp + delay, side)

    if ros1:
        from rosbags.rosbag1 import Writer as Writer1

        writer = Writer1(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        folder = path.with_suffix("") if storage == "mcap" else path
        writer = Writer(folder, version=9, storage_plugin=plugin)
    conns: dict[str, object] = {}
    with writer:
        for topic, msgtype, t, msg in messages():
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], t, bytes(serialize(msg, msgtype)))
    if storage == "mcap":  # one .mcap file where the caller asked, not a bag folder
        made = next(folder.glob("*.mcap"))
        made.replace(path)
        for rest in folder.iterdir():
            rest.unlink()
        folder.rmdir()
    return path


def write_video(
    path: str | Path,
    pairs: Iterable[tuple[np.ndarray, np.ndarray]],
    *,
    fps: int = 10,
    codec: str = "libx264",
    right_path: str | Path | None = None,
    options: dict[str, str] | None = None,
) -> Path:
    """A side-by-side stereo video of ``pairs`` (left | right) at ``path``, or with ``right_path``
    two videos (left at ``path``). ``codec`` is PyAV's (libx264 at crf 12 by default, ffv1 lossless,
    mjpeg)."""
    import av

    outs = []
    try:
        for p in [path] + ([right_path] if right_path is not None else []):
            c = av.open(str(p), "w")
            outs.append([c, None])
        for left, right in pairs:
            imgs = [left, right] if right_path is not None else [np.hstack([left, right])]
            for slot, img in zip(outs, imgs):
                c, s = slot
                if s is None:
                    s = slot[1] = c.add_stream(codec, rate=fps)
                    s.width, s.height = img.shape[1], img.shape[0]
                    s.pix_fmt = {"ffv1": "bgr0", "mjpeg": "yuvj444p", "libx264rgb": "bgr24"}.get(
                        codec, "yuv444p"
                    )
                    s.options = (
                        options
                        if options is not None
                        else ({"crf": "12"} if codec.startswith("libx264") else {})
                    )
                frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="bgr24")
                for packet in s.encode(frame):
                    c.mux(packet)
        for c, s in outs:
            if s is not None:
                for packet in s.encode():
                    c.mux(packet)
    finally:
        for c, _ in outs:
            c.close()
    return Path(path)


def synthetic_recording(preset_name: str = "straight", n: int = 6, seed: int = 0, **overrides):
    """``(stereo, rectified, raw_pairs, frames)``: the synthetic scene ``preset_name`` as an
    unrectified rig (:func:`~lanegraph_io._stereo.example_rig`) would record it -- its calibration,
    the rectified calibration its rectification gives (the scene's own), the raw pairs (a
    generator) and the scene's rendered frames (ground truth)."""
    from lanegraph_synthetic import SceneRenderer, preset

    renderer = SceneRenderer(preset(preset_name, seed=seed, **overrides))
    rectified: Calibration = renderer.calib
    stereo = example_rig(rectified)
    frames = [renderer.render(k) for k in range(n)]
    raw = (unrectify(stereo, rectified, fr.left, fr.right) for fr in frames)
    return stereo, rectified, raw, frames


def recorded_input(path: Path, n: int):
    """``(stereo, pairs)``: the first ``n`` frames of the input ``path`` (any installed source that
    reads it) and its rectified calibration as a rig that needs no rectification."""
    from lanegraph import RunContext
    from lanegraph.lifecycle import close
    from lanegraph.plugins import call_hook, get_plugin_manager

    from ._calibfiles import from_rectified

    pm = get_plugin_manager()
    name = call_hook(pm, "lanegraph_detect_source", path=path)
    nt = pm.get_node_type(name) if name is not None else None
    if nt is None or not nt.source:
        raise SystemExit(f"{path}: no installed source reads this input")
    src = nt.func(nt.params(), RunContext(input_path=path, frames=slice(0, n), node_id="src"))
    calib = src.constants()["calib"]

    def pairs():
        try:
            for item in src:
                if isinstance(item, dict):
                    yield item["left"], item["right"]
        finally:
            close(src, nt)

    return from_rectified(calib, str(path), {}), pairs()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m lanegraph_io.recordings",
        description="Write the synthetic scene as an unrectified rig records it: a bag (.mcap, .bag, a folder "
        "for sqlite3) or a video (.mp4, .mkv), with left.yaml, right.yaml (ROS camera_info) and opencv.yaml "
        "beside it.",
    )
    ap.add_argument("out", help="recording.mcap, recording.bag, a folder (ROS 2 sqlite3) or stereo.mp4")
    ap.add_argument("--frames", type=int, default=6, help="how many frames (default 6)")
    ap.add_argument("--preset", default="straight", help="the synthetic scene's preset (default straight)")
    ap.add_argument("--encoding", default="bgr8", choices=ENCODINGS, help="how a bag holds the images")
    ap.add_argument(
        "--sqlite3", action="store_true", help="a ROS 2 bag folder in sqlite3 (out names the folder)"
    )
    ap.add_argument(
        "--from",
        dest="source",
        type=Path,
        help="record the frames of this input (a KITTI drive or sequence, a folder of pairs) as they are, "
        "rectified, instead of the synthetic scene",
    )
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.source is not None:
        stereo, raw = recorded_input(args.source, args.frames)
    else:
        stereo, _rect, raw, _frames = synthetic_recording(args.preset, args.frames)
    if out.suffix.lower() in (".mp4", ".mkv", ".avi", ".mov"):
        write_video(out, raw)
    else:
        storage = "sqlite3" if args.sqlite3 else "ros1" if out.suffix.lower() == ".bag" else "mcap"
        write_bag(out, raw, stereo=stereo, storage=storage, encoding=args.encoding)
    where = out.parent
    write_camera_info(stereo, where / "left.yaml", where / "right.yaml")
    write_opencv(stereo, where / "opencv.yaml")
    print(
        f"wrote {out}, {where / 'left.yaml'}, {where / 'right.yaml'}, {where / 'opencv.yaml'} ({args.frames} frames)"
    )
    return 0


if __name__ == "__main__":  # pragma: no cover - the command line
    raise SystemExit(main())
