"""Lane features in the BEV: SLT and the extended SLT (ESLT), and masking.

SLT (symmetrical local threshold): a pixel is a feature when ``I - T`` exceeds both the mean of
the ``w`` pixels to its left and the mean of the ``w`` pixels to its right on the same row.

ESLT adds the parallel-border test: in the left and in the right window, the pixel with the
strongest Sobel gradient (the marking's borders) must have edge orientations within
``max_angle_deg`` (15 degrees) of each other; the feature's orientation is their mean.

Orientation convention (docs/architecture.md): radians in [0, pi) from the +x axis (columns)
towards *up*; a lane straight ahead is pi/2. ``-1`` where unknown.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from pydantic import Field, field_validator

from lanegraph import InputError, NodeParams, Port, jit, node_type, prange
from lanegraph.threads import available_cpus, worker_pool
from lanegraph.types import BevGeometry, Calibration, FeatureMap, RoadModel

from ._border import obstacle_border


@jit
def _row_span(where, r, cols):
    """The first and one past the last column of row ``r`` where ``where`` is set (``where`` of
    shape (0, 0): the whole row); ``(0, 0)`` for an empty row."""
    if where.shape[0] == 0:
        return 0, cols
    c0 = 0
    while c0 < cols and where[r, c0] == 0:
        c0 += 1
    c1 = cols
    while c1 > c0 and where[r, c1 - 1] == 0:
        c1 -= 1
    return c0, c1


#: odd minimax polynomial of atan on [-1, 1] (Abramowitz & Stegun 4.4.49, |error| <= 2e-8 rad)
_ATAN_COEFFS = (
    1.0,
    -0.3333314528,
    0.1999355085,
    -0.1420889944,
    0.1065626393,
    -0.0752896400,
    0.0429096138,
    -0.0161657367,
    0.0028662257,
)


@jit
def atan2_fast(y, x):
    """``atan2(y, x)`` within 2e-8 rad (far below the float32 the orientations are stored in) by
    one division and a polynomial: libm's ``atan2`` dominated ESLT's time per feature."""
    ax = abs(x)
    ay = abs(y)
    big = max(ax, ay)
    if big == 0.0:
        return 0.0
    t = min(ax, ay) / big
    z = t * t
    p = _ATAN_COEFFS[8]
    p = p * z + _ATAN_COEFFS[7]
    p = p * z + _ATAN_COEFFS[6]
    p = p * z + _ATAN_COEFFS[5]
    p = p * z + _ATAN_COEFFS[4]
    p = p * z + _ATAN_COEFFS[3]
    p = p * z + _ATAN_COEFFS[2]
    p = p * z + _ATAN_COEFFS[1]
    p = p * z + _ATAN_COEFFS[0]
    r = t * p
    r = 0.5 * math.pi - r if ay > ax else r
    r = math.pi - r if x < 0.0 else r
    return -r if y < 0.0 else r


@jit
def _eslt_borders(gx, gy, mag2, r, c, lo, hi, cos2_max):
    """The border test of ESLT at an SLT feature ``(r, c)`` with the left window ``[lo, c)`` and the
    right one ``(c, hi)`` (both non-empty); ``mag2``: the row's squared gradient. Returns the
    feature's orientation in ``[0, pi]``, or -1 when the borders are not parallel (no feature)."""
    # strongest gradient in each window, first one on ties; selects rather than branches (which
    # way a comparison goes is unpredictable)
    bl = lo
    ml = mag2[lo]
    for k in range(lo + 1, c):
        m2 = mag2[k]
        gt = m2 > ml
        ml = m2 if gt else ml
        bl = k if gt else bl
    br = c + 1
    mr = mag2[c + 1]
    for k in range(c + 2, hi):
        m2 = mag2[k]
        gt = m2 > mr
        mr = m2 if gt else mr
        br = k if gt else br
    if ml <= 0.0 or mr <= 0.0:
        return -1.0
    ax = float(gx[r, bl])
    ay = float(gy[r, bl])
    bx = float(gx[r, br])
    by = float(gy[r, br])
    na = ax * ax + ay * ay
    nb = bx * bx + by * by
    dot = ax * bx + ay * by
    if not dot * dot > cos2_max * na * nb:
        return -1.0
    # circular mean modulo pi: the sum of the doubled-angle unit vectors, scaled by na nb > 0
    # (atan2 does not change: no divisions)
    s = 2.0 * (ax * ay * nb + bx * by * na)
    co = (ay * ay - ax * ax) * nb + (by * by - bx * bx) * na
    m = 0.5 * atan2_fast(s, co)
    if m < 0:
        m += math.pi
    return m


