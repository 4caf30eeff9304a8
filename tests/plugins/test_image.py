"""lanegraph_image: image.gray and image.blur, called as the plain functions they are, against
OpenCV-free NumPy references."""

from __future__ import annotations

import numpy as np
import pytest
from lanegraph_image import BlurParams, GrayParams, blur, gray
from pydantic import ValidationError

from lanegraph import node_type_of


def test_gray_weights_the_channels_as_bt601():
    rng = np.random.default_rng(0)
    bgr = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    out = gray(GrayParams(), image=bgr)["image"]
    b, g, r = (bgr[..., k].astype(np.float64) for k in range(3))
    ref = 0.114 * b + 0.587 * g + 0.299 * r
    assert out.dtype == np.uint8 and out.shape == (5, 7)
    assert np.abs(out.astype(np.float64) - ref).max() <= 1.0


def test_gray_passes_a_gray_image_through_and_converts_the_dtype():
    img = np.arange(12, dtype=np.uint8).reshape(3, 4)
    assert gray(GrayParams(), image=img)["image"] is img
    out = gray(GrayParams(dtype="float32"), image=img)["image"]
    assert out.dtype == np.float32 and np.array_equal(out, img.astype(np.float32))
    with pytest.raises(ValidationError):
        GrayParams(dtype="int7")


def test_blur_is_a_normalised_gaussian():
    img = np.zeros((21, 21), np.uint8)
    img[10, 10] = 255
    out = blur(BlurParams(ksize=5, sigma=1.0), image=img)["image"].astype(np.float64)
    x = np.arange(-2, 3)
    k = np.exp(-(x**2) / 2.0)
    ref = 255 * np.outer(k, k) / k.sum() ** 2
    assert np.abs(out[8:13, 8:13] - ref).max() <= 1.0 and out[:8].max() == 0
    even = blur(BlurParams(ksize=4, sigma=1.0), image=img)["image"]  # an even size is made odd (| 1)
    assert np.array_equal(even, blur(BlurParams(ksize=5, sigma=1.0), image=img)["image"])


def test_the_functions_carry_their_node_types():
    assert node_type_of(gray).name == "image.gray" and node_type_of(gray).params is GrayParams
    assert node_type_of(blur).name == "image.blur" and node_type_of(blur).outputs["image"].type == "image"


def test_rectify_node_rectifies_once_and_passes_a_rectified_pair():
    from lanegraph_image import Rectify, RectifyParams
    from lanegraph_io import Rectifier
    from lanegraph_io._calibfiles import from_rectified
    from lanegraph_io._stereo import example_rig

    from lanegraph.errors import InputError
    from lanegraph.nodes import RunContext
    from lanegraph.types import Calibration

    rect = Calibration(f=200.0, cx=159.5, cy=59.5, baseline=0.3, width=320, height=120)
    rig = example_rig(rect)
    rng = np.random.default_rng(1)
    left = rng.integers(0, 256, (120, 320, 3), dtype=np.uint8)
    right = rng.integers(0, 256, (120, 320, 3), dtype=np.uint8)
    node = Rectify(RectifyParams(), RunContext())
    out = node(left=left, right=right, stereo=rig)
    want = Rectifier(rig)(left, right)
    assert np.array_equal(out["left"], want[0]) and np.array_equal(out["right"], want[1])
    assert out["calib"].baseline == pytest.approx(0.3) and out["calib"].f == pytest.approx(200.0)
    maps = node._rectifier.maps
    node(left=left, right=right, stereo=rig)
    assert node._rectifier.maps is maps  # computed once
    flat = Rectify(RectifyParams(), RunContext())(
        left=left, right=right, stereo=from_rectified(rect, "c", {})
    )
    assert flat["left"] is left and flat["right"] is right
    with pytest.raises(InputError, match="the calibration is for 320x120 images, the frames are 160x60"):
        Rectify(RectifyParams(), RunContext())(left=left[:60, :160], right=right[:60, :160], stereo=rig)


def test_rectify_node_passes_a_rectified_source_without_a_stereo_output():
    from lanegraph_image import Rectify, RectifyParams

    from lanegraph.nodes import RunContext
    from lanegraph.types import Calibration

    calib = Calibration(f=200.0, cx=159.5, cy=59.5, baseline=0.3, width=320, height=120)
    img = np.zeros((120, 320, 3), np.uint8)
    out = Rectify(RectifyParams(), RunContext())(left=img, right=img, calib=calib)
    assert out["left"] is img and out["calib"] is calib
    with pytest.raises(ValueError, match="inputs 'stereo' and 'calib' are both empty"):
        Rectify(RectifyParams(), RunContext())(left=img, right=img)
