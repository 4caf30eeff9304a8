"""Basic image nodes: colour conversion and smoothing."""

from __future__ import annotations

import cv2
import numpy as np
from pydantic import Field

from lanegraph import NodeParams, hookimpl, node_type


class GrayParams(NodeParams):
    """Params of ``image.gray``."""

    dtype: str = Field(
        "uint8", pattern="^(uint8|float32)$", description="output dtype: uint8 or float32 (0-255)"
    )


@node_type("image.gray", inputs={"image": "image"}, outputs={"image": "gray"})
def gray(params: GrayParams, image: np.ndarray) -> dict:
    """Convert a BGR image to gray (a gray image passes through)."""
    g = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if params.dtype == "float32":
        g = g.astype(np.float32)
    return {"image": g}


class BlurParams(NodeParams):
    """Params of ``image.blur``."""

    ksize: int = Field(5, ge=1, le=99, description="Gaussian kernel size in pixels (odd)")
    sigma: float = Field(
        0.0, ge=0.0, le=50.0, description="Gaussian sigma in pixels; 0 derives it from ksize"
    )


@node_type("image.blur", inputs={"image": "image"}, outputs={"image": "image"})
def blur(params: BlurParams, image: np.ndarray) -> dict:
    """Gaussian blur."""
    k = params.ksize | 1
    return {"image": cv2.GaussianBlur(image, (k, k), params.sigma)}


@hookimpl
def lanegraph_node_types():
    return [gray, blur]
