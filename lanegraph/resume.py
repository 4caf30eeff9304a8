"""Resuming an interrupted run (``lanegraph run ... --resume``).

A run rewrites ``OUT/checkpoint.pkl`` atomically after every complete frame (after its sinks
wrote it) with the frame's index and the values of the graph's feedback edges. To resume:

1. the checkpoint says which frame was the last complete one and restores the feedback values, so
   the temporal nodes continue exactly as in an uninterrupted run;
2. ``lanes.jsonl`` is cut back to the lines up to that frame (a frame written after the checkpoint,
   or a partial last line of a killed process, is dropped and computed again);
3. the frame selection continues with the next frame and the lanes writer appends.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path
from typing import Any

from .errors import UsageError
from .graph import Graph


def _cut_lanes(path: Path, last_frame: str) -> int:
    """Keep the complete lines of ``path`` up to the one of ``last_frame``; returns how many."""
    if not path.is_file():
        return 0
    keep: list[str] = []
    found = False
    with path.open(encoding="utf-8") as fh:
        for line in fh:
            if not line.endswith("\n"):
                break  # a partial last line
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                break
            keep.append(line)
            if str(rec.get("frame")) == str(last_frame):
                found = True
                break
    if not found:
        raise UsageError(f"{path}: frame {last_frame} of the checkpoint is not in the file; cannot resume (run without --resume)")
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(keep), encoding="utf-8")
    tmp.replace(path)
    return len(keep)


def prepare_resume(out_dir: Path, checkpoint: Path, selection: slice | None, graph: Graph) -> tuple[slice | None, dict[str, Any] | None]:
    """The frame selection that continues the interrupted run, and the state to resume from
    (``None``: nothing to resume, start from the beginning)."""
    if not checkpoint.is_file():
        return selection, None
    try:
        state = pickle.loads(checkpoint.read_bytes())  # noqa: S301 - written by lanegraph in OUT
    except Exception as exc:  # noqa: BLE001
        raise UsageError(f"{checkpoint}: unreadable checkpoint ({exc}); run without --resume") from None
    if state.get("graph") != graph.file:
        raise UsageError(f"{checkpoint}: was written by graph {state.get('graph')!r}, not {graph.file!r}; run without --resume")
    sel = selection or slice(None)
    if (sel.start or 0) < 0 or (sel.stop is not None and sel.stop < 0) or (sel.step or 1) < 1:
        raise UsageError("--resume needs a frame selection with non-negative start/stop and a positive step")
    done = int(state["index"]) + 1
    step = sel.step or 1
    state["done"] = _cut_lanes(out_dir / "lanes.jsonl", state["frame"])
    return slice((sel.start or 0) + done * step, sel.stop, step), state
