"""The pair in, the disparity out, around ``disparity.onnx``'s network (:mod:`._onnx`): the images
converted to the network's colour order, resized, normalised, padded and laid out as its inputs
(:func:`network_inputs`); its output map brought back to a disparity in pixels of the input image
(:func:`to_image_disparity`).
"""

from __future__ import annotations

import cv2
import numpy as np

from lanegraph import InputError

from ._common import upsample_disparity
from ._onnx_params import OnnxParams

# --------------------------------------------------------------------------- pre- and post-processing


def to_network_channels(image: np.ndarray, port: str, channels: str) -> np.ndarray:
    """An image as float32 HxWxC in the network's colour order, values 0..255.

    Parameters
    ----------
    image : ndarray
        HxW grey or HxWx3 BGR (HxWx4 BGRA and HxWx1 are accepted too); uint8, or any
        integer or float array in 0..255 (non-finite values become 0).
    port : str
        Input port name, for the error message.
    channels : str
        ``"rgb"``, ``"bgr"`` or ``"gray"``.

    Returns
    -------
    ndarray
        HxWx3 (RGB or BGR) or HxWx1 float32.
    """
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (3, 4))):
        raise InputError(
            f"input '{port}': expected an HxW gray or HxWx3 BGR image, got shape {np.shape(image)}"
        )
    if img.dtype.kind not in "biuf":
        raise InputError(f"input '{port}': expected a uint8 (or 0-255 float) image, got dtype {img.dtype}")
    if img.shape[0] < 2 or img.shape[1] < 2:
        raise InputError(f"input '{port}': image of {img.shape[0]}x{img.shape[1]} pixels is too small")
    if img.dtype != np.uint8:
        img = np.clip(np.nan_to_num(img.astype(np.float32), nan=0.0, posinf=255.0, neginf=0.0), 0, 255)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if channels == "gray":
        if img.ndim == 3:
            img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2GRAY)
        return img.astype(np.float32)[:, :, None]
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if channels == "rgb":
        img = img[:, :, ::-1]
    return np.ascontiguousarray(img, dtype=np.float32)


def network_size(h: int, w: int, resize: tuple[int, int] | None, pad_to: int) -> tuple[int, int, int, int]:
    """``(hn, wn, hp, wp)``: the image size after ``resize`` (rows, cols) and after padding to ``pad_to``."""
    hn, wn = (int(resize[0]), int(resize[1])) if resize is not None else (h, w)
    hp = -(-hn // pad_to) * pad_to
    wp = -(-wn // pad_to) * pad_to
    return hn, wn, hp, wp


def prepare_image(image: np.ndarray, port: str, params: OnnxParams) -> np.ndarray:
    """One image as the network takes it: HpxWpxC float32, resized, normalised and padded.

    Value of channel ``c``: ``(pixel * pixel_scale - mean[c]) / std[c]``; the padding (top rows,
    right columns) is 0.
    """
    img = to_network_channels(image, port, params.channels)
    h, w = img.shape[:2]
    hn, wn, hp, wp = network_size(h, w, params.resize, params.pad_to)
    if (hn, wn) != (h, w):
        shrink = hn <= h and wn <= w
        img = cv2.resize(img, (wn, hn), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        if img.ndim == 2:  # OpenCV drops a single channel
            img = img[:, :, None]
    c = img.shape[2]
    std = np.broadcast_to(np.asarray(params.std, np.float32), (c,))
    mean = np.broadcast_to(np.asarray(params.mean, np.float32), (c,))
    x = img * (np.float32(params.pixel_scale) / std) - mean / std
    if (hp, wp) != (hn, wn):
        x = np.pad(x, ((hp - hn, 0), (0, wp - wn), (0, 0)))
    return x.astype(np.float32, copy=False)


def network_inputs(left: np.ndarray, right: np.ndarray, params: OnnxParams) -> dict[str, np.ndarray]:
    """The feeds of one pair: ``{input name: 1xCxHxW (NCHW) or 1xHxWxC (NHWC) float32}``."""
    xl, xr = prepare_image(left, "left", params), prepare_image(right, "right", params)
    (hl, wl), (hr, wr) = np.shape(left)[:2], np.shape(right)[:2]
    if (hl, wl) != (hr, wr):
        raise InputError(
            f"left and right images differ in size: left {hl}x{wl}, right {hr}x{wr} (expected a rectified pair "
            "of the same size)"
        )

    def lay(x: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray((x.transpose(2, 0, 1) if params.layout == "NCHW" else x)[None])

    if params.stacked_input:
        return {params.stacked_input: lay(np.concatenate([xl, xr], axis=2))}
    return {params.left_input: lay(xl), params.right_input: lay(xr)}


def output_map(raw: np.ndarray, layout: str) -> np.ndarray:
    """The network's output as an HxW map: leading axes of size 1 dropped (and a trailing one for NHWC).

    Raises ``ValueError`` when the output is not one map (a batch, or several channels).
    """
    d = np.asarray(raw)
    if d.ndim == 4 and layout == "NHWC" and d.shape[3] == 1:
        d = d[..., 0]
    while d.ndim > 2 and d.shape[0] == 1:
        d = d[0]
    if d.ndim != 2:
        raise ValueError(
            f"expected one HxW map (shape 1x1xHxW, 1xHxW or HxW), got shape {tuple(np.shape(raw))}"
        )
    return d


def to_image_disparity(raw: np.ndarray, shape: tuple[int, int], params: OnnxParams) -> np.ndarray:
    """The network's output as a disparity of the input image.

    Parameters
    ----------
    raw : ndarray
        The output as the network gives it (see :func:`output_map`), in ``params.output_unit``.
    shape : tuple of int
        The input image's ``(rows, cols)``.
    params : OnnxParams
        ``resize``, ``pad_to``, ``layout``, ``output_unit``, ``output_factor``, ``interpolation``,
        ``max_disparity``.

    Returns
    -------
    ndarray
        HxW float32 disparity in pixels of the input image; invalid pixels (<= 0, non-finite,
        above ``max_disparity``) are 0.
    """
    h, w = shape
    hn, wn, hp, wp = network_size(h, w, params.resize, params.pad_to)
    d = output_map(raw, params.layout).astype(np.float32) * np.float32(params.output_factor)
    d[~(np.isfinite(d) & (d > 0))] = 0.0
    image_unit = params.output_unit == "image_pixels"
    ho, wo = d.shape
    if (ho, wo) != (hp, wp):  # a smaller (or larger) map than the network input: to the input's size
        unit_scale = wo / wp if params.output_unit == "output_pixels" else 1.0
        d = upsample_disparity(d, (hp, wp), unit_scale, params.interpolation)
    d = d[hp - hn :, :wn]  # the padding: rows at the top, columns on the right
    if (hn, wn) != (h, w):
        d = upsample_disparity(
            np.ascontiguousarray(d), (h, w), 1.0 if image_unit else wn / w, params.interpolation
        )
    d = d.astype(np.float32, copy=False)
    d[~(d <= np.float32(params.max_disparity))] = 0.0
    return np.ascontiguousarray(d)
