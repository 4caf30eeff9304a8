"""What a run did: :class:`RunResult` (frames, per-node timings, failures) and :class:`FrameFailure`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class FrameFailure:
    """A frame that failed: which node, and why."""

    frame: str | None
    index: int
    node_id: str
    node_type: str
    error: str

    def to_json(self) -> dict[str, Any]:
        return {
            "frame": self.frame,
            "index": self.index,
            "node": self.node_id,
            "type": self.node_type,
            "error": self.error,
        }


@dataclass
class RunResult:
    """What a run did: frames processed, per-node timings and failures.

    In a resumed run ``frames``, ``failures`` and ``invalid_outputs`` include what the checkpoint
    recorded (``resumed_frames`` of the frames were done before); timings cover this process only.
    ``invalid_outputs``: ``"node.port" -> [frames with an invalid value, frames with a value]``
    for values that carry a ``valid`` flag (a road model the profile could not fit).
    """

    frames: int = 0
    timings_ms: dict[str, list[float]] = field(default_factory=dict)
    node_types: dict[str, str] = field(default_factory=dict)
    failures: list[FrameFailure] = field(default_factory=list)
    frame_ms: list[float] = field(default_factory=list)
    cache_hits: dict[str, int] = field(default_factory=dict)
    cache_misses: dict[str, int] = field(default_factory=dict)
    invalid_outputs: dict[str, list[int]] = field(default_factory=dict)
    resumed_frames: int = 0
    notes: list[str] = field(default_factory=list)
    results: dict[str, str] = field(
        default_factory=dict
    )  # the sinks' result files by kind (lanegraph.records.results)
    #: the ids of the frames of the selection the run consumed (done or failed), in order: what
    #: ``eval`` and ``report`` score (warm-up frames are not among them)
    frame_ids: list[str] = field(default_factory=list)
    #: node id -> the frames on which it was computed ahead (lanegraph.run.ahead): its time there
    #: is the wall time on its own thread, beside the previous frame's later nodes
    ahead: dict[str, int] = field(default_factory=dict)

    def warnings(self) -> list[str]:
        """Things that did not fail a frame but make the result doubtful: an output invalid on every
        frame, a run that cannot be resumed."""
        out = list(self.notes)
        for key, (bad, total) in self.invalid_outputs.items():
            if total and bad == total:
                nid, _, port = key.rpartition(".")
                out.append(
                    f"node '{nid}' ({self.node_types.get(nid, '?')}): output '{port}' was invalid on every frame "
                    f"({bad} of {total}); check the calibration and the input"
                )
        return out

    def timings_json(self) -> dict[str, Any]:
        nodes = {}
        for nid, ts in self.timings_ms.items():
            arr = np.asarray(ts, dtype=np.float64)
            nodes[nid] = {
                "type": self.node_types.get(nid, "?"),
                "median_ms": round(float(np.median(arr)), 3) if arr.size else None,
                "p90_ms": round(float(np.percentile(arr, 90)), 3) if arr.size else None,
                "calls": int(arr.size),
            }
            if self.ahead.get(nid):
                nodes[nid]["ahead"] = self.ahead[nid]
        out: dict[str, Any] = {"frames": self.frames, "nodes": nodes}
        if self.frame_ms:
            total = np.asarray(self.frame_ms)
            out["total"] = {
                "median_ms": round(float(np.median(total)), 3),
                "p90_ms": round(float(np.percentile(total, 90)), 3),
            }
        return out
