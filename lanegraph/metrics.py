"""The lane metric of ``shared/data/README.md``: detection ratio, precision, ego recall, mean |dx|.

Rules (verbatim from the data README):

- ``x(y)`` of a polyline is linear interpolation between its points, defined only inside its y range.
- A prediction *matches* a marking when it covers at least 50 % of the marking's annotated rows and,
  on those rows, at least 85 % have ``|x_pred - x_gt| <= 20 px``.
- Matching is one-to-one, greedy by mean ``|dx|``.
- A frame is *correct* when every reported lane matches a distinct marking (no false lane) and every
  painted ego-lane boundary (``ego.left``, ``ego.right`` when not null) is matched. A frame with no
  markings is correct only if nothing is reported.
- detection ratio = correct frames / frames; precision = matched lanes / reported lanes;
  ego recall = matched ego boundaries / ego boundaries; mean |dx| over matched lanes, in pixels.
- A frame missing from the predictions counts as a frame with nothing reported.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError

COVER_MIN = 0.5
ROW_OK_FRACTION = 0.85
DX_MAX_PX = 20.0


def polyline_x_at(points: Sequence[Sequence[float]], ys: np.ndarray) -> np.ndarray:
    """``x(y)`` of a polyline at rows ``ys`` by linear interpolation; NaN outside its y range."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    out = np.full(np.shape(ys), np.nan)
    if len(pts) == 0:
        return out
    order = np.argsort(pts[:, 1], kind="stable")
    x, y = pts[order, 0], pts[order, 1]
    ys = np.asarray(ys, dtype=np.float64)
    inside = (ys >= y[0]) & (ys <= y[-1])
    if len(pts) == 1:
        out[inside] = x[0]
    else:
        out[inside] = np.interp(ys[inside], y, x)
    return out


def match_score(pred_points: Sequence[Sequence[float]], gt_points: Sequence[Sequence[float]]) -> float | None:
    """Mean |dx| over the covered rows if the prediction matches the marking, else None."""
    gt = np.asarray(gt_points, dtype=np.float64).reshape(-1, 2)
    if len(gt) == 0:
        return None
    xp = polyline_x_at(pred_points, gt[:, 1])
    covered = ~np.isnan(xp)
    n_cov = int(covered.sum())
    if n_cov == 0 or n_cov < COVER_MIN * len(gt):
        return None
    dx = np.abs(xp[covered] - gt[covered, 0])
    if np.mean(dx <= DX_MAX_PX) < ROW_OK_FRACTION:
        return None
    return float(dx.mean())


#: outcome of a reported lane: it matches a distinct marking, or it is a false lane
LANE_MATCHED, LANE_FALSE = "matched", "false"
#: outcome of a ground-truth marking: matched; a painted ego boundary left unmatched (the frame
#: fails); any other marking left unmatched (allowed: only ego boundaries must be found)
MARKING_MATCHED, MARKING_MISSED_EGO, MARKING_UNMATCHED = "matched", "missed_ego", "unmatched"


@dataclass
class FrameMatch:
    """The one-to-one matching of one frame's reported lanes to its ground-truth markings.

    ``lane_marking[i]`` is the index (into the frame's ``markings``) of the marking reported lane
    ``i`` matches, or None for a false lane; ``lane_dx[i]`` its mean |dx| in pixels (None when
    unmatched); ``marking_lane[j]`` the reverse. ``ego`` maps each side with a painted ego boundary
    (``ego.left`` / ``ego.right`` not null) to that marking's index, None when the id names no marking.
    """

    lane_marking: list[int | None]
    lane_dx: list[float | None]
    marking_lane: list[int | None]
    ego: dict[str, int | None]
    ego_ids: dict[str, Any] = field(default_factory=dict)

    def lane_outcomes(self) -> list[str]:
        """Per reported lane: ``"matched"`` or ``"false"``."""
        return [LANE_FALSE if j is None else LANE_MATCHED for j in self.lane_marking]

    def marking_outcomes(self) -> list[str]:
        """Per marking: ``"matched"``, ``"missed_ego"`` (an ego boundary left unmatched) or ``"unmatched"``."""
        ego = {j for j in self.ego.values() if j is not None}
        return [
            MARKING_MATCHED if i is not None else (MARKING_MISSED_EGO if j in ego else MARKING_UNMATCHED)
            for j, i in enumerate(self.marking_lane)
        ]


