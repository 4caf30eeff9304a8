"""``io.video``: stereo pairs from one side-by-side video (left | right halves) or from two videos
(``left.<ext>`` and ``right.<ext>`` in a folder) paired by timestamp, decoded by PyAV (the ``io``
extra). Frames are indexed from the container's packets when the source opens (a variable frame
rate is refused); ``--frames`` and a resumed run seek to the key frame before the first frame
wanted; a packet that does not decode fails its frame only.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from lanegraph import RunContext, node_type
from lanegraph.errors import InputError

from ._auto import video_pair
from ._streams import (
    STREAM_OUTPUTS,
    STREAM_SOURCE_CAPABILITIES,
    StreamParams,
    StreamSource,
    log,
    match_stamps,
)


def need_av():
    try:
        import av
    except ImportError:
        raise InputError("io.video needs the 'av' package (PyAV): pip install 'lanegraph[io]'") from None
    return av


class VideoParams(StreamParams):
    """Params of ``io.video``."""

    sync_tolerance_ms: float = Field(
        -1.0,
        ge=-1.0,
        le=1000.0,
        description="two videos: frames further apart in time do not pair, ms; -1 = half a frame interval",
    )
    max_rate_jitter: float = Field(
        0.02,
        ge=0.0,
        le=1.0,
        description="largest relative difference between a frame interval and the median one; a video beyond it "
        "has a variable frame rate and is refused (re-encode it at a constant rate)",
    )


class _Track:
    """One video file: its stream's frame timestamps (pts, sorted) and how to decode them."""

    def __init__(self, path: Path, jitter: float):
        av = need_av()
        self.path = path
        try:
            container = av.open(str(path))
        except Exception as exc:  # noqa: BLE001 - av.error.* (InvalidDataError ...), OSError
            raise InputError(f"cannot open the video ({type(exc).__name__}: {exc})", path=str(path)) from None
        try:
            if not container.streams.video:
                raise InputError("no video stream in the file", path=str(path))
            stream = container.streams.video[0]
            self.time_base = stream.time_base
            self.width, self.height = int(stream.codec_context.width), int(stream.codec_context.height)
            pts = []
            for packet in container.demux(stream):
                if packet.size and packet.pts is not None:
                    pts.append(int(packet.pts))
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 - a container that ends early
            raise InputError(
                f"cannot read the video's packets ({type(exc).__name__}: {exc})", path=str(path)
            ) from None
        finally:
            container.close()
        if not pts:
            raise InputError("the video holds no frames", path=str(path))
        self.pts = sorted(pts)
        if len(set(self.pts)) != len(self.pts):
            raise InputError("two frames of the video have the same timestamp (pts)", path=str(path))
        steps = np.diff(self.pts)
        if len(steps):
            med = float(np.median(steps))
            worst = int(np.argmax(np.abs(steps - med)))
            if abs(steps[worst] - med) > max(jitter * med, 1):
                ms = [float(s * self.time_base * 1000) for s in (steps.min(), steps.max())]
                raise InputError(
                    f"variable frame rate: frame intervals from {ms[0]:.2f} to {ms[1]:.2f} ms (frame {worst + 1} after "
                    f"{float(steps[worst] * self.time_base * 1000):.2f} ms, the median is {float(med * self.time_base * 1000):.2f} ms); "
                    "expected a constant frame rate (re-encode at one, e.g. ffmpeg -fps_mode cfr)",
                    path=str(path),
                )
        self.interval_s = float(np.median(steps) * self.time_base) if len(steps) else 0.1

    def seconds(self, k: int) -> float:
        return float(self.pts[k] * self.time_base)

    def decode(self, wanted: list[int], frame_ids: list[str]):
        """``(k, BGR image or InputError)`` for each frame index of ``wanted`` (increasing), in that
        order, seeking to the key frame before the first; a packet that does not decode fails its
        frame."""
        av = need_av()
        if not wanted:
            return
        want = {self.pts[k]: (k, fid) for k, fid in zip(wanted, frame_ids)}
        order = [self.pts[k] for k in wanted]
        got: dict[int, Any] = {}
        nxt = 0
        container = av.open(str(self.path))
        try:
            stream = container.streams.video[0]
            if wanted[0] > 0:
                container.seek(self.pts[wanted[0]], stream=stream, backward=True, any_frame=False)
            for packet in container.demux(stream):
                try:
                    frames = packet.decode()
                except Exception as exc:  # noqa: BLE001 - av.error.InvalidDataError: a corrupt packet
                    if packet.pts in want and packet.pts not in got:
                        got[packet.pts] = InputError(
                            f"the frame's packet does not decode ({type(exc).__name__}: {exc}); corrupt?",
                            path=str(self.path),
                            frame=want[packet.pts][1],
                        )
                    frames = []
                for frame in frames:
                    if frame.pts in want and frame.pts not in got:
                        got[frame.pts] = frame.to_ndarray(format="bgr24")
                    # frames come out in presentation order: a wanted one before this one is lost
                    for q in order[nxt:]:
                        if q >= frame.pts:
                            break
                        got.setdefault(q, None)
                while nxt < len(order) and order[nxt] in got:
                    yield want[order[nxt]][0], self._or_lost(got.pop(order[nxt]), want[order[nxt]][1])
                    nxt += 1
                if nxt == len(order):
                    return
        except Exception as exc:  # noqa: BLE001 - the file ends early
            log.debug("io.video: %s: decoding stopped: %s", self.path, exc)
        finally:
            container.close()
        for p in order[nxt:]:
            k, fid = want[p]
            yield k, self._or_lost(got.pop(p, None), fid)

    def _or_lost(self, item: Any, fid: str) -> Any:
        if item is not None:
            return item
        return InputError(
            "the frame was not decoded (its packet missing or corrupt)", path=str(self.path), frame=fid
        )