@jit
def _row_csum(img, r, cols, zero, csum):
    """``csum[c] = img[r, :c].sum()``; ``zero``: an int64 0 for an integer image (an integer running
    sum: one-cycle adds instead of a chain of float additions, the same exact sums), a float64 0
    for a float image."""
    acc = zero
    csum[0] = 0.0
    for c in range(cols):
        acc += img[r, c]
        csum[c + 1] = acc


@jit
def _slt_span(img, csum, r, c0, c1, window, cols, threshold, where, use_where, slt):
    """SLT (``v n_l > sum_l`` and ``v n_r > sum_r``, ``v = I - T``) at the columns ``[c0, c1)`` of
    row ``r`` into the 0/1 row ``slt``, which must be 0 there. Where both windows are whole the test
    runs on row slices (contiguous views, a loop without branches: it vectorises); the few columns
    near the row's ends with their windows clipped. ``csum``: the row's :func:`_row_csum`."""
    w = min(window, cols)
    a = max(c0, w)
    b = max(min(c1, cols - w), a)
    n = b - a
    iv = img[r, a:b]
    left = csum[a - w : b - w]
    mid0 = csum[a:b]
    mid1 = csum[a + 1 : b + 1]
    right = csum[a + 1 + w : b + 1 + w]
    ov = slt[a:b]
    wf = float(w)
    if use_where:
        wv = where[r, a:b]
        for k in range(n):
            v = iv[k] - threshold
            ov[k] = (v * wf > mid0[k] - left[k]) & (v * wf > right[k] - mid1[k]) & (wv[k] != 0)
    else:
        for k in range(n):
            v = iv[k] - threshold
            ov[k] = (v * wf > mid0[k] - left[k]) & (v * wf > right[k] - mid1[k])
    # the columns near the row's ends, ``[c0, a)`` then ``[max(b, c0), c1)``: the windows clipped
    # there (an empty one: no feature); written here, not in a function of their own (one more for
    # numba to compile on the first run's path)
    for part in range(2):
        k0 = c0 if part == 0 else max(b, c0)
        k1 = a if part == 0 else c1
        for c in range(k0, k1):
            lo = max(c - window, 0)
            hi = min(c + 1 + window, cols)
            nl = c - lo
            nr = hi - (c + 1)
            if nl == 0 or nr == 0 or (use_where and where[r, c] == 0):
                continue
            v = img[r, c] - threshold
            if v * nl > csum[c] - csum[lo] and v * nr > csum[hi] - csum[c + 1]:
                slt[c] = 1


@jit(parallel=True)
def _slt(img, window, threshold, where, out):
    """SLT; writes a uint8 0/1 map into ``out``. Windows are clipped at the borders; a pixel with an
    empty window on either side is not a feature. Only the pixels where the uint8 map ``where`` is
    set can be features; ``where`` of shape (0, 0): every pixel. The test is :func:`_slt_span`, the
    one ESLT makes: ESLT's features are always a subset of SLT's, also on a float image's exact
    boundaries (a test by division could round the other way). Rows in parallel."""
    rows, cols = img.shape
    use_where = where.shape[0] > 0
    zbuf = np.empty(1, img.dtype)  # not np.zeros: one function less to compile (first run)
    zbuf[0] = 0
    zero = zbuf[0] + np.int64(0)  # int64 for an integer image, float64 for a float one
    for r in prange(rows):
        row = out[r]
        for c in range(cols):
            row[c] = 0
        c0, c1 = _row_span(where, r, cols)
        if c0 < c1:
            csum = np.empty(cols + 1, np.float64)
            _row_csum(img, r, cols, zero, csum)
            _slt_span(img, csum, r, c0, c1, window, cols, threshold, where, use_where, row)


