"""A graph on real KITTI sequences changed the way other cameras, days and speeds change them.

    python benchmarks/sweep_kitti.py [GRAPH] [--input FOLDER | --dataset FILE] [--variants gain:0.5,mirror,...] [--set NODE.PARAM=V ...]

The input is a KITTI raw drive (``image_02``/``image_03``, or the grey ``image_00``/``image_01``,
``calib_cam_to_cam.txt`` one folder up) or a KITTI odometry sequence (the grey ``image_0``/``image_1``
or the colour ``image_2``/``image_3``, ``calib.txt`` with their ``P0``/``P1`` or ``P2``/``P3`` rows)
with its ``lanes_gt.jsonl``, recognised and read as ``lanegraph run`` does (``lanegraph_io``'s
``detect_source`` and sources: the pair it reads is the pair changed). ``--input`` names one (default:
drive 0001 of ``../shared/data``); ``--dataset FILE`` names several, each with its ground truth and
optional frame selection (a dataset file, ``lanegraph.evaluation.dataset``; ``graphs/datasets/dev.yaml``).

Each variant of each sequence is written into ``--work`` (a temporary folder by default) in the
input's own layout (KITTI raw: ``<date>/calib_cam_to_cam.txt`` and ``image_0X/data``; KITTI odometry:
``image_0``/``image_1`` or ``image_2``/``image_3`` and ``calib.txt``; grey images stay grey) with the
ground truth carried over, then ``lanegraph run GRAPH`` runs on it and the lane metric of the data
README is printed (detection ratio, precision, ego recall, lanes reported): a row per sequence and,
with several sequences, a pooled row ``all`` per variant (every frame of every sequence as one set,
``lanegraph.evaluation.dataset.evaluate_sequences``, as ``lanegraph ablate --dataset`` pools). The figures are
also written to ``WORK/sweep.json``. The variants:

- ``recorded``: the sequence as it is;
- ``gain:G``: both cameras' images times ``G`` (another exposure), clipped to 0-255;
- ``right_gain:G``: the right camera's images alone times ``G`` (a mismatched pair);
- ``haze:C``: both images at contrast ``C`` around mid-grey, ``C I + (1 - C) 128`` (haze, glare);
- ``blur:S``: both images blurred by a Gaussian of sigma ``S`` pixels;
- ``noise:S``: Gaussian noise of sigma ``S`` grey levels added to every pixel of both images (the
  same on each colour channel; independent per image, a fixed seed);
- ``crop:WxH``: the top-left ``W x H`` of both images (the principal point stays, so the projection
  rows do too; KITTI raw's ``S_rect_0X`` image sizes follow, KITTI odometry's ``calib.txt`` has none);
- ``step:N``: every ``N``-th frame (``N`` times the speed), on the sequence as it is;
- ``unpainted``: the annotated markings inpainted away in both images (OpenCV's Telea inpainting
  over each polyline, extended to the image's bottom and 40 rows beyond its far end, 0.45 m wide at
  the measured disparity; in the right image moved by that disparity); the ground truth then lists
  no marking, and any lane reported is a false one. Where the inpainting leaves a strip brighter
  than the asphalt (next to paint the polyline misses by a few pixels) a lane can follow it;
- ``mirror``: both images flipped left-right and swapped (the right camera becomes the left one),
  ``cx`` of the pair's projection rows mirrored (``P_rect_02``/``03`` or ``P0``/``P1`` ...); the ground
  truth moves into the right camera by OpenCV SGBM's disparity at each annotated point (median of the
  7 x 7 pixels around it) and is mirrored, ego sides swapped. The road's features change sides: a
  rule that favours one side shows.

Every sequence is opened (layout, calibration, its ground truth's frames among its images) before
anything is written: an unusable one stops the sweep with exit status 2; a run that fails prints its
row and the sweep goes on, ending with status 1. Writing a variant takes a few seconds (the mirror's
and the inpainting's disparities about 10 s on drive 0001's 54 frames); the default list on drive
0001 takes about 2.5 minutes on the 2-core reference machine, on ``graphs/datasets/dev.yaml`` (99
frames, 39 runs) 2.5 to 3.5 minutes. A progress bar on stderr (where it is a terminal) says which variant and
sequence is being written or run (``--quiet``: none); each row is printed as its run ends.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from _sweep import (  # benchmarks/ (the script's folder)
    HEADER,
    lanes_file,
    lanes_reported,
    metric_row,
    run_graph,
)
from lanegraph_io import detect_source
from lanegraph_io._calib import projection, read_key_rows
from lanegraph_io._sources import KittiOdometrySource, KittiRawSource, read_image
from tqdm import tqdm

from lanegraph.errors import InputError
from lanegraph.evaluation.dataset import (
    POOLED,
    Dataset,
    evaluate_sequences,
    load_dataset,
    read_gt,
    single_sequence,
)
from lanegraph.evaluation.metrics import evaluate, read_ground_truth, read_predictions
from lanegraph.frames import selection_text
from lanegraph.nodes import RunContext, node_type_of
from lanegraph.types import Calibration

ROOT = Path(__file__).resolve().parents[1]
DRIVE = ROOT.parent / "shared/data/kitti_raw/2011_09_26/2011_09_26_drive_0001_sync"
DEFAULT = "recorded,gain:0.35,gain:0.5,gain:0.7,gain:1.2,right_gain:0.75,mirror,unpainted,step:3,noise:4,noise:8,haze:0.6,blur:1.2"

#: the source node type of each layout the sweep writes
SOURCES = {"io.kitti_raw": KittiRawSource, "io.kitti_odometry": KittiOdometrySource}
#: the projection rows of each camera pair, by the left camera's folder (as the sources read them)
PROJECTIONS = {
    "image_02": ("P_rect_02", "P_rect_03"),
    "image_00": ("P_rect_00", "P_rect_01"),
    "image_2": ("P2", "P3"),
    "image_0": ("P0", "P1"),
}


def parse_variant(spec: str) -> tuple[str, float | tuple[int, int] | None]:
    """``"gain:0.5"`` -> ``("gain", 0.5)``; ``"crop:1224x368"`` -> ``("crop", (1224, 368))``; a
    ValueError saying what was expected otherwise."""
    kind, _, arg = spec.partition(":")
    if kind in ("recorded", "mirror", "unpainted"):
        if arg:
            raise ValueError(f"{spec!r}: {kind} takes no argument")
        return kind, None
    if kind == "crop":
        try:
            w, h = (int(v) for v in arg.lower().split("x"))
        except ValueError:
            raise ValueError(f"{spec!r}: expected crop:WIDTHxHEIGHT, e.g. crop:1224x368") from None
        return kind, (w, h)
    if kind in ("gain", "right_gain", "haze", "blur", "noise", "step"):
        try:
            value = float(arg)
        except ValueError:
            raise ValueError(f"{spec!r}: expected {kind}:NUMBER") from None
        if not value > 0 or value == float("inf") or (kind == "step" and value != int(value)):
            raise ValueError(f"{spec!r}: expected a positive {'integer' if kind == 'step' else 'number'}")
        return kind, value
    raise ValueError(
        f"{spec!r}: unknown variant; expected recorded, gain:G, right_gain:G, haze:C, blur:S, noise:S, crop:WxH, step:N, mirror or unpainted"
    )


@dataclass(frozen=True)
class StereoSequence:
    """A KITTI raw drive or KITTI odometry sequence as ``lanegraph run`` reads it.

    ``source`` is its source node type, ``cameras`` the left and right image folders relative to
    ``root`` (``image_02/data``, ``image_03/data``; ``image_0``, ``image_1`` ...), ``keys`` their
    projection rows in ``calib_path``, ``images`` every frame's left and right image, in order."""

    root: Path
    source: str
    cameras: tuple[Path, Path]
    keys: tuple[str, str]
    calib_path: Path
    calib: Calibration
    gray: bool
    images: dict[str, tuple[Path, Path]]

    @property
    def raw(self) -> bool:
        return self.source == "io.kitti_raw"


