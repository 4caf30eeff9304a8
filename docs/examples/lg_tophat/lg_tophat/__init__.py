"""lanegraph-tophat: an example third-party lanegraph plugin.

It provides one node type, ``features.tophat``: lane features in the bird's-eye view by a
morphological white top-hat, a classic lane-marking extractor from the related work of
Ozgunalp, Fan et al. (a drop-in replacement for ``features.slt`` / ``features.eslt``), and one port
type, ``bev_response``: the per-pixel response map it thresholds, for any node that wants it.

The white top-hat of an image is the image minus its morphological opening. Opening with a
horizontal line of ``width`` pixels removes every bright structure narrower than ``width``
columns, so the top-hat keeps exactly those: near-vertical paint in the BEV, which is 2-4 px wide at
5 cm per pixel. The response is averaged over ``smooth_rows`` rows (markings are long, noise is
not) and a pixel is a feature when it exceeds ``threshold`` grey levels. With ``min_run`` > 1 a
feature is kept only in a vertical run of that many feature pixels in its column (a numba kernel,
``_vertical_runs``, with lanegraph's kernel flags).

Orientation (the ``FeatureMap.orientation`` that ``lanes.orientation`` histograms) comes from the
structure tensor of the top-hat response: the dominant Sobel gradient direction averaged over an
``orientation_window`` square, turned by 90 degrees (a marking runs perpendicular to the gradients
across its borders). Units and convention as everywhere in lanegraph: radians in ``[0, pi)`` from
the BEV's +x axis (columns) towards up; a lane straight ahead is ``pi/2``; ``-1`` off the features.
``orientation: vertical`` gives every feature ``pi/2`` instead (cheaper, but only right when the lanes
run straight ahead in the BEV), and ``orientation: none`` gives no orientation, like ``features.slt``
(``lanes.orientation`` then falls back to its default).
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np
from pydantic import Field

from lanegraph import FeatureMap, NodeParams, Port, PortType, hookimpl, jit, node_type

__all__ = ["TophatParams", "tophat", "vertical_runs", "white_tophat", "structure_orientation"]

#: the port type this plugin adds: any node may produce or take it
BEV_RESPONSE = PortType(
    "bev_response", "a response map on the BEV grid, Hb x Wb float32 (larger: more marking-like)"
)


def white_tophat(gray: np.ndarray, width: int) -> np.ndarray:
    """White top-hat of a float32 image with a horizontal line of ``width`` pixels (float32, >= 0)."""
    kernel = np.ones((1, width), np.uint8)
    return cv2.morphologyEx(gray, cv2.MORPH_TOPHAT, kernel, borderType=cv2.BORDER_REPLICATE)


def structure_orientation(response: np.ndarray, window: int) -> np.ndarray:
    """Local ridge orientation of ``response`` (float32) from its structure tensor, in ``[0, pi)``
    from +x towards up (rows grow downwards), float32, same shape."""
    gx = cv2.Sobel(response, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(response, cv2.CV_32F, 0, 1, ksize=3)
    box = (window, window)
    jxx = cv2.boxFilter(gx * gx, cv2.CV_32F, box)
    jyy = cv2.boxFilter(gy * gy, cv2.CV_32F, box)
    jxy = cv2.boxFilter(gx * gy, cv2.CV_32F, box)
    # dominant gradient angle, measured in (x right, y down); the ridge runs perpendicular to it.
    # In (x right, y up) the ridge angle is -(phi + pi/2), taken modulo pi.
    phi = 0.5 * np.arctan2(2.0 * jxy, jxx - jyy)
    return np.mod(-(phi + np.pi / 2), np.pi).astype(np.float32)


@jit
def _vertical_runs(mask: np.ndarray, min_run: int) -> np.ndarray:
    out = np.zeros_like(mask)
    rows, cols = mask.shape
    for c in range(cols):
        r = 0
        while r < rows:
            if not mask[r, c]:
                r += 1
                continue
            start = r
            while r < rows and mask[r, c]:
                r += 1
            if r - start >= min_run:
                out[start:r, c] = True
    return out


def vertical_runs(mask: np.ndarray, min_run: int) -> np.ndarray:
    """The pixels of ``mask`` (Hb x Wb bool) that lie in a vertical run of at least ``min_run``
    set pixels of their column (bool, same shape)."""
    mask = np.asarray(mask)
    if mask.ndim != 2 or mask.dtype != np.bool_:
        raise ValueError(
            f"vertical_runs: expected an Hb x Wb bool mask, got {mask.dtype} of shape {mask.shape}"
        )
    if min_run <= 1:
        return mask
    return _vertical_runs(np.ascontiguousarray(mask), int(min_run))


class TophatParams(NodeParams):
    """Params of ``features.tophat``."""

    width: int = Field(9, ge=3, le=99, description="horizontal line element, BEV pixels (> marking width)")
    threshold: float = Field(20.0, ge=0.0, le=255.0, description="minimum top-hat response, grey levels")
    smooth_rows: int = Field(5, ge=1, le=51, description="rows averaged before thresholding, BEV pixels")
    min_run: int = Field(
        1,
        ge=1,
        le=200,
        description="keep a feature only in a vertical run of this many feature rows, BEV pixels (1: all)",
    )
    orientation: Literal["structure", "vertical", "none"] = Field(
        "structure", description="feature orientation: structure tensor, constant pi/2, or none (like SLT)"
    )
    orientation_window: int = Field(7, ge=3, le=51, description="structure tensor window side, BEV pixels")


@node_type(
    "features.tophat",
    inputs={"image": Port("bev_image", "BEV grey image")},
    outputs={
        "features": "features",
        "response": Port("bev_response", "the smoothed top-hat response, grey levels"),
    },
)
def tophat(params: TophatParams, image: np.ndarray) -> dict:
    """White top-hat: T brighter than the opening by a horizontal line; structure-tensor orientation."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    gray = np.ascontiguousarray(image, dtype=np.float32)
    response = white_tophat(gray, params.width)
    if params.smooth_rows > 1:
        response = cv2.blur(response, (1, params.smooth_rows), borderType=cv2.BORDER_REPLICATE)
    mask = vertical_runs(response > params.threshold, params.min_run)
    if params.orientation == "none":
        return {"features": FeatureMap(mask=mask, orientation=None), "response": response}
    if params.orientation == "vertical":
        theta = np.full(gray.shape, np.pi / 2, np.float32)
    else:
        theta = structure_orientation(response, params.orientation_window)
    return {
        "features": FeatureMap(mask=mask, orientation=np.where(mask, theta, np.float32(-1.0))),
        "response": response,
    }


@hookimpl
def lanegraph_port_types():
    return [BEV_RESPONSE]


@hookimpl
def lanegraph_node_types():
    return [tophat]
