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
from typing import Any

import numpy as np

from lanegraph import GraphError, InputError, Problem, RunContext, node_type

from ._onnx_params import OnnxParams
from ._onnx_tensors import (  # noqa: F401 - the node's steps, and the tests' names in this module
    network_inputs,
    network_size,
    output_map,
    prepare_image,
    to_image_disparity,
    to_network_channels,
)

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