def open_sequence(folder: str | Path) -> StereoSequence:
    """The sequence in ``folder``, its layout told by ``lanegraph_io.detect_source`` and its frames,
    camera pair and calibration read by that source; an :class:`InputError` saying where and what
    was expected for anything else (a folder of pairs, a missing right image, a broken calibration)."""
    folder = Path(folder)
    source = detect_source(folder)
    if source not in SOURCES:
        what = f"a folder for {source}" if source else "no stereo input"
        raise InputError(
            f"{what}: expected a KITTI raw drive (image_02/data or image_00/data, calib_cam_to_cam.txt one folder up) "
            "or a KITTI odometry sequence (image_0 or image_2, calib.txt)",
            path=str(folder),
        )
    node = SOURCES[source]
    src = node(node_type_of(node).params(), RunContext(input_path=folder))
    left, right = src.all_pairs[0][1].parent, src.all_pairs[0][2].parent
    cameras = (left.relative_to(src.root), right.relative_to(src.root))
    calib_path = (
        src.root.resolve().parent / "calib_cam_to_cam.txt"
        if source == "io.kitti_raw"
        else src.root / "calib.txt"
    )
    return StereoSequence(
        src.root,
        source,
        cameras,
        PROJECTIONS[cameras[0].parts[0]],
        calib_path,
        src.calib,
        src.gray,
        {stem: (lp, rp) for stem, lp, rp in src.all_pairs},
    )


