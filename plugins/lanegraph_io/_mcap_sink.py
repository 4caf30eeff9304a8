"""``io.write_mcap``: the run as an MCAP file that Foxglove opens -- the left image, the lanes drawn
on it (``foxglove.ImageAnnotations``), the lanes in metres on the road (``foxglove.SceneUpdate``)
and every frame's time. Messages are Foxglove's protobuf schemas (the ``foxglove-sdk`` package)
written by the ``mcap`` package's writer (the ``io`` extra).

A resumed run copies the frames done (as the checkpoint recorded them) from the file of the
interrupted run into a new file, then goes on; the old file is replaced only once the copy is
whole.
"""

from __future__ import annotations

import io
import json
import os
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import Field

from lanegraph import NodeParams, Port, RunContext, node_type
from lanegraph.errors import InputError
from lanegraph.paths import OutputFile, create_new, inside
from lanegraph.types import BevGeometry, Lane

from ._sinks import SIDE_COLOURS, _out_dir, _where

TOPICS = {
    "image": "/camera/left/image",
    "annotations": "/lanes/annotations",
    "scene": "/lanes/scene",
    "timings": "/lanegraph/timings",
}
TIMINGS_SCHEMA = {
    "type": "object",
    "title": "lanegraph.FrameTiming",
    "properties": {
        "frame": {"type": "string", "description": "the frame id"},
        "index": {"type": "integer", "description": "the frame's place in this file"},
        "frame_ms": {
            "type": "number",
            "description": "wall time since the previous frame reached the sink, ms",
        },
        "lanes": {"type": "integer", "description": "lanes found"},
    },
}


def need_foxglove():
    try:
        import foxglove.messages as fm
        from mcap.writer import Writer  # noqa: F401
    except ImportError:
        raise InputError(
            "io.write_mcap needs the 'mcap' and 'foxglove-sdk' packages: pip install 'lanegraph[io]'"
        ) from None
    return fm


class WriteMcapParams(NodeParams):
    """Params of ``io.write_mcap``."""

    filename: OutputFile = Field(
        "lanes.mcap", description="output file, relative to --out (inside it: no absolute path, no '..')"
    )
    image: str = Field(
        "jpeg",
        pattern="^(jpeg|png|raw)$",
        description="how the left image is stored: foxglove.CompressedImage (jpeg, png) or foxglove.RawImage (raw)",
    )
    jpeg_quality: int = Field(90, ge=1, le=100, description="JPEG quality of the left image, 1-100")
    fps: float = Field(
        10.0,
        gt=0.0,
        le=1000.0,
        description="frames per second of the file's clock, for frame ids that are not times (a bag's frame ids "
        "are its header stamps in nanoseconds and are used as they are)",
    )


def lane_metres(lane: Lane, geometry: BevGeometry) -> np.ndarray:
    """The lane's BEV rows as road points, metres: ``N x 2`` (x right, z ahead)."""
    first, last = lane.bev_rows
    rows = np.arange(int(first), int(last) + 1, dtype=np.float64)
    t = geometry.rows - 1 - rows
    c0, c1, c2 = lane.coeffs
    x, z = geometry.bev_to_metric(c0 + c1 * t + c2 * t * t, rows)
    return np.stack([x, z], axis=1)


