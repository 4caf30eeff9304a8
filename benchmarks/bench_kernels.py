"""Each numba kernel against its plain NumPy twin from the tests: median time and speed-up.

    python benchmarks/bench_kernels.py

Inputs are BEV- or image-sized (a KITTI disparity map, an 800x400 BEV); twins that loop in Python
get smaller inputs and their time is scaled by the pixel count (stated in the output).
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lanegraph_disparity import _sgm  # noqa: E402
from lanegraph_lanes import _features, _hough  # noqa: E402
from lanegraph_road import mask, profile  # noqa: E402

from lanegraph.testing import make_bev_image, make_disparity  # noqa: E402
from tests.plugins import test_disparity as td  # noqa: E402
from tests.plugins import test_lanes as tl  # noqa: E402
from tests.plugins import test_road as tr  # noqa: E402


def timed(fn, repeat=5) -> float:
    fn()
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)) * 1000


def row(name: str, kernel_ms: float, twin_ms: float, note: str = "") -> None:
    print(f"{name:24s} numba {kernel_ms:9.3f} ms   numpy twin {twin_ms:10.1f} ms   speed-up {twin_ms / kernel_ms:8.1f}x  {note}")


def main() -> None:
    rng = np.random.default_rng(0)
    bev = make_bev_image(rows=800, cols=400, lane_cols=(150.0, 250.0), noise=8).astype(np.float32)
    small = bev[:40]
    scale = bev.size / small.size
    out = np.zeros(bev.shape, np.uint8)
    k = timed(lambda: _features._slt(bev, 6, 10.0, out))
    t = timed(lambda: tl.slt_twin(small, 6, 10.0), 1) * scale
    row("_slt", k, t, f"(twin on 40 rows, x{scale:.0f})")
    gx, gy = _features.sobel(bev)
    ori = np.empty(bev.shape, np.float32)
    k = timed(lambda: _features._eslt(bev, gx, gy, 6, 10.0, math.radians(15), out, ori))
    sgx, sgy = _features.sobel(small)
    t = timed(lambda: tl.eslt_twin(small, sgx, sgy, 6, 10.0, math.radians(15)), 1) * scale
    row("_eslt", k, t, f"(twin on 40 rows, x{scale:.0f})")
    r = rng.integers(0, 800, 20000).astype(float)
    c = rng.integers(0, 400, 20000).astype(float)
    acc = np.zeros(2000)
    k = timed(lambda: _hough._vote_1d(r, c, 800.0, 0.05, 800, acc))
    t = timed(lambda: tl.vote_twin(r, c, 800.0, 0.05, 800, 2000))
    row("_vote_1d", k, t, "(20000 features)")
    inv = np.linspace(-0.5, 0.5, 121)
    acc2 = np.zeros((121, 2000))
    k = timed(lambda: _hough._vote_2d(r, c, 800.0, inv, 800, acc2))
    t = timed(lambda: [tl.vote_twin(r, c, 800.0, it, 800, 2000) for it in inv])
    row("_vote_2d", k, t, "(121 thetas)")

    disp, calib = make_disparity(375, 1242, pitch_deg=0.5, cam_height=1.65, f=721.5, baseline=0.54)
    disp = disp + rng.normal(0, 0.3, disp.shape).astype(np.float32)
    keep = np.ones(disp.shape, bool)
    s_, c_ = 0.01, 0.9999
    band = (1.0 / 1.65, -40.0, 0.0, 0.23)
    k = timed(lambda: profile.select_pixels(disp, calib.cx, calib.cy, s_, c_, band))
    t = timed(lambda: tr.select_np(disp, band, calib.cx, calib.cy, s_, c_), 2)
    row("_select_kernel", k, t, "(road band, roll-corrected rows)")
    rows, d = profile.select_pixels(disp, calib.cx, calib.cy, s_, c_)
    k = timed(lambda: profile._vdisparity_kernel(rows, d, disp.shape[0], 129, 1.0, 128.0))
    t = timed(lambda: tr.vdisparity_np(disp, keep, 129, 1.0, 128.0, calib.cx, calib.cy, s_, c_), 2)
    row("_vdisparity_kernel", k, t, "(twin from the image)")
    centre = np.asarray(np.clip(-40.0 + 0.23 * np.arange(disp.shape[0]), 0, None), np.float64)
    radius = np.full(disp.shape[0], 1.0)
    k = timed(lambda: profile._row_refine_kernel(rows, d, centre, radius))
    t = timed(lambda: tr.row_refine_np(disp, keep, centre, radius, calib.cx, calib.cy, s_, c_), 2)
    row("_row_refine_kernel", k, t, "(twin from the image)")
    hargs = (-40.0, 0.23, 0.0, calib.cx, calib.cy, 0.01, 0.9999, 1.65, 0.08, 0.5, 2.0)
    k = timed(lambda: mask._height_class_kernel(disp, *hargs))
    t = timed(lambda: tr.height_class_np(disp, *hargs), 2)
    row("_height_class_kernel", k, t)
    labels = mask._height_class_kernel(disp, *hargs)
    k = timed(lambda: mask._free_space_kernel(labels, 4, True))
    sl = labels[:, :60]
    t = timed(lambda: tr.free_space_np(sl, 4, True), 1) * (labels.size / sl.size)
    row("_free_space_kernel", k, t, "(twin on 60 columns, scaled)")

    img = rng.integers(0, 255, (60, 120)).astype(np.uint8)
    k = timed(lambda: _sgm._census(img, 7, 9))
    t = timed(lambda: td.census_ref(img, 7, 9), 2)
    row("_census", k, t, "(60x120)")
    cl = _sgm._census(img, 7, 9)
    cr = _sgm._census(np.roll(img, -3, axis=1), 7, 9)
    k = timed(lambda: _sgm._cost_volume(cl, cr, 32, 62))
    t = timed(lambda: td.cost_volume_ref(cl, cr, 32, 62), 2)
    row("_cost_volume", k, t, "(60x120x32)")


if __name__ == "__main__":
    main()
