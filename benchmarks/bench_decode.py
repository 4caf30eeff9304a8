"""CPU time of decoding a drive's PNG images, by decoder, and whether each gives OpenCV's pixels.

    python benchmarks/bench_decode.py [--input DRIVE] [--images 40] [--rounds 3]

For every image of the colour pair (``image_02``/``image_03``, the first ``--images`` of each) it
times, in one thread, the CPU time of one decode (``time.thread_time``: other load on a shared
machine changes it little) and prints the median per image, each round:

- ``cv2.imread`` as the sources read (``IMREAD_UNCHANGED``), ``cv2.imdecode`` of the file's bytes,
  and ``IMREAD_GRAYSCALE`` (not the same grey as ``cvtColor`` of the colour image: it would change
  the lanes);
- the sources' own decoder (``lanegraph_io._png.decode_png``: ISA-L's inflate and a numba kernel for
  the row filters), colour and grey (checked against ``IMREAD_GRAYSCALE``), and ``read_image`` as the
  sources call it (the file read included);
- where installed (never a dependency of lanegraph): ``imagecodecs.png_decode`` and
  ``imagecodecs.spng_decode`` (they release the GIL while decoding), ``pyspng.load`` (it does not:
  a reading thread would stop every node's Python code while it decodes), each turned from RGB to
  BGR in place, and checked to give ``cv2.imread``'s pixels on every image.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np
from lanegraph_io._png import decode_png
from lanegraph_io._sources import read_image

from lanegraph._runtime import tune_allocator

ROOT = Path(__file__).resolve().parents[1]
DRIVE = ROOT.parent / "shared/data/kitti_raw/2011_09_26/2011_09_26_drive_0001_sync"


def _bgr(rgb: np.ndarray) -> np.ndarray:
    cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR, dst=rgb)
    return rgb


def decoders() -> dict:
    """name -> function(path, bytes) -> image; the optional ones where installed."""
    out = {
        "cv2.imread UNCHANGED": lambda p, b: cv2.imread(str(p), cv2.IMREAD_UNCHANGED),
        "cv2.imdecode UNCHANGED": lambda p, b: cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_UNCHANGED),
        "cv2.imread GRAYSCALE": lambda p, b: cv2.imread(str(p), cv2.IMREAD_GRAYSCALE),
        "lanegraph decode_png": lambda p, b: decode_png(b),
        "lanegraph decode_png GRAYSCALE": lambda p, b: decode_png(b, True),
        "lanegraph read_image": lambda p, b: read_image(p, "bench"),
    }
    try:
        import imagecodecs

        out["imagecodecs.png_decode"] = lambda p, b: _bgr(imagecodecs.png_decode(b))
        out["imagecodecs.spng_decode"] = lambda p, b: _bgr(imagecodecs.spng_decode(b))
    except ImportError:
        print("imagecodecs not installed: left out")
    try:
        import pyspng

        out["pyspng.load"] = lambda p, b: _bgr(pyspng.load(b))
    except ImportError:
        print("pyspng not installed: left out")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--input", type=Path, default=DRIVE)
    ap.add_argument("--images", type=int, default=40, help="images of each camera (default 40)")
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    paths = []
    for cam in ("image_02", "image_03"):
        paths += sorted((a.input / cam / "data").glob("*.png"))[: a.images]
    if not paths:
        raise SystemExit(f"no PNG images under {a.input}/image_02/data")
    tune_allocator()
    cv2.setNumThreads(1)
    data = [p.read_bytes() for p in paths]
    decs = decoders()
    ref = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in paths]
    ref_gray = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
    decode_png(data[0])  # the kernel compiled (or loaded) before the clock starts
    print(f"{len(paths)} images of {a.input.name}, median CPU ms per image in one thread, {a.rounds} rounds")
    for name, fn in decs.items():
        rounds = []
        for _ in range(a.rounds):
            ts = []
            for p, b in zip(paths, data):
                t0 = time.thread_time()
                fn(p, b)
                ts.append(time.thread_time() - t0)
            rounds.append(1000.0 * float(np.median(ts)))
        gray = "GRAYSCALE" in name
        same = (
            "  pixels as cv2.imread" + (" GRAYSCALE" if gray else "")
            if all(np.array_equal(fn(p, b), r) for p, b, r in zip(paths, data, ref_gray if gray else ref))
            else "  PIXELS DIFFER"
        )
        print(f"  {name:32s} " + " ".join(f"{x:6.2f}" for x in rounds) + same)
    print("  load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