@node_type(
    "io.write_mcap",
    sink=True,
    implements=("outputs", "resume", "close"),
    inputs={
        "frame": Port("frame_id"),
        "image": Port("image", "the left image"),
        "lanes": Port("lanes", "lanes with image points", optional=True),
        "geometry": Port("bev_geometry", "the BEV geometry: the lanes in metres on the road", optional=True),
    },
)
class WriteMcap:
    """Writes OUT/lanes.mcap for Foxglove: the left image, the lanes on it and on the road in metres
    (x ahead, y left, frame ``road``), and each frame's time (``/lanegraph/timings``, JSON)."""

    outputs: list[Path]

    def __init__(self, params: WriteMcapParams, context: RunContext):
        self.fm = need_foxglove()
        self.p = params
        self.path = inside(_out_dir(context), params.filename, _where(context, "io.write_mcap", "filename"))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.outputs = [self.path]
        self.count = 0
        self.last_time = -1
        self._prev: float | None = None
        self.writer = None
        if not context.extra.get("resume"):
            self._open(self.path)

    def _open(self, path: Path) -> None:
        """A new file at ``path`` (a file or a link there removed first: never written through a
        link; the run's folder check has made sure it is this run's to write)."""
        from mcap.writer import Writer

        fm = self.fm
        self.fh = io.BufferedWriter(create_new(path), 1 << 20)
        self.writer = Writer(self.fh)
        self.writer.start(profile="", library="lanegraph")
        kinds = {
            "image": fm.RawImage if self.p.image == "raw" else fm.CompressedImage,
            "annotations": fm.ImageAnnotations,
            "scene": fm.SceneUpdate,
        }
        self.channels = {}
        for key, cls in kinds.items():
            schema = cls.get_schema()
            sid = self.writer.register_schema(schema.name, schema.encoding, bytes(schema.data))
            self.channels[key] = self.writer.register_channel(TOPICS[key], "protobuf", sid)
        sid = self.writer.register_schema(
            "lanegraph.FrameTiming", "jsonschema", json.dumps(TIMINGS_SCHEMA).encode()
        )
        self.channels["timings"] = self.writer.register_channel(TOPICS["timings"], "json", sid)

    def _time(self, frame: str) -> int:
        if frame.isdigit() and len(frame) >= 16:  # a bag's header stamp, nanoseconds
            t = int(frame)
        else:
            t = int(round(self.count * 1e9 / self.p.fps))
        return max(t, self.last_time + 1)

    def __call__(
        self,
        frame: str,
        image: np.ndarray,
        lanes: list[Lane] | None = None,
        geometry: BevGeometry | None = None,
    ) -> dict:
        fm = self.fm
        now = time.perf_counter()
        t = self._time(str(frame))
        stamp = fm.Timestamp(sec=t // 1_000_000_000, nsec=t % 1_000_000_000)
        lanes = lanes or []
        msgs = {"image": self._image(image, stamp)}
        points = []
        for lane in lanes:
            if lane.points is None or len(lane.points) < 2:
                continue
            b, g, r = SIDE_COLOURS.get(lane.side, SIDE_COLOURS[""])
            points.append(
                fm.PointsAnnotation(
                    timestamp=stamp,
                    type=fm.PointsAnnotationType.LineStrip,
                    points=[fm.Point2(x=float(x), y=float(y)) for x, y in np.asarray(lane.points, float)],
                    outline_color=fm.Color(r=r / 255, g=g / 255, b=b / 255, a=1.0),
                    thickness=3.0,
                )
            )
        msgs["annotations"] = fm.ImageAnnotations(
            points=points, texts=[self._label(str(frame), len(lanes), image, stamp)]
        )
        lines = []
        if geometry is not None:
            for lane in lanes:
                xz = lane_metres(lane, geometry)
                b, g, r = SIDE_COLOURS.get(lane.side, SIDE_COLOURS[""])
                lines.append(
                    fm.LinePrimitive(
                        type=fm.LinePrimitiveLineType.LineStrip,
                        points=[fm.Point3(x=float(z), y=float(-x), z=0.0) for x, z in xz],
                        thickness=0.15,
                        color=fm.Color(r=r / 255, g=g / 255, b=b / 255, a=1.0),
                    )
                )
        entity = fm.SceneEntity(timestamp=stamp, frame_id="road", id="lanes", lines=lines)
        msgs["scene"] = fm.SceneUpdate(entities=[entity])
        for key, msg in msgs.items():
            self.writer.add_message(self.channels[key], t, msg.encode(), t)
        timing = {
            "frame": str(frame),
            "index": self.count,
            "frame_ms": None if self._prev is None else round((now - self._prev) * 1000, 3),
            "lanes": len(lanes),
        }
        self.writer.add_message(self.channels["timings"], t, json.dumps(timing).encode(), t)
        self._prev = now
        self.count += 1
        self.last_time = t
        return {}

    def _label(self, frame: str, n: int, image: np.ndarray, stamp: Any) -> Any:
        """The frame id and lane count at the image's top left, stamped with the image's time: every
        frame's annotations then carry its stamp, which the Image panel's "sync annotations" mode
        matches (a frame without lanes would otherwise wait there for annotations that never come)."""
        fm = self.fm
        size = float(max(12, round(image.shape[1] / 60)))
        return fm.TextAnnotation(
            timestamp=stamp,
            position=fm.Point2(x=size / 2, y=size * 1.5),
            text=f"{frame}: {n} lane{'' if n == 1 else 's'}",
            font_size=size,
            text_color=fm.Color(r=1.0, g=1.0, b=1.0, a=1.0),
            background_color=fm.Color(r=0.0, g=0.0, b=0.0, a=0.6),
        )

    def _image(self, image: np.ndarray, stamp: Any) -> Any:
        fm = self.fm
        if self.p.image == "raw":
            img = np.ascontiguousarray(image)
            enc = "mono8" if img.ndim == 2 else "bgr8"
            return fm.RawImage(
                timestamp=stamp, frame_id="camera", width=img.shape[1], height=img.shape[0],
                encoding=enc, step=img.strides[0], data=img.tobytes(),
            )  # fmt: skip
        ext = ".jpg" if self.p.image == "jpeg" else ".png"
        args = [cv2.IMWRITE_JPEG_QUALITY, self.p.jpeg_quality] if ext == ".jpg" else []
        ok, buf = cv2.imencode(ext, image, args)
        if not ok:
            raise ValueError(f"cannot encode the left image as {self.p.image}")
        return fm.CompressedImage(timestamp=stamp, frame_id="camera", data=buf.tobytes(), format=self.p.image)

    def state(self) -> dict[str, Any]:
        """The frames written and the last one's time (the checkpoint checks ``frames``)."""
        return {"frames": self.count, "last_time": self.last_time}

    def restore(self, state: Any) -> None:
        """Copy the frames done (log time up to the checkpoint's ``last_time``) from the interrupted
        run's file into a new one, which then replaces it; refused (InputError) when the file is
        gone or holds fewer frames than the checkpoint recorded."""
        from mcap.stream_reader import StreamReader

        hint = "; cannot resume (run without --resume to start over)"
        frames = state.get("frames") if isinstance(state, dict) else None
        last = state.get("last_time") if isinstance(state, dict) else None
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in (frames, last)):
            raise InputError(
                f"the checkpoint holds no valid state of this writer (expected {{frames, last_time}}){hint}",
                path=str(self.path),
            )
        if frames and not self.path.is_file():
            raise InputError(
                f"missing: the checkpoint recorded {frames} frame(s) written here{hint}", path=str(self.path)
            )
        kept = []
        if frames:
            try:
                with open(self.path, "rb") as fh:
                    from mcap.records import Channel, Message

                    topics: dict[int, str] = {}
                    for record in StreamReader(fh, skip_magic=False).records:
                        if isinstance(record, Channel):
                            topics[record.id] = record.topic
                        elif isinstance(record, Message) and record.log_time <= last:
                            kept.append((topics.get(record.channel_id), record.log_time, record.data))
            except Exception as exc:  # noqa: BLE001 - a file cut short by a killed run: what was read is kept
                if not kept:
                    raise InputError(
                        f"cannot read the interrupted run's file ({exc}){hint}", path=str(self.path)
                    ) from None
            n = sum(1 for topic, _, _ in kept if topic == TOPICS["timings"])
            if n < frames:
                raise InputError(
                    f"holds {n} whole frame(s), the checkpoint recorded {frames}{hint}", path=str(self.path)
                )
        tmp = self.path.with_name(self.path.name + ".part")
        self._open(tmp)
        ids = {TOPICS[k]: v for k, v in self.channels.items()}
        for topic, t, data in kept:
            if topic in ids:
                self.writer.add_message(ids[topic], t, data, t)
        self.count, self.last_time = frames, last
        self._tmp = tmp

    def close(self) -> None:
        if self.writer is not None:
            self.writer.finish()
            self.fh.close()
            self.writer = None
            tmp = getattr(self, "_tmp", None)
            if tmp is not None:  # the resumed file is whole: it takes the interrupted run's place
                os.replace(tmp, self.path)
