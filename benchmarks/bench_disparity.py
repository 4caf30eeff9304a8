"""Disparity backends on real KITTI frames: median ms per frame and valid-pixel fraction.

    python benchmarks/bench_disparity.py [--frames 5] [--repeat 3] [--drive PATH]

Runs each backend (SGBM, SGBM 3-way, BM, our census SGM, SGBM at scale 0.5) on the first
``--frames`` colour pairs of the drive (``image_02`` / ``image_03``), after one warm-up call
(numba compilation, OpenCV buffers), and prints per backend the median wall time per frame,
the fraction of valid pixels over the whole image and over its lower half (the road), and
the agreement (|d - d_sgbm| < 1 px where both are valid) with the plain SGBM map.
The drive defaults to ``../shared/data/kitti_raw/2011_09_26/2011_09_26_drive_0001_sync``
relative to the repository root. No assertions: numbers only.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import cv2
import lanegraph_disparity as ld
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DRIVE = ROOT.parent / "shared" / "data" / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"

BACKENDS = [
    ("sgbm", ld.sgbm, ld.SgbmParams()),
    ("sgbm 3way", ld.sgbm, ld.SgbmParams(mode="3way")),
    ("bm", ld.bm, ld.BmParams()),
    ("sgm (own, 8 paths)", ld.sgm, ld.SgmParams()),
    ("sgm (own, 4 paths)", ld.sgm, ld.SgmParams(paths=4)),
    ("sgbm scale 0.5", ld.sgbm, ld.SgbmParams(scale=0.5)),
    ("sgm (own) scale 0.5", ld.sgm, ld.SgmParams(scale=0.5)),
    ("sgbm lr_check", ld.sgbm, ld.SgbmParams(lr_check=True)),
    ("sgbm wls", ld.sgbm, ld.SgbmParams(wls=True)),
]


def load_pairs(drive: Path, n: int) -> list[tuple[str, np.ndarray, np.ndarray]]:
    files = sorted((drive / "image_02" / "data").glob("*.png"))[:n]
    pairs = []
    for f in files:
        left = cv2.imread(str(f), cv2.IMREAD_COLOR)
        right = cv2.imread(str(drive / "image_03" / "data" / f.name), cv2.IMREAD_COLOR)
        if left is None or right is None:
            sys.exit(f"cannot read the pair {f.name} in {drive}")
        pairs.append((f.stem, left, right))
    return pairs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=5, help="number of frames (default 5)")
    ap.add_argument("--repeat", type=int, default=1, help="timed calls per frame (default 1)")
    ap.add_argument("--drive", type=Path, default=DRIVE, help="KITTI raw drive folder")
    args = ap.parse_args()
    if not (args.drive / "image_02" / "data").is_dir():
        sys.exit(f"KITTI drive not found: {args.drive}")
    pairs = load_pairs(args.drive, args.frames)
    h, w = pairs[0][1].shape[:2]
    print(
        f"{len(pairs)} frames of {w}x{h} from {args.drive.name}; {os.cpu_count()} CPUs; cv2 {cv2.__version__}"
    )
    reference = {stem: ld.sgbm.func(ld.SgbmParams(), left, right)["disparity"] for stem, left, right in pairs}
    print(f"{'backend':22s} {'ms/frame':>9s} {'valid':>7s} {'valid lower':>12s} {'agree sgbm':>11s}")
    for name, node, params in BACKENDS:
        try:
            node.func(params, pairs[0][1], pairs[0][2])  # warm-up: numba compilation, allocations
        except Exception as exc:  # noqa: BLE001 - report and go on with the other backends
            print(f"{name:22s} failed: {type(exc).__name__}: {exc}")
            continue
        times, valid, lower, agree = [], [], [], []
        for stem, left, right in pairs:
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                d = node.func(params, left, right)["disparity"]
                times.append((time.perf_counter() - t0) * 1000.0)
            ref = reference[stem]
            both = (d > 0) & (ref > 0)
            valid.append(float((d > 0).mean()))
            lower.append(float((d[h // 2 :] > 0).mean()))
            agree.append(float((np.abs(d - ref)[both] < 1.0).mean()) if both.any() else 0.0)
        print(
            f"{name:22s} {statistics.median(times):9.1f} {statistics.mean(valid):7.3f} "
            f"{statistics.mean(lower):12.3f} {statistics.mean(agree):11.3f}"
        )


if __name__ == "__main__":
    main()