def _calib_lines(seq: StereoSequence, kind: str, arg, width: int) -> list[str]:
    """The calibration file for the variant: the mirror's projection rows of the pair (cx mirrored,
    the old right camera on the left: the same baseline), the crop's image size (KITTI raw's
    ``S_rect_0X``); every other row as it is."""
    lines = seq.calib_path.read_text().splitlines()
    if kind == "mirror":
        rows = read_key_rows(seq.calib_path)
        f, baseline = seq.calib.f, seq.calib.baseline
        out = []
        for ln in lines:
            key = ln.partition(":")[0].strip()
            if key in seq.keys:
                q = projection(rows, key, seq.calib_path).copy()
                q[0, 2] = width - 1 - q[0, 2]
                q[:, 3] = 0.0
                q[0, 3] = 0.0 if key == seq.keys[0] else -f * baseline
                ln = key + ": " + " ".join(f"{x:.6e}" for x in q.ravel())
            out.append(ln)
        return out
    if kind == "crop" and seq.raw:
        w, h = arg
        return [f"{ln[:9]}: {w:.6e} {h:.6e}" if ln.startswith("S_rect_0") else ln for ln in lines]
    return lines


def _disparity_at(disparity: np.ndarray, x: float, y: float) -> float:
    """The median of the valid disparities in the 7 x 7 pixels around ``(x, y)``; NaN when none."""
    h, w = disparity.shape
    xi, yi = int(round(x)), int(round(y))
    win = disparity[max(0, yi - 3) : min(h, yi + 4), max(0, xi - 3) : min(w, xi + 4)]
    win = win[win > 0]
    return float(np.median(win)) if win.size else float("nan")


def mirror_ground_truth(rec: dict, disparity: np.ndarray, width: int) -> dict:
    """A ground-truth record of the left image moved into the mirrored right image: each point
    ``(x, y)`` to ``(width - 1 - (x - d), y)``, ``d`` the median of the valid disparities in the 7 x 7
    pixels around it (points without one are dropped, and markings left with fewer than 2 points);
    ego sides swapped."""
    markings = []
    for m in rec["markings"]:
        pts = []
        for x, y in m["points"]:
            d = _disparity_at(disparity, x, y)
            if not np.isnan(d):
                pts.append([round(width - 1 - (x - d), 1), y])
        if len(pts) >= 2:
            markings.append({**m, "points": pts})
    ego = rec.get("ego") or {}
    return {**rec, "markings": markings, "ego": {"left": ego.get("right"), "right": ego.get("left")}}


