"""``io.rosbag``: stereo pairs from a ROS 1 bag or a ROS 2 bag (MCAP or sqlite3), read by the
``rosbags`` library (no ROS installation; the ``io`` extra).

The left and right image topics are given, or found from the bag's ``CameraInfo`` topics (an image
topic beside each ``camera_info``; left and right told by the right camera's baseline term
``P[0,3]``, else by the names). Pairs are matched by header stamp within ``stamp_tolerance_ms``;
what does not pair is reported. ``sensor_msgs/Image`` (mono8, bgr8, rgb8, bgra8, rgba8, bayer_*8)
and ``sensor_msgs/CompressedImage`` (JPEG, PNG) are read.
"""

from __future__ import annotations

import bisect
from typing import Any

import cv2
import numpy as np
from pydantic import Field

from lanegraph import RunContext, node_type
from lanegraph.errors import InputError

from ._calibfiles import stereo_from_cameras
from ._png import decode_png
from ._stereo import StereoCalibration
from ._streams import (
    STREAM_OUTPUTS,
    STREAM_SOURCE_CAPABILITIES,
    StreamParams,
    StreamSource,
    log,
    match_stamps,
)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
#: ROS Bayer encodings -> OpenCV's conversion (cv_bridge's table: OpenCV names the pattern by its second row)
BAYER = {
    "bayer_rggb8": cv2.COLOR_BayerBG2BGR,
    "bayer_bggr8": cv2.COLOR_BayerRG2BGR,
    "bayer_gbrg8": cv2.COLOR_BayerGR2BGR,
    "bayer_grbg8": cv2.COLOR_BayerGB2BGR,
}
ENCODINGS = ("mono8", "bgr8", "rgb8", "bgra8", "rgba8", *BAYER)


def need_rosbags():
    try:
        import rosbags.highlevel  # noqa: F401
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise InputError("io.rosbag needs the 'rosbags' package: pip install 'lanegraph[io]'") from None
    return get_typestore(Stores.ROS2_HUMBLE)


class RosbagParams(StreamParams):
    """Params of ``io.rosbag``."""

    left_topic: str = Field("", max_length=500, description="left image topic; empty: found from CameraInfo")
    right_topic: str = Field(
        "", max_length=500, description="right image topic; empty: found from CameraInfo"
    )
    stamp_tolerance_ms: float = Field(
        5.0,
        ge=0.0,
        le=1000.0,
        description="left and right header stamps further apart than this do not pair, ms",
    )
    stamps: str = Field(
        "header",
        pattern="^(header|log)$",
        description="pair by the messages' header stamps, or by the times the bag logged them (log)",
    )


def _stamp(msg: Any, log_time: int, which: str) -> int:
    if which == "log":
        return int(log_time)
    st = msg.header.stamp
    return int(st.sec) * 1_000_000_000 + int(getattr(st, "nanosec", getattr(st, "nsec", 0)))


def _field(msg: Any, *names: str) -> Any:
    for n in names:
        if hasattr(msg, n):
            return getattr(msg, n)
    raise AttributeError(names[0])


def camera_from_info(msg: Any) -> dict:
    """A ROS ``CameraInfo`` message (ROS 1 ``K``, ROS 2 ``k`` ...) as ``{K, D, R, P, width, height}``."""
    return {
        "K": np.asarray(_field(msg, "k", "K"), np.float64).reshape(3, 3),
        "D": np.asarray(_field(msg, "d", "D"), np.float64).reshape(-1),
        "R": np.asarray(_field(msg, "r", "R"), np.float64).reshape(3, 3),
        "P": np.asarray(_field(msg, "p", "P"), np.float64).reshape(3, 4),
        "width": int(msg.width),
        "height": int(msg.height),
    }