#: rows per task of :func:`_eslt_rows`
_CHUNK = 16


@jit
def _eslt_rows(img, gx, gy, window, threshold, max_angle, where, pr, pc, pv, t0, t1):
    """ESLT: SLT plus parallel strongest-gradient borders. ``gx``, ``gy`` are Sobel gradients (rows
    growing downwards); the edge orientation of a border pixel is ``atan2(gx, gy)`` modulo pi (from
    +x towards up). Every feature's row, column and orientation go into ``pr``, ``pc``, ``pv``
    (row-major order) from index ``t0 * _CHUNK * cols`` on; returns the index after the last one
    written. No dense mask or orientation map: written one after the other instead of scattered
    over a dense 1.3 MB map (800 x 400 float32) that is not in the cache, the orientations cost
    0.2-0.5 ms a frame less in the graph (docs/pipeline.md, "Round s8"); the feature map builds its
    dense views from the list when a consumer asks.
    Only the pixels where the uint8 map ``where`` is set are tested (their windows may reach
    beyond it); ``where`` of shape (0, 0): every pixel.

    Per row: the cumulative intensity (an integer running sum for an integer image: one-cycle adds
    instead of a chain of float additions, the same exact sums), then SLT on every pixel of the
    row's span in one loop without branches (the compiler vectorises it; the windows have fixed
    bounds away from the row's ends), then the border test on the SLT features only (a few
    percent of the pixels).

    No trigonometry per border: two borders (gradients ``a``, ``b``) are within ``max_angle`` of
    each other, modulo pi, when ``(a.b)^2 > cos^2(max_angle) |a|^2 |b|^2``; the mean orientation
    is half the angle of the sum of their doubled-angle unit vectors
    ``((gy^2 - gx^2) / |g|^2, 2 gx gy / |g|^2)``, one :func:`atan2_fast` per feature. Windows are clipped
    at the borders (a pixel with an empty window is no feature). Rows with nothing to test are skipped.

    Computes the rows of the tasks ``t0 .. t1 - 1`` (``_CHUNK`` rows each) only: :func:`_eslt` runs
    blocks of them on threads (the kernel releases the GIL). A plain kernel on threads instead of
    ``parallel=True``: the same maps, and it compiles in a quarter of the time (2.6 s against 9 s on
    the 2-core reference machine; the first run on a machine compiles it)."""
    rows, cols = img.shape
    cmax = math.cos(max_angle)
    cos2_max = cmax * cmax if max_angle < math.pi / 2 else 0.0
    use_where = where.shape[0] > 0
    zbuf = np.empty(1, img.dtype)  # not np.zeros: one function less to compile (first run)
    zbuf[0] = 0
    zero = zbuf[0] + np.int64(0)  # int64 for an integer image, float64 for a float one
    words = (cols + 7) // 8
    csum = np.empty(cols + 1, np.float64)
    mag2 = np.empty(cols, np.float32)
    slt = np.empty(8 * words, np.uint8)
    for c in range(8 * words):
        slt[c] = 0
    slt_words = slt.view(np.uint64)
    n = t0 * _CHUNK * cols
    for t in range(t0, t1):
        for r in range(t * _CHUNK, min(rows, (t + 1) * _CHUNK)):
            c0, c1 = _row_span(where, r, cols)
            if c0 >= c1:
                continue
            # the whole row (from a span's start, LLVM no longer vectorised these loops)
            _row_csum(img, r, cols, zero, csum)
            for c in range(cols):
                mag2[c] = gx[r, c] * gx[r, c] + gy[r, c] * gy[r, c]
            _slt_span(img, csum, r, c0, c1, window, cols, threshold, where, use_where, slt)
            # the border test at the SLT features: eight flags at a time, most words are 0
            for q in range(c0 // 8, (c1 + 7) // 8):
                if slt_words[q] == 0:
                    continue
                for c in range(max(8 * q, c0), min(8 * q + 8, c1)):
                    if slt[c]:
                        slt[c] = 0
                        m = _eslt_borders(
                            gx, gy, mag2, r, c, max(c - window, 0), min(c + 1 + window, cols), cos2_max
                        )
                        if m >= 0.0:
                            pr[n] = r
                            pc[n] = c
                            pv[n] = m
                            n += 1
    return n


@functools.cache
def _cpus() -> int:
    return available_cpus()


def _threads() -> int:
    """The threads ESLT runs on: the CPUs free to the process, at most OpenCV's thread count
    (which a Dask worker limits to its share)."""
    return max(1, min(_cpus(), cv2.getNumThreads()))


def _eslt(img, gx, gy, window, threshold, max_angle, where):
    """ESLT (:func:`_eslt_rows`) over the whole image, in as many blocks of rows as there are
    threads (:func:`_threads`), the calling thread taking the first: the same maps on any number
    of threads. Returns the features' ``(rows, cols, orientations)`` (int64, int64, float32; the
    points in row-major order, as ``np.nonzero`` of a mask gives them)."""
    rows, cols = img.shape
    tasks = (rows + _CHUNK - 1) // _CHUNK
    n = min(_threads(), tasks)
    # room for a feature at every pixel; each block writes from its first pixel's index on (only
    # the pages written are ever touched)
    pr = np.empty(rows * cols, np.int64)
    pc = np.empty(rows * cols, np.int64)
    pv = np.empty(rows * cols, np.float32)
    args = (
        img,
        gx,
        gy,
        int(window),
        float(threshold),
        float(max_angle),
        where,
        pr,
        pc,
        pv,
    )
    if n <= 1:
        end = _eslt_rows(*args, 0, tasks)
        return pr[:end].copy(), pc[:end].copy(), pv[:end].copy()
    cut = [tasks * k // n for k in range(n + 1)]
    futures = [worker_pool("eslt", n - 1).submit(_eslt_rows, *args, cut[k], cut[k + 1]) for k in range(1, n)]
    ends = [_eslt_rows(*args, cut[0], cut[1])] + [f.result() for f in futures]
    parts = [slice(cut[k] * _CHUNK * cols, ends[k]) for k in range(n)]
    return tuple(np.concatenate([a[p] for p in parts]) for a in (pr, pc, pv))


def _feature_map(mask: np.ndarray, theta: np.ndarray | None) -> FeatureMap:
    """The feature nodes' output: the dense uint8 0/1 ``mask`` (and float32 ``theta``) with their
    points gathered once here (``np.flatnonzero`` of the bool view: a kernel was only 1.3x faster),
    so no consumer scans the map for them again."""
    m = mask.view(bool)
    flat = np.flatnonzero(m)
    r, c = np.divmod(flat, max(mask.shape[1], 1))
    v = None if theta is None else theta.reshape(-1).take(flat)
    return FeatureMap.from_points(mask.shape, r, c, v, mask=m, orientation=theta)


def sobel(gray: np.ndarray, ksize: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Sobel gradients ``(gx, gy)`` of a float32 image (rows growing downwards)."""
    g = gray.astype(np.float32, copy=False)
    return cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=ksize), cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=ksize)


def edge_orientation(gray: np.ndarray, ksize: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Sobel gradient magnitude and *edge* orientation (perpendicular to the gradient) in [0, pi),
    measured from +x towards up, both float32."""
    g = gray.astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=ksize)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=ksize)  # rows grow downwards
    mag = cv2.magnitude(gx, gy)
    # the gradient in (x, up) coordinates is (gx, -gy); the edge runs perpendicular to it, along
    # (gy, gx), whose angle from +x towards up is atan2(gx, gy), taken modulo pi.
    theta = np.mod(np.arctan2(gx, gy), np.pi).astype(np.float32)
    return mag, theta


def _as_gray32(image: np.ndarray, node: str) -> np.ndarray:
    """The BEV image as C-contiguous float32 HxW grey levels (BGR converted, non-finite pixels 0);
    an array that is no image raises an InputError naming ``node`` and the port."""
    img = np.asarray(image)
    if img.ndim == 3 and (img.shape[2] == 1 or (img.shape[2] == 3 and img.size == 0)):
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] == 3 and img.dtype.kind in "biuf":
        if img.dtype not in (np.uint8, np.uint16, np.float32):
            img = img.astype(np.float32)  # the dtypes cv2.cvtColor takes
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2GRAY)
    if img.ndim != 2 or img.dtype.kind not in "biuf":
        raise InputError(
            f"{node}: image: expected an HxW grey (or HxWx3 BGR) BEV image of numbers, "
            f"got shape {np.shape(image)} of dtype {img.dtype}"
        )
    g = np.ascontiguousarray(img, dtype=np.float32)
    if not np.isfinite(g).all():  # no NaN inside the kernels
        g = np.where(np.isfinite(g), g, np.float32(0.0))
    return g


