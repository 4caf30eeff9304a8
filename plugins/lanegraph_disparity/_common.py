"""What every computing disparity backend shares.

A backend turns a rectified gray pair into a left disparity map (and, when asked, a
right one). :func:`run_backend` wraps it with the common steps: input checks and gray
conversion, optional computation at reduced resolution (``scale``), the left-right
consistency check (``lr_check``) and upsampling back to the input resolution.

Conventions: disparities are float32 pixels of the *input* resolution; invalid pixels
are exactly ``0`` (never NaN, never negative).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

import cv2
import numpy as np
from pydantic import Field

from lanegraph import InputError, NodeParams

#: ``compute(left_gray, right_gray, scale, need_right) -> (left_disp, right_disp or None)``;
#: both float32 HxW at the computing resolution, in computing-resolution pixels, invalid = 0
#: (the right one may hold -1 where it could not be evaluated, see :func:`lr_consistency`).
Backend = Callable[[np.ndarray, np.ndarray, float, bool], tuple[np.ndarray, "np.ndarray | None"]]


class DisparityParams(NodeParams):
    """Params shared by every computing backend (``disparity.sgbm``, ``.bm``, ``.sgm``)."""

    scale: float = Field(
        1.0,
        ge=0.25,
        le=1.0,
        description="compute at this fraction of the input resolution (unitless, 0.25..1), then upsample the "
        "disparity to the input size and multiply its values by 1/scale",
    )
    upsample: Literal["nearest", "linear"] = Field(
        "nearest",
        description="how a reduced-resolution disparity is brought back to the input size: 'nearest', or "
        "'linear' (bilinear where all four neighbours are valid, nearest elsewhere)",
    )
    lr_check: bool = Field(
        False,
        description="left-right consistency check: invalidate a left pixel x when "
        "|dL(x) - dR(x - dL(x))| > lr_max_diff (costs a right disparity map)",
    )
    lr_max_diff: float = Field(
        1.0,
        ge=0.0,
        le=16.0,
        description="largest accepted left-right disparity difference, pixels of the input resolution",
    )
    top_fraction: float = Field(
        0.0,
        ge=0.0,
        le=0.9,
        description="compute only from this fraction of the image height downwards (unitless); the rows "
        "above (sky, far above the horizon) are left invalid",
    )
    strips: int = Field(
        1,
        ge=1,
        le=8,
        description="split the rows into this many horizontal strips computed in parallel threads",
    )
    strip_overlap: int = Field(
        24,
        ge=0,
        le=256,
        description="rows each strip extends into its neighbours, pixels of the computing resolution",
    )


def odd_pixels(name: str, v: int) -> int:
    """``v`` when it is odd (a window of pixels centred on one); else ValueError naming the field
    ``name`` and the odd numbers beside it. For the params' field validators."""
    if v % 2 == 0:
        raise ValueError(f"{name}: expected an odd number of pixels, got {v} (hint: use {v - 1} or {v + 1})")
    return v


def to_gray(image: np.ndarray, port: str) -> np.ndarray:
    """A gray uint8 HxW view of ``image``.

    Parameters
    ----------
    image : ndarray
        HxW gray or HxWx3 BGR (HxWx4 BGRA and HxWx1 are accepted too); uint8, or a
        float array in 0..255 (clipped and rounded).
    port : str
        Input port name, for the error message.

    Returns
    -------
    ndarray
        HxW uint8, C-contiguous.
    """
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] in (3, 4):
        if img.dtype != np.uint8:
            if img.dtype.kind not in "biuf":
                raise InputError(
                    f"input '{port}': expected a uint8 (or 0-255 float) image, got dtype {img.dtype}"
                )
            img = np.clip(np.rint(np.nan_to_num(img.astype(np.float64))), 0, 255).astype(np.uint8)
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = cv2.cvtColor(np.ascontiguousarray(img), code)
    if img.ndim != 2:
        raise InputError(f"input '{port}': expected an HxW gray or HxWx3 BGR image, got shape {image.shape}")
    if img.dtype != np.uint8:
        if not (np.issubdtype(img.dtype, np.floating) or np.issubdtype(img.dtype, np.integer)):
            raise InputError(
                f"input '{port}': expected a uint8 (or 0-255 float) image, got dtype {img.dtype}"
            )
        img = np.clip(np.rint(np.nan_to_num(img.astype(np.float64))), 0, 255).astype(np.uint8)
    if img.shape[0] < 2 or img.shape[1] < 2:
        raise InputError(f"input '{port}': image of {img.shape[0]}x{img.shape[1]} pixels is too small")
    return np.ascontiguousarray(img)


