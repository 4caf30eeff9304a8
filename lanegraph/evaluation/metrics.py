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
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError

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


def select_frames(
    gt_records: Iterable[Mapping[str, Any]], frames: Collection[str] | slice | None
) -> tuple[list[Mapping[str, Any]], int]:
    """The ground-truth records of the frames a run selected, and how many others it has.

    ``frames``: the frame ids the run selected (as its record lists them), a slice over the
    ground truth's records in file order (``eval --frames``, as ``ablate`` cuts a sequence's ground
    truth), or None for every record. Returns ``(records, not run)``: the records kept, in file
    order, and the number of ground-truth frames left out (frames the run did not select, which
    must not be scored as failures).
    """
    records = list(gt_records)
    if frames is None:
        return records, 0
    if isinstance(frames, slice):  # in file order whatever the step's sign (``--frames 9:0:-1``)
        kept = [records[i] for i in sorted(range(len(records))[frames])]
    else:
        ids = {str(f) for f in frames}
        kept = [g for g in records if str(g.get("frame")) in ids]
    return kept, len(records) - len(kept)


def evaluate(
    pred_records: Iterable[Mapping[str, Any]],
    gt_records: Iterable[Mapping[str, Any]],
    frames: Collection[str] | slice | None = None,
) -> dict[str, Any]:
    """Evaluate prediction records against ground-truth records (both as parsed JSON lines).

    ``frames``: score only these frames of the ground truth (:func:`select_frames`: the ids a run
    selected, or a slice over the ground truth's records); None scores every record.

    Returns a dict with the keys ``frames``, ``detection_ratio``, ``precision``, ``ego_recall``,
    ``mean_abs_dx_px``, ``failed_frames`` (a list of ``{"frame", "reasons"}``), ``per_frame`` and
    ``frames_not_run`` (ground-truth frames left out by ``frames``, not scored).
    Ratios with an empty denominator are ``None``.
    """
    preds: dict[str, list] = {}
    for rec in pred_records:
        preds[str(rec.get("frame"))] = list(rec.get("lanes") or [])
    gt_records, not_run = select_frames(gt_records, frames)
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
        "frames_not_run": not_run,
    }


def _where(k: int) -> str:
    return f"line {k}"


def _check_points(points: Any, where: str) -> None:
    if not isinstance(points, list):
        raise ValueError(f"{where}: 'points' must be a list of [x, y] pairs, got {type(points).__name__}")
    for i, pt in enumerate(points):
        if not (isinstance(pt, list) and len(pt) == 2):
            raise ValueError(
                f"{where}: points[{i}]: expected [x, y] (two numbers, pixels), got {str(pt)[:60]}"
            )
        for v in pt:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"{where}: points[{i}]: expected two finite numbers, got {str(pt)[:60]}")


def _check_frame(rec: dict[str, Any], where: str, seen: dict[str, int], k: int) -> str:
    frame = rec.get("frame")
    if (
        isinstance(frame, bool)
        or not isinstance(frame, (str, int))
        or (isinstance(frame, str) and not frame.strip())
    ):
        raise ValueError(f"{where}: 'frame' must be a frame id (a non-empty string), got {frame!r}")
    key = str(frame)
    if key in seen:
        raise ValueError(
            f"{where}: frame {key!r} appears twice (first at line {seen[key]}); one record per frame"
        )
    seen[key] = k
    return key


def validate_predictions(records: list[dict[str, Any]], lines: list[int]) -> None:
    """Check predictions records (a run's lanes, :data:`lanegraph.records.results.LANES`): ``{"frame": id,
    "lanes": [{"points": [[x, y], ...], ...}]}``,
    one record per frame; raises ``ValueError`` naming the line."""
    seen: dict[str, int] = {}
    for rec, k in zip(records, lines):
        where = _where(k)
        _check_frame(rec, where, seen, k)
        if "lanes" not in rec:
            hint = (
                " (it has 'markings' like a ground-truth file: PRED and GT swapped?)"
                if "markings" in rec
                else ""
            )
            raise ValueError(f"{where}: expected a predictions record {{frame, lanes}}, no 'lanes' key{hint}")
        lanes = rec["lanes"]
        if not isinstance(lanes, list):
            raise ValueError(f"{where}: 'lanes' must be a list of lanes, got {str(lanes)[:60]}")
        for j, lane in enumerate(lanes):
            if not isinstance(lane, dict) or "points" not in lane:
                raise ValueError(
                    f"{where}: lanes[{j}]: expected an object with 'points', got {str(lane)[:60]}"
                )
            _check_points(lane["points"], f"{where}: lanes[{j}]")