def match_frame(pred_lanes: Sequence[Mapping[str, Any]], gt: Mapping[str, Any]) -> FrameMatch:
    """Match one frame's reported lanes to its ground-truth markings: every (lane, marking) pair
    that :func:`match_score` accepts, taken greedily by mean |dx|, each lane and marking once."""
    markings = list(gt.get("markings") or [])
    pairs = []
    for i, lane in enumerate(pred_lanes):
        for j, m in enumerate(markings):
            s = match_score(lane.get("points") or [], m.get("points") or [])
            if s is not None:
                pairs.append((s, i, j))
    pairs.sort()
    lane_marking: list[int | None] = [None] * len(pred_lanes)
    lane_dx: list[float | None] = [None] * len(pred_lanes)
    marking_lane: list[int | None] = [None] * len(markings)
    for s, i, j in pairs:
        if lane_marking[i] is not None or marking_lane[j] is not None:
            continue
        lane_marking[i], lane_dx[i], marking_lane[j] = j, s, i
    ego_spec = gt.get("ego") or {}
    ids = {m.get("id"): j for j, m in enumerate(markings)}
    ego: dict[str, int | None] = {}
    ego_ids: dict[str, Any] = {}
    for side in ("left", "right"):
        mid = ego_spec.get(side)
        if mid is not None:
            ego[side] = ids.get(mid)
            ego_ids[side] = mid
    return FrameMatch(lane_marking, lane_dx, marking_lane, ego, ego_ids)


@dataclass
class FrameResult:
    frame: str
    correct: bool
    reported: int
    matched: int
    ego_total: int
    ego_matched: int
    dx: list[float] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)
    match: FrameMatch | None = None  # the matching the figures were counted from


def evaluate_frame(pred_lanes: Sequence[Mapping[str, Any]], gt: Mapping[str, Any]) -> FrameResult:
    """Evaluate one frame's reported lanes against its ground-truth record."""
    m = match_frame(pred_lanes, gt)
    frame = str(gt.get("frame"))
    # mean |dx| of the matches, in the order they were taken (greedy by mean |dx|)
    dx = sorted(d for d in m.lane_dx if d is not None)
    reasons = []
    unmatched = [i for i, j in enumerate(m.lane_marking) if j is None]
    if unmatched:
        reasons.append(f"{len(unmatched)} false lane(s) (reported lane index {unmatched})")
    ego_matched = 0
    for side, j in m.ego.items():
        if j is not None and m.marking_lane[j] is not None:
            ego_matched += 1
        else:
            reasons.append(f"ego {side} boundary (marking {m.ego_ids[side]}) not matched")
    correct = not reasons
    matched = len(pred_lanes) - len(unmatched)
    return FrameResult(frame, correct, len(pred_lanes), matched, len(m.ego), ego_matched, dx, reasons, m)


def evaluate(pred_records: Iterable[Mapping[str, Any]], gt_records: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Evaluate prediction records against ground-truth records (both as parsed JSON lines).

    Returns a dict with the keys ``frames``, ``detection_ratio``, ``precision``, ``ego_recall``,
    ``mean_abs_dx_px``, ``failed_frames`` (a list of ``{"frame", "reasons"}``) and ``per_frame``.
    Ratios with an empty denominator are ``None``.
    """
    preds: dict[str, list] = {}
    for rec in pred_records:
        preds[str(rec.get("frame"))] = list(rec.get("lanes") or [])
    results = [evaluate_frame(preds.get(str(g.get("frame")), []), g) for g in gt_records]
    n = len(results)
    reported = sum(r.reported for r in results)
    matched = sum(r.matched for r in results)
    ego_total = sum(r.ego_total for r in results)
    ego_matched = sum(r.ego_matched for r in results)
    dx = [d for r in results for d in r.dx]

    def ratio(a: int, b: int) -> float | None:
        return a / b if b else None

    return {
        "frames": n,
        "detection_ratio": ratio(sum(r.correct for r in results), n),
        "precision": ratio(matched, reported),
        "ego_recall": ratio(ego_matched, ego_total),
        "mean_abs_dx_px": float(np.mean(dx)) if dx else None,
        "failed_frames": [{"frame": r.frame, "reasons": r.reasons} for r in results if not r.correct],
        "per_frame": results,
    }


def read_jsonl(path: str | Path) -> list[dict[str, Any]]:
    """Read a JSON-lines file; a malformed line raises :class:`InputError` naming the line."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found (expected a JSON-lines file)", path=str(path))
    out = []
    with path.open(encoding="utf-8") as fh:
        for k, line in enumerate(fh, 1):
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
            except json.JSONDecodeError as exc:
                raise InputError(f"line {k}: not valid JSON ({exc.msg})", path=str(path)) from None
            if not isinstance(rec, dict) or "frame" not in rec:
                raise InputError(f"line {k}: expected an object with a 'frame' key", path=str(path))
            out.append(rec)
    return out
