"""A graph on a real KITTI raw drive changed the way other cameras, days and speeds change it.

    python benchmarks/sweep_kitti.py [GRAPH] [--input DRIVE] [--variants gain:0.5,mirror,...] [--set NODE.PARAM=V ...]

Each variant is written into ``--work`` (a temporary folder by default) in KITTI raw's layout, with
the drive's ``lanes_gt.jsonl`` carried over, then ``lanegraph run GRAPH`` runs on it and the lane
metric of the data README is printed (detection ratio, precision, ego recall, lanes reported):

- ``recorded``: the drive as it is;
- ``gain:G``: both cameras' images times ``G`` (another exposure), clipped to 0-255;
- ``right_gain:G``: the right camera's images alone times ``G`` (a mismatched pair);
- ``haze:C``: both images at contrast ``C`` around mid-grey, ``C I + (1 - C) 128`` (haze, glare);
- ``blur:S``: both images blurred by a Gaussian of sigma ``S`` pixels;
- ``noise:S``: Gaussian noise of sigma ``S`` grey levels added to every pixel of both images (the
  same on each colour channel; independent per image, a fixed seed);
- ``crop:WxH``: the top-left ``W x H`` of both images (the principal point stays; the calibration's
  image size follows);
- ``step:N``: every ``N``-th frame (``N`` times the speed), on the drive as it is;
- ``unpainted``: the annotated markings inpainted away in both images (OpenCV's Telea inpainting
  over each polyline, extended to the image's bottom and 40 rows beyond its far end, 0.45 m wide at
  the measured disparity; in the right image moved by that disparity); the ground truth then lists
  no marking, and any lane reported is a false one. Where the inpainting leaves a strip brighter
  than the asphalt (next to paint the polyline misses by a few pixels) a lane can follow it;
- ``mirror``: both images flipped left-right and swapped (the right camera becomes the left one),
  ``cx`` mirrored; the ground truth moves into the right camera by OpenCV SGBM's disparity at each
  annotated point (median of the 7 x 7 pixels around it) and is mirrored, ego sides swapped. The
  road's features change sides: a rule that favours one side shows.

Writing a variant takes a few seconds (the mirror's and the inpainting's disparities about 10 s); the default list on
drive 0001 (54 frames) takes about 2.5 minutes on the 2-core reference machine.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from _sweep import HEADER, metric_row, run_graph  # benchmarks/ (the script's folder)
from lanegraph_io._calib import calibration_from_projections, projection, read_key_rows

from lanegraph.metrics import evaluate, read_jsonl
from lanegraph.types import Calibration

ROOT = Path(__file__).resolve().parents[1]
DRIVE = ROOT.parent / "shared/data/kitti_raw/2011_09_26/2011_09_26_drive_0001_sync"
DEFAULT = "recorded,gain:0.35,gain:0.5,gain:0.7,gain:1.2,right_gain:0.75,mirror,unpainted,step:3,noise:4,noise:8,haze:0.6,blur:1.2"
CAMERAS = ("image_02", "image_03")


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
        if value <= 0 or (kind == "step" and value != int(value)):
            raise ValueError(f"{spec!r}: expected a positive {'integer' if kind == 'step' else 'number'}")
        return kind, value
    raise ValueError(f"{spec!r}: unknown variant; expected recorded, gain:G, right_gain:G, haze:C, blur:S, noise:S, crop:WxH, step:N, mirror or unpainted")


def _colour_pair(calib_path: Path) -> tuple[dict[str, np.ndarray], Calibration]:
    """The colour pair's rectified projections (``P_rect_02``, ``P_rect_03``, 3 x 4) of a KITTI raw
    ``calib_cam_to_cam.txt`` and their calibration, read as the ``io.kitti_raw`` source reads them."""
    rows = read_key_rows(calib_path)
    p = {k: projection(rows, k, calib_path) for k in ("P_rect_02", "P_rect_03")}
    return p, calibration_from_projections(p["P_rect_02"], p["P_rect_03"], calib_path)


def _calib_lines(src_dir: Path, kind: str, arg, width: int) -> list[str]:
    """``calib_cam_to_cam.txt`` for the variant: the mirror's P_rect_02 / 03 (cx mirrored, the old
    right camera on the left: the same baseline), the crop's image size."""
    lines = (src_dir / "calib_cam_to_cam.txt").read_text().splitlines()
    if kind == "mirror":
        p, calib = _colour_pair(src_dir / "calib_cam_to_cam.txt")
        f, baseline = calib.f, calib.baseline
        out = []
        for ln in lines:
            key = ln.partition(":")[0]
            if key in p:
                q = p[key].copy()
                q[0, 2] = width - 1 - q[0, 2]
                q[:, 3] = 0.0
                q[0, 3] = 0.0 if key == "P_rect_02" else -f * baseline
                ln = key + ": " + " ".join(f"{x:.6e}" for x in q.ravel())
            out.append(ln)
        return out
    if kind == "crop":
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