class SltParams(NodeParams):
    """Params of ``features.slt``."""

    window: int = Field(6, ge=1, le=200, description="width w of the left and right windows, BEV pixels")
    threshold: float = Field(10.0, ge=0.0, le=255.0, description="threshold T, grey levels")


#: the optional ``where`` input of the feature nodes: compute only on the BEV road mask
_WHERE_PORT = Port(
    "bev_mask",
    "only these pixels are tested (the road mask: the same features there as masking afterwards, "
    "found faster; their windows may reach beyond it); every pixel when not wired",
    optional=True,
)
_EVERYWHERE = np.zeros((0, 0), np.uint8)


def _where_map(where, shape: tuple[int, ...], node: str) -> np.ndarray:
    """The ``where`` input as the kernels' C-contiguous uint8 0/1 map (``_EVERYWHERE`` when absent)."""
    if where is None:
        return _EVERYWHERE
    if np.shape(where) != tuple(shape):
        raise InputError(
            f"{node}: where: expected a BEV mask of the image's shape {tuple(shape)}, got {np.shape(where)}"
        )
    return np.ascontiguousarray(where, dtype=bool).view(np.uint8)  # no copy for the usual bool mask


@node_type(
    "features.slt",
    inputs={"image": Port("bev_image", "BEV grey image"), "where": _WHERE_PORT},
    outputs={"features": "features"},
)
def slt(params: SltParams, image: np.ndarray, where: np.ndarray | None = None) -> dict:
    """Symmetrical local threshold: brighter than the mean of the left and of the right window by T."""
    img = _as_gray32(image, "features.slt")
    out = np.zeros(img.shape, np.uint8)
    _slt(img, params.window, float(params.threshold), _where_map(where, img.shape, "features.slt"), out)
    return {"features": _feature_map(out, None)}


