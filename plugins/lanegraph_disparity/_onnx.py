"""``disparity.onnx``: a stereo network exported to ONNX (PSMNet, HITNet, CREStereo, RAFT-Stereo ...),
run by ONNX Runtime on the CPU or a CUDA GPU.

Per frame: the pair is converted to the network's colour order (``channels``), optionally resized to
a fixed size (``resize``), normalised (``pixel_scale``, ``mean``, ``std``), padded at the top and on
the right up to a multiple of ``pad_to`` and laid out as ``NCHW`` or ``NHWC`` (one input per image,
or one ``stacked_input``). The network's output is brought back: a smaller output map is resized to
the network input's size, the padding is cut off, the map is resized to the image's size and its
values are rescaled from the unit they were given in (``output_unit``) to pixels of the input image.

ONNX Runtime is the optional ``onnx`` extra (``pip install "lanegraph[onnx]"``): it is imported
when a run opens the node, never when the plugin is imported, so ``lanegraph nodes`` lists the node
type without it. The session is created once per run (the node is stateful) and reused for every
frame; the model's inputs and outputs (names, ranks, element types, fixed sizes) are checked when it
is created, the shapes against the image at the first frame. An ``.onnx`` file is a protobuf: loading
one runs no code, and no custom-operator library is ever registered.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from pydantic import Field, field_validator, model_validator

from lanegraph import GraphError, InputError, NodeParams, Problem, RunContext, node_type

from ._common import upsample_disparity

log = logging.getLogger("lanegraph.disparity.onnx")

INSTALL_HINT = 'install the onnx extra: pip install "lanegraph[onnx]"'

#: seconds the session may take to load before the log says what the run is waiting for
SLOW_LOAD_S = 3.0

#: element types a network input may have, and the NumPy type it is fed as
_INPUT_TYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16, "tensor(double)": np.float64}
#: element types of an acceptable disparity output
_OUTPUT_TYPES = {
    *_INPUT_TYPES,
    "tensor(int8)",
    "tensor(uint8)",
    "tensor(int16)",
    "tensor(uint16)",
}
#: element types a disparity output may not have: 32- and 64-bit integers are indices or labels
#: (an argmax over disparity levels, a class map), not a disparity (a 16-bit one is KITTI's
#: fixed point: give output_factor 1/256)
_INDEX_TYPES = {
    "tensor(int32)": "int32",
    "tensor(int64)": "int64",
    "tensor(uint32)": "uint32",
    "tensor(uint64)": "uint64",
}
#: an output map smaller than this fraction of the network input (on either side) is refused
MIN_OUTPUT_FRACTION = 1 / 16


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


# --------------------------------------------------------------------------- the session


def _shape_text(shape: Any) -> str:
    """``[1, 3, height, width]``: fixed sizes as numbers, dynamic ones by their name (``?`` unnamed)."""
    if shape is None:
        return "[?]"
    return "[" + ", ".join(str(s) if isinstance(s, int) or s else "?" for s in shape) + "]"


def _describe(arg: Any) -> str:
    return f"{arg.name!r} ({arg.type} {_shape_text(arg.shape)})"


def _import_onnxruntime() -> Any:
    """onnxruntime, or None when it is not installed (or cannot be imported)."""
    try:
        import onnxruntime
    except ImportError:
        return None
    return onnxruntime


@node_type(
    "disparity.onnx",
    inputs={"left": "image", "right": "image"},
    outputs={"disparity": "disparity"},
    implements=("close",),
)
class OnnxDisparity:
    """Disparity by a stereo network exported to ONNX (PSMNet, HITNet, CREStereo, RAFT-Stereo ...), run by ONNX Runtime on the CPU or CUDA; needs `pip install "lanegraph[onnx]"`.

    The pair is converted, resized, normalised and padded as the params say, fed to the
    network, and its output brought back to a disparity in pixels of the input image. The
    ONNX Runtime session is created once per run; the model's inputs and outputs are checked
    then, their shapes against the image at the first frame.

    Parameters
    ----------
    params : OnnxParams
        The model, its input and output names, the pre-processing and the providers.
    left, right : ndarray
        Rectified pair, HxW gray or HxWx3 BGR uint8, same size.

    Returns
    -------
    dict
        ``disparity``: HxW float32 disparity of the left image in pixels of the input
        image; invalid pixels are 0.

    Raises
    ------
    GraphError
        When the run opens: no model, a missing or unloadable file, inputs or outputs
        without the declared names, ranks, element types or channel count (an output of
        32- or 64-bit integers is an index, not a disparity), no ONNX Runtime,
        ``providers: cuda`` without a CUDA provider.
    InputError
        At a frame: images the model's fixed input sizes do not fit, an output that is not
        one map or is smaller than 1/16 of the network input (1x1), or ONNX Runtime failing
        on the input.
    """

    def __init__(self, params: OnnxParams, context: RunContext):
        self.p = params
        self._where = {
            "file": context.graph_file,
            "node": context.node_id or None,
            "node_type": "disparity.onnx",
        }
        self.path = Path(params.model) if params.model else None
        ort = self._check_setup(context)
        self.session, self.provider = self._create_session(ort)
        self.model_inputs = {a.name: a for a in self.session.get_inputs()}
        self.model_outputs = {a.name: a for a in self.session.get_outputs()}
        problems = self._check_signature()
        if problems:
            self.close()
            raise GraphError(problems)
        self._checked: tuple[int, int] | None = None  # image size whose shapes were checked

    # -- opening -----------------------------------------------------------------
    def _problem(self, field: str | None, message: str, hint: str | None = None) -> Problem:
        return Problem(message, field=f"params.{field}" if field else None, hint=hint, **self._where)

    def _check_setup(self, context: RunContext) -> Any:
        problems = []
        if self.path is None:
            problems.append(
                self._problem(
                    "model",
                    "no model given: expected the path of an .onnx file",
                    f"--set {context.node_id or 'NODE'}.model=path/to/model.onnx",
                )
            )
        elif not self.path.is_file():
            why = "is not a file" if self.path.exists() else "not found"
            problems.append(
                self._problem("model", f"model file {why}: {self.path} (resolved to {self.path.resolve()})")
            )
        ort = _import_onnxruntime()
        if ort is None:
            problems.append(
                self._problem(
                    None, "needs ONNX Runtime (the onnxruntime package), which is not installed", INSTALL_HINT
                )
            )
        if problems:
            raise GraphError(problems)
        return ort

    def _create_session(self, ort: Any) -> tuple[Any, str]:
        p = self.p
        available = list(ort.get_available_providers())
        cuda = "CUDAExecutionProvider" in available
        if p.providers == "cuda" and not cuda:
            raise GraphError(
                [
                    self._problem(
                        "providers",
                        f"'cuda': this ONNX Runtime ({ort.__version__}) has no CUDA provider (it has: "
                        f"{', '.join(available)})",
                        "install onnxruntime-gpu in place of onnxruntime, or use providers: auto or cpu",
                    )
                ]
            )
        use_cuda = p.providers != "cpu" and cuda
        providers: list[Any] = ["CPUExecutionProvider"]
        if use_cuda:
            providers.insert(0, ("CUDAExecutionProvider", {"device_id": p.device}))
        options = ort.SessionOptions()
        options.log_severity_level = 3  # ONNX Runtime's own warnings off: this node says what matters
        options.intra_op_num_threads = p.threads
        name = self._where["node"] or "disparity.onnx"
        # a large network (or CUDA starting) can take a while: say what the run waits for
        slow = threading.Timer(
            SLOW_LOAD_S,
            lambda: log.warning(
                "%s: loading %s into ONNX Runtime (%s) ...", name, self.path, "CUDA" if use_cuda else "CPU"
            ),
        )
        slow.daemon = True
        slow.start()
        try:
            session = ort.InferenceSession(str(self.path), sess_options=options, providers=providers)
        except Exception as exc:  # noqa: BLE001 - a protobuf that does not parse, an unknown operator ...
            text = str(exc).strip().splitlines()
            raise GraphError(
                [
                    self._problem(
                        "model",
                        f"cannot load {self.path} as an ONNX model: {type(exc).__name__}: {text[0] if text else ''}",
                    )
                ]
            ) from None
        finally:
            slow.cancel()
        used = session.get_providers()
        on_cuda = "CUDAExecutionProvider" in used
        if use_cuda and not on_cuda:
            if p.providers == "cuda":
                raise GraphError(
                    [
                        self._problem(
                            "providers",
                            f"'cuda': the CUDA provider did not start on device {p.device} (CUDA or cuDNN "
                            f"libraries missing or not matching this ONNX Runtime?); the session runs on {', '.join(used)}",
                            "check `python -c 'import onnxruntime; onnxruntime.preload_dlls()'`, or use "
                            "providers: auto or cpu",
                        )
                    ]
                )
            log.warning(
                "%s: providers auto: the CUDA provider did not start; running %s on the CPU", name, self.path
            )
        elif p.providers == "auto" and not cuda:
            log.warning(
                "%s: providers auto: this ONNX Runtime has no CUDA provider (it has %s); running %s on the CPU",
                name,
                ", ".join(available),
                self.path,
            )
        elif on_cuda:
            log.info("%s: running %s on CUDA device %d", name, self.path, p.device)
        return session, ("CUDAExecutionProvider" if on_cuda else "CPUExecutionProvider")

    def _check_signature(self) -> list[Problem]:
        """The model's inputs and outputs against the params: names, ranks, element types, fixed sizes."""
        p = self.p
        problems: list[Problem] = []
        have_in = ", ".join(_describe(a) for a in self.model_inputs.values()) or "(none)"
        have_out = ", ".join(_describe(a) for a in self.model_outputs.values()) or "(none)"
        fed = (
            {p.stacked_input: ("stacked_input", 2 * p.n_channels)}
            if p.stacked_input
            else {
                p.left_input: ("left_input", p.n_channels),
                p.right_input: ("right_input", p.n_channels),
            }
        )
        c_axis = 1 if p.layout == "NCHW" else 3
        h_axis, w_axis = (2, 3) if p.layout == "NCHW" else (1, 2)
        for name, (field, channels) in fed.items():
            arg = self.model_inputs.get(name)
            if arg is None:
                problems.append(
                    self._problem(
                        field,
                        f"the model has no input {name!r}; its inputs: {have_in}",
                        f"set {field} to one of them",
                    )
                )
                continue
            if arg.type not in _INPUT_TYPES:
                problems.append(
                    self._problem(
                        field,
                        f"model input {_describe(arg)}: expected a float tensor (float, float16 or double), got {arg.type}",
                    )
                )
            shape = arg.shape
            if shape is None or len(shape) != 4:
                problems.append(
                    self._problem(
                        field,
                        f"model input {_describe(arg)}: expected rank 4 ({p.layout}: one image, "
                        f"{'channels, height, width' if p.layout == 'NCHW' else 'height, width, channels'}), got rank "
                        f"{'unknown' if shape is None else len(shape)}",
                    )
                )
                continue
            if isinstance(shape[0], int) and shape[0] != 1:
                problems.append(
                    self._problem(
                        field, f"model input {_describe(arg)}: expected a batch of 1, got {shape[0]}"
                    )
                )
            ch, other = shape[c_axis], shape[4 - c_axis]  # the channel axis, and the other layout's
            if isinstance(other, int) and other == channels and not (isinstance(ch, int) and ch == channels):
                problems.append(
                    self._problem(
                        "layout",
                        f"model input {_describe(arg)}: {channels} channel(s) on axis {4 - c_axis}, where layout "
                        f"{p.layout} puts the {'width' if p.layout == 'NCHW' else 'height'}",
                        f"layout: {'NHWC' if p.layout == 'NCHW' else 'NCHW'}",
                    )
                )
            elif isinstance(ch, int) and ch != channels:
                problems.append(
                    self._problem(
                        "stacked_input" if p.stacked_input else "channels",
                        f"model input {_describe(arg)}: expected {channels} channel(s) on axis {c_axis} "
                        f"({p.layout}, channels '{p.channels}'{', stacked' if p.stacked_input else ''}), got {ch}",
                    )
                )
            if p.resize is not None:
                hn, wn, hp, wp = network_size(p.resize[0], p.resize[1], p.resize, p.pad_to)
                for axis, size, what in ((h_axis, hp, "height"), (w_axis, wp, "width")):
                    if isinstance(shape[axis], int) and shape[axis] != size:
                        problems.append(
                            self._problem(
                                "resize",
                                f"model input {_describe(arg)} has a fixed {what} of {shape[axis]}, but resize "
                                f"{list(p.resize)} with pad_to {p.pad_to} feeds {size}",
                            )
                        )
        extra = [a for n, a in self.model_inputs.items() if n not in fed]
        if extra:
            problems.append(
                self._problem(
                    "stacked_input" if p.stacked_input else "left_input",
                    f"the model has input(s) the node does not feed: {', '.join(_describe(a) for a in extra)}; "
                    f"it feeds {', '.join(repr(n) for n in fed)}",
                    "a stereo model takes the two images (or one stacked input) only",
                )
            )
        out = self.model_outputs.get(p.output)
        if out is None:
            problems.append(
                self._problem(
                    "output",
                    f"the model has no output {p.output!r}; its outputs: {have_out}",
                    "set output to one of them",
                )
            )
        else:
            if out.type in _INDEX_TYPES:
                problems.append(
                    self._problem(
                        "output",
                        f"model output {_describe(out)}: a {_INDEX_TYPES[out.type]} tensor holds indices or labels, "
                        "not a disparity in pixels: expected a float tensor (or a 16-bit fixed-point one with "
                        "output_factor); cast the output to float in the model",
                    )
                )
            elif out.type not in _OUTPUT_TYPES:
                problems.append(
                    self._problem(
                        "output",
                        f"model output {_describe(out)}: expected a float or integer tensor, got {out.type}",
                    )
                )
            if out.shape is not None and not 2 <= len(out.shape) <= 4:
                problems.append(
                    self._problem(
                        "output",
                        f"model output {_describe(out)}: expected rank 2, 3 or 4 (one HxW map), got rank {len(out.shape)}",
                    )
                )
            elif out.shape is not None:
                lead = out.shape[:-2] if not (p.layout == "NHWC" and len(out.shape) == 4) else out.shape[:1]
                bad = [s for s in lead if isinstance(s, int) and s != 1]
                if bad or (
                    p.layout == "NHWC"
                    and len(out.shape) == 4
                    and isinstance(out.shape[3], int)
                    and out.shape[3] != 1
                ):
                    problems.append(
                        self._problem(
                            "output",
                            f"model output {_describe(out)}: expected one HxW map (leading axes of size 1)",
                        )
                    )
        return problems

    # -- per frame -----------------------------------------------------------------
    def _check_shapes(self, feeds: dict[str, np.ndarray], h: int, w: int) -> None:
        """The fed shapes against the model's fixed sizes (first frame, or a new image size)."""
        hn, wn, hp, wp = network_size(h, w, self.p.resize, self.p.pad_to)
        for name, x in feeds.items():
            shape = self.model_inputs[name].shape
            if all(not isinstance(s, int) or s == n for s, n in zip(shape, x.shape)):
                continue
            fixed = _shape_text(shape)
            hint = (
                "set resize to the model's [height, width]"
                if self.p.resize is None
                else "set resize (and pad_to) so that the network input is the model's size"
            )
            raise InputError(
                f"model input {name!r} has the fixed shape {fixed} ({self.p.layout}); a {h}x{w} image "
                f"(rows x cols) is fed as {_shape_text(x.shape)} (resize {list(self.p.resize) if self.p.resize else None}, "
                f"pad_to {self.p.pad_to}: network input {hp}x{wp}) (hint: {hint})",
                path=str(self.path),
            )

    def __call__(self, left: np.ndarray, right: np.ndarray) -> dict:
        feeds = network_inputs(left, right, self.p)
        h, w = np.shape(left)[:2]
        first = self._checked != (h, w)
        if first:
            self._check_shapes(feeds, h, w)
        feeds = {k: v.astype(_INPUT_TYPES[self.model_inputs[k].type], copy=False) for k, v in feeds.items()}
        try:
            (raw,) = self.session.run([self.p.output], feeds)
        except Exception as exc:  # noqa: BLE001 - ONNX Runtime's errors have no common base
            hn, wn, hp, wp = network_size(h, w, self.p.resize, self.p.pad_to)
            text = str(exc).strip().splitlines()
            raise InputError(
                f"ONNX Runtime failed on a {h}x{w} image fed as {hp}x{wp}: {type(exc).__name__}: "
                f"{text[0] if text else ''} (hint: many networks need sizes that are multiples of 32 or 64: "
                "raise pad_to, or give resize)",
                path=str(self.path),
            ) from None
        if first:
            try:
                d = output_map(raw, self.p.layout)
            except ValueError as exc:
                raise InputError(f"model output {self.p.output!r}: {exc}", path=str(self.path)) from None
            hn, wn, hp, wp = network_size(h, w, self.p.resize, self.p.pad_to)
            ho, wo = d.shape
            if d.dtype.kind not in "fiub" or (d.dtype.kind in "iu" and d.dtype.itemsize > 2):
                raise InputError(
                    f"model output {self.p.output!r} is of dtype {d.dtype}: expected a float disparity (a wider "
                    "integer is an index or a label, not a disparity in pixels); cast it to float in the model",
                    path=str(self.path),
                )
            least_h, least_w = max(2, int(hp * MIN_OUTPUT_FRACTION)), max(2, int(wp * MIN_OUTPUT_FRACTION))
            if ho < least_h or wo < least_w:
                raise InputError(
                    f"model output {self.p.output!r} is a {ho}x{wo} map for a {hp}x{wp} network input: expected "
                    f"a disparity map of at least 1/{round(1 / MIN_OUTPUT_FRACTION)} of the input's size "
                    f"({least_h}x{least_w} here)",
                    path=str(self.path),
                )
            if abs(ho * wp / wo - hp) > wp / wo:
                raise InputError(
                    f"model output {self.p.output!r} is a {ho}x{wo} map for a {hp}x{wp} network input: expected the "
                    "input's size or a fraction of it with the same aspect",
                    path=str(self.path),
                )
            self._checked = (h, w)
        return {"disparity": to_image_disparity(raw, (h, w), self.p)}

    def close(self) -> None:
        """Release the session (and its GPU memory)."""
        self.session = None