def unpaint(left: np.ndarray, right: np.ndarray, rec: dict, disparity: np.ndarray, baseline: float) -> tuple[np.ndarray, np.ndarray]:
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
        for (ya, xa), (yb, xb), sel in (((pts[0, 1], pts[0, 0]), (pts[1, 1], pts[1, 0]), ys > pts[0, 1]), ((pts[-1, 1], pts[-1, 0]), (pts[-2, 1], pts[-2, 0]), ys < pts[-1, 1])):
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
    sgbm = cv2.StereoSGBM_create(0, 128, 5, P1=8 * 25, P2=32 * 25, uniquenessRatio=10, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    gray = [cv2.cvtColor(i, cv2.COLOR_BGR2GRAY) if i.ndim == 3 else i for i in (left, right)]
    return sgbm.compute(*gray).astype(np.float32) / 16.0


def _read(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FileNotFoundError(f"{path}: no readable image (the frame is in lanes_gt.jsonl)")
    return img


def write_variant(drive: Path, dst: Path, kind: str, arg) -> Path:
    """The variant of ``drive`` (a KITTI raw ``..._sync`` folder, its calibration in the parent) in
    ``dst`` with the same layout; returns the new drive folder."""
    out = dst / drive.parent.name / drive.name
    if (out / "lanes_gt.jsonl").is_file():
        return out
    gt = read_jsonl(drive / "lanes_gt.jsonl")
    frames = [rec["frame"] for rec in gt]
    width = _read(drive / CAMERAS[0] / "data" / f"{frames[0]}.png").shape[1]
    baseline = _colour_pair(drive.parent / "calib_cam_to_cam.txt")[1].baseline
    out.parent.mkdir(parents=True, exist_ok=True)
    for p in drive.parent.glob("calib_*.txt"):
        shutil.copy(p, out.parent / p.name)
    (out.parent / "calib_cam_to_cam.txt").write_text("\n".join(_calib_lines(drive.parent, kind, arg, width)) + "\n")
    for cam in CAMERAS:
        (out / cam / "data").mkdir(parents=True, exist_ok=True)
        if (drive / cam / "timestamps.txt").is_file():
            shutil.copy(drive / cam / "timestamps.txt", out / cam / "timestamps.txt")
    new_gt = []
    rng = np.random.default_rng(0)
    for rec in gt:
        fr = rec["frame"]
        L, R = (_read(drive / cam / "data" / f"{fr}.png") for cam in CAMERAS)
        if kind == "mirror":
            rec = mirror_ground_truth(rec, _sgbm(L, R), width)
            L, R = cv2.flip(R, 1), cv2.flip(L, 1)
        elif kind == "unpainted":
            L, R = unpaint(L, R, rec, _sgbm(L, R), baseline)
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
            L, R = (np.clip(i + rng.normal(0.0, arg, i.shape[:2] + (1,) * (i.ndim - 2)), 0, 255).astype(np.uint8) for i in (L, R))
        elif kind == "crop":
            w, h = arg
            L, R = L[:h, :w], R[:h, :w]
        for cam, img in zip(CAMERAS, (L, R)):
            cv2.imwrite(str(out / cam / "data" / f"{fr}.png"), img)
        new_gt.append(json.dumps(rec))
    (out / "lanes_gt.jsonl").write_text("\n".join(new_gt) + "\n")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("graph", nargs="?", default=str(ROOT / "graphs" / "paper.yaml"))
    ap.add_argument("--input", default=str(DRIVE), help="a KITTI raw drive folder with lanes_gt.jsonl")
    ap.add_argument("--variants", default=DEFAULT, help=f"comma-separated (default: {DEFAULT})")
    ap.add_argument("--set", action="append", default=[], metavar="NODE.PARAM=VALUE", help="passed to lanegraph run")
    ap.add_argument("--work", default="", help="folder for the variants and the runs (kept)")
    args = ap.parse_args()
    drive = Path(args.input)
    if not (drive / "lanes_gt.jsonl").is_file():
        ap.error(f"--input: {drive}: expected a KITTI raw drive folder with lanes_gt.jsonl")
    try:
        variants = [(spec, *parse_variant(spec)) for spec in args.variants.split(",") if spec]
    except ValueError as exc:
        ap.error(f"--variants: {exc}")
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="lanegraph-kitti-sweep-"))
    print(f"{args.graph} on {len(variants)} variants of {drive.name} (work: {work})")
    print(f"{'variant':20s} {HEADER}")
    for spec, kind, arg in variants:
        name = spec.replace(":", "_")
        frames = []
        if kind in ("recorded", "step"):
            data = drive
            if kind == "step":
                frames = ["--frames", f"0::{int(arg)}"]
        else:
            data = write_variant(drive, work / "data" / name, kind, arg)
        out = work / "runs" / name
        failed = run_graph(args.graph, data, out, args.set, frames)
        if failed:
            print(f"{spec:20s} {failed}")
            continue
        pred = read_jsonl(out / "lanes.jsonl")
        ran = {p["frame"] for p in pred}
        gt = [g for g in read_jsonl(data / "lanes_gt.jsonl") if kind != "step" or g["frame"] in ran]
        print(f"{spec:20s} {metric_row(evaluate(pred, gt), sum(len(p['lanes']) for p in pred))}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