def validate_ground_truth(records: list[dict[str, Any]], lines: list[int]) -> None:
    """Check ``lanes_gt.jsonl`` records (the data README's format): ``{"frame": id, "markings":
    [{"id": ..., "points": [[x, y], ...]}], "ego": {"left": id | null, "right": id | null}}``, one
    record per frame, marking ids unique in a frame, ego ids among them; raises ``ValueError``
    naming the line."""
    seen: dict[str, int] = {}
    for rec, k in zip(records, lines):
        where = _where(k)
        _check_frame(rec, where, seen, k)
        if "markings" not in rec:
            hint = " (it has 'lanes' like a predictions file: PRED and GT swapped?)" if "lanes" in rec else ""
            raise ValueError(
                f"{where}: expected a ground-truth record {{frame, markings, ego}}, no 'markings' key{hint}"
            )
        markings = rec["markings"]
        if not isinstance(markings, list):
            raise ValueError(f"{where}: 'markings' must be a list of markings, got {str(markings)[:60]}")
        ids = set()
        for j, m in enumerate(markings):
            if not isinstance(m, dict) or "points" not in m:
                raise ValueError(
                    f"{where}: markings[{j}]: expected an object with 'id' and 'points', got {str(m)[:60]}"
                )
            mid = m.get("id")
            if isinstance(mid, (dict, list, float)):
                raise ValueError(f"{where}: markings[{j}]: 'id' must be an integer or a string, got {mid!r}")
            if mid is not None and mid in ids:
                raise ValueError(f"{where}: markings[{j}]: id {mid!r} appears twice in the frame")
            ids.add(mid)
            _check_points(m["points"], f"{where}: markings[{j}]")
        ego = rec.get("ego", {})
        if ego is None:
            ego = {}
        if not isinstance(ego, dict):
            raise ValueError(f"{where}: 'ego' must be an object {{left, right}}, got {str(ego)[:60]}")
        for side in ("left", "right"):
            mid = ego.get(side)
            if mid is not None and mid not in ids:
                raise ValueError(
                    f"{where}: ego.{side}: {mid!r} is not the id of a marking of the frame (ids: {sorted(map(str, ids))})"
                )
        extra = set(ego) - {"left", "right"}
        if extra:
            raise ValueError(f"{where}: ego: unknown key(s) {sorted(extra)}; expected left and right")


def read_predictions(path: str | Path) -> list[dict[str, Any]]:
    """A predictions file (a run's lanes), validated: a malformed one raises :class:`InputError`
    naming the file and the line."""
    return _read_validated(path, validate_predictions)


def read_ground_truth(path: str | Path) -> list[dict[str, Any]]:
    """A ground-truth file (``lanes_gt.jsonl``), validated: a malformed one raises
    :class:`InputError` naming the file and the line."""
    return _read_validated(path, validate_ground_truth)


def _read_validated(path: str | Path, check: Any) -> list[dict[str, Any]]:
    records, lines = _read_lines(Path(path))
    try:
        check(records, lines)
    except ValueError as exc:
        raise InputError(str(exc), path=str(path)) from None
    return records


def _read_lines(path: Path) -> tuple[list[dict[str, Any]], list[int]]:
    if not path.is_file():
        raise InputError("file not found (expected a JSON-lines file)", path=str(path))
    out, lines = [], []
    try:
        with path.open(encoding="utf-8") as fh:
            for k, line in enumerate(fh, 1):
                if not line.strip():
                    continue
                try:
                    rec = json.loads(line)
                except (json.JSONDecodeError, RecursionError) as exc:
                    msg = exc.msg if isinstance(exc, json.JSONDecodeError) else "nested too deeply"
                    raise InputError(f"line {k}: not valid JSON ({msg})", path=str(path)) from None
                if not isinstance(rec, dict) or "frame" not in rec:
                    raise InputError(f"line {k}: expected an object with a 'frame' key", path=str(path))
                out.append(rec)
                lines.append(k)
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 text file", path=str(path)) from None
    except OSError as exc:
        raise InputError(f"cannot read the file: {exc.strerror or exc}", path=str(path)) from None
    return out, lines


def read_jsonl(path: str | Path) -> list[dict[str, Any]]:
    """Read a JSON-lines file of ``{"frame": ...}`` objects; a malformed line raises
    :class:`InputError` naming the line (no check of the rest of the record: see
    :func:`read_predictions` and :func:`read_ground_truth`)."""
    return _read_lines(Path(path))[0]
