"""``road.vdisparity``: the v-disparity of a disparity map, and the pixel selection of a road-profile
pass (:mod:`.profile`, steps 1 and 4 of its method).

A v-disparity is a histogram of the disparities of each image row (``H x D``, bins of ``bin_size``
pixels; invalid ``<= 0`` and ``>= max_disparity`` disparities are left out). A profile pass first
compacts its pixels into a list (row in the pass -- roll-corrected, see :mod:`.geometry` --,
disparity; every ``step``-th column) and counts them in one pass over the image
(:func:`_select_kernel`); ``road.vdisparity`` counts every column.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field, model_validator

from lanegraph import InputError, NodeParams, Port, jit, node_type
from lanegraph.types import Calibration

from . import geometry


@jit
def _select_kernel(disp, step, band_k, b0, b1, b2, cx, cy, s, c, bin_size, max_disp, out_rows, out_d, vd):
    """The pixels of a profile pass, compacted, and their v-disparity, in one pass over the image.

    Selects the pixels with ``d > 0`` and, when ``band_k > 0``, within the band
    ``|d - (b0 + b1 u + b2 v)| <= band_k d`` of the road plane (disparity space; ``band_k`` is the
    band in metres over the camera height, eq. 4), whose roll-corrected row
    ``v' = cy + s (u - cx) + c (v - cy)``, rounded to the nearest row, lies in ``[0, H)``; only every
    ``step``-th column (from column 0) is looked at. Writes each one's row and disparity into
    ``out_rows`` / ``out_d`` in row-major order and counts it in ``vd[row, int(d / bin_size)]``
    (``H x n_bins`` float32, zeroed by the caller; ``n_bins`` may be 0: no counts) when
    ``d < max_disp`` and the bin exists. Returns the number of pixels selected.

    A NaN or an infinity is invalid, as 0 is (one more comparison on the pixels read anyway)."""
    H, W = disp.shape
    n_bins = vd.shape[1]
    n = 0
    for v in range(H):
        for u in range(0, W, step):
            d = disp[v, u]
            if not (d > 0.0 and d < math.inf):  # 0, negative, NaN, +-inf: invalid
                continue
            if band_k > 0.0 and abs(d - (b0 + b1 * u + b2 * v)) > band_k * d:
                continue
            r = int(math.floor(cy + s * (u - cx) + c * (v - cy) + 0.5))
            if r < 0 or r >= H:
                continue
            out_rows[n] = r
            out_d[n] = d
            n += 1
            if d < max_disp:
                k = int(d / bin_size)
                if k < n_bins:
                    vd[r, k] += 1.0  # exact: float32 counts up to 2**24
    return n


# --------------------------------------------------------------------------- helpers


class RoadInputError(InputError, ValueError):
    """An input of a road node is not what its port promises: lanegraph's own :class:`InputError`
    (so the executor reports it like any bad input) that stays a ``ValueError`` for Python callers."""


def checked_disparity(disparity: np.ndarray, node: str) -> np.ndarray:
    """Validate a disparity map's shape and dtype; C-contiguous float32 (no copy when it is already).
    NaNs and infinities stay: every road kernel treats them as invalid pixels, as it does 0 (no
    pass over the map to look for them)."""
    disparity = np.asarray(disparity)
    if (
        disparity.ndim != 2
        or disparity.shape[0] < 1
        or disparity.shape[1] < 1
        or disparity.dtype.kind not in "biuf"
    ):
        raise RoadInputError(
            f"{node}: disparity: expected a non-empty HxW array of numbers, "
            f"got shape {disparity.shape} of dtype {disparity.dtype}"
        )
    return np.ascontiguousarray(disparity, dtype=np.float32)


#: the most v-disparity bins (max_disparity / bin_size) the params may ask for
MAX_BINS = 1024


def n_bins(max_disparity: float, bin_size: float) -> int:
    return max(1, int(math.ceil(max_disparity / bin_size)))


def _select(disp, cx, cy, s, c, bins, bin_size, max_disparity, band, step):
    """:func:`_select_kernel` into new arrays: ``(rows, disparities, vdisparity)``. Rows are int16
    (half the memory traffic of int32) unless the image has too many rows for it."""
    H, W = disp.shape
    cap = H * -(-W // step)
    rows = np.empty(cap, np.int16 if H < 32767 else np.int32)
    d = np.empty(cap, np.float32)
    vd = np.zeros((H, bins), np.float32)
    k, b0, b1, b2 = band if band is not None else (0.0, 0.0, 0.0, 0.0)
    n = _select_kernel(
        disp,
        int(step),
        float(k),
        float(b0),
        float(b1),
        float(b2),
        float(cx),
        float(cy),
        float(s),
        float(c),
        float(bin_size),
        float(max_disparity),
        rows,
        d,
        vd,
    )
    return rows[:n], d[:n], vd


def select_and_count(
    disp: np.ndarray,
    cx: float,
    cy: float,
    s: float,
    c: float,
    max_disparity: float,
    bin_size: float,
    band: tuple[float, float, float, float] | None = None,
    step: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels of a pass and their v-disparity in one pass over a validated map
    (:func:`_select_kernel`): ``(rows, disparities, H x D vdisparity)`` of the selected pixels of every
    ``step``-th column, in roll-corrected rows ``v' = cy + s (u - cx) + c (v - cy)`` (pixels);
    ``band = (band_k, b0, b1, b2)`` or None for every valid pixel."""
    return _select(disp, cx, cy, s, c, n_bins(max_disparity, bin_size), bin_size, max_disparity, band, step)


