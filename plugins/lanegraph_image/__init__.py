"""Basic image nodes: colour conversion, smoothing, and stereo rectification (``image.rectify``)."""

from __future__ import annotations

import cv2
import numpy as np
from pydantic import Field

from lanegraph import NodeParams, Port, RunContext, hookimpl, node_type


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


class RectifyParams(NodeParams):
    """Params of ``image.rectify``."""

    min_baseline_m: float = Field(
        0.05, gt=0.0, le=1000.0, description="smallest plausible rectified baseline, metres"
    )
    max_baseline_m: float = Field(
        2.0, gt=0.0, le=1000.0, description="largest plausible rectified baseline, metres"
    )


@node_type(
    "image.rectify",
    inputs={
        "left": Port("image", "left image as recorded"),
        "right": Port("image", "right image as recorded"),
        "stereo": Port(
            "stereo_calibration",
            "the rig's calibration (a bag or video source's stereo output)",
            optional=True,
        ),
        "calib": Port(
            "calibration",
            "a rectified input's calibration, for a source that gives no stereo output",
            optional=True,
        ),
    },
    outputs={
        "left": Port("image", "left image, rectified"),
        "right": Port("image", "right image, rectified"),
        "calib": Port("calibration", "the rectified calibration"),
    },
)
class Rectify:
    """Rectifies a stereo pair: undistorts both images and turns them into one image plane
    (``cv2.stereoRectify`` from the rig's R, T, or the calibration's own R1/P1, R2/P2), with the
    remap tables computed once; a pair that is rectified already passes unchanged. For a source
    whose ``rectify`` is false (docs/inputs.md)."""

    def __init__(self, params: RectifyParams, context: RunContext):
        self.params = params
        self._for = None
        self._rectifier = None

    def __call__(self, left: np.ndarray, right: np.ndarray, stereo=None, calib=None) -> dict:
        from lanegraph_io import Rectifier

        if stereo is None:
            if calib is None:
                raise ValueError(
                    "inputs 'stereo' and 'calib' are both empty: expected the source's stereo calibration "
                    "(lanegraph_io's sources give it) or, for a rectified source, its calib"
                )
            return {"left": left, "right": right, "calib": calib}  # a rectified source that says so
        if self._rectifier is None or self._for is not stereo:
            size = (left.shape[1], left.shape[0])
            checked = stereo.check(size, (self.params.min_baseline_m, self.params.max_baseline_m))
            self._rectifier, self._for = (
                Rectifier(checked, (self.params.min_baseline_m, self.params.max_baseline_m)),
                stereo,
            )
        a, b = self._rectifier(left, right)
        return {"left": a, "right": b, "calib": self._rectifier.calib}


@hookimpl
def lanegraph_node_types():
    return [gray, blur, Rectify]
