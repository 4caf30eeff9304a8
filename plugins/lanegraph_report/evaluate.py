"""``lanegraph eval``: a run's lanes against the ground truth -- the lane metric of the data README
(:mod:`lanegraph.evaluation.scoring`, which ``lanegraph run`` ends with) plus CULane-style F1,
TuSimple-style accuracy and, for synthetic scenes, the lateral error; a command of the
``lanegraph.commands`` entry-point group, like a third party's."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from lanegraph.api import (
    PATH,
    POOLED,
    culane_metrics,
    evaluate_sequences,
    handled,
    lateral_error_cm,
    load_dataset,
    parse_frames,
    pct,
    read_calibration,
    read_gt,
    read_predictions,
    run_ground_truth,
    run_lanes,
    run_selection,
    score,
    select_frames,
    session,
    some_frames,
    tusimple_metrics,
)
from lanegraph.errors import InputError, UsageError


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


def _eval_one(
    pred: Path,
    gt: Path,
    wanted: set[str],
    scene: Path | None,
    calib: Path | None,
    frames: slice | None = None,
) -> dict[str, Any]:
    res, pred_recs, gt_recs = score(pred, gt, frames)
    if "culane" in wanted:
        res["culane"] = culane_metrics(pred_recs, gt_recs)
    if "tusimple" in wanted:
        res["tusimple"] = tusimple_metrics(pred_recs, gt_recs)
    if "lateral" in wanted:
        if scene is None:
            raise UsageError(
                "--metrics lateral needs --scene scene.json (and --calib, default: the calibration of the input folder holding it)"
            )
        cal = read_calibration(session().pm, calib or Path(scene).parent)
        pitch, height = _scene_pose(Path(scene))
        res["lateral_error_cm"] = lateral_error_cm(pred_recs, gt_recs, cal, pitch, height)
    return res


def _not_run(n: int, chosen_by: str | None) -> str:
    return f" ({n} frame(s) of the ground truth not run, not scored: {chosen_by})" if n else ""


def _print_eval(res: dict[str, Any]) -> None:
    click.echo(
        f"frames:          {res['frames']}{_not_run(res['frames_not_run'], res.get('frames_chosen_by'))}"
    )
    click.echo(f"detection ratio: {pct(res['detection_ratio'])}")
    click.echo(f"precision:       {pct(res['precision'])}")
    click.echo(f"ego recall:      {pct(res['ego_recall'])}")
    dx = res["mean_abs_dx_px"]
    click.echo(f"mean |dx|:       {'n/a' if dx is None else f'{dx:.2f} px'}")
    if "culane" in res:
        c = res["culane"]
        click.echo(
            f"CULane F1:       {pct(c['f1'])} (precision {pct(c['precision'])}, recall {pct(c['recall'])}; TP {c['tp']} FP {c['fp']} FN {c['fn']})"
        )
    if "tusimple" in res:
        t = res["tusimple"]
        click.echo(f"TuSimple:        accuracy {pct(t['accuracy'])}, FP {pct(t['fp'])}, FN {pct(t['fn'])}")
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
        lanes = run_lanes(pred_dir / seq.name, f"sequence {seq.name!r} of {dataset_path}")
        pairs.append((seq.name, read_predictions(lanes), gt))
        recorded = run_selection(pred_dir / seq.name)
        # --frames, else the frames the run selected, else the sequence's own frames
        chosen[seq.name] = frames if frames is not None else (recorded[1] if recorded else seq.frames)
        if frames is not None:
            some_frames(select_frames(gt, frames)[0], gt, frames, f" of sequence {seq.name!r}")
    if not pairs:
        raise UsageError(f"{dataset_path}: no sequence has a ground truth ('gt') to evaluate against")
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
            f"| {label} | {r['frames']} | {pct(r['detection_ratio'])} | {pct(r['precision'])} | "
            f"{pct(r['ego_recall'])} | {'n/a' if dx is None else f'{dx:.2f}'} |"
        )
    if res[POOLED]["frames_not_run"]:
        click.echo(f"{res[POOLED]['frames_not_run']} frame(s) of the ground truth not run, not scored")
    failed = res[POOLED]["failed_frames"]
    if failed:
        click.echo(f"failed frames ({len(failed)}):")
        for f in failed:
            click.echo(f"  {f['frame']}: {'; '.join(f['reasons'])}")


__all__ = ["eval_cmd"]