@node_type("io.video", source=True, outputs=STREAM_OUTPUTS, implements=STREAM_SOURCE_CAPABILITIES)
class VideoSource(StreamSource):
    """Stereo pairs from one side-by-side video (left | right halves) or from a folder holding
    ``left.<ext>`` and ``right.<ext>``, paired by timestamp; the calibration from ``--calib``."""

    def __init__(self, params: VideoParams, context: RunContext):
        self.p = params
        super().__init__(params, context)

    def index(self) -> list[str]:
        jitter = self.p.max_rate_jitter
        if self.root.is_dir():
            files = video_pair(self.root)
            if files is None:
                raise InputError(
                    "expected a side-by-side video file, or a folder holding left.<ext> and right.<ext> videos",
                    path=str(self.root),
                )
            self.tracks = [_Track(files[0], jitter), _Track(files[1], jitter)]
            self.pairs = self._match(*self.tracks)
        else:
            track = _Track(self.root, jitter)
            if track.width % 2:
                raise InputError(
                    f"a side-by-side stereo video has an even width (left | right halves), this one is "
                    f"{track.width} px wide",
                    path=str(self.root),
                )
            self.tracks = [track]
            self.pairs = [(k, k) for k in range(len(track.pts))]
        return [f"{k:010d}" for k, _ in self.pairs]

    def _match(self, left: _Track, right: _Track) -> list[tuple[int, int]]:
        tol = self.p.sync_tolerance_ms / 1000 if self.p.sync_tolerance_ms >= 0 else left.interval_s / 2
        ls = [left.seconds(k) for k in range(len(left.pts))]
        rs = [right.seconds(k) for k in range(len(right.pts))]
        pairs = match_stamps(ls, rs, tol)
        worst = max((abs(rs[j] - ls[i]) for i, j in pairs), default=0.0)
        if not pairs:
            raise InputError(
                f"no frame of {left.path.name} has a frame of {right.path.name} within {tol * 1000:g} ms",
                path=str(self.root),
            )
        lo, ro = len(left.pts) - len(pairs), len(right.pts) - len(pairs)
        if lo or ro:
            log.warning(
                "io.video %s: %d pair(s) matched by timestamp within %g ms; left out: %d left and %d right frame(s) "
                "without a partner (largest difference kept: %.3f ms)",
                self.root, len(pairs), tol * 1000, lo, ro, worst * 1000,
            )  # fmt: skip
        if (left.width, left.height) != (right.width, right.height):
            raise InputError(
                f"the left video is {left.width}x{left.height}, the right {right.width}x{right.height} (expected one size)",
                path=str(self.root),
            )
        return pairs

    def frame_size(self) -> tuple[int, int]:
        t = self.tracks[0]
        return (t.width // 2, t.height) if len(self.tracks) == 1 else (t.width, t.height)

    def input_files(self) -> list[Path]:
        return [t.path for t in self.tracks]

    def read(self, frames: list[int]):
        ids = [self.all_ids[f] for f in frames]
        if len(self.tracks) == 1:
            half = self.tracks[0].width // 2
            for (_, img), fid in zip(
                self.tracks[0].decode([self.pairs[f][0] for f in frames], ids), ids, strict=True
            ):
                if isinstance(img, InputError):
                    yield img
                else:
                    yield fid, np.ascontiguousarray(img[:, :half]), np.ascontiguousarray(img[:, half:])
            return
        lefts = self.tracks[0].decode([self.pairs[f][0] for f in frames], ids)
        rights = self.tracks[1].decode([self.pairs[f][1] for f in frames], ids)
        for (_, a), (_, b), fid in zip(lefts, rights, ids):
            bad: Any = a if isinstance(a, InputError) else b if isinstance(b, InputError) else None
            yield bad if bad is not None else (fid, a, b)