def unpaint(
    left: np.ndarray, right: np.ndarray, rec: dict, disparity: np.ndarray, baseline: float
) -> tuple[np.ndarray, np.ndarray]:
    """Both images with the markings of the ground-truth record ``rec`` inpainted away (see the
    module docstring): discs along each polyline every 2 rows, of radius ``0.225 m * d / baseline + 4``
    pixels (a 0.45 m wide strip) at the polyline's disparity ``d`` (interpolated between its points
    that have one), at ``x`` in the left image and ``x - d`` in the right one."""
    h = left.shape[0]
    masks = (np.zeros(left.shape[:2], np.uint8), np.zeros(right.shape[:2], np.uint8))
    for m in rec["markings"]:
        pts = np.array(sorted(m["points"], key=lambda p: -p[1]), float)  # near (bottom) first
        if len(pts) < 2:
            continue
        d = np.array([_disparity_at(disparity, x, y) for x, y in pts])
        if np.all(np.isnan(d)):
            continue
        ok = ~np.isnan(d)
        # rows from the image's bottom to 40 rows beyond the far end, x and d linear in y (the
        # road's disparity is linear in the row), extrapolated from the end segments
        ys = np.arange(h - 1, max(pts[-1, 1] - 40, 0), -2.0)
        xs = np.interp(-ys, -pts[:, 1], pts[:, 0])
        for (ya, xa), (yb, xb), sel in (
            ((pts[0, 1], pts[0, 0]), (pts[1, 1], pts[1, 0]), ys > pts[0, 1]),
            ((pts[-1, 1], pts[-1, 0]), (pts[-2, 1], pts[-2, 0]), ys < pts[-1, 1]),
        ):
            xs[sel] = xa + (xb - xa) / (yb - ya) * (ys[sel] - ya)
        dp, yp = d[ok], pts[ok, 1]
        ds = np.polyval(np.polyfit(yp, dp, 1), ys) if dp.size >= 2 else np.full(ys.shape, dp[0])
        ds = np.clip(ds, 1.0, None)
        for x, y, dd in zip(xs, ys, ds):
            radius = int(round(0.225 * dd / baseline + 4))
            cv2.circle(masks[0], (int(round(x)), int(round(y))), radius, 255, -1)
            cv2.circle(masks[1], (int(round(x - dd)), int(round(y))), radius, 255, -1)
    return tuple(cv2.inpaint(img, mk, 5, cv2.INPAINT_TELEA) for img, mk in zip((left, right), masks))


