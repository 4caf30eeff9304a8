"""The params of ``disparity.onnx`` (:mod:`._onnx`): the model file, how the pair is prepared for the
network (colour order, size, normalisation, padding, layout) and how its output is read back
(unit, range), where the network runs; checked together before any frame.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from lanegraph import NodeParams


class OnnxParams(NodeParams):
    """Params of ``disparity.onnx``. The defaults are PSMNet's (RGB, ImageNet normalisation)."""

    model: str = Field(
        "",
        max_length=4096,
        description="the network, an .onnx file (a protobuf: loading it runs no code); a relative path is "
        "relative to the working directory; required to run (e.g. --set disp.model=psmnet.onnx)",
    )
    left_input: str = Field(
        "left", min_length=1, max_length=256, description="name of the model input fed the left image"
    )
    right_input: str = Field(
        "right", min_length=1, max_length=256, description="name of the model input fed the right image"
    )
    stacked_input: str = Field(
        "",
        max_length=256,
        description="name of a single model input fed the pair stacked along the channel axis, left first "
        "(2 channels grey, 6 colour); when set, left_input and right_input are not used",
    )
    output: str = Field(
        "disparity",
        min_length=1,
        max_length=256,
        description="name of the model output holding the disparity",
    )
    channels: Literal["rgb", "bgr", "gray"] = Field(
        "rgb",
        description="colour order the network takes: 'rgb' (networks trained on PIL images, PSMNet), 'bgr' "
        "(trained on OpenCV images) or 'gray' (one channel); grey input images are repeated for colour",
    )
    layout: Literal["NCHW", "NHWC"] = Field(
        "NCHW", description="the inputs' axes: batch, channels, height, width (PyTorch) or channels last"
    )
    pixel_scale: float = Field(
        1.0 / 255.0,
        ge=1e-6,
        le=1000.0,
        description="normalisation, first step: pixel values 0..255 are multiplied by this (1/255: 0..1; "
        "1: raw 0..255)",
    )
    mean: list[float] = Field(
        [0.485, 0.456, 0.406],
        min_length=1,
        max_length=3,
        description="normalisation, second step: subtracted per channel, in the order of 'channels', after "
        "pixel_scale (one value for all channels or one per channel; -1e4..1e4); ImageNet's by default",
    )
    std: list[float] = Field(
        [0.229, 0.224, 0.225],
        min_length=1,
        max_length=3,
        description="normalisation, last step: divided per channel, after subtracting mean (one value or one "
        "per channel; 1e-6..1e4); ImageNet's by default",
    )
    resize: tuple[int, int] | None = Field(
        None,
        description="resize the pair to this [height, width] (pixels, 8..8192 each) before the network, e.g. "
        "the fixed size a model was exported with; null: the image's own size (then padded to pad_to)",
    )
    pad_to: int = Field(
        32,
        ge=1,
        le=256,
        description="pad the network input (after any resize) at the top and on the right up to a multiple of "
        "this many pixels (zeros after normalisation, i.e. the mean colour), as PSMNet's test script does; "
        "the padding is cut off the output; 1: no padding",
    )
    output_unit: Literal["network_pixels", "output_pixels", "image_pixels"] = Field(
        "network_pixels",
        description="unit of the output's values: 'network_pixels' (pixels of the network input, after "
        "resize and padding: PSMNet and most exports), 'output_pixels' (pixels of a smaller output map's own "
        "width) or 'image_pixels' (already pixels of the input image); the node converts to image pixels",
    )
    output_factor: float = Field(
        1.0,
        ge=-1000.0,
        le=1000.0,
        description="the raw output is multiplied by this first, e.g. -1 for a network that outputs the "
        "horizontal flow (minus the disparity) or 1/256 for KITTI's 16-bit convention; not 0",
    )
    interpolation: Literal["linear", "nearest"] = Field(
        "linear",
        description="how the disparity map is resized to the image: 'linear' (bilinear where all four "
        "neighbours are valid, nearest elsewhere) or 'nearest'",
    )
    max_disparity: float = Field(
        192.0,
        ge=1.0,
        le=8192.0,
        description="largest valid disparity, pixels of the input image (PSMNet is trained for 192); larger "
        "values, values <= 0 and non-finite ones are invalid (0)",
    )
    providers: Literal["auto", "cpu", "cuda"] = Field(
        "auto",
        description="where ONNX Runtime runs the network: 'cpu', 'cuda' (an error if this ONNX Runtime has "
        "no CUDA provider) or 'auto' (CUDA when ONNX Runtime has it, else the CPU, said once in the log)",
    )
    device: int = Field(0, ge=0, le=63, description="CUDA device id (providers cuda or auto)")
    threads: int = Field(
        0,
        ge=0,
        le=256,
        description="ONNX Runtime's threads per operator on the CPU; 0: its default (one per core)",
    )

    @field_validator("mean")
    @classmethod
    def _mean_bounds(cls, v: list[float]) -> list[float]:
        if not all(np.isfinite(x) and abs(x) <= 1e4 for x in v):
            raise ValueError(f"mean: expected finite values in -1e4..1e4, got {v}")
        return v

    @field_validator("std")
    @classmethod
    def _std_bounds(cls, v: list[float]) -> list[float]:
        if not all(np.isfinite(x) and 1e-6 <= x <= 1e4 for x in v):
            raise ValueError(f"std: expected values in 1e-6..1e4 (a division), got {v}")
        return v

    @field_validator("resize")
    @classmethod
    def _resize_bounds(cls, v: tuple[int, int] | None) -> tuple[int, int] | None:
        if v is not None and not all(8 <= x <= 8192 for x in v):
            raise ValueError(f"resize: expected [height, width], each 8..8192 pixels, got {list(v)}")
        return v

    @field_validator("output_factor")
    @classmethod
    def _factor_not_zero(cls, v: float) -> float:
        if v == 0:
            raise ValueError(
                "output_factor: expected a non-zero factor, got 0 (every pixel would be invalid)"
            )
        return v

    @model_validator(mode="after")
    def _consistent(self) -> OnnxParams:
        n = self.n_channels
        for name in ("mean", "std"):
            values = getattr(self, name)
            if len(values) not in (1, n):
                hint = f"e.g. [{sum(values) / len(values):.3g}]" if n == 1 else "one value or three"
                raise ValueError(
                    f"{name}: {len(values)} values for {n} channel(s) of channels '{self.channels}' ({hint})"
                )
        if not self.stacked_input and self.left_input == self.right_input:
            raise ValueError(
                f"left_input and right_input are both {self.left_input!r}: expected two different model inputs "
                "(or stacked_input for a model with one input)"
            )
        return self

    @property
    def n_channels(self) -> int:
        """Channels of one image as fed to the network: 1 grey, 3 colour."""
        return 1 if self.channels == "gray" else 3