def select_pixels(
    disp: np.ndarray,
    cx: float,
    cy: float,
    s: float,
    c: float,
    band: tuple[float, float, float, float] | None = None,
    step: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`select_and_count` without the counts: ``(rows, disparities)``."""
    return _select(disp, cx, cy, s, c, 0, 1.0, 0.0, band, step)[:2]


def compute_vdisparity(
    disp: np.ndarray,
    max_disparity: float,
    bin_size: float,
    roll: float = 0.0,
    calib: Calibration | None = None,
) -> np.ndarray:
    """``H x D`` v-disparity of a validated disparity map, optionally in roll-corrected rows."""
    if roll != 0.0 and calib is None:
        raise ValueError("a roll needs the calibration (principal point)")
    s, c = geometry.roll_row_coeffs(roll, calib) if calib is not None else (0.0, 1.0)
    cx, cy = (calib.cx, calib.cy) if calib is not None else (0.0, 0.0)
    return select_and_count(disp, cx, cy, s, c, max_disparity, bin_size)[2]


# --------------------------------------------------------------------------- road.vdisparity


def bins_bounded(params):
    """``params`` (with ``max_disparity`` and ``bin_size``) when its v-disparity has at most
    :data:`MAX_BINS` bins (memory and time grow with them: 8x the default's 128); else ValueError."""
    if params.max_disparity / params.bin_size > MAX_BINS:
        raise ValueError(
            f"max_disparity / bin_size = {params.max_disparity / params.bin_size:.0f} disparity bins, "
            f"more than {MAX_BINS}; raise bin_size or lower max_disparity"
        )
    return params


class VDisparityParams(NodeParams):
    """Params of ``road.vdisparity``."""

    max_disparity: float = Field(
        128.0, gt=0.0, le=1024.0, description="disparities >= this are left out, pixels; D = ceil(max / bin)"
    )
    bin_size: float = Field(
        1.0, ge=0.25, le=16.0, description="width of a disparity bin, pixels (>= 0.25; at most 1024 bins)"
    )

    @model_validator(mode="after")
    def _bins_bounded(self):
        return bins_bounded(self)


@node_type(
    "road.vdisparity",
    inputs={"disparity": Port("disparity", "left disparity map")},
    outputs={"vdisparity": Port("vdisparity", "H x D count of disparities per row")},
)
def road_vdisparity(params: VDisparityParams, disparity: np.ndarray) -> dict:
    """The v-disparity image: per image row, a histogram of its valid disparities (H x D float32)."""
    disp = checked_disparity(disparity, "road.vdisparity")  # NaN, +-inf: invalid to the kernel
    return {"vdisparity": compute_vdisparity(disp, params.max_disparity, params.bin_size)}
