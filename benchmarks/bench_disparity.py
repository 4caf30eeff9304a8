"""Disparity backends on real KITTI frames: median ms per frame and valid-pixel fraction.

    python benchmarks/bench_disparity.py [--frames 5] [--repeat 3] [--drive PATH]
        [--onnx MODEL.onnx [--onnx-set PARAM=VALUE ...]] [--providers cpu|cuda|auto]

Runs each backend (SGBM, SGBM 3-way, BM, our census SGM, SGBM at scale 0.5, ``disparity.onnx``)
on the first ``--frames`` colour pairs of the drive (``image_02`` / ``image_03``), after one
warm-up call (numba compilation, OpenCV buffers, ONNX Runtime's first run), and prints per
backend the median wall time per frame, the fraction of valid pixels over the whole image and
over its lower half (the road), and the agreement (|d - d_sgbm| < 1 px where both are valid)
with the plain SGBM map.

``disparity.onnx`` runs the tests' model (``lanegraph_disparity.onnx_models.cost_volume_model``:
a SAD cost volume and ArgMin; 48 shifts at half resolution as in the graph test, and 96 at full
resolution) and every ``--onnx`` model, on the CPU unless ``--providers`` says otherwise; the
session is created once per model, outside the timing, as a run does. ``--onnx-set`` gives the
node's params for the ``--onnx`` models (values read as YAML, e.g. ``--onnx-set resize=[384,1248]``).
It needs the onnx extra (``pip install "lanegraph[onnx]"``); without it those rows say so.
The drive defaults to ``../shared/data/kitti_raw/2011_09_26/2011_09_26_drive_0001_sync``
relative to the repository root. No assertions: numbers only.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import lanegraph_disparity as ld
import numpy as np
import yaml

from lanegraph import RunContext

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


def onnx_backends(
    models: list[Path], sets: list[str], providers: str, tmp: Path, test_models: bool = True
) -> list[tuple[str, Callable[[np.ndarray, np.ndarray], np.ndarray] | str]]:
    """(name, compute or the reason it cannot run) of every ``disparity.onnx`` configuration."""
    try:
        import onnx
        import onnxruntime
        from lanegraph_disparity.onnx_models import cost_volume_model
    except ImportError as exc:
        return [("onnx", f'skipped: {exc} (pip install "lanegraph[onnx]")')]
    print(
        f"onnxruntime {onnxruntime.__version__}, providers here: {', '.join(onnxruntime.get_available_providers())}"
    )
    configs = []
    for n, resize in ((48, (188, 622)), (96, None)) if test_models else ():
        path = tmp / f"cost_volume_{n}.onnx"
        onnx.save(cost_volume_model(n, window=5), str(path))
        configs.append((f"onnx cv{n}" + (" half" if resize else ""), {"model": str(path), "resize": resize}))
    user = {}
    for item in sets:
        key, _, value = item.partition("=")
        user[key.strip()] = yaml.safe_load(value)
    for m in models:
        configs.append((f"onnx {m.stem}"[:22], {**user, "model": str(m)}))
    out: list[tuple[str, Callable[[np.ndarray, np.ndarray], np.ndarray] | str]] = []
    for name, values in configs:
        try:
            params = ld.OnnxParams(**{"providers": providers, **values})
            node = ld.OnnxDisparity(params, RunContext(node_id=name))
        except Exception as exc:  # noqa: BLE001 - report and go on with the other backends
            out.append((name, f"failed: {type(exc).__name__}: {exc}"))
            continue
        name = f"{name} ({'cuda' if node.provider.startswith('CUDA') else 'cpu'})"
        out.append((name, lambda left, right, node=node: node(left=left, right=right)["disparity"]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=5, help="number of frames (default 5)")
    ap.add_argument("--repeat", type=int, default=1, help="timed calls per frame (default 1)")
    ap.add_argument("--drive", type=Path, default=DRIVE, help="KITTI raw drive folder")
    ap.add_argument(
        "--onnx", type=Path, action="append", default=[], help="an ONNX stereo model to time too (repeatable)"
    )
    ap.add_argument(
        "--onnx-set",
        action="append",
        default=[],
        metavar="PARAM=VALUE",
        help="a disparity.onnx param for --onnx models",
    )
    ap.add_argument(
        "--providers",
        choices=["cpu", "cuda", "auto"],
        default="cpu",
        help="ONNX Runtime providers (default cpu)",
    )
    ap.add_argument("--no-onnx-test-models", action="store_true", help="skip the tests' cost-volume models")
    args = ap.parse_args()
    if not (args.drive / "image_02" / "data").is_dir():
        sys.exit(f"KITTI drive not found: {args.drive}")
    pairs = load_pairs(args.drive, args.frames)
    h, w = pairs[0][1].shape[:2]
    print(
        f"{len(pairs)} frames of {w}x{h} from {args.drive.name}; {os.cpu_count()} CPUs; cv2 {cv2.__version__}"
    )
    reference = {stem: ld.sgbm(ld.SgbmParams(), left, right)["disparity"] for stem, left, right in pairs}
    backends: list[tuple[str, Callable[[np.ndarray, np.ndarray], np.ndarray] | str]] = [
        (name, lambda left, right, node=node, params=params: node(params, left, right)["disparity"])
        for name, node, params in BACKENDS
    ]
    tmp = tempfile.TemporaryDirectory(prefix="bench-onnx-")
    if args.onnx or not args.no_onnx_test_models:
        backends += onnx_backends(
            args.onnx, args.onnx_set, args.providers, Path(tmp.name), not args.no_onnx_test_models
        )
    print(f"{'backend':22s} {'ms/frame':>9s} {'valid':>7s} {'valid lower':>12s} {'agree sgbm':>11s}")
    for name, compute in backends:
        if isinstance(compute, str):
            print(f"{name:22s} {compute}")
            continue
        try:
            compute(pairs[0][1], pairs[0][2])  # warm-up: numba compilation, allocations
        except Exception as exc:  # noqa: BLE001 - report and go on with the other backends
            print(f"{name:22s} failed: {type(exc).__name__}: {exc}")
            continue
        times, valid, lower, agree = [], [], [], []
        for stem, left, right in pairs:
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                d = compute(left, right)
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