def decode_image(
    msg: Any, msgtype: str, topic: str, max_megapixels: float, path: str, frame: str
) -> np.ndarray:
    """A ROS image message as an 8-bit BGR or grey array; an InputError naming the topic otherwise."""
    if msgtype == COMPRESSED:
        fmt = str(msg.format).lower()
        data = np.asarray(msg.data, dtype=np.uint8)
        img = None
        if "png" in fmt:
            try:
                img = decode_png(data.tobytes(), False)
            except OSError:
                img = None
        elif "jpeg" in fmt or "jpg" in fmt:
            pass
        else:
            raise InputError(
                f"topic {topic}: CompressedImage format {msg.format!r} is not read (expected jpeg or png)",
                path=path,
                frame=frame,
            )
        if img is None:
            img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError(f"topic {topic}: cannot decode the compressed image", path=path, frame=frame)
        if img.ndim == 3 and img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
        return img
    h, w, enc = int(msg.height), int(msg.width), str(msg.encoding).lower()
    if h * w > max_megapixels * 1e6:
        raise InputError(
            f"topic {topic}: image is {w}x{h}, above the source's max_megapixels {max_megapixels:g}; refused",
            path=path,
            frame=frame,
        )
    if enc not in ENCODINGS:
        raise InputError(
            f"topic {topic}: image encoding {msg.encoding!r} is not read (expected one of {', '.join(ENCODINGS)})",
            path=path,
            frame=frame,
        )
    ch = 3 if enc in ("bgr8", "rgb8") else 4 if enc in ("bgra8", "rgba8") else 1
    step = int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * ch or data.size < step * h:
        raise InputError(
            f"topic {topic}: a {w}x{h} {enc} image needs {w * ch * h} bytes (step {step}), the message holds {data.size}",
            path=path,
            frame=frame,
        )
    img = data[: step * h].reshape(h, step)[:, : w * ch]
    img = img.reshape(h, w, ch) if ch > 1 else img
    if enc == "rgb8":
        return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    if enc == "bgra8":
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    if enc == "rgba8":
        return cv2.cvtColor(img, cv2.COLOR_RGBA2BGR)
    if enc in BAYER:
        return cv2.cvtColor(np.ascontiguousarray(img), BAYER[enc])
    return np.array(img, order="C")  # its own, writeable pixels: not a view of the bag's read-only buffer


def _namespace(topic: str) -> str:
    return topic.rsplit("/", 1)[0]


def info_topic(topic: str, infos: list[str] | set[str]) -> str | None:
    """The ``camera_info`` topic of image topic ``topic``: beside it, or beside a namespace above it
    (``/cam/left/image_raw/compressed`` -> ``/cam/left/camera_info``); None when there is none."""
    ns = _namespace(topic)
    while ns:
        if ns + "/camera_info" in infos:
            return ns + "/camera_info"
        ns = _namespace(ns)
    return None


