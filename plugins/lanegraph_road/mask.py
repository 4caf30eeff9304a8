"""``road.mask``: the drivable road area in the left image, from the disparity and the road model.

A pixel ``(u, v)`` with disparity ``d`` is road when its metric height above the fitted road plane
(:mod:`.geometry`, eq. 4)

    height = h * (d - d_road(u, v)) / d,     d_road from the profile at the roll-corrected row,

is within ``height_tolerance_m`` (equivalently ``|d - d_road| <= height_tolerance_m * d / h``).
Thresholding a metric height rather than a raw disparity difference keeps the test equally strict
near and far: a 10-15 cm kerb, a car, a pole or a tree trunk is rejected at every distance where
the stereo can resolve it. Far away, disparity noise (a fraction of a pixel) becomes a large height,
so the tolerance never drops below ``min_disparity_tolerance_px``. Pixels whose road disparity is
below ``f B / max_distance_m`` (far away, the horizon and the sky) are never road.

Then, optionally:

* column-wise free space (as in stixel-style free-space estimation): each column is scanned from
  the bottom row up and its road pixels are kept only up to the first run of
  ``min_obstacle_run_px`` pixels above the road (below-road pixels, a road falling away or
  disparity noise far off, are not road but do not end a column). A kerb is a thin ridge whose
  step fades into the disparity noise far away, so the area behind it (a pavement, a track bed at
  road level) may touch the road in the far field; the free space stops every column at the
  kerb where it is still resolved, and cars, poles and walls end their columns the same way;
* an opening removes specks and thin bridges, only the connected components touching the bottom
  centre of the image (where the ego vehicle stands) are kept, a closing fills small gaps, and
  enclosed holes with hardly any above-road pixels (shadows or paint without a disparity, a road
  dipping below the plane) are filled; holes around obstacles (mostly above-road pixels) stay.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np
from pydantic import Field

from lanegraph import NodeParams, Port, node_type
from lanegraph._numba import jit, prange
from lanegraph.types import Calibration, RoadModel

from . import geometry
from .profile import as_disparity

ROAD, ABOVE, BELOW, UNKNOWN = 1, 2, 3, 4  # labels of _height_class_kernel (0: beyond max_distance_m)


@jit
def _height_class_kernel(disp, a0, a1, a2, cx, cy, s, c, height, height_tol, min_disp_tol, min_road_disp):
    """Label each pixel by its height above the road (eq. 4): 1 road (``|d - d_road| <= tol`` with
    ``tol = max(height_tol * d / height, min_disp_tol)``), 2 above, 3 below, 4 no disparity (``d <= 0``)
    where the road would be visible; 0 where the road disparity at the pixel (roll-corrected row
    ``cy + s (u-cx) + c (v-cy)``) is < ``min_road_disp`` (beyond ``max_distance_m`` or the horizon).
    Rows in parallel."""
    H, W = disp.shape
    out = np.zeros((H, W), np.uint8)
    for v in prange(H):
        if a2 == 0.0:
            # a linear profile along a straight (roll-corrected) row: its ends bound the row
            r_a = cy + s * (0 - cx) + c * (v - cy)
            r_b = cy + s * (W - 1 - cx) + c * (v - cy)
            if a0 + a1 * r_a < min_road_disp and a0 + a1 * r_b < min_road_disp:
                continue
        for u in range(W):
            d = disp[v, u]
            r = cy + s * (u - cx) + c * (v - cy)
            dr = a0 + a1 * r + a2 * r * r
            if dr < min_road_disp:
                continue
            if d <= 0.0:
                out[v, u] = 4
                continue
            tol = height_tol * d / height
            if tol < min_disp_tol:
                tol = min_disp_tol
            if d - dr > tol:
                out[v, u] = 2
            elif dr - d > tol:
                out[v, u] = 3
            else:
                out[v, u] = 1
    return out


@jit
def _free_space_kernel(labels, min_run, unknown_is_road):
    """Column-wise free space: scanning each column from the bottom row up, road pixels (label 1,
    and label 4 -- no disparity -- when ``unknown_is_road`` and a road pixel was seen below it in the
    column) are kept until the first run of ``min_run`` pixels above the road (label 2; pixels below
    the road, label 3, or beyond range, label 0, neither count nor break a run); everything above it
    is dropped."""
    H, W = labels.shape
    out = np.zeros((H, W), np.bool_)
    for u in range(W):
        run = 0
        seen = False
        for v in range(H - 1, -1, -1):
            lab = labels[v, u]
            if lab == 1 or (lab == 4 and unknown_is_road and seen):
                run = 0
                seen = True
                out[v, u] = True
            elif lab == 2:
                run += 1
                if run >= min_run:
                    # the run's first pixels were not road anyway; nothing above is reachable
                    break
    return out


@jit(parallel=True)
def _fill_holes_kernel(mask, holes, n, classes, max_above):
    """``mask`` with the components ``1..n-1`` of the label image ``holes`` filled when they touch
    no image border and at most ``max_above`` of their pixels have the class ``ABOVE`` (2).
    Label 0 (the mask itself) is skipped; the per-label counts are taken in row-interleaved blocks
    in parallel (integer sums), and only labelled pixels are visited again to fill."""
    H, W = holes.shape
    n_blocks = 4
    psize = np.zeros((n_blocks, n), np.int64)
    pabove = np.zeros((n_blocks, n), np.int64)
    for blk in prange(n_blocks):
        for v in range(blk, H, n_blocks):
            for u in range(W):
                lab = holes[v, u]
                if lab == 0:
                    continue
                psize[blk, lab] += 1
                pabove[blk, lab] += classes[v, u] == 2
    fill = np.zeros(n, np.bool_)
    for lab in range(1, n):
        size = 0
        n_above = 0
        for blk in range(n_blocks):
            size += psize[blk, lab]
            n_above += pabove[blk, lab]
        fill[lab] = n_above <= max_above * size
    for u in range(W):
        fill[holes[0, u]] = False
        fill[holes[H - 1, u]] = False
    for v in range(H):
        fill[holes[v, 0]] = False
        fill[holes[v, W - 1]] = False
    out = mask.copy()
    if not fill.any():
        return out
    for v in prange(H):
        for u in range(W):
            lab = holes[v, u]
            if lab != 0 and fill[lab]:
                out[v, u] = True
    return out


@jit(parallel=True)
def _lookup_kernel(lut, labels):
    """``lut[labels]`` (a bool per label). Rows in parallel."""
    H, W = labels.shape
    out = np.empty((H, W), np.bool_)
    for v in prange(H):
        for u in range(W):
            out[v, u] = lut[labels[v, u]]
    return out


class MaskParams(NodeParams):
    """Params of ``road.mask``."""

    height_tolerance_m: float = Field(
        0.08, gt=0.0, le=2.0, description="largest |height above the road plane| of a road pixel, metres"
    )
    min_disparity_tolerance_px: float = Field(
        0.5,
        ge=0.0,
        le=16.0,
        description="the disparity tolerance never goes below this (far-away noise), pixels",
    )
    max_distance_m: float = Field(
        80.0,
        gt=0.0,
        le=1000.0,
        description="pixels whose road point is farther than this are not road, metres",
    )
    free_space: bool = Field(
        True,
        description="column-wise free space: drop road pixels above the first obstacle run in each column",
    )
    min_obstacle_run_px: int = Field(
        4,
        ge=1,
        le=1000,
        description="free space: consecutive above-road pixels (bottom-up) that end a column, pixels",
    )
    open_px: int = Field(
        3, ge=0, le=101, description="morphological opening (speck removal) diameter, pixels; 0 = off"
    )
    close_px: int = Field(
        7, ge=0, le=101, description="morphological closing (hole filling) diameter, pixels; 0 = off"
    )
    fill_holes_max_above: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="holes enclosed by the road are filled when at most this fraction of their pixels is above "
        "the road (shadows, paint without disparity); 0 = never fill, fraction",
    )
    keep: Literal["all", "bottom", "bottom_centre"] = Field(
        "bottom_centre",
        description="connected components kept: all, those touching the bottom band, or those touching its "
        "central half (falls back to 'bottom', then 'all', when none does)",
    )
    bottom_band_frac: float = Field(
        0.15,
        gt=0.0,
        le=1.0,
        description="height of the bottom band used by 'keep', fraction of the image rows",
    )
    textureless_is_road: bool = Field(
        True,
        description="free-space scan: pixels with no disparity (smooth, textureless asphalt far away) below "
        "the first obstacle of their column count as road",
    )
    invalid_road: Literal["all", "none"] = Field(
        "all", description="mask when the road model is invalid: every pixel (no masking) or none"
    )


def _disk(diameter: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (diameter, diameter))


def _keep_components(mask: np.ndarray, keep: str, band_frac: float, cx: float, image_rows: int | None = None) -> np.ndarray:
    """Keep the connected components that cover the seed region (the bottom band, or its central
    half) best: every component with at least a tenth of the largest one's overlap with the seed.
    ``mask`` may be the bottom rows of an image of ``image_rows`` rows (the band is a fraction of those)."""
    H, W = mask.shape
    image_rows = H if image_rows is None else image_rows
    n, labels = cv2.connectedComponents(np.ascontiguousarray(mask).view(np.uint8), connectivity=8)
    if n <= 1:
        return mask
    band = labels[max(0, H - max(1, int(round(band_frac * image_rows)))) :]
    lo, hi = int(max(0, cx - W / 4)), int(min(W, cx + W / 4 + 1))
    seeds = ([band[:, lo:hi]] if keep == "bottom_centre" else []) + [band]
    for region in seeds:
        overlap = np.bincount(region.ravel(), minlength=n)[1:]
        if overlap.max() > 0:
            lut = np.zeros(n, bool)
            lut[1:] = overlap >= 0.1 * overlap.max()
            return _lookup_kernel(lut, labels)
    return mask


def _fill_holes(mask: np.ndarray, classes: np.ndarray, max_above: float) -> np.ndarray:
    """Fill the regions of ``~mask`` that do not touch the image border and whose share of
    above-road pixels (``classes == ABOVE``) is at most ``max_above``."""
    n, labels = cv2.connectedComponents(np.logical_not(mask).view(np.uint8), connectivity=4)
    if n <= 1:
        return mask
    return _fill_holes_kernel(np.ascontiguousarray(mask), labels, n, classes, float(max_above))


def road_mask_array(
    params: MaskParams, disparity: np.ndarray, road: RoadModel, calib: Calibration
) -> np.ndarray:
    """The work of ``road.mask`` (HxW bool).

    Everything after the height classes runs on the rows from the first one with a road label
    down (above it, beyond ``max_distance_m`` or the horizon, nothing is road), with a margin of
    empty rows wide enough for the morphology: the result is that of the whole image."""
    disp = as_disparity(disparity, "road.mask")
    if not road.valid or not road.height > 0:
        return np.full(disp.shape, params.invalid_road == "all", dtype=bool)
    s, c = geometry.roll_row_coeffs(road.roll, calib)
    min_road_disp = calib.f * calib.baseline / params.max_distance_m
    labels = _height_class_kernel(
        disp,
        float(road.a0),
        float(road.a1),
        float(road.a2),
        float(calib.cx),
        float(calib.cy),
        s,
        c,
        float(road.height),
        float(params.height_tolerance_m),
        float(params.min_disparity_tolerance_px),
        float(min_road_disp),
    )
    H = labels.shape[0]
    labelled = np.flatnonzero(labels.any(axis=1))
    out = np.zeros(disp.shape, bool)
    if labelled.size == 0:
        return out
    top = max(0, int(labelled[0]) - 2 * (params.open_px + params.close_px) - 2)
    labels = labels[top:]
    mask = (
        _free_space_kernel(labels, int(params.min_obstacle_run_px), bool(params.textureless_is_road)) if params.free_space else labels == ROAD
    )
    if params.open_px > 1:
        # bool and 0/1 uint8 share their bytes: views, no copies
        mask = cv2.morphologyEx(np.ascontiguousarray(mask).view(np.uint8), cv2.MORPH_OPEN, _disk(params.open_px)).view(bool)
    if params.keep != "all":
        mask = _keep_components(mask, params.keep, params.bottom_band_frac, calib.cx, H)
    if params.close_px > 1:
        mask = cv2.morphologyEx(np.ascontiguousarray(mask).view(np.uint8), cv2.MORPH_CLOSE, _disk(params.close_px)).view(bool)
    if params.fill_holes_max_above > 0:
        mask = _fill_holes(mask, labels, params.fill_holes_max_above)
    out[top:] = mask
    return out


@node_type(
    "road.mask",
    inputs={
        "disparity": Port("disparity", "left disparity map"),
        "road": Port("road_model", "road profile and pose (road.profile)"),
        "calib": Port("calibration", "stereo calibration", rate="constant"),
    },
    outputs={"mask": Port("mask", "HxW bool, True on the drivable road")},
)
def road_mask(params: MaskParams, disparity: np.ndarray, road: RoadModel, calib: Calibration) -> dict:
    """Road pixels: metric height above the fitted road plane within a tolerance, below the horizon,
    cleaned by morphology and kept where connected to the bottom centre of the image."""
    return {"mask": road_mask_array(params, disparity, road, calib)}
