"""Dev / benchmark script for the road stage on the real KITTI frames.

Runs ``road.vdisparity``, ``road.profile``, ``road.mask`` and ``bev.ipm`` on KITTI raw drive 0001
(SGBM disparity: the ``disparity.sgbm`` node when a plugin registers it, else OpenCV's StereoSGBM
directly), prints per-frame pitch / roll / height and the time per node, summarises their stability,
and writes debug PNGs (road-mask overlay, v-disparity with the profile, BEV image, BEV mask) to
``/tmp/road_dbg/``.

    python benchmarks/dev_road.py [--frames 0:54] [--out /tmp/road_dbg] [--no-images]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import cv2
import numpy as np

from lanegraph.types import Calibration, RoadModel

ROOT = Path(__file__).resolve().parents[1]
DRIVE = ROOT.parent / "shared" / "data" / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"
CALIB = Calibration(f=721.5377, cx=609.5593, cy=172.854, baseline=0.5327, width=1242, height=375)


def sgbm_disparity(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """SGBM disparity (float32 pixels, invalid <= 0): the project's ``disparity.sgbm`` node if any."""
    try:
        from lanegraph.plugins import get_plugin_manager

        nt = get_plugin_manager().get_node_type("disparity.sgbm")
    except Exception:  # the engine / plugin may be work in progress
        nt = None
    if nt is not None and not nt.stateful:
        try:
            out = nt.func(nt.params(), left=left, right=right)
            if not getattr(sgbm_disparity, "_told", False):
                print(f"disparity: the {nt.name!r} node of plugin {nt.plugin!r} (default params)")
                sgbm_disparity._told = True
            return np.asarray(next(iter(out.values())), dtype=np.float32)
        except Exception as exc:  # fall back to plain OpenCV
            print(f"disparity.sgbm failed ({exc!r}); using cv2.StereoSGBM directly")
    gl = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
    gr = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
    block = 5
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0,
        numDisparities=128,
        blockSize=block,
        P1=8 * block * block,
        P2=32 * block * block,
        disp12MaxDiff=1,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    return sgbm.compute(gl, gr).astype(np.float32) / 16.0