@node_type("io.rosbag", source=True, outputs=STREAM_OUTPUTS, implements=STREAM_SOURCE_CAPABILITIES)
class RosbagSource(StreamSource):
    """Stereo pairs from a ROS 1 bag (``.bag``) or a ROS 2 bag (a ``.mcap`` or ``.db3`` file, or the bag's
    folder), paired by header stamp; the calibration from ``--calib`` or the bag's CameraInfo."""

    def __init__(self, params: RosbagParams, context: RunContext):
        self.p = params
        super().__init__(params, context)

    def _open(self):
        from rosbags.highlevel import AnyReader

        typestore = need_rosbags()
        try:
            reader = AnyReader([self.root], default_typestore=typestore)
            reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags' own errors (ReaderError, AnyReaderError, struct, ...)
            raise InputError(
                f"cannot read the bag ({type(exc).__name__}: {exc}); truncated or not a ROS bag?",
                path=str(self.root),
            ) from None
        return reader

    def index(self) -> list[str]:
        reader = self.reader = self._open()
        path = str(self.root)
        images = sorted({c.topic for c in reader.connections if c.msgtype in (IMAGE, COMPRESSED)})
        infos = sorted({c.topic for c in reader.connections if c.msgtype == CAMERA_INFO})
        listing = ", ".join(images) or "none"
        if self.p.left_topic or self.p.right_topic:
            if not (self.p.left_topic and self.p.right_topic):
                raise InputError("give both left_topic and right_topic, or neither", path=path)
            for t in (self.p.left_topic, self.p.right_topic):
                if t not in images:
                    raise InputError(
                        f"topic {t!r}: no image messages in the bag (its image topics: {listing})", path=path
                    )
            left, right = self.p.left_topic, self.p.right_topic
            if left == right:
                raise InputError(
                    f"left_topic and right_topic are both {left!r}; expected two cameras", path=path
                )
        else:
            left, right = self._find_topics(reader, images, infos)
        self.topics = (left, right)
        conns = {t: [c for c in reader.connections if c.topic == t] for t in (left, right)}
        self.msgtypes = {t: cs[0].msgtype for t, cs in conns.items()}
        stamps: dict[str, list[tuple[int, int]]] = {left: [], right: []}  # (stamp, log time) in bag order
        self.infos: dict[str, Any] = {}
        self.info_of = {t: info_topic(t, infos) for t in (left, right)}
        info_topics = {i: t for t, i in self.info_of.items() if i is not None}
        wanted = [c for cs in conns.values() for c in cs] + [
            c for c in reader.connections if c.topic in info_topics
        ]
        log.info("io.rosbag: indexing %s (topics %s, %s)", self.root, left, right)
        try:
            for conn, t, raw in reader.messages(connections=wanted):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.msgtype == CAMERA_INFO:
                    self.infos.setdefault(info_topics[conn.topic], msg)
                    continue
                stamps[conn.topic].append((_stamp(msg, t, self.p.stamps), t))
                if len(stamps[conn.topic]) == 1:
                    self._first = getattr(self, "_first", {})
                    self._first[conn.topic] = (msg, conn.msgtype)
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 - a truncated chunk, an unknown compression, a bad message
            raise InputError(
                f"cannot read the bag's messages ({type(exc).__name__}: {exc}); truncated, or compressed with a codec rosbags does not read?",
                path=path,
            ) from None
        self.log_times = {t: [lt for _, lt in stamps[t]] for t in (left, right)}
        for t in (left, right):
            if not stamps[t]:
                raise InputError(f"topic {t!r} holds no messages", path=path)
            self._check_stamps(t, [s for s, _ in stamps[t]])
        self.pairs = self._match(stamps[left], stamps[right])
        if not self.pairs:
            raise InputError(
                f"no left image of {left} has a right image of {right} within {self.p.stamp_tolerance_ms:g} ms "
                f"(first stamps {stamps[left][0][0]} and {stamps[right][0][0]} ns); raise stamp_tolerance_ms, or "
                "pair by log time (stamps: log)",
                path=path,
            )
        return [str(pair[0]) for pair in self.pairs]

    def _find_topics(self, reader: Any, images: list[str], infos: list[str]) -> tuple[str, str]:
        path = str(self.root)
        listing = ", ".join(images) or "none"
        if not images:
            raise InputError(
                "no sensor_msgs/Image or CompressedImage topic in the bag; expected a left and a right camera",
                path=path,
            )
        beside = [t for t in images if info_topic(t, infos) is not None]
        cands = beside if len(beside) >= 2 else images
        lefts = [t for t in cands if "left" in t.lower()]
        rights = [t for t in cands if "right" in t.lower()]
        if len(cands) == 1:
            raise InputError(
                f"one camera only: the bag's one image topic is {cands[0]}; a stereo pair needs a left and a right camera",
                path=path,
            )
        if len(lefts) == 1 and len(rights) == 1:
            return lefts[0], rights[0]
        if len(beside) == 2:  # two cameras with CameraInfo: the right one's P[0,3] is -fx B
            tx = self._baseline_terms(reader, {info_topic(t, infos): t for t in beside})
            if len(tx) == 2 and sorted(v == 0 for v in tx.values()) == [False, True]:
                left = next(t for t, v in tx.items() if v == 0)
                return left, next(t for t in tx if t != left)
        raise InputError(
            f"cannot tell the left and right image topics among {listing} (CameraInfo topics: {', '.join(infos) or 'none'}); "
            "give them: --set src.left_topic=TOPIC --set src.right_topic=TOPIC",
            path=path,
        )

    def _baseline_terms(self, reader: Any, info_to_image: dict[str, str]) -> dict[str, float]:
        """Image topic -> ``P[0,3]`` of its first CameraInfo message."""
        out: dict[str, float] = {}
        conns = [c for c in reader.connections if c.topic in info_to_image]
        try:
            for conn, _t, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                out.setdefault(info_to_image[conn.topic], float(camera_from_info(msg)["P"][0, 3]))
                if len(out) == len(info_to_image):
                    break
        except Exception:  # noqa: BLE001 - reported when the messages are indexed
            pass
        return out

    def _check_stamps(self, topic: str, stamps: list[int]) -> None:
        for k in range(1, len(stamps)):
            if stamps[k] == stamps[k - 1]:
                raise InputError(
                    f"topic {topic}: messages {k - 1} and {k} have the same stamp {stamps[k]} ns (duplicate frame?); "
                    "expected increasing stamps (stamps: log pairs by the bag's log times)",
                    path=str(self.root),
                )
            if stamps[k] < stamps[k - 1]:
                raise InputError(
                    f"topic {topic}: stamps not in order: message {k} has stamp {stamps[k]} ns, before message "
                    f"{k - 1}'s {stamps[k - 1]} ns; expected increasing stamps",
                    path=str(self.root),
                )

    def _match(
        self, lefts: list[tuple[int, int]], rights: list[tuple[int, int]]
    ) -> list[tuple[int, int, int]]:
        """``(stamp, left message index, right message index)`` for every left image whose nearest
        right image (each used once) is within the tolerance; the rest reported."""
        tol = int(round(self.p.stamp_tolerance_ms * 1e6))
        ls, rs = [s for s, _ in lefts], [s for s, _ in rights]
        pairs = [(ls[i], i, j) for i, j in match_stamps(ls, rs, tol)]
        worst = max((abs(rs[j] - s) for s, _, j in pairs), default=0)
        left_out, right_out = len(lefts) - len(pairs), len(rights) - len(pairs)
        self.pairing = {
            "pairs": len(pairs),
            "left_unpaired": left_out,
            "right_unpaired": right_out,
            "max_dt_ms": worst / 1e6,
        }
        if left_out or right_out:
            log.warning(
                "io.rosbag %s: %d pair(s) matched by stamp within %g ms; left out: %d left and %d right image(s) "
                "without a partner (largest difference kept: %.3f ms)",
                self.root, len(pairs), self.p.stamp_tolerance_ms, left_out, right_out, worst / 1e6,
            )  # fmt: skip
        return pairs

    def frame_size(self) -> tuple[int, int]:
        msg, msgtype = self._first[self.topics[0]]
        if msgtype == IMAGE:
            return int(msg.width), int(msg.height)
        img = decode_image(msg, msgtype, self.topics[0], self.p.max_megapixels, str(self.root), "first")
        return img.shape[1], img.shape[0]

    def input_calibration(self) -> StereoCalibration | None:
        left, right = self.topics
        if left not in self.infos or right not in self.infos:
            return None
        cams = [camera_from_info(self.infos[t]) for t in (left, right)]
        names = {
            "P1": f"{self.info_of[left]} P",
            "P2": f"{self.info_of[right]} P",
            "K1": f"{self.info_of[left]} K",
            "K2": f"{self.info_of[right]} K",
            "width": f"{self.info_of[left]} width/height",
        }
        return stereo_from_cameras(cams[0], cams[1], f"{self.root} (CameraInfo)", names)

    def read(self, frames: list[int]):
        if not frames:
            return
        left, right = self.topics
        want_l = {self.pairs[f][1]: f for f in frames}
        want_r = {self.pairs[f][2]: f for f in frames}
        got: dict[int, dict[str, Any]] = {}
        order = iter(frames)
        nxt = next(order, None)
        # seek: start at the first wanted message's log time, each topic's count where it is there
        start = min(self.log_times[left][min(want_l)], self.log_times[right][min(want_r)])
        count = {t: bisect.bisect_left(self.log_times[t], start) - 1 for t in (left, right)}
        conns = [c for c in self.reader.connections if c.topic in (left, right)]
        path = str(self.root)
        try:
            for conn, _t, raw in self.reader.messages(connections=conns, start=start):
                count[conn.topic] += 1
                k = count[conn.topic]
                f = (want_l if conn.topic == left else want_r).get(k)
                if f is None:
                    continue
                frame = str(self.pairs[f][0])
                try:
                    msg = self.reader.deserialize(raw, conn.msgtype)
                    img = decode_image(msg, conn.msgtype, conn.topic, self.p.max_megapixels, path, frame)
                except InputError as exc:
                    img = exc
                got.setdefault(f, {})["left" if conn.topic == left else "right"] = img
                while nxt is not None and len(got.get(nxt, {})) == 2:
                    pair = got.pop(nxt)
                    fid = str(self.pairs[nxt][0])
                    bad = next((v for v in pair.values() if isinstance(v, InputError)), None)
                    yield bad if bad is not None else (fid, pair["left"], pair["right"])
                    nxt = next(order, None)
                if nxt is None:
                    return
        except Exception as exc:  # noqa: BLE001 - the bag ends early (truncated since it was opened)
            yield InputError(f"cannot read the bag's messages ({type(exc).__name__}: {exc})", path=path)

    def close(self) -> None:
        super().close()
        reader = getattr(self, "reader", None)
        if reader is not None:
            try:
                reader.close()
            except Exception:  # noqa: BLE001 - closing a reader that failed to read
                pass
            self.reader = None
