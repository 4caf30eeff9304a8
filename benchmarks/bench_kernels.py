"""Each numba kernel against its plain NumPy twin from the tests: time and speed-up.

    python benchmarks/bench_kernels.py [--repeat 7]

Inputs have the sizes of the real pipeline: a 1242 x 375 KITTI-like disparity map (a flat road
with noise, in 1/16 pixels, the top 30 % empty as disparity.sgbm leaves it), an 800 x 400 BEV, 20 000 Hough
features, a half-resolution (621 x 187) image for the census. Twins that loop in Python run on a
slice and their time is scaled by the work (stated in the output). Times are the best of
``--repeat`` runs (the machines are shared: the best run is the least disturbed one).
The DP's twin loops over rows in Python (bins vectorised) and the SGM aggregation's and
winner-take-all's twins loop pixel by pixel: they are timed on slices too.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lanegraph_disparity import _sgm  # noqa: E402
from lanegraph_lanes import _features, _fit, _hough, _temporal, _verify  # noqa: E402
from lanegraph_road import mask, profile  # noqa: E402

from lanegraph.testing import make_bev_image, make_disparity  # noqa: E402
from lanegraph.types import FeatureMap, Lane  # noqa: E402
from tests.plugins import test_disparity as td  # noqa: E402
from tests.plugins import test_lanes as tl  # noqa: E402
from tests.plugins import test_road as tr  # noqa: E402

REPEAT = 7
ROWS: list[tuple[str, float, float]] = []


def timed(fn, repeat: int | None = None) -> float:
    """Best of ``repeat`` calls after a warm-up call, ms."""
    fn()
    ts = []
    for _ in range(repeat or REPEAT):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.min(ts)) * 1000


def row(name: str, kernel_ms: float, twin_ms: float, note: str = "") -> None:
    ROWS.append((name, kernel_ms, twin_ms))
    print(
        f"{name:24s} numba {kernel_ms:9.3f} ms   numpy twin {twin_ms:10.2f} ms   speed-up {twin_ms / kernel_ms:8.1f}x  {note}",
        flush=True,
    )


def bev_kernels(rng: np.random.Generator) -> None:
    bev = make_bev_image(rows=800, cols=400, lane_cols=(150.0, 250.0), noise=8).astype(np.float32)
    small = bev[:40]
    scale = bev.size / small.size
    out = np.zeros(bev.shape, np.uint8)
    row(
        "_slt",
        timed(lambda: _features._slt(bev, 6, 10.0, _features._EVERYWHERE, out)),
        timed(lambda: tl.slt_twin(small, 6, 10.0), 1) * scale,
        f"(twin on 40 rows, x{scale:.0f})",
    )
    gx, gy = _features.sobel(bev)
    sgx, sgy = _features.sobel(small)
    row(
        "_eslt",
        timed(lambda: _features._eslt(bev, gx, gy, 6, 10.0, math.radians(15), _features._EVERYWHERE)),
        timed(lambda: tl.eslt_twin(small, sgx, sgy, 6, 10.0, math.radians(15)), 1) * scale,
        f"(twin on 40 rows, x{scale:.0f})",
    )
    r = rng.integers(0, 800, 20000).astype(np.int32)  # pixel coordinates, as the Hough nodes pass them
    c = rng.integers(0, 400, 20000).astype(np.int32)
    acc = np.zeros(2000)
    row(
        "_vote_1d",
        timed(lambda: _hough._vote_1d(r, c, 800.0, 0.05, 800, acc)),
        timed(lambda: tl.vote_twin(r, c, 800.0, 0.05, 800, 2000)),
        "(20000 features)",
    )
    inv = np.linspace(-0.5, 0.5, 121)
    acc2 = np.zeros((121, 2000))
    row(
        "_vote_2d",
        timed(lambda: _hough._vote_2d(r, c, 800.0, inv, 800, acc2)),
        timed(lambda: [tl.vote_twin(r, c, 800.0, it, 800, 2000) for it in inv], 3),
        "(20000 features, 121 thetas)",
    )
    feats = FeatureMap(mask=rng.random((800, 400)) < 0.05)
    t, y, _ = tl.parabola_with_outliers(n=3000, seed=1)
    row(
        "_irls_kernel",
        timed(lambda: _fit._irls_kernel(t, y, 2, 10, True, 4.685, 0.01, np.empty(0), np.empty(0))),
        timed(lambda: _fit.irls_fit_lstsq(t, y, 2, 10, "tukey")),
        "(3000 points, 30 % outliers)",
    )
    samples = _fit.ransac_samples(t.size, 3, 200, 0)
    row(
        "_ransac_kernel",
        timed(lambda: _fit._ransac_kernel(t, y, samples, np.full(t.size, 3.0))),
        timed(lambda: tl.ransac_np(t, y, samples, 3.0), 3),
        "(3000 points, 200 parabola samples)",
    )
    lcols = np.stack([150.0 + 0.05 * np.arange(800), 250.0 + 0.05 * np.arange(800)])[None, 0]
    band = np.zeros((800, 400), bool)
    fm = feats.mask
    fr, fc = feats.points()
    row(
        "_side_band_kernel",
        timed(lambda: _temporal._side_band_kernel(lcols, 0, 200, 30.0, fr, fc, band)),
        timed(lambda: tl.side_band_np(lcols, 0, 200, 30.0, fm)),
    )
    img8 = bev.astype(np.uint8)
    lane = Lane((150.0, 0.05, 0.0), (0, 799), "left", 0.9)
    for measure in ("mdiff", "diff"):
        row(
            f"_side_texture_kernel {measure}",
            timed(lambda m=measure: _verify.side_texture(img8, lane, 6, 30, m, 0.75)),
            timed(lambda m=measure: tl.side_texture_twin(img8, lane, 6, 30, m, 0.75)),
            "(800 rows, both sides, 75th percentile of the rows)",
        )


def road_kernels(rng: np.random.Generator) -> None:
    disp, calib = make_disparity(375, 1242, pitch_deg=0.5, cam_height=1.65, f=721.5, baseline=0.54)
    # in OpenCV's 1/16 pixels, as disparity.sgbm gives them
    disp = (np.round((disp + rng.normal(0, 0.3, disp.shape)) * 16) / 16).astype(np.float32)
    disp[: int(0.3 * 375)] = 0.0
    disp[rng.random(disp.shape) < 0.2] = 0.0
    keep = np.ones(disp.shape, bool)
    s_, c_ = 0.01, 0.9999
    band = (1.0 / 1.65, -40.0, 0.0, 0.23)
    in_band = tr.plane_band_np(disp, band[1], band[2], band[3], 1.0, band[0])
    row(
        "_select_kernel",
        timed(lambda: profile.select_and_count(disp, calib.cx, calib.cy, s_, c_, 128.0, 1.0, band)),
        timed(
            lambda: (
                tr.select_np(disp, band, calib.cx, calib.cy, s_, c_),
                tr.vdisparity_np(disp, in_band, 128, 1.0, 128.0, calib.cx, calib.cy, s_, c_),
            )
        ),
        "(pixel list + v-disparity; road band, roll-corrected rows)",
    )
    rows, d = profile.select_pixels(disp, calib.cx, calib.cy, s_, c_)
    centre = np.clip(-40.0 + 0.23 * np.arange(disp.shape[0]), 0, None).astype(np.float64)
    radius = np.full(disp.shape[0], 1.0)
    row(
        "_row_refine_kernel",
        timed(lambda: profile._row_refine_kernel(rows, d, centre, radius)),
        timed(lambda: tr.row_refine_np(disp, keep, centre, radius, calib.cx, calib.cy, s_, c_)),
        "(twin from the image)",
    )
    prow, pd, pvd = profile.select_and_count(disp, calib.cx, calib.cy, s_, c_, 128.0, 1.0, band, 4)
    kargs = (pvd, 311.0, 3, 0.02, 1.0, 1.0, prow, pd, 1.65, 0.05, 0.25, 4, 10, np.float32(3.0))
    row(
        "_profile_kernel",
        timed(lambda: profile._profile_kernel(*kargs)),
        timed(lambda: tr.profile_np(*kargs)),
        "(pass 2: DP, 3 refinements, every 4th column)",
    )
    pargs = (4, 120, 3.0, -40.0, 0.0, 0.23, 1.0, 0.05, 1.65, 0.25, 620.5, 187.0, 3)
    row(
        "_plane_fit_kernel",
        timed(lambda: profile._plane_fit_kernel(disp, *pargs)),
        timed(lambda: tr.plane_fit_np(disp, *pargs)),
        "(3 rounds, every 4th row and column)",
    )
    v = np.arange(120, 375, dtype=np.float64)
    dv = -40.0 + 0.23 * v + rng.normal(0, 0.2, v.size)
    w = rng.integers(100, 600, v.size).astype(np.float64)  # the rows' pixel counts, as the profile gives them
    ii, jj = profile._sample_pairs(v.size, 300, 0)
    row(
        "_line_fit",
        timed(lambda: profile._line_fit(v, dv, w, ii, jj, 1.0, 4, 0.0)),
        timed(lambda: tr.line_fit_np(v, dv, w, 1.0, 300)),
        "(255 rows, 300 RANSAC samples, 4 rounds at most)",
    )
    inl0 = rng.random(v.size) < 0.8
    row(
        "_line_refit_kernel",
        timed(lambda: profile._line_refit_kernel(v, dv, w, inl0, 1.0, 4)),
        timed(lambda: profile._robust_refit_np(v, dv, w, 1, 1.0, inl0)),
        "(255 rows, 4 rounds at most)",
    )
    hargs = (-40.0, 0.23, 0.0, calib.cx, calib.cy, s_, c_, 1.65, 0.08, 0.5, 2.0)
    row(
        "_height_class_kernel",
        timed(lambda: mask._height_class_kernel(disp, 1, *hargs)),
        timed(lambda: tr.height_class_np(disp, *hargs)),
    )
    labels, _ = mask._height_class_kernel(disp, 1, *hargs)
    sl = labels[:, :60]
    row(
        "_free_space_kernel",
        timed(lambda: mask._free_space_kernel(labels, 4, True)),
        timed(lambda: tr.free_space_np(sl, 4, True), 1) * (labels.size / sl.size),
        "(twin on 60 columns, scaled)",
    )
    score = rng.random((255, 128))
    sc = score[:, :40]
    row(
        "_dp_path_kernel",
        timed(lambda: profile._dp_path_kernel(score, 3, 0.02)),
        timed(lambda: tr.dp_np(sc, 3, 0.02)) * (score.size / sc.size),
        "(twin: the DP vectorised over bins, 40 bins, scaled)",
    )


def sgm_kernels(rng: np.random.Generator) -> None:
    img = rng.integers(0, 255, (187, 621)).astype(np.uint8)
    row(
        "_census",
        timed(lambda: _sgm._census(img, 7, 9)),
        timed(lambda: td.census_ref(img, 7, 9), 3),
        "(621 x 187, 7 x 9)",
    )
    cl = _sgm._census(img, 7, 9)
    cr = _sgm._census(np.roll(img, -3, axis=1), 7, 9)
    row(
        "_cost_volume",
        timed(lambda: _sgm._cost_volume(cl, cr, 64, 62)),
        timed(lambda: td.cost_volume_ref(cl, cr, 64, 62), 2),
        "(621 x 187 x 64)",
    )
    cost = _sgm._cost_volume(cl[:40, :120], cr[:40, :120], 32, 62)
    total = np.zeros(cost.shape, np.uint16)
    row(
        "_aggregate_path",
        timed(lambda: _sgm._aggregate_path(cost, 1, 0, 7, 40, total)),
        timed(lambda: td.path_ref(cost, 1, 0, 7, 40), 1),
        "(120 x 40 x 32, one direction; twin pixel by pixel)",
    )
    row(
        "_wta",
        timed(lambda: _sgm._wta(total, 15, True, False)),
        timed(lambda: td.wta_ref(total, 15, True, False), 1),
        "(120 x 40 x 32; twin pixel by pixel)",
    )


def main() -> None:
    global REPEAT
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=REPEAT)
    REPEAT = ap.parse_args().repeat
    rng = np.random.default_rng(0)
    bev_kernels(rng)
    road_kernels(rng)
    sgm_kernels(rng)
    below = [name for name, k, t in ROWS if t / k < 10]
    print(f"\n{len(ROWS)} kernels; below 10x their twin: {', '.join(below) if below else 'none'}")


if __name__ == "__main__":
    main()