def _overlay(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    out = img.copy()
    green = np.zeros_like(img)
    green[:, :, 1] = 255
    out[mask] = (0.55 * img[mask] + 0.45 * green[mask]).astype(np.uint8)
    return out


def _vdisp_image(vd: np.ndarray, road) -> np.ndarray:
    v = np.log1p(vd)
    v = (255 * v / max(v.max(), 1e-6)).astype(np.uint8)
    img = cv2.cvtColor(v, cv2.COLOR_GRAY2BGR)
    img = cv2.resize(img, (img.shape[1] * 3, img.shape[0]), interpolation=cv2.INTER_NEAREST)
    if road.profile is not None:
        for r, d in enumerate(road.profile):
            if d > 0:
                img[r, min(img.shape[1] - 1, int(d * 3))] = (0, 0, 255)
    if road.valid:
        for r in range(img.shape[0]):
            d = road.disparity_at(r)
            if 0 < d * 3 < img.shape[1]:
                img[r, int(d * 3)] = (0, 255, 0)
    return img


def main() -> None:
    import lanegraph_road as rd

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="0:54", help="python slice of frame indices, e.g. 0:54 or 0:1")
    ap.add_argument("--out", default="/tmp/road_dbg", help="folder for the debug PNGs")
    ap.add_argument("--no-images", action="store_true", help="do not write debug PNGs")
    args = ap.parse_args()

    lefts = sorted((DRIVE / "image_02" / "data").glob("*.png"))
    if not lefts:
        raise SystemExit(f"no KITTI frames in {DRIVE}")
    a, b = (int(x) if x else None for x in args.frames.split(":"))
    lefts = lefts[slice(a, b)]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    vd_p, prof_p, mask_p, ipm_p = rd.VDisparityParams(), rd.ProfileParams(), rd.MaskParams(), rd.IpmParams()
    # warm-up (numba compilation / cache load) so the timings are per frame
    warm = np.zeros((8, 16), np.float32)
    rd.road_vdisparity(vd_p, disparity=warm)
    rd.road_profile(prof_p, disparity=warm, calib=CALIB)
    warm_road = RoadModel(a0=-50.0, a1=0.3, height=1.6)
    rd.road_mask(mask_p, disparity=warm + 1.0, road=warm_road, calib=CALIB)

    times: dict[str, list[float]] = {
        "disparity": [],
        "road.vdisparity": [],
        "road.profile": [],
        "road.mask": [],
        "bev.ipm": [],
    }
    rows = []
    print(f"{'frame':>10} {'valid':>5} {'pitch°':>7} {'roll°':>7} {'height m':>8} {'v_min':>5} {'road %':>6}")
    for lp in lefts:
        left = cv2.imread(str(lp), cv2.IMREAD_COLOR)
        right = cv2.imread(str(DRIVE / "image_03" / "data" / lp.name), cv2.IMREAD_COLOR)
        t = time.perf_counter()
        disp = sgbm_disparity(left, right)
        times["disparity"].append(1e3 * (time.perf_counter() - t))
        t = time.perf_counter()
        vd = rd.road_vdisparity(vd_p, disparity=disp)["vdisparity"]
        times["road.vdisparity"].append(1e3 * (time.perf_counter() - t))
        t = time.perf_counter()
        res = rd.road_profile(prof_p, disparity=disp, calib=CALIB, vdisparity=vd)
        times["road.profile"].append(1e3 * (time.perf_counter() - t))
        road = res["road"]
        t = time.perf_counter()
        mask = rd.road_mask(mask_p, disparity=disp, road=road, calib=CALIB)["mask"]
        times["road.mask"].append(1e3 * (time.perf_counter() - t))
        t = time.perf_counter()
        bev = rd.bev_ipm(ipm_p, image=left, mask=mask, road=road, calib=CALIB)
        times["bev.ipm"].append(1e3 * (time.perf_counter() - t))
        rows.append((road.valid, math.degrees(road.pitch), math.degrees(road.roll), road.height))
        print(
            f"{lp.stem:>10} {road.valid!s:>5} {math.degrees(road.pitch):7.3f} {math.degrees(road.roll):7.3f} "
            f"{road.height:8.3f} {road.v_min:5d} {100 * mask.mean():6.1f}"
        )
        if not args.no_images:
            cv2.imwrite(str(out / f"{lp.stem}_mask.png"), _overlay(left, mask))
            cv2.imwrite(str(out / f"{lp.stem}_vdisp.png"), _vdisp_image(res["vdisparity"], road))
            cv2.imwrite(str(out / f"{lp.stem}_bev.png"), bev["image"])
            cv2.imwrite(str(out / f"{lp.stem}_bevmask.png"), (bev["mask"] * 255).astype(np.uint8))
            dv = np.clip(disp * 2, 0, 255).astype(np.uint8)
            cv2.imwrite(str(out / f"{lp.stem}_disp.png"), cv2.applyColorMap(dv, cv2.COLORMAP_JET))

    arr = np.array([r[1:] for r in rows if r[0]])
    print(f"\nvalid frames: {len(arr)}/{len(rows)}")
    if len(arr):
        for k, name in enumerate(("pitch deg", "roll deg", "height m")):
            col = arr[:, k]
            print(
                f"{name:>10}: mean {col.mean():7.3f}  std {col.std():6.3f}  min {col.min():7.3f}  max {col.max():7.3f}"
                f"  max |frame-to-frame| {np.abs(np.diff(col)).max() if len(col) > 1 else 0:6.3f}"
            )
    print("\nms per frame (median / max):")
    for k, v in times.items():
        print(f"{k:>16}: {np.median(v):7.2f} / {np.max(v):7.2f}")


if __name__ == "__main__":
    main()
