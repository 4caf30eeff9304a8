"""``lanegraph eval``: a run's lanes against the ground truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from ..errors import InputError, LanegraphError, UsageError
from ..frames import selection_text
from ..plugins import get_plugin_manager
from ._common import PATH, parse_frames, session
from ._errors import handled


def _scene_pose(scene: Path) -> tuple[float, float]:
    """``(pitch in radians, camera height in metres)`` of a synthetic sequence's ``scene.json``."""
    import math

    try:
        info = json.loads(scene.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read the scene description: {exc}", path=str(scene)) from None
    if not isinstance(info, dict):
        raise InputError("expected a JSON object with height and pitch_rad (or pitch_deg)", path=str(scene))
    pitch = info.get(
        "pitch_rad", math.radians(info["pitch_deg"]) if _is_number(info.get("pitch_deg")) else 0.0
    )
    height = info.get("height")
    for key, v in (("pitch_rad", pitch), ("height", height)):
        if not _is_number(v) or not math.isfinite(v):
            raise InputError(f"key {key!r}: expected a finite number, got {v!r}", path=str(scene))
    if height <= 0:
        raise InputError(f"key 'height': the camera height must be > 0 m, got {height}", path=str(scene))
    return float(pitch), float(height)


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


@click.command(name="eval")
@click.argument("pred", type=PATH)
@click.argument("gt", type=PATH, required=False)
@click.option(
    "--dataset",
    "dataset_path",
    type=PATH,
    help="a dataset file: PRED is then a folder with a run folder PRED/<sequence>/ per sequence (as `run --dataset` writes)",
)
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
@click.option(
    "--metrics",
    default="readme,culane,tusimple",
    show_default=True,
    help="readme, culane, tusimple, lateral (comma-separated)",
)
@click.option(
    "--scene", type=PATH, help="scene.json of a synthetic sequence (pitch, height) for the lateral error"
)
@click.option(
    "--calib",
    type=PATH,
    help="the calibration for the lateral error: a calibration file, or an input folder (default: the folder of --scene)",
)
@click.option(
    "--frames",
    help="score these frames of the ground truth only: A:B, A:B:S or A (positions in GT; "
    "default: the frames the run selected, as its run.json records them, else all)",
)
@handled(every_exit=2)  # whatever is wrong is the input's or the options': exit 2
def eval_cmd(
    pred: Path,
    gt: Path | None,
    dataset_path: Path | None,
    as_json: bool,
    metrics: str,
    scene: Path | None,
    calib: Path | None,
    frames: str | None,
) -> None:
    """Evaluate PRED (a run's lanes file, or its run folder) against GT lanes_gt.jsonl (default:
    the ground truth of the input the run recorded, or the synthetic scene's in the run folder):
    lanegraph's lane metric (detection ratio: the share of frames where every reported lane matches
    a distinct marking -- on 85 % of its rows within 20 px -- and every painted ego boundary is
    matched; precision: matched lanes / reported lanes; ego recall), plus
    CULane-style F1, TuSimple-style accuracy and, for synthetic scenes, the lateral error in cm.
    With --dataset, every sequence of the dataset and all of them pooled. Only the frames the run
    selected are scored (its run.json says which; --frames chooses), and the ground-truth frames
    left out are counted."""
    wanted = {m.strip() for m in metrics.split(",") if m.strip()}
    unknown = wanted - {"readme", "culane", "tusimple", "lateral"}
    if unknown:
        raise UsageError(
            f"--metrics: unknown metric(s) {sorted(unknown)}; expected readme, culane, tusimple, lateral"
        )
    if scene is not None:
        wanted.add("lateral")
    if dataset_path is not None:
        if gt is not None:
            raise UsageError(
                "--dataset names every sequence's ground truth: give PRED (a folder) and --dataset, not GT"
            )
        _eval_dataset(pred, dataset_path, as_json, parse_frames(frames))
        return
    if gt is None:
        gt = run_ground_truth(pred)
        if gt is None:
            raise UsageError(
                f"{pred}: no ground truth found (its run.json names no input folder holding a lanes_gt.jsonl, "
                "and the run folder has none): give GT (a lanes_gt.jsonl), or --dataset FILE with PRED a "
                "folder of <sequence>/ run folders"
            )
        click.echo(f"ground truth: {gt}", err=True)
    res = _eval_one(pred, gt, wanted, scene, calib, parse_frames(frames))
    if as_json:
        click.echo(json.dumps(res))
        return
    _print_eval(res)


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


def _some(kept: list, gt_recs: list, frames: slice, where: str = "") -> None:
    """A ``--frames`` that selects no frame of a ground truth is refused, as ``run`` refuses it."""
    if gt_recs and not kept:
        n = len(gt_recs)
        raise UsageError(
            f"--frames {selection_text(frames)}: selects no frame{where}: the ground truth has {n} "
            f"frame(s), indices 0..{n - 1}"
        )


def _selected(gt_recs: list, frames: slice | None, pred: Path) -> tuple[list, int, str | None]:
    """The ground-truth records to score, how many are left out and why (for the summary)."""
    from ..evaluation.metrics import select_frames

    if frames is not None:
        kept, not_run = select_frames(gt_recs, frames)
        _some(kept, gt_recs, frames)
        return kept, not_run, "--frames"
    recorded = run_selection(pred)
    if recorded is None:
        return gt_recs, 0, None
    kept, not_run = select_frames(gt_recs, recorded[1])
    return kept, not_run, f"the frames the run selected ({recorded[0] / 'run.json'})"


def _eval_one(
    pred: Path,
    gt: Path,
    wanted: set[str],
    scene: Path | None,
    calib: Path | None,
    frames: slice | None = None,
) -> dict[str, Any]:
    from ..evaluation.metrics import evaluate, read_ground_truth, read_predictions
    from ..evaluation.metrics_extra import culane_metrics, lateral_error_cm, tusimple_metrics

    given = pred
    if pred.is_dir():  # a run folder: the lanes its sinks recorded
        pred = _run_lanes(pred)
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
    if "culane" in wanted:
        res["culane"] = culane_metrics(pred_recs, gt_recs)
    if "tusimple" in wanted:
        res["tusimple"] = tusimple_metrics(pred_recs, gt_recs)
    if "lateral" in wanted:
        if scene is None:
            raise UsageError(
                "--metrics lateral needs --scene scene.json (and --calib, default: the calibration of the input folder holding it)"
            )
        from ..run.sources import read_calibration

        cal = read_calibration(session().pm, calib or Path(scene).parent)
        pitch, height = _scene_pose(Path(scene))
        res["lateral_error_cm"] = lateral_error_cm(pred_recs, gt_recs, cal, pitch, height)
    return res


def score_line(out_dir: Path) -> str | None:
    """One line scoring the run in ``out_dir`` against its ground truth (:func:`run_ground_truth`),
    as ``lanegraph run`` ends with; None when the run has no ground truth or cannot be scored."""
    gt = run_ground_truth(out_dir)
    if gt is None:
        return None
    try:
        res = _eval_one(out_dir, gt, set(), None, None)
    except LanegraphError as exc:  # the run's outputs stay as they are: only the score is missing
        return f"not scored against {gt}: {exc}"
    return (
        f"detection ratio {_pct(res['detection_ratio'])} on {res['frames']} frame(s), precision "
        f"{_pct(res['precision'])}, ego recall {_pct(res['ego_recall'])} against {gt} (lanegraph eval {out_dir})"
    )


def _run_lanes(folder: Path, what: str = "") -> Path:
    """The lanes file of run folder ``folder`` (the one its run.json records; :mod:`lanegraph.records.results`)."""
    from ..records.results import LANES, describe, find_result

    lanes = find_result(folder, LANES, get_plugin_manager())
    if lanes is None:
        raise UsageError(
            f"{folder}: no predictions{' for ' + what if what else ''} (expected {describe(folder, LANES)})"
        )
    return lanes


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def _not_run(n: int, chosen_by: str | None) -> str:
    return f" ({n} frame(s) of the ground truth not run, not scored: {chosen_by})" if n else ""


def _print_eval(res: dict[str, Any]) -> None:
    click.echo(
        f"frames:          {res['frames']}{_not_run(res['frames_not_run'], res.get('frames_chosen_by'))}"
    )
    click.echo(f"detection ratio: {_pct(res['detection_ratio'])}")
    click.echo(f"precision:       {_pct(res['precision'])}")
    click.echo(f"ego recall:      {_pct(res['ego_recall'])}")
    dx = res["mean_abs_dx_px"]
    click.echo(f"mean |dx|:       {'n/a' if dx is None else f'{dx:.2f} px'}")
    if "culane" in res:
        c = res["culane"]
        click.echo(
            f"CULane F1:       {_pct(c['f1'])} (precision {_pct(c['precision'])}, recall {_pct(c['recall'])}; TP {c['tp']} FP {c['fp']} FN {c['fn']})"
        )
    if "tusimple" in res:
        t = res["tusimple"]
        click.echo(f"TuSimple:        accuracy {_pct(t['accuracy'])}, FP {_pct(t['fp'])}, FN {_pct(t['fn'])}")
    if "lateral_error_cm" in res:
        lat = ", ".join(
            f"{k} m: {'n/a' if v is None else f'{v:.1f} cm'}" for k, v in res["lateral_error_cm"].items()
        )
        click.echo(f"lateral error:   {lat}")
    if res["failed_frames"]:
        click.echo(f"failed frames ({len(res['failed_frames'])}):")
        for f in res["failed_frames"]:
            click.echo(f"  {f['frame']}: {'; '.join(f['reasons'])}")


def _eval_dataset(pred_dir: Path, dataset_path: Path, as_json: bool, frames: slice | None = None) -> None:
    """``eval PRED --dataset FILE``: each sequence's figures and the pooled ones (the README metric)."""
    from ..evaluation.dataset import POOLED, load_dataset, read_gt
    from ..evaluation.metrics import read_predictions

    ds = load_dataset(dataset_path)
    if not pred_dir.is_dir():
        raise UsageError(
            f"{pred_dir}: expected a folder with a run folder <sequence>/ for each sequence of {dataset_path}"
        )
    pairs = []
    chosen: dict[str, Any] = {}
    for seq in ds:
        gt = read_gt(seq)
        if gt is None:
            continue
        lanes = _run_lanes(pred_dir / seq.name, f"sequence {seq.name!r} of {dataset_path}")
        pairs.append((seq.name, read_predictions(lanes), gt))
        recorded = run_selection(pred_dir / seq.name)
        # --frames, else the frames the run selected, else the sequence's own frames
        chosen[seq.name] = frames if frames is not None else (recorded[1] if recorded else seq.frames)
        if frames is not None:
            from ..evaluation.metrics import select_frames

            _some(select_frames(gt, frames)[0], gt, frames, f" of sequence {seq.name!r}")
    if not pairs:
        raise UsageError(f"{dataset_path}: no sequence has a ground truth ('gt') to evaluate against")
    from ..evaluation.dataset import evaluate_sequences

    res = evaluate_sequences(pairs, chosen)
    if as_json:
        click.echo(json.dumps({"dataset": ds.name, "sequences": res}))
        return
    click.echo("| sequence | frames | detection ratio | precision | ego recall | mean abs dx (px) |")
    click.echo("|---|---|---|---|---|---|")
    for name, r in res.items():
        dx = r["mean_abs_dx_px"]
        label = f"**{name}** (pooled)" if name == POOLED else name
        click.echo(
            f"| {label} | {r['frames']} | {_pct(r['detection_ratio'])} | {_pct(r['precision'])} | "
            f"{_pct(r['ego_recall'])} | {'n/a' if dx is None else f'{dx:.2f}'} |"
        )
    if res[POOLED]["frames_not_run"]:
        click.echo(f"{res[POOLED]['frames_not_run']} frame(s) of the ground truth not run, not scored")
    failed = res[POOLED]["failed_frames"]
    if failed:
        click.echo(f"failed frames ({len(failed)}):")
        for f in failed:
            click.echo(f"  {f['frame']}: {'; '.join(f['reasons'])}")
