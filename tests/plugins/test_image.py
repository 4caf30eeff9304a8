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
