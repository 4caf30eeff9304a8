"""A run folder scored against its ground truth: the line ``lanegraph run`` ends with, and what
``lanegraph eval`` (the report plugin's command) builds on: which ground truth is the run's, which
of its frames the run selected, and the lane metric of the data README on them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import InputError, LanegraphError, UsageError
from ..frames import selection_text
from .metrics import evaluate, read_ground_truth, read_predictions, select_frames


def run_ground_truth(pred: Path) -> Path | None:
    """The ground truth of the run that wrote ``pred`` (a run folder, or a lanes file in one):
    ``lanes_gt.jsonl`` in the input folder its run.json names (KITTI data laid out by ``lanegraph
    data kitti``, a written synthetic sequence), else the one in the run folder (a run of the
    synthetic scene writes its exact ground truth there); None when there is neither."""
    from ..records.record import read_record

    folder = pred if pred.is_dir() else pred.parent
    record = read_record(folder)
    if record is not None and record.input:
        recorded = Path(record.input)
        bases = [Path.cwd()] if recorded.is_absolute() else [Path.cwd(), *folder.resolve().parents]
        for base in bases:
            cand = base / recorded / "lanes_gt.jsonl"
            if cand.is_file():
                return cand
        return None  # the run read an input: only that input's ground truth is its answer
    cand = folder / "lanes_gt.jsonl"
    return cand if cand.is_file() else None


def run_selection(pred: Path) -> tuple[Path, list[str]] | None:
    """The frames the run that wrote ``pred`` (a run folder, or the lanes file its run.json names)
    selected: ``(its folder, the frame ids)``; None when no record says."""
    from ..records.results import LANES, find_result, recorded_selection

    folder = pred if pred.is_dir() else pred.parent
    sel = recorded_selection(folder)
    if sel is None:
        return None
    if not pred.is_dir():
        lanes = find_result(folder, LANES)
        if lanes is None or lanes.resolve() != pred.resolve():
            return None
    return folder, sel[1]


def some_frames(kept: list, gt_recs: list, frames: slice, where: str = "") -> None:
    """A ``--frames`` that selects no frame of a ground truth is refused, as ``run`` refuses it."""
    if gt_recs and not kept:
        n = len(gt_recs)
        raise UsageError(
            f"--frames {selection_text(frames)}: selects no frame{where}: the ground truth has {n} "
            f"frame(s), indices 0..{n - 1}"
        )


def _selected(gt_recs: list, frames: slice | None, pred: Path) -> tuple[list, int, str | None]:
    """The ground-truth records to score, how many are left out and why (for the summary)."""
    if frames is not None:
        kept, not_run = select_frames(gt_recs, frames)
        some_frames(kept, gt_recs, frames)
        return kept, not_run, "--frames"
    recorded = run_selection(pred)
    if recorded is None:
        return gt_recs, 0, None
    kept, not_run = select_frames(gt_recs, recorded[1])
    return kept, not_run, f"the frames the run selected ({recorded[0] / 'run.json'})"


def score(pred: Path, gt: Path, frames: slice | None = None) -> tuple[dict[str, Any], list, list]:
    """The lane metric of ``pred`` (a lanes file, or a run folder: the lanes its sinks recorded)
    against ``gt`` on the frames chosen (``frames``, else those the run selected): the figures
    (``frames_not_run``, ``frames_chosen_by`` added; no per-frame rows), the predictions and the
    ground-truth records scored."""
    given = pred
    if pred.is_dir():  # a run folder: the lanes its sinks recorded
        pred = run_lanes(pred)
    pred_recs, gt_recs = read_predictions(pred), read_ground_truth(gt)
    gt_recs, not_run, chosen_by = _selected(gt_recs, frames, given)
    pred_frames, gt_frames = {str(r["frame"]) for r in pred_recs}, {str(r["frame"]) for r in gt_recs}
    if pred_frames and gt_frames and not pred_frames & gt_frames:
        raise InputError(
            f"no frame of {pred} is in {gt} (e.g. {sorted(pred_frames)[0]!r} against {sorted(gt_frames)[0]!r}): "
            "predictions and ground truth of different sequences?",
            path=str(pred),
        )
    res = evaluate(pred_recs, gt_recs)
    res.pop("per_frame")
    res["frames_not_run"] = not_run
    res["frames_chosen_by"] = chosen_by
    return res, pred_recs, gt_recs


def score_line(out_dir: Path) -> str | None:
    """One line scoring the run in ``out_dir`` against its ground truth (:func:`run_ground_truth`),
    as ``lanegraph run`` ends with; None when the run has no ground truth or cannot be scored."""
    gt = run_ground_truth(out_dir)
    if gt is None:
        return None
    try:
        res = score(out_dir, gt)[0]
    except LanegraphError as exc:  # the run's outputs stay as they are: only the score is missing
        return f"not scored against {gt}: {exc}"
    return (
        f"detection ratio {pct(res['detection_ratio'])} on {res['frames']} frame(s), precision "
        f"{pct(res['precision'])}, ego recall {pct(res['ego_recall'])} against {gt} (lanegraph eval {out_dir})"
    )


def run_lanes(folder: Path, what: str = "") -> Path:
    """The lanes file of run folder ``folder`` (the one its run.json records; :mod:`lanegraph.records.results`)."""
    from ..plugins import get_plugin_manager
    from ..records.results import LANES, describe, find_result

    lanes = find_result(folder, LANES, get_plugin_manager())
    if lanes is None:
        raise UsageError(
            f"{folder}: no predictions{' for ' + what if what else ''} (expected {describe(folder, LANES)})"
        )
    return lanes


def pct(x: float | None) -> str:
    """A share as a percentage with one decimal, ``n/a`` for None."""
    return "n/a" if x is None else f"{100 * x:.1f} %"


__all__ = ["pct", "run_ground_truth", "run_lanes", "run_selection", "score", "score_line", "some_frames"]
