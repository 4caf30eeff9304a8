"""More lane metrics: CULane-style F1, TuSimple-style accuracy / FP / FN, and the lateral error in
centimetres on the road for synthetic scenes with a known camera.

CULane-style F1 (Pan et al., SCNN): every lane, predicted or annotated, is drawn as its polyline
``width`` (30) pixels wide on a mask of the image size; a prediction and a marking match when the
IoU of their masks is at least ``iou`` (0.5); matching is one-to-one (Hungarian assignment on IoU,
keeping pairs above the threshold). TP, FP, FN are summed over frames; precision = TP / (TP + FP),
recall = TP / (TP + FN), F1 their harmonic mean.

TuSimple-style (TuSimple lane benchmark): for every annotated marking, at its annotated rows, a
prediction's x is linearly interpolated (rows the prediction does not cover count as misses); a
row is correct when ``|dx| < threshold`` (20 px); a marking's accuracy is its best prediction's
fraction of correct rows. Per frame: accuracy = sum of the markings' accuracies / markings; a
marking is matched when its accuracy is >= 0.85 (its best prediction is then used once); FP =
unmatched predictions / predictions, FN = unmatched markings / markings. The three are averaged
over frames (a frame without predictions has FP 0; a frame without markings contributes accuracy 1
and FN 0).

Lateral error (synthetic scenes): for the pairs matched by the README metric, both polylines are
read at the image rows where the flat road lies ``distances`` (10, 20, 30 m) ahead and back-projected
onto the road plane; the mean absolute lateral difference in centimetres per distance.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from ..types import Calibration
from .metrics import match_frame, polyline_x_at


def _lane_mask(points: Sequence[Sequence[float]], size: tuple[int, int], width: int) -> np.ndarray:
    import cv2  # when a CULane figure is computed: importing this module (lanegraph --help) stays cheap

    w, h = size
    m = np.zeros((h, w), np.uint8)
    pts = np.round(np.asarray(points, dtype=np.float64).reshape(-1, 2)).astype(np.int32)
    if len(pts) >= 2:
        cv2.polylines(m, [pts.reshape(-1, 1, 2)], False, 1, thickness=int(width), lineType=cv2.LINE_8)
    elif len(pts) == 1:
        cv2.circle(m, tuple(int(v) for v in pts[0]), int(width) // 2, 1, -1)
    return m.astype(bool)


def _index(records: Iterable[Mapping[str, Any]]) -> dict[str, list]:
    return {str(r.get("frame")): list(r.get("lanes") or []) for r in records}


def culane_metrics(
    pred_records: Iterable[Mapping[str, Any]],
    gt_records: Iterable[Mapping[str, Any]],
    width: int = 30,
    iou: float = 0.5,
    image_size: tuple[int, int] = (1242, 375),
) -> dict[str, Any]:
    """CULane-style precision, recall, F1 and TP/FP/FN (see the module docstring)."""
    from scipy.optimize import linear_sum_assignment

    preds = _index(pred_records)
    tp = fp = fn = 0
    for g in gt_records:
        size = tuple(g.get("image_size") or image_size)
        gts = [m.get("points") or [] for m in g.get("markings") or []]
        ps = [ln.get("points") or [] for ln in preds.get(str(g.get("frame")), [])]
        if not ps or not gts:
            fp += len(ps)
            fn += len(gts)
            continue
        gm = [_lane_mask(p, size, width) for p in gts]
        pm = [_lane_mask(p, size, width) for p in ps]
        ious = np.zeros((len(pm), len(gm)))
        for i, a in enumerate(pm):
            for j, b in enumerate(gm):
                union = np.count_nonzero(a | b)
                ious[i, j] = np.count_nonzero(a & b) / union if union else 0.0
        rows, cols = linear_sum_assignment(-ious)
        matched = int(np.sum(ious[rows, cols] >= iou))
        tp += matched
        fp += len(ps) - matched
        fn += len(gts) - matched
    precision = tp / (tp + fp) if tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    f1 = (
        2 * precision * recall / (precision + recall)
        if precision and recall
        else (0.0 if tp + fp + fn else None)
    )
    return {"precision": precision, "recall": recall, "f1": f1, "tp": tp, "fp": fp, "fn": fn}


def tusimple_metrics(
    pred_records: Iterable[Mapping[str, Any]],
    gt_records: Iterable[Mapping[str, Any]],
    threshold: float = 20.0,
    match: float = 0.85,
) -> dict[str, Any]:
    """TuSimple-style accuracy, FP and FN rates averaged over frames (see the module docstring)."""
    preds = _index(pred_records)
    accs, fps, fns = [], [], []
    for g in gt_records:
        markings = [
            np.asarray(m.get("points") or [], dtype=np.float64).reshape(-1, 2)
            for m in g.get("markings") or []
        ]
        ps = preds.get(str(g.get("frame")), [])
        if not markings:
            accs.append(1.0)
            fps.append(1.0 if ps else 0.0)
            fns.append(0.0)
            continue
        used: set[int] = set()
        total_acc = 0.0
        matched = 0
        for gt in markings:
            best, best_i = 0.0, -1
            for i, ln in enumerate(ps):
                xp = polyline_x_at(ln.get("points") or [], gt[:, 1])
                ok = ~np.isnan(xp) & (np.abs(np.nan_to_num(xp, nan=1e9) - gt[:, 0]) < threshold)
                acc = float(ok.mean()) if len(gt) else 0.0
                if acc > best:
                    best, best_i = acc, i
            total_acc += best
            if best >= match and best_i not in used:
                matched += 1
                used.add(best_i)
        accs.append(total_acc / len(markings))
        fps.append((len(ps) - len(used)) / len(ps) if ps else 0.0)
        fns.append((len(markings) - matched) / len(markings))
    n = len(accs)
    return {
        "accuracy": float(np.mean(accs)) if n else None,
        "fp": float(np.mean(fps)) if n else None,
        "fn": float(np.mean(fns)) if n else None,
    }


def road_row(z: float, calib: Calibration, pitch: float, height: float) -> float:
    """Image row (float) where the flat road lies ``z`` metres ahead (camera pitched down by ``pitch``)."""
    # a road point (x, h, z) in the level frame; the camera looks down by pitch
    y_c = height * np.cos(pitch) - z * np.sin(pitch)
    z_c = height * np.sin(pitch) + z * np.cos(pitch)
    return float(calib.cy + calib.f_y * y_c / z_c)


def image_to_road_x(x: float, y: float, calib: Calibration, pitch: float, height: float) -> float:
    """Lateral road coordinate (metres) of image pixel (x, y) on the flat road (roll 0)."""
    ray = np.array([(x - calib.cx) / calib.f, (y - calib.cy) / calib.f_y, 1.0])
    cp, sp = np.cos(pitch), np.sin(pitch)
    # camera -> level frame (y down): rotate by the pitch about x
    d_y = ray[1] * cp + ray[2] * sp
    t = height / d_y
    return float(t * ray[0])


def lateral_error_cm(
    pred_records: Iterable[Mapping[str, Any]],
    gt_records: Iterable[Mapping[str, Any]],
    calib: Calibration,
    pitch: float,
    height: float,
    distances: Sequence[float] = (10.0, 20.0, 30.0),
) -> dict[str, float | None]:
    """Mean |lateral error| in cm at each distance over the README metric's matched pairs."""
    preds = _index(pred_records)
    errors: dict[float, list[float]] = {z: [] for z in distances}
    rows = {z: road_row(z, calib, pitch, height) for z in distances}
    for g in gt_records:
        lanes = preds.get(str(g.get("frame")), [])
        markings = list(g.get("markings") or [])
        m = match_frame(lanes, g)
        # the matched pairs in the order the README metric took them (greedy by mean |dx|)
        for _, i, j in sorted((m.lane_dx[i], i, j) for i, j in enumerate(m.lane_marking) if j is not None):
            for z, y in rows.items():
                xp = polyline_x_at(lanes[i].get("points") or [], np.array([y]))[0]
                xg = polyline_x_at(markings[j].get("points") or [], np.array([y]))[0]
                if np.isnan(xp) or np.isnan(xg):
                    continue
                dx = image_to_road_x(xp, y, calib, pitch, height) - image_to_road_x(
                    xg, y, calib, pitch, height
                )
                errors[z].append(abs(dx) * 100.0)
    return {f"{z:g}": (float(np.mean(v)) if v else None) for z, v in errors.items()}