class EsltParams(SltParams):
    """Params of ``features.eslt``."""

    max_angle_deg: float = Field(
        15.0, gt=0.0, le=90.0, description="largest angle between the two borders, degrees"
    )
    sobel_ksize: int = Field(3, ge=1, le=7, description="Sobel aperture (1, 3, 5 or 7), pixels")

    @field_validator("sobel_ksize")
    @classmethod
    def _odd_aperture(cls, v: int) -> int:
        if v % 2 == 0:
            raise ValueError(f"sobel_ksize: expected an odd Sobel aperture (1, 3, 5 or 7), got {v}")
        return v


@node_type(
    "features.eslt",
    inputs={"image": Port("bev_image", "BEV grey image"), "where": _WHERE_PORT},
    outputs={"features": "features"},
)
def eslt(params: EsltParams, image: np.ndarray, where: np.ndarray | None = None) -> dict:
    """Extended SLT: SLT plus parallel strongest-gradient borders; features get the borders' mean orientation."""
    k = params.sobel_ksize
    raw = np.asarray(image)
    if raw.dtype == np.uint8 and raw.ndim == 2 and k == 3 and min(raw.shape) >= 2:
        # a grey uint8 BEV (the usual case): integer 3x3 Sobel gradients in one pass, exactly the
        # float32 ones (|g| <= 1020), and the kernel reads the uint8 grey levels directly
        img = np.ascontiguousarray(raw)
        gx, gy = cv2.spatialGradient(img, ksize=3)
    else:
        img = _as_gray32(image, "features.eslt")
        if img.size == 0:  # an empty BEV: no features (cv2.Sobel refuses empty images)
            _where_map(where, img.shape, "features.eslt")
            return {
                "features": FeatureMap(
                    mask=np.zeros(img.shape, bool), orientation=np.full(img.shape, -1.0, np.float32)
                )
            }
        gx, gy = sobel(img, k)
    wm = _where_map(where, img.shape, "features.eslt")
    r, c, v = _eslt(
        img,
        gx,
        gy,
        params.window,
        float(params.threshold),
        math.radians(params.max_angle_deg),
        wm,
    )
    # the points and their orientations as the kernel found them (no scan of a mask for them); the
    # map builds its dense mask and orientation (-1 elsewhere) only if a consumer asks for them
    # (none in paper.yaml: every node after it reads the points)
    return {"features": FeatureMap.from_points(img.shape, r, c, v)}