def _sgbm(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    sgbm = cv2.StereoSGBM_create(
        0, 128, 5, P1=8 * 25, P2=32 * 25, uniquenessRatio=10, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY
    )
    gray = [cv2.cvtColor(i, cv2.COLOR_BGR2GRAY) if i.ndim == 3 else i for i in (left, right)]
    return sgbm.compute(*gray).astype(np.float32) / 16.0


def _check_frames(seq: StereoSequence, gt: list[dict], gt_path: Path) -> None:
    """Every frame of the ground truth ``gt`` (read from ``gt_path``) is one of ``seq``'s."""
    missing = [rec["frame"] for rec in gt if str(rec["frame"]) not in seq.images]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise InputError(
            f"frame {missing[0]}{more} of the ground truth is not among the images of {seq.root}/{seq.cameras[0]}",
            path=str(gt_path),
        )


def write_variant(
    seq: str | Path | StereoSequence, dst: Path, kind: str, arg, gt: list[dict] | None = None
) -> Path:
    """The variant of ``seq`` (a KITTI raw drive, its calibration in the parent, or a KITTI odometry
    sequence) in ``dst`` with the same layout, for the frames of ``gt`` (its ground-truth records;
    default: the sequence's ``lanes_gt.jsonl``), their ground truth beside the images as
    ``lanes_gt.jsonl``; returns the new sequence folder (``dst/<date>/<drive>`` or ``dst/<sequence>``).
    A folder already written there (its ``lanes_gt.jsonl`` present) is taken as it is."""
    seq = seq if isinstance(seq, StereoSequence) else open_sequence(seq)
    root = seq.root.resolve()
    out = dst / root.parent.name / root.name if seq.raw else dst / root.name
    if (out / "lanes_gt.jsonl").is_file():
        return out
    if gt is None:
        gt = read_ground_truth(seq.root / "lanes_gt.jsonl")
        _check_frames(seq, gt, seq.root / "lanes_gt.jsonl")
    frames = [str(rec["frame"]) for rec in gt]
    width = read_image(seq.images[frames[0]][0], frames[0], seq.gray).shape[1]
    calib_dir = out.parent if seq.raw else out
    calib_dir.mkdir(parents=True, exist_ok=True)
    side = seq.calib_path.parent.glob("calib_*.txt") if seq.raw else seq.root.glob("times.txt")
    for p in side:  # KITTI raw's other calibration files, KITTI odometry's times.txt
        shutil.copy(p, calib_dir / p.name)
    (calib_dir / seq.calib_path.name).write_text("\n".join(_calib_lines(seq, kind, arg, width)) + "\n")
    for cam in seq.cameras:
        (out / cam).mkdir(parents=True, exist_ok=True)
        if seq.raw and (seq.root / cam.parent / "timestamps.txt").is_file():
            shutil.copy(seq.root / cam.parent / "timestamps.txt", out / cam.parent / "timestamps.txt")
    new_gt = []
    rng = np.random.default_rng(0)
    for rec in gt:
        fr = str(rec["frame"])
        L, R = (read_image(p, fr, seq.gray) for p in seq.images[fr])
        if kind == "mirror":
            rec = mirror_ground_truth(rec, _sgbm(L, R), width)
            L, R = cv2.flip(R, 1), cv2.flip(L, 1)
        elif kind == "unpainted":
            L, R = unpaint(L, R, rec, _sgbm(L, R), seq.calib.baseline)
            rec = {**rec, "markings": [], "ego": {"left": None, "right": None}}
        elif kind == "gain":
            L, R = (np.clip(i * arg, 0, 255).astype(np.uint8) for i in (L, R))
        elif kind == "right_gain":
            R = np.clip(R * arg, 0, 255).astype(np.uint8)
        elif kind == "haze":
            L, R = (np.clip(i * arg + (1 - arg) * 128, 0, 255).astype(np.uint8) for i in (L, R))
        elif kind == "blur":
            L, R = (cv2.GaussianBlur(i, (0, 0), arg) for i in (L, R))
        elif kind == "noise":
            # the same noise on every colour channel: the grey image gets sigma arg
            L, R = (
                np.clip(i + rng.normal(0.0, arg, i.shape[:2] + (1,) * (i.ndim - 2)), 0, 255).astype(np.uint8)
                for i in (L, R)
            )
        elif kind == "crop":
            w, h = arg
            L, R = L[:h, :w], R[:h, :w]
        for cam, img in zip(seq.cameras, (L, R)):
            cv2.imwrite(str(out / cam / f"{fr}.png"), img)
        new_gt.append(json.dumps(rec))
    (out / "lanes_gt.jsonl").write_text("\n".join(new_gt) + "\n")
    return out


def _selection_text(r: range) -> str:
    """``--frames`` for the indices of ``r`` (a range over the input's frames)."""
    return selection_text(slice(r.start, r.stop if r.stop >= 0 else None, r.step))


def _open_dataset(args: argparse.Namespace) -> tuple[Dataset, dict[str, tuple[StereoSequence, list[dict]]]]:
    """The dataset of ``--dataset`` or ``--input``, and each sequence opened with its ground truth
    (cut to its frame selection); an :class:`InputError` for the first that is unusable."""
    if args.dataset:
        ds = load_dataset(args.dataset)
    else:
        drive = Path(args.input or DRIVE)
        ds = single_sequence(drive, drive / "lanes_gt.jsonl")
    opened = {}
    for s in ds:
        where = f"sequence {s.name!r} of {args.dataset}: " if args.dataset else "--input: "
        if s.gt is None or not s.gt.is_file():
            raise InputError(
                f"{where}no ground truth (the sweep scores every variant against it; expected {'a gt file' if args.dataset else 'lanes_gt.jsonl in the folder'})",
                path=str(s.gt or s.input),
            )
        seq = open_sequence(s.input)
        gt = read_gt(s, s.frames)
        if not gt:
            raise InputError(
                f"{where}the ground truth lists no frame{' in the selection' if s.frames else ''}",
                path=str(s.gt),
            )
        _check_frames(seq, gt, s.gt)
        opened[s.name] = (seq, gt)
    return ds, opened


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("graph", nargs="?", default=str(ROOT / "graphs" / "paper.yaml"))
    ap.add_argument(
        "--input",
        default="",
        help=f"a KITTI raw drive or KITTI odometry sequence folder with lanes_gt.jsonl (default: {DRIVE})",
    )
    ap.add_argument(
        "--dataset",
        default="",
        help="a dataset file (YAML list of sequences with ground truth, e.g. graphs/datasets/dev.yaml) in place of --input",
    )
    ap.add_argument("--variants", default=DEFAULT, help=f"comma-separated (default: {DEFAULT})")
    ap.add_argument(
        "--set", action="append", default=[], metavar="NODE.PARAM=VALUE", help="passed to lanegraph run"
    )
    ap.add_argument(
        "--work",
        default="",
        help="folder for the variants and the runs, kept (default: a temporary folder, removed at the end)",
    )
    ap.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    args = ap.parse_args(argv)
    if args.dataset and args.input:
        ap.error(
            "--dataset lists the inputs and their ground truths: give it instead of --input, not with it"
        )
    try:
        variants = [(spec, *parse_variant(spec)) for spec in args.variants.split(",") if spec]
    except ValueError as exc:
        ap.error(f"--variants: {exc}")
    try:
        ds, opened = _open_dataset(args)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    def sweep(work: Path) -> int:
        names = list(opened)
        col = max(len("sequence"), *(len(n) for n in names))
        print(f"{args.graph} on {len(variants)} variant(s) of {', '.join(names)} (work: {work})")
        print(f"{'variant':20s} {'sequence':{col}s} {HEADER}")
        rows: list[dict] = []
        failed_any = False
        # on a terminal: which variant and sequence is being written or run (None: off where stderr is no terminal)
        bar = tqdm(
            total=len(variants) * len(names),
            unit="run",
            file=sys.stderr,
            leave=False,
            disable=True if args.quiet else None,
        )

        def show(spec: str, name: str, text: str) -> None:
            tqdm.write(f"{spec:20s} {name:{col}s} {text}", file=sys.stdout)
            sys.stdout.flush()

        for spec, kind, arg in variants:
            vname = spec.replace(":", "_")
            evals, broken = [], []
            for s in ds:
                seq, gt = opened[s.name]
                extra: list[str] = []
                if kind in ("recorded", "step"):
                    data = s.input
                    picked = range(len(seq.images))[s.frames or slice(None)]
                    if kind == "step":
                        picked = picked[:: int(arg)]
                        ids = list(seq.images)
                        chosen = {ids[i] for i in picked}
                        gt = [g for g in gt if str(g["frame"]) in chosen]
                    if picked != range(len(seq.images)):
                        extra = ["--frames", _selection_text(picked)]
                else:
                    bar.set_description(f"{spec} / {s.name}: writing the variant")
                    data = write_variant(seq, work / "data" / vname / s.name, kind, arg, gt)
                    gt = read_ground_truth(data / "lanes_gt.jsonl")
                bar.set_description(f"{spec} / {s.name}: lanegraph run")
                out = work / "runs" / vname / s.name
                failed = run_graph(args.graph, data, out, args.set, extra)
                bar.update()
                if not failed:
                    try:
                        pred = read_predictions(lanes_file(out))
                    except InputError as exc:
                        failed = f"unreadable predictions: {exc}"
                if failed:
                    failed_any = True
                    broken.append(s.name)
                    show(spec, s.name, failed)
                    continue
                res = evaluate(pred, gt)
                evals.append((s.name, pred, gt))
                rows.append(_row(spec, s.name, res, lanes_reported(pred)))
                show(spec, s.name, metric_row(res, lanes_reported(pred)))
            if len(names) > 1:
                if broken:
                    show(spec, POOLED, f"- (not pooled: {', '.join(broken)} failed)")
                else:
                    res = evaluate_sequences(evals)[POOLED]
                    n = sum(lanes_reported(pred) for _, pred, _ in evals)
                    rows.append(_row(spec, POOLED, res, n))
                    show(spec, POOLED, metric_row(res, n))
        bar.close()
        summary = {
            "graph": args.graph,
            "set": args.set,
            "dataset": str(args.dataset) if args.dataset else None,
            "sequences": names,
            "rows": rows,
        }
        (work / "sweep.json").write_text(json.dumps(summary, indent=1) + "\n")
        return 1 if failed_any else 0

    if args.work:
        return sweep(Path(args.work))
    # the data and the runs go to a temporary folder removed at the end (--work keeps them)
    with tempfile.TemporaryDirectory(prefix="lanegraph-kitti-sweep-") as tmp:
        return sweep(Path(tmp))


def _row(variant: str, sequence: str, res: dict, lanes: int) -> dict:
    keys = ("frames", "detection_ratio", "precision", "ego_recall", "mean_abs_dx_px")
    return {"variant": variant, "sequence": sequence, **{k: res.get(k) for k in keys}, "lanes": lanes}


if __name__ == "__main__":
    sys.exit(main())