def gray_pair(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both images as gray uint8, checked to have the same size (a rectified pair)."""
    gl, gr = to_gray(left, "left"), to_gray(right, "right")
    if gl.shape != gr.shape:
        raise InputError(
            f"left and right images differ in size: left {gl.shape[0]}x{gl.shape[1]}, "
            f"right {gr.shape[0]}x{gr.shape[1]} (expected a rectified pair of the same size)"
        )
    return gl, gr


def scaled_disparities(num_disparities: int, scale: float, multiple: int = 1) -> int:
    """The disparity range at the computing resolution.

    ``num_disparities`` (input pixels) times ``scale``, rounded up to a multiple of
    ``multiple`` (16 for OpenCV), at least ``multiple``.
    """
    n = math.ceil(num_disparities * scale / multiple - 1e-9) * multiple
    return max(n, multiple)


def lr_consistency(dl: np.ndarray, dr: np.ndarray, max_diff: float) -> np.ndarray:
    """Left-right consistency check.

    Parameters
    ----------
    dl, dr : ndarray
        HxW float32 disparities (pixels) of the left and the right view; ``dr`` is indexed
        by right-image column: left pixel ``x`` matches right pixel ``x - dl[x]``.
        Invalid pixels are ``0``; ``dr < 0`` marks right pixels the matcher could not
        evaluate at all (the strip at the right border where a left-view matcher, run on
        the mirrored pair, lacks disparity range): left pixels landing there are kept.
    max_diff : float
        Largest accepted ``|dl(x) - dr(x - dl(x))|``, pixels.

    Returns
    -------
    ndarray
        HxW float32, ``dl`` with inconsistent, occluded (``dr == 0``) or out-of-image
        pixels set to 0.
    """
    w = dl.shape[1]
    xr = np.arange(w)[None, :] - np.rint(dl).astype(np.int64)
    inside = (dl > 0) & (xr >= 0)
    dr_at = np.take_along_axis(dr, np.clip(xr, 0, w - 1), axis=1)
    ok = inside & ((dr_at < 0) | ((dr_at > 0) & (np.abs(dl - dr_at) <= max_diff)))
    return np.where(ok, dl, 0).astype(np.float32)


def right_by_flipping(
    compute_left: Callable[[np.ndarray, np.ndarray], np.ndarray], gl: np.ndarray, gr: np.ndarray
) -> np.ndarray:
    """The right view's disparity from a left-view matcher, by mirroring the pair.

    Mirrored, the right image becomes the left one of a pair with the same (positive)
    disparities: ``dR = flip(compute_left(flip(gr), flip(gl)))``.
    """
    return np.ascontiguousarray(
        compute_left(np.ascontiguousarray(gr[:, ::-1]), np.ascontiguousarray(gl[:, ::-1]))[:, ::-1]
    )


def reduce_pair(gl: np.ndarray, gr: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The gray pair resized to ``round(W * scale) x round(H * scale)`` for matching (OpenCV's area
    average), and the horizontal factor actually applied (the disparities are horizontal); at
    ``scale`` 1 the pair as it is.

    (Tried: whole ``k x k`` blocks where ``1 / scale`` is a whole number, OpenCV's integer-factor
    path, 0.03 ms an image against 1.26 ms for KITTI's 375 rows into 188. Its map differs, and
    half_res.yaml then lost frames on two developer sequences: seq2 100 -> 94.7 %, seq2_ramp
    37.5 -> 25 %.)
    """
    if scale >= 1.0:
        return gl, gr, 1.0
    h, w = gl.shape
    size = (max(2, int(round(w * scale))), max(2, int(round(h * scale))))
    small = [cv2.resize(g, size, interpolation=cv2.INTER_AREA) for g in (gl, gr)]
    return small[0], small[1], size[0] / w


def upsample_disparity(d: np.ndarray, shape: tuple[int, int], scale: float, mode: str) -> np.ndarray:
    """Bring a disparity computed at ``scale`` back to ``shape`` (rows, cols) and input-pixel units.

    Values are multiplied by ``1 / scale``; invalid pixels (``<= 0``) are exactly 0. ``mode``
    ``"linear"`` interpolates bilinearly where all four neighbours are valid and falls
    back to nearest elsewhere, so invalid zeros never bleed into valid values.
    """
    h, w = shape
    if d.shape == (h, w) and scale == 1.0:
        return d.astype(np.float32, copy=False)
    k = np.float32(1.0 / scale)
    if mode == "linear":
        near = cv2.resize(d, (w, h), interpolation=cv2.INTER_NEAREST)
        lin = cv2.resize(d, (w, h), interpolation=cv2.INTER_LINEAR)
        valid = cv2.resize((d > 0).astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
        out = np.where(valid >= 1.0 - 1e-6, lin, near) * k
        out[out <= 0] = 0.0
    else:
        # a nearest neighbour copies values: scaled and cleared on the small map, the same floats
        small = d.astype(np.float32) * k
        small[small <= 0] = 0.0
        out = cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)
    return out.astype(np.float32, copy=False)


def _compute_strips(
    compute: Backend, gl: np.ndarray, gr: np.ndarray, s: float, need_right: bool, strips: int, overlap: int
) -> tuple[np.ndarray, np.ndarray | None]:
    """``compute`` on ``strips`` horizontal strips (each extended by ``overlap`` rows) in threads
    (OpenCV and the numba kernels release the GIL), stitched back together."""
    h = gl.shape[0]
    strips = max(1, min(strips, h // max(1, 2 * overlap + 8)))
    if strips == 1:
        return compute(gl, gr, s, need_right)
    from concurrent.futures import ThreadPoolExecutor

    bounds = np.linspace(0, h, strips + 1).round().astype(int)
    jobs = [(max(0, a - overlap), min(h, b + overlap), a, b) for a, b in zip(bounds[:-1], bounds[1:])]
    with ThreadPoolExecutor(max_workers=strips) as pool:
        results = list(
            pool.map(
                lambda j: compute(
                    np.ascontiguousarray(gl[j[0] : j[1]]),
                    np.ascontiguousarray(gr[j[0] : j[1]]),
                    s,
                    need_right,
                ),
                jobs,
            )
        )
    dl = np.zeros(gl.shape, np.float32)
    dr = np.zeros(gl.shape, np.float32) if need_right else None
    for (lo, _hi, a, b), (sl, sr) in zip(jobs, results):
        dl[a:b] = sl[a - lo : b - lo]
        if dr is not None and sr is not None:
            dr[a:b] = sr[a - lo : b - lo]
    return dl, dr


def run_backend(left: np.ndarray, right: np.ndarray, params: DisparityParams, compute: Backend) -> np.ndarray:
    """Run ``compute`` with the common steps (gray, scale, lr check, upsample).

    Parameters
    ----------
    left, right : ndarray
        The rectified pair, HxW gray or HxWx3 BGR uint8.
    params : DisparityParams
        The node's params.
    compute : callable
        ``compute(left_gray, right_gray, scale, need_right) -> (dl, dr)``, see :data:`Backend`.

    Returns
    -------
    ndarray
        HxW float32 disparity of the left view in input pixels; invalid pixels are 0.
    """
    gl, gr = gray_pair(left, right)
    h, w = gl.shape
    gl, gr, s = reduce_pair(gl, gr, float(params.scale))
    # at least one row is computed: an empty strip would reach the kernels as a 0-row volume
    top = min(int(round(params.top_fraction * gl.shape[0])), gl.shape[0] - 1)
    dl, dr = _compute_strips(
        compute, gl[top:], gr[top:], s, params.lr_check, params.strips, params.strip_overlap
    )
    if top:
        pad = np.zeros((top, gl.shape[1]), np.float32)
        dl = np.vstack([pad, dl])
        dr = None if dr is None else np.vstack([pad, dr])
    if params.lr_check:
        if dr is None:  # pragma: no cover - a backend bug, not a user error
            raise RuntimeError("backend returned no right disparity although lr_check is on")
        dl = lr_consistency(dl, dr, params.lr_max_diff * s)
    dl = np.where(np.isfinite(dl) & (dl > 0), dl, 0).astype(np.float32)
    return upsample_disparity(dl, (h, w), s, params.upsample)