class MaskParams(NodeParams):
    """Params of ``features.mask``."""

    erode_px: int = Field(
        4, ge=0, le=100, description="erode the road mask by this many BEV pixels so its border is no feature"
    )
    obstacle_height_m: float | None = Field(
        None,
        gt=0.0,
        le=5.0,
        description="with the disparity, road, calib and geometry wired: the border is not eroded where most pixels "
        "with a disparity within obstacle_reach_m beyond it stand higher than this above the road plane, metres: an "
        "obstacle's foot (a parked car, a wall), where a line painted along it lies, not a kerb (10-15 cm, at most "
        "20: its lit edge or gutter on the mask's last pixels is what the erosion drops); None: erode everywhere",
    )
    obstacle_reach_m: float = Field(
        0.4,
        gt=0.0,
        le=5.0,
        description="obstacle_height_m: how far beyond the border the heights are read, metres (at least erode_px)",
    )


@node_type(
    "features.mask",
    inputs={
        "features": "features",
        "mask": Port("bev_mask", "BEV road mask"),
        "temporal": Port("bev_mask", "previous-frame mask", optional=True),
        "geometry": Port("bev_geometry", "the BEV's geometry (obstacle_height_m)", optional=True),
        "disparity": Port("disparity", "the disparity map (obstacle_height_m)", optional=True),
        "road": Port("road_model", "the fitted road (obstacle_height_m)", optional=True),
        "calib": Port("calibration", "the calibration (obstacle_height_m)", optional=True, rate="constant"),
    },
    outputs={"features": "features"},
)
def mask_features(
    params: MaskParams,
    features: FeatureMap,
    mask: np.ndarray,
    temporal: np.ndarray | None = None,
    geometry: BevGeometry | None = None,
    disparity: np.ndarray | None = None,
    road: RoadModel | None = None,
    calib: Calibration | None = None,
) -> dict:
    """Features multiplied by the BEV road mask (eroded, except along an obstacle's foot with
    obstacle_height_m) and, when given, the previous-frame mask."""
    shape = features.shape
    for port, m in (("mask", mask), ("temporal", temporal)):
        if m is not None and np.shape(m) != shape:
            raise InputError(
                f"features.mask: {port}: expected a BEV mask of the features' shape {shape}, got {np.shape(m)}"
            )
    keep = np.ascontiguousarray(mask, dtype=bool)  # no copy for the usual bool BEV mask
    if params.erode_px > 0 and keep.size:
        k = 2 * params.erode_px + 1
        full = keep
        # bool and 0/1 uint8 share their bytes: erode the view, read the result back as bool
        keep = cv2.erode(
            keep.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)), borderValue=0
        ).view(bool)
        wired = geometry is not None and disparity is not None and road is not None and calib is not None
        if params.obstacle_height_m is not None and wired:
            reach = int(round(params.obstacle_reach_m / geometry.resolution))
            keep = keep | obstacle_border(
                full, geometry, disparity, road, calib, params.erode_px, params.obstacle_height_m, reach
            )
    # the masks read at the feature points only: a sparse map out, no dense pass over the features
    r, c = features.points()
    flat = r * shape[1] + c
    sel = keep.reshape(-1).take(flat)
    if temporal is not None:
        sel &= np.ascontiguousarray(temporal, dtype=bool).reshape(-1).take(flat)
    out = features.select(sel)
    ori = out.point_orientations()
    if ori is not None and ori.dtype != np.float32:  # the masked map's orientations are float32
        out = FeatureMap.from_points(shape, *out.points(), ori.astype(np.float32))
    return {"features": out}
