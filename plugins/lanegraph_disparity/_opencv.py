"""OpenCV block-matching backends: ``disparity.sgbm`` (StereoSGBM) and ``disparity.bm`` (StereoBM).

OpenCV returns int16 fixed-point disparities (1/16 pixel); they are converted to float32
pixels with invalid pixels set to 0. The optional WLS filter comes from opencv-contrib
(``cv2.ximgproc``) and is looked up only when ``wls`` is on.
"""

from __future__ import annotations

from typing import Any, Literal

import cv2
import numpy as np
from pydantic import Field, field_validator, model_validator

from lanegraph import InputError, node_type

from ._common import DisparityParams, odd_pixels, right_by_flipping, run_backend, scaled_disparities

_SGBM_MODES = {
    "sgbm": cv2.StereoSGBM_MODE_SGBM,
    "3way": cv2.StereoSGBM_MODE_SGBM_3WAY,
    "hh": cv2.StereoSGBM_MODE_HH,
    "hh4": cv2.StereoSGBM_MODE_HH4,
}


class OpenCVDisparityParams(DisparityParams):
    """Params shared by the OpenCV matchers (``disparity.sgbm``, ``disparity.bm``)."""

    num_disparities: int = Field(
        128,
        ge=16,
        le=512,
        description="disparity search range, pixels of the input resolution (multiple of 16); at scale < 1 "
        "the range searched is num_disparities*scale rounded up to a multiple of 16",
    )
    min_disparity: int = Field(
        0, ge=0, le=256, description="smallest disparity searched, pixels of the input resolution"
    )
    block_size: int = Field(5, ge=1, le=255, description="matching block size, pixels (odd)")
    uniqueness_ratio: int = Field(
        10, ge=0, le=100, description="margin in percent by which the best cost must beat the second best"
    )
    speckle_window_size: int = Field(
        100,
        ge=0,
        le=10000,
        description="largest speckle (connected region) removed as noise, pixels; 0 = off",
    )
    speckle_range: int = Field(
        2, ge=0, le=256, description="largest disparity variation inside one connected region, pixels"
    )
    disp12_max_diff: int = Field(
        1,
        ge=-1,
        le=256,
        description="OpenCV's internal left-right check: largest difference, pixels; -1 = off "
        "(see also lr_check)",
    )
    wls: bool = Field(
        False,
        description="smooth and densify with the weighted-least-squares filter of opencv-contrib "
        "(cv2.ximgproc.DisparityWLSFilter, guided by the left image, with left-right confidence)",
    )
    wls_lambda: float = Field(
        8000.0, ge=0.0, le=1e6, description="WLS smoothness weight (unitless; larger = smoother)"
    )
    wls_sigma: float = Field(
        1.5, ge=0.1, le=10.0, description="WLS edge sensitivity to left-image colour, intensity levels / 10"
    )

    @field_validator("num_disparities")
    @classmethod
    def _multiple_of_16(cls, v: int) -> int:
        if v % 16:
            lo, hi = max(16, v // 16 * 16), (v // 16 + 1) * 16
            raise ValueError(f"num_disparities: expected a multiple of 16, got {v} (hint: use {lo} or {hi})")
        return v

    @field_validator("block_size")
    @classmethod
    def _odd_block(cls, v: int) -> int:
        return odd_pixels("block_size", v)


class SgbmParams(OpenCVDisparityParams):
    """Params of ``disparity.sgbm`` (OpenCV semi-global block matching)."""

    block_size: int = Field(5, ge=1, le=31, description="matching block size, pixels (odd)")
    mode: Literal["sgbm", "3way", "hh", "hh4"] = Field(
        "sgbm",
        description="'sgbm': 5 paths, single pass (its paths all come from above, so on a road "
        "sloping away it reads 0.5-1 px low); '3way': faster 3-way variant; 'hh4': 4 symmetric "
        "paths, two passes (unbiased on the road); 'hh': full 8-path Hirschmueller (slow, memory hungry)",
    )
    p1: int = Field(
        0,
        ge=0,
        le=100000,
        description="penalty for a disparity change of 1 pixel between neighbours, cost units; "
        "0 = auto, 8*block_size**2",
    )
    p2: int = Field(
        0,
        ge=0,
        le=400000,
        description="penalty for a disparity change of more than 1 pixel, cost units (> p1); "
        "0 = auto, 32*block_size**2",
    )
    prefilter_cap: int = Field(
        63, ge=1, le=63, description="clip of the x-derivative prefilter, intensity levels"
    )

    @model_validator(mode="after")
    def _p2_above_p1(self) -> SgbmParams:
        p1, p2 = self.penalties()
        if p2 <= p1:
            raise ValueError(
                f"p2 ({p2}) must be greater than p1 ({p1}) (0 means auto: p1=8*bs^2, p2=32*bs^2)"
            )
        return self

    def penalties(self) -> tuple[int, int]:
        """(P1, P2) with 0 replaced by the usual defaults for one gray channel."""
        bs2 = self.block_size * self.block_size
        return (self.p1 or 8 * bs2, self.p2 or 32 * bs2)


class BmParams(OpenCVDisparityParams):
    """Params of ``disparity.bm`` (OpenCV local block matching)."""

    block_size: int = Field(11, ge=5, le=255, description="matching block size, pixels (odd)")
    uniqueness_ratio: int = Field(
        10, ge=0, le=100, description="margin in percent by which the best cost must beat the second best"
    )
    speckle_range: int = Field(
        32, ge=0, le=256, description="largest disparity variation inside one connected region, pixels"
    )
    prefilter: Literal["xsobel", "normalized"] = Field(
        "normalized",
        description="prefilter: 'normalized' (local mean-normalised response; denser on the road) or "
        "'xsobel' (x-derivative)",
    )
    prefilter_size: int = Field(
        9, ge=5, le=255, description="window of the 'normalized' prefilter, pixels (odd)"
    )
    prefilter_cap: int = Field(31, ge=1, le=63, description="clip of the prefiltered image, intensity levels")
    texture_threshold: int = Field(
        10,
        ge=0,
        le=100000,
        description="minimum texture (sum of |prefiltered|) in the block; weaker = invalid",
    )

    @field_validator("prefilter_size")
    @classmethod
    def _odd_prefilter(cls, v: int) -> int:
        return odd_pixels("prefilter_size", v)


def _ximgproc() -> Any:
    xip = getattr(cv2, "ximgproc", None)
    if xip is None or not hasattr(xip, "createDisparityWLSFilter"):
        raise RuntimeError(
            "wls: true needs cv2.ximgproc (the WLS filter of opencv-contrib), which this OpenCV lacks "
            f"(cv2 {cv2.__version__}); install opencv-contrib-python-headless, never opencv-python, "
            "or set wls: false"
        )
    return xip


def _check_range(width: int, min_disp: int, num_disp: int, block: int, scale: float) -> None:
    if width - (min_disp + num_disp) <= block // 2:
        raise InputError(
            f"image too narrow for the disparity range: width {width} px at scale {scale:g} must exceed "
            f"min_disparity + num_disparities ({min_disp} + {num_disp}) + block_size/2 ({block // 2}) "
            "(hint: lower num_disparities or raise scale)"
        )


def _from_fixed(raw: np.ndarray, min_disp: int = 0) -> np.ndarray:
    """OpenCV int16 1/16-pixel disparity -> float32 pixels; invalid = 0: OpenCV's invalid value
    ``(min_disp - 1) * 16`` and everything below ``min_disp`` (and ``<= 0``)."""
    d = raw.astype(np.float32) * np.float32(1.0 / 16.0)
    d[(raw <= 0) | (raw < 16 * min_disp)] = 0.0
    return d


def _compute_opencv(
    matcher: Any, params: OpenCVDisparityParams, gl: np.ndarray, gr: np.ndarray, need_right: bool
):
    raw = matcher.compute(gl, gr)
    if params.wls:
        xip = _ximgproc()
        right_matcher = xip.createRightMatcher(matcher)
        wls = xip.createDisparityWLSFilter(matcher)
        wls.setLambda(params.wls_lambda)
        wls.setSigmaColor(params.wls_sigma)
        raw = wls.filter(raw, gl, disparity_map_right=right_matcher.compute(gr, gl))
    mind = matcher.getMinDisparity()
    dl = _from_fixed(raw, mind)
    dr = None
    if need_right:
        dr = right_by_flipping(lambda a, b: _from_fixed(matcher.compute(a, b), mind), gl, gr)
        # the mirrored matcher leaves its left strip (our right border) invalid for lack of
        # range, not for a mismatch: mark it "unknown" so lr_check keeps those left pixels
        w = gl.shape[1]
        strip = min(w, matcher.getMinDisparity() + matcher.getNumDisparities() + matcher.getBlockSize() // 2)
        border = dr[:, w - strip :]
        border[border <= 0] = -1.0
    return dl, dr


def _sgbm_matcher(params: SgbmParams, num_disp: int, min_disp: int) -> Any:
    p1, p2 = params.penalties()
    return cv2.StereoSGBM_create(
        minDisparity=min_disp,
        numDisparities=num_disp,
        blockSize=params.block_size,
        P1=p1,
        P2=p2,
        disp12MaxDiff=params.disp12_max_diff,
        preFilterCap=params.prefilter_cap,
        uniquenessRatio=params.uniqueness_ratio,
        speckleWindowSize=params.speckle_window_size,
        speckleRange=params.speckle_range,
        mode=_SGBM_MODES[params.mode],
    )


def _bm_matcher(params: BmParams, num_disp: int, min_disp: int) -> Any:
    m = cv2.StereoBM_create(numDisparities=num_disp, blockSize=params.block_size)
    m.setMinDisparity(min_disp)
    m.setPreFilterType(
        cv2.STEREO_BM_PREFILTER_XSOBEL
        if params.prefilter == "xsobel"
        else cv2.STEREO_BM_PREFILTER_NORMALIZED_RESPONSE
    )
    m.setPreFilterSize(params.prefilter_size)
    m.setPreFilterCap(params.prefilter_cap)
    m.setTextureThreshold(params.texture_threshold)
    m.setUniquenessRatio(params.uniqueness_ratio)
    m.setSpeckleWindowSize(params.speckle_window_size)
    m.setSpeckleRange(params.speckle_range)
    m.setDisp12MaxDiff(params.disp12_max_diff)
    return m


@node_type(
    "disparity.sgbm",
    inputs={"left": "image", "right": "image"},
    outputs={"disparity": "disparity"},
    ahead=True,
)
def sgbm(params: SgbmParams, left: np.ndarray, right: np.ndarray) -> dict:
    """Disparity by OpenCV semi-global block matching (StereoSGBM).

    Parameters
    ----------
    params : SgbmParams
        Matcher and common params.
    left, right : ndarray
        Rectified pair, HxW gray or HxWx3 BGR uint8, same size.

    Returns
    -------
    dict
        ``disparity``: HxW float32 disparity of the left image in pixels (input
        resolution, 1/16-pixel steps before any upsampling); invalid pixels are 0.
    """
    if params.wls:
        _ximgproc()

    def compute(gl: np.ndarray, gr: np.ndarray, scale: float, need_right: bool):
        num = scaled_disparities(params.num_disparities, scale, 16)
        mind = int(round(params.min_disparity * scale))
        _check_range(gl.shape[1], mind, num, params.block_size, scale)
        return _compute_opencv(_sgbm_matcher(params, num, mind), params, gl, gr, need_right)

    return {"disparity": run_backend(left, right, params, compute)}


@node_type(
    "disparity.bm",
    inputs={"left": "image", "right": "image"},
    outputs={"disparity": "disparity"},
    ahead=True,
)
def bm(params: BmParams, left: np.ndarray, right: np.ndarray) -> dict:
    """Disparity by OpenCV local block matching (StereoBM): fast, sparse on weak texture.

    Parameters
    ----------
    params : BmParams
        Matcher, prefilter and common params.
    left, right : ndarray
        Rectified pair, HxW gray or HxWx3 BGR uint8, same size.

    Returns
    -------
    dict
        ``disparity``: HxW float32 disparity of the left image in pixels (input
        resolution); invalid pixels are 0.
    """
    if params.wls:
        _ximgproc()

    def compute(gl: np.ndarray, gr: np.ndarray, scale: float, need_right: bool):
        num = scaled_disparities(params.num_disparities, scale, 16)
        mind = int(round(params.min_disparity * scale))
        _check_range(gl.shape[1], mind, num, params.block_size, scale)
        if min(gl.shape) <= params.block_size:  # StereoBM needs block_size < width and height
            raise InputError(
                f"image of {gl.shape[0]}x{gl.shape[1]} px at scale {scale:g} is not larger than block_size "
                f"{params.block_size}"
            )
        return _compute_opencv(_bm_matcher(params, num, mind), params, gl, gr, need_right)

    return {"disparity": run_backend(left, right, params, compute)}
