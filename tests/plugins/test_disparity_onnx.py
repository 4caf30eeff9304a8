"""``disparity.onnx`` (plugins/lanegraph_disparity/_onnx.py) with small ONNX models built here.

Two kinds of model, written with ``onnx.helper``: an *affine* one whose output is a known function
of its inputs (``bias + sum_c wl[c] * left[c] + wr[c] * right[c]``), which shows exactly what the
node fed the network (layout, colour order, normalisation, padding); and the *cost volume* of
``lanegraph_disparity.onnx_models`` (SAD over a few shifts, ArgMin), which computes a real
disparity on a synthetic pair with a known shift, so that resizing and the rescaling of the
disparity values to image pixels are checked on the number that matters.
"""

from __future__ import annotations

import importlib
import json
import logging
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from pydantic import ValidationError

onnx = pytest.importorskip("onnx", reason="the onnx extra is not installed (pip install 'lanegraph[onnx]')")
ort = pytest.importorskip(
    "onnxruntime", reason="the onnx extra is not installed (pip install 'lanegraph[onnx]')"
)

import lanegraph_disparity as ld  # noqa: E402
from lanegraph_disparity import _onnx  # noqa: E402
from lanegraph_disparity.onnx_models import IR_VERSION, OPSET, cost_volume_model  # noqa: E402
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from lanegraph import (  # noqa: E402
    GraphError,
    InputError,
    RunContext,
    hookimpl,
    node_type_of,  # noqa: E402
)
from lanegraph.cli import main  # noqa: E402
from lanegraph.plugins import get_plugin_manager  # noqa: E402
from lanegraph.testing import check_node_type, run_node  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
ONNX_GRAPH = str(ROOT / "graphs" / "paper_onnx.yaml")
WHERE = RunContext(graph_file="g.yaml", node_id="disp")

# --------------------------------------------------------------------------- models


def save(model, path: Path) -> str:
    model.ir_version = IR_VERSION
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return str(path)


def make_model(nodes, inputs, outputs, inits=()):
    graph = helper.make_graph(nodes, "test", inputs, outputs, list(inits))
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])


def affine_model(
    path: Path,
    wl,
    wr,
    bias: float = 100.0,
    layout: str = "NCHW",
    stacked: bool = False,
    names=("left", "right"),
    out_name: str = "disparity",
) -> str:
    """``out = bias + sum_c wl[c] * left[c] + wr[c] * right[c]`` (1 x H x W); with ``stacked`` one
    input of 2C channels weighted by ``wl + wr``."""
    c = len(wl)
    c_axis = 1 if layout == "NCHW" else 3

    def dims(ch: int) -> list:
        return [1, ch, "h", "w"] if layout == "NCHW" else [1, "h", "w", ch]

    def weights(name: str, w) -> onnx.TensorProto:
        shape = [1, len(w), 1, 1] if layout == "NCHW" else [1, 1, 1, len(w)]
        return numpy_helper.from_array(np.asarray(w, np.float32).reshape(shape), name)

    inits = [
        numpy_helper.from_array(np.asarray([c_axis], np.int64), "axis"),
        numpy_helper.from_array(np.float32(bias), "bias"),
    ]
    nodes = []
    if stacked:
        inits.append(weights("w", [*wl, *wr]))
        inputs = [helper.make_tensor_value_info(names[0], TensorProto.FLOAT, dims(2 * c))]
        nodes += [
            helper.make_node("Mul", [names[0], "w"], ["x"]),
            helper.make_node("ReduceSum", ["x", "axis"], ["s"], keepdims=0),
        ]
    else:
        inits += [weights("wl", wl), weights("wr", wr)]
        inputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, dims(c)) for n in names]
        nodes += [
            helper.make_node("Mul", [names[0], "wl"], ["xl"]),
            helper.make_node("Mul", [names[1], "wr"], ["xr"]),
            helper.make_node("Add", ["xl", "xr"], ["x"]),
            helper.make_node("ReduceSum", ["x", "axis"], ["s"], keepdims=0),
        ]
    nodes.append(helper.make_node("Add", ["s", "bias"], [out_name]))
    out = helper.make_tensor_value_info(out_name, TensorProto.FLOAT, [1, "h", "w"])
    return save(make_model(nodes, inputs, [out], inits), path)


def add_model(
    path: Path,
    shape_l,
    shape_r=None,
    dtype=TensorProto.FLOAT,
    names=("left", "right"),
    out_shape=None,
    extra=(),
) -> str:
    """``out = left + right`` with the given declared shapes and element type (signature tests)."""
    shape_r = shape_r or shape_l
    inputs = [
        helper.make_tensor_value_info(names[0], dtype, shape_l),
        helper.make_tensor_value_info(names[1], dtype, shape_r),
    ]
    nodes = [
        helper.make_node("Add", list(names), ["sum"]),
        helper.make_node("Cast", ["sum"], ["disparity"], to=TensorProto.FLOAT),
    ]
    for name in extra:
        inputs.append(helper.make_tensor_value_info(name, dtype, shape_l))
        nodes.append(helper.make_node("Identity", [name], [f"{name}_out"]))
    outputs = [helper.make_tensor_value_info("disparity", TensorProto.FLOAT, out_shape or shape_l)]
    outputs += [helper.make_tensor_value_info(f"{n}_out", dtype, shape_l) for n in extra]
    return save(make_model(nodes, inputs, outputs), path)


def fixed_size(model, h: int, w: int):
    """``model`` with its inputs' height and width fixed (NCHW)."""
    for vi in model.graph.input:
        dims = vi.type.tensor_type.shape.dim
        dims[2].dim_value, dims[3].dim_value = h, w
    return model


@pytest.fixture(scope="module")
def cv_model(tmp_path_factory) -> str:
    """The cost volume over 16 shifts, dynamic size."""
    return save(cost_volume_model(16, window=5), tmp_path_factory.mktemp("onnx") / "cv16.onnx")


def shifted_pair(shift: int, h: int = 48, w: int = 96, colour: bool = True, seed: int = 0):
    """A smooth random texture seen with disparity ``shift`` everywhere: ``right[:, x] == left[:, x + shift]``."""
    rng = np.random.default_rng(seed)
    tw = w + shift
    shape = (h // 4, tw // 4, 3) if colour else (h // 4, tw // 4)
    tex = cv2.resize(rng.integers(0, 256, shape, dtype=np.uint8), (tw, h), interpolation=cv2.INTER_CUBIC)
    return np.ascontiguousarray(tex[:, :w]), np.ascontiguousarray(tex[:, shift : shift + w])


def disparity(model: str, left, right, **params) -> np.ndarray:
    params.setdefault("providers", "cpu")
    out = run_node("disparity.onnx", {"left": left, "right": right}, model=model, **params)["disparity"]
    assert out.dtype == np.float32 and out.shape == left.shape[:2]
    assert np.all(np.isfinite(out)) and np.all(out >= 0)
    return out


def open_node(model: str, **params) -> _onnx.OnnxDisparity:
    params.setdefault("providers", "cpu")
    return ld.OnnxDisparity(ld.OnnxParams(model=model, **params), WHERE)


def normalised(img: np.ndarray, channels: str, scale: float, mean, std) -> np.ndarray:
    """The reference pre-processing: HxWxC float64 in the network's channel order."""
    x = img[:, :, None] if img.ndim == 2 else img
    if channels == "rgb":
        x = x[:, :, ::-1]
    if channels in ("rgb", "bgr") and x.shape[2] == 1:
        x = np.repeat(x, 3, axis=2)
    return (x.astype(np.float64) * scale - np.asarray(mean, np.float64)) / np.asarray(std, np.float64)


# --------------------------------------------------------------------------- what the network is fed


@pytest.mark.parametrize("layout", ["NCHW", "NHWC"])
@pytest.mark.parametrize("channels", ["rgb", "bgr", "gray"])
@pytest.mark.parametrize("stacked", [False, True])
def test_layout_channels_and_normalisation_reach_the_network(tmp_path, layout, channels, stacked):
    rng = np.random.default_rng(3)
    colour = channels != "gray"
    shape = (13, 17, 3) if colour else (13, 17)
    left, right = (rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(2))
    n = 3 if colour else 1
    wl, wr = [0.5, -1.25, 2.0][:n], [-0.75, 1.5, 0.25][:n]
    names = ("pair", "unused") if stacked else ("im_left", "im_right")
    model = affine_model(tmp_path / "affine.onnx", wl, wr, layout=layout, stacked=stacked, names=names)
    mean, std = ([10.0, 20.0, 30.0], [2.0, 4.0, 8.0]) if colour else ([5.0], [3.0])
    wiring = {"stacked_input": "pair"} if stacked else {"left_input": "im_left", "right_input": "im_right"}
    out = disparity(
        model,
        left,
        right,
        channels=channels,
        layout=layout,
        pixel_scale=0.5,
        mean=mean,
        std=std,
        pad_to=1,
        output_unit="image_pixels",
        max_disparity=8192,
        **wiring,
    )
    xl, xr = normalised(left, channels, 0.5, mean, std), normalised(right, channels, 0.5, mean, std)
    expected = 100.0 + (xl * wl).sum(axis=2) + (xr * wr).sum(axis=2)
    np.testing.assert_allclose(out, expected, rtol=0, atol=2e-3)


def test_gray_images_are_repeated_for_a_colour_network(tmp_path):
    rng = np.random.default_rng(4)
    left, right = (rng.integers(0, 256, (9, 11), dtype=np.uint8) for _ in range(2))
    model = affine_model(tmp_path / "affine.onnx", [1.0, 2.0, 3.0], [0.0, 0.0, -1.0])
    out = disparity(model, left, right, pad_to=1, output_unit="image_pixels", max_disparity=8192)
    expected = 100.0 + (
        normalised(left, "rgb", 1 / 255, [0.485, 0.456, 0.406], [0.229, 0.224, 0.225]) * [1, 2, 3]
    ).sum(2)
    expected -= normalised(right, "rgb", 1 / 255, [0.485, 0.456, 0.406], [0.229, 0.224, 0.225])[:, :, 2]
    np.testing.assert_allclose(out, expected, rtol=0, atol=2e-3)


def test_padding_goes_on_top_and_on_the_right_and_is_cut_off(tmp_path):
    rng = np.random.default_rng(5)
    left, right = (rng.integers(0, 256, (37, 53, 3), dtype=np.uint8) for _ in range(2))
    params = ld.OnnxParams(pad_to=16, mean=[0.5], std=[0.25])
    feeds = _onnx.network_inputs(left, right, params)
    x = feeds["left"]
    assert x.shape == (1, 3, 48, 64) and x.dtype == np.float32
    assert np.all(x[0, :, :11, :] == 0) and np.all(x[0, :, :, 53:] == 0)  # 11 rows on top, 11 columns right
    np.testing.assert_allclose(
        x[0, :, 11:, :53].transpose(1, 2, 0), normalised(left, "rgb", 1 / 255, [0.5], [0.25]), atol=1e-5
    )
    # the output of the padded input, cut back: the pointwise function of the image, no row or column off
    model = affine_model(tmp_path / "affine.onnx", [1.0, -2.0, 0.5], [0.25, 1.0, -1.0])
    out = disparity(
        model, left, right, pad_to=16, mean=[0.5], std=[0.25], output_unit="image_pixels", max_disparity=8192
    )
    xl, xr = normalised(left, "rgb", 1 / 255, [0.5], [0.25]), normalised(right, "rgb", 1 / 255, [0.5], [0.25])
    expected = 100.0 + (xl * [1.0, -2.0, 0.5]).sum(2) + (xr * [0.25, 1.0, -1.0]).sum(2)
    np.testing.assert_allclose(out, expected, rtol=0, atol=2e-3)


# --------------------------------------------------------------------------- a real disparity


def interior_error(d: np.ndarray, shift: float, border: int = 6) -> tuple[float, float]:
    """(median |d - shift|, fraction within 0.5 px) away from the borders and the left strip without a match."""
    v = d[border:-border, 24:-border]
    return float(np.median(np.abs(v - shift))), float(np.mean(np.abs(v - shift) <= 0.5))


@pytest.mark.parametrize(
    "params, shift, expected",
    [
        ({}, 6, 6.0),  # the image's size, padded from 48x96 to 64x96
        ({"pad_to": 1}, 6, 6.0),
        ({"pad_to": 7}, 5, 5.0),  # 49x98: padding of one row and two columns
        ({"resize": (24, 48)}, 8, 8.0),  # half size: 4 px at the network, x2 back
        ({"resize": (24, 48), "interpolation": "nearest"}, 8, 8.0),
        ({"resize": (72, 144), "pad_to": 16}, 6, 6.0),  # 1.5 x: 9 px at the network, / 1.5 back
        (
            {"resize": (24, 48), "output_unit": "image_pixels"},
            8,
            4.0,
        ),  # said to be image pixels: not rescaled
        ({"resize": (24, 48), "pad_to": 16, "channels": "gray", "mean": [0.45], "std": [0.225]}, 8, 8.0),
    ],
)
def test_cost_volume_recovers_the_shift_in_image_pixels(tmp_path, params, shift, expected):
    channels = params.get("channels", "rgb")
    model = cost_volume_model(16, channels=1 if channels == "gray" else 3)
    path = save(model, tmp_path / "cv.onnx")
    left, right = shifted_pair(shift)
    d = disparity(path, left, right, **params)
    median, within = interior_error(d, expected)
    assert median < 0.01 and within >= 0.98, (median, within)


def test_a_smaller_output_map_in_output_pixels(tmp_path):
    """A network matching at half resolution outputs a half-size map in its own pixels."""
    path = save(cost_volume_model(8, downsample=2), tmp_path / "half.onnx")
    left, right = shifted_pair(8, h=64, w=128)
    d = disparity(path, left, right, output_unit="output_pixels")
    assert interior_error(d, 8.0)[1] >= 0.95
    d = disparity(path, left, right, output_unit="network_pixels")  # the wrong unit: half the shift
    assert interior_error(d, 4.0)[1] >= 0.95


@pytest.mark.parametrize(
    "bias, factor, max_disparity, expected",
    [
        (-100.0, -1.0, 192.0, 100.0),  # a flow network: minus the disparity
        (-100.0, 1.0, 192.0, 0.0),  # negative: invalid
        (100.0, 1.0, 99.0, 0.0),  # above max_disparity: invalid
        (100.0, 1.0, 100.0, 100.0),
        (300.0, 0.5, 192.0, 150.0),
        (float("nan"), 1.0, 192.0, 0.0),
        (float("inf"), 1.0, 8192.0, 0.0),
    ],
)
def test_output_factor_and_the_valid_range(tmp_path, bias, factor, max_disparity, expected):
    model = affine_model(tmp_path / "const.onnx", [0.0] * 3, [0.0] * 3, bias=bias)
    left, right = shifted_pair(2, h=20, w=30)
    d = disparity(
        model, left, right, output_factor=factor, max_disparity=max_disparity, output_unit="image_pixels"
    )
    assert np.all(d == np.float32(expected))


def test_session_is_reused_for_every_frame(cv_model, monkeypatch):
    made = []

    class Counting(ort.InferenceSession):
        def __init__(self, *args, **kwargs):
            made.append(args[0])
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(ort, "InferenceSession", Counting)
    node = open_node(cv_model)
    for shift in (3, 5, 7):
        left, right = shifted_pair(shift, seed=shift)
        assert interior_error(node(left=left, right=right)["disparity"], shift)[0] == 0.0
    assert made == [cv_model]


def test_conformance(cv_model):
    left, right = shifted_pair(4, h=24, w=40)
    check_node_type(ld.OnnxDisparity, {"left": left, "right": right}, {"model": cv_model, "providers": "cpu"})


# --------------------------------------------------------------------------- errors when the run opens


def problems_of(exc: GraphError) -> list[str]:
    return [str(p) for p in exc.problems]


@pytest.mark.parametrize(
    "build, params, field, words",
    [
        (
            lambda p: add_model(p, [1, 3, "h", "w"], names=("a", "b")),
            {},
            "params.left_input",
            ["the model has no input 'left'", "its inputs: 'a' (tensor(float) [1, 3, h, w])"],
        ),
        (lambda p: add_model(p, [1, 3, "h"]), {}, "params.left_input", ["expected rank 4", "got rank 3"]),
        (
            lambda p: add_model(p, [1, 3, "h", "w"], dtype=TensorProto.INT64),
            {},
            "params.left_input",
            ["expected a float tensor", "tensor(int64)"],
        ),
        (lambda p: add_model(p, [2, 3, "h", "w"]), {}, "params.left_input", ["expected a batch of 1, got 2"]),
        (
            lambda p: add_model(p, [1, 1, "h", "w"]),
            {},
            "params.channels",
            ["expected 3 channel(s) on axis 1", "got 1"],
        ),
        (
            lambda p: add_model(p, [1, 3, "h", "w"]),
            {"channels": "gray", "mean": [0.5], "std": [0.25]},
            "params.channels",
            ["expected 1 channel(s)"],
        ),
        (
            lambda p: add_model(p, [1, "h", "w", 3], out_shape=[1, "h", "w", 1]),
            {},
            "params.layout",
            ["3 channel(s) on axis 3", "hint: layout: NHWC"],
        ),
        (
            lambda p: add_model(p, [1, 3, "h", "w"], extra=("confidence",)),
            {},
            "params.left_input",
            ["input(s) the node does not feed: 'confidence'"],
        ),
        (
            lambda p: add_model(p, [1, 3, "h", "w"]),
            {"output": "disp"},
            "params.output",
            ["the model has no output 'disp'", "its outputs: 'disparity'"],
        ),
        (
            lambda p: add_model(p, [1, 3, "h", "w"]),
            {},
            "params.output",
            ["expected one HxW map"],
        ),  # 1x3xHxW out
        (
            lambda p: add_model(p, [1, 3, 32, 48]),
            {"resize": (30, 50), "pad_to": 1},
            "params.resize",
            ["fixed height of 32", "feeds 30"],
        ),
        (
            lambda p: add_model(p, [1, 6, "h", "w"], [1, 6, "h", "w"], names=("pair", "x")),
            {"stacked_input": "pair"},
            "params.stacked_input",
            ["input(s) the node does not feed: 'x'"],
        ),
    ],
)
def test_model_with_the_wrong_signature_is_refused_when_the_run_opens(tmp_path, build, params, field, words):
    model = build(tmp_path / "bad.onnx")
    with pytest.raises(GraphError) as info:
        open_node(model, **params)
    text = str(info.value)
    assert f"g.yaml: node 'disp' (disparity.onnx): {field}: " in text, text
    for w in words:
        assert w in text, text


def test_every_signature_problem_is_reported_at_once(tmp_path):
    model = add_model(tmp_path / "bad.onnx", [1, 1, "h", "w"], names=("a", "right"))
    with pytest.raises(GraphError) as info:
        open_node(model, output="out")
    fields = sorted(p.field for p in info.value.problems)
    assert fields == ["params.channels", "params.left_input", "params.left_input", "params.output"], (
        problems_of(info.value)
    )


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda d: "", ["params.model: no model given", "hint: --set disp.model=path/to/model.onnx"]),
        (lambda d: str(d / "nope.onnx"), ["params.model: model file not found", "nope.onnx"]),
        (lambda d: str(d), ["params.model: model file is not a file"]),
        (
            lambda d: (
                (d / "junk.onnx").write_bytes(b"\x08\x07not a protobuf at all") and str(d / "junk.onnx")
            ),
            ["params.model: cannot load", "junk.onnx as an ONNX model"],
        ),
    ],
)
def test_missing_or_unreadable_model_is_located(tmp_path, make, words):
    with pytest.raises(GraphError) as info:
        open_node(make(tmp_path))
    for w in words:
        assert w in str(info.value), str(info.value)


def test_a_relative_model_path_is_relative_to_the_working_directory(tmp_path, monkeypatch, cv_model):
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "m.onnx").write_bytes(Path(cv_model).read_bytes())
    monkeypatch.chdir(tmp_path)
    left, right = shifted_pair(5)
    assert interior_error(disparity("models/m.onnx", left, right), 5)[0] == 0.0


def test_without_onnxruntime_the_node_says_how_to_install_it(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # `import onnxruntime` raises ImportError
    with pytest.raises(GraphError) as info:
        open_node("")
    text = str(info.value)
    assert "params.model: no model given" in text  # every problem at once
    assert "needs ONNX Runtime (the onnxruntime package), which is not installed" in text
    assert 'pip install "lanegraph[onnx]"' in text


def test_plugin_imports_and_lists_the_node_without_onnxruntime(monkeypatch):
    for name in ("onnxruntime", "onnx"):
        monkeypatch.setitem(sys.modules, name, None)
    for name in ("lanegraph_disparity", "lanegraph_disparity._onnx", "lanegraph_disparity.onnx_models"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    fresh = importlib.import_module("lanegraph_disparity")
    assert fresh is not ld
    assert "disparity.onnx" in [node_type_of(t).name for t in fresh.lanegraph_node_types()]
    r = CliRunner().invoke(main, ["nodes"])
    assert r.exit_code == 0
    assert "disparity.onnx  [lanegraph_disparity] (stateful)" in r.output
    assert 'needs `pip install "lanegraph[onnx]"`' in r.output


# --------------------------------------------------------------------------- providers


def test_auto_falls_back_to_the_cpu_and_says_so_once(cv_model, monkeypatch, caplog):
    monkeypatch.setattr(ort, "get_available_providers", lambda: ["CPUExecutionProvider"])
    with caplog.at_level(logging.INFO, logger="lanegraph.disparity.onnx"):
        node = open_node(cv_model, providers="auto")
        left, right = shifted_pair(4)
        for _ in range(2):
            node(left=left, right=right)
    said = [r for r in caplog.records if r.name == "lanegraph.disparity.onnx"]
    assert len(said) == 1 and said[0].levelno == logging.WARNING
    assert "disp: providers auto: this ONNX Runtime has no CUDA provider" in said[0].getMessage()
    assert "on the CPU" in said[0].getMessage()
    assert node.provider == "CPUExecutionProvider"


def test_cpu_says_nothing(cv_model, caplog):
    with caplog.at_level(logging.INFO, logger="lanegraph.disparity.onnx"):
        node = open_node(cv_model, providers="cpu")
    assert node.provider == "CPUExecutionProvider" and not caplog.records


def test_cuda_without_a_cuda_provider_is_refused(cv_model, monkeypatch):
    monkeypatch.setattr(ort, "get_available_providers", lambda: ["CPUExecutionProvider"])
    with pytest.raises(GraphError) as info:
        open_node(cv_model, providers="cuda")
    text = str(info.value)
    assert "params.providers: 'cuda': this ONNX Runtime" in text and "has no CUDA provider" in text
    assert "onnxruntime-gpu" in text


@pytest.mark.parametrize("providers", ["auto", "cuda"])
def test_a_cuda_provider_that_does_not_start_is_noticed(cv_model, monkeypatch, caplog, providers):
    """ONNX Runtime said it has CUDA, but the session came up on the CPU (libraries missing)."""
    asked = []

    class Spy(ort.InferenceSession):
        def __init__(self, path, sess_options=None, providers=None, **kwargs):
            asked.append(providers)
            with warnings.catch_warnings():  # ONNX Runtime warns that it has no CUDA provider
                warnings.simplefilter("ignore")
                super().__init__(path, sess_options=sess_options, providers=providers, **kwargs)

    monkeypatch.setattr(ort, "InferenceSession", Spy)
    monkeypatch.setattr(
        ort, "get_available_providers", lambda: ["CUDAExecutionProvider", "CPUExecutionProvider"]
    )
    if providers == "cuda":
        with pytest.raises(
            GraphError, match=r"params.providers: 'cuda': the CUDA provider did not start on device 1"
        ):
            open_node(cv_model, providers="cuda", device=1)
    else:
        with caplog.at_level(logging.INFO, logger="lanegraph.disparity.onnx"):
            node = open_node(cv_model, providers="auto", device=1)
        assert node.provider == "CPUExecutionProvider"
        assert [r.getMessage() for r in caplog.records] == [
            f"disp: providers auto: the CUDA provider did not start; running {cv_model} on the CPU"
        ]
    assert asked == [[("CUDAExecutionProvider", {"device_id": 1}), "CPUExecutionProvider"]]


def test_a_slow_load_says_what_the_run_waits_for(cv_model, monkeypatch, caplog):
    class Slow(ort.InferenceSession):
        def __init__(self, *args, **kwargs):
            time.sleep(0.3)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(ort, "InferenceSession", Slow)
    monkeypatch.setattr(_onnx, "SLOW_LOAD_S", 0.05)
    with caplog.at_level(logging.INFO, logger="lanegraph.disparity.onnx"):
        open_node(cv_model)
    assert [r.getMessage() for r in caplog.records] == [
        f"disp: loading {cv_model} into ONNX Runtime (CPU) ..."
    ]


def test_a_quick_load_says_nothing(cv_model, caplog):
    with caplog.at_level(logging.INFO, logger="lanegraph.disparity.onnx"):
        open_node(cv_model)
        time.sleep(0.05)
    assert not caplog.records


# --------------------------------------------------------------------------- errors at the first frame


def test_fixed_size_model_and_the_image_at_the_first_frame(tmp_path):
    path = save(fixed_size(cost_volume_model(12), 32, 48), tmp_path / "fixed.onnx")
    left, right = shifted_pair(10, h=40, w=60)
    node = open_node(path)
    with pytest.raises(InputError) as info:
        node(left=left, right=right)
    text = str(info.value)
    assert text.startswith(f"{path}: model input 'left' has the fixed shape [1, 3, 32, 48] (NCHW)")
    assert "a 40x60 image (rows x cols) is fed as [1, 3, 64, 64]" in text
    assert "hint: set resize to the model's [height, width]" in text
    # resized to the model's size: 40x60 -> 32x48, 8 px at the network, back to 10
    d = disparity(path, left, right, resize=(32, 48), pad_to=16)
    assert interior_error(d, 10.0)[1] >= 0.95


def test_onnx_runtime_failing_on_the_input_is_an_input_error(tmp_path):
    """A network that only works at one size although its inputs are declared dynamic."""
    inits = [numpy_helper.from_array(np.zeros((1, 1, 32, 32), np.float32), "fixed")]
    inputs = [
        helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, 3, "h", "w"]) for n in ("left", "right")
    ]
    nodes = [
        helper.make_node("Add", ["left", "fixed"], ["s"]),
        helper.make_node("ReduceMean", ["s"], ["disparity"], axes=[1], keepdims=0),
    ]
    model = make_model(
        nodes, inputs, [helper.make_tensor_value_info("disparity", TensorProto.FLOAT, [1, "h", "w"])], inits
    )
    model.opset_import[0].version = 13
    path = save(model, tmp_path / "only32.onnx")
    left, right = shifted_pair(2, h=40, w=60)
    with pytest.raises(
        InputError, match=r"ONNX Runtime failed on a 40x60 image fed as 64x64: .*raise pad_to, or give resize"
    ):
        open_node(path)(left=left, right=right)
    assert disparity(path, *shifted_pair(2, h=32, w=32), output_unit="image_pixels").shape == (32, 32)


def test_an_output_that_is_not_the_input_map_is_an_input_error(tmp_path):
    inputs = [
        helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, 3, "h", "w"]) for n in ("left", "right")
    ]
    nodes = [
        helper.make_node("ReduceMean", ["left"], ["m"], axes=[1], keepdims=0),
        helper.make_node("Transpose", ["m"], ["disparity"], perm=[0, 2, 1]),
    ]
    model = make_model(
        nodes, inputs, [helper.make_tensor_value_info("disparity", TensorProto.FLOAT, [1, "w", "h"])]
    )
    model.opset_import[0].version = 13
    path = save(model, tmp_path / "transposed.onnx")
    with pytest.raises(
        InputError, match=r"model output 'disparity' is a 96x64 map for a 64x96 network input"
    ):
        open_node(path)(left=shifted_pair(2)[0], right=shifted_pair(2)[1])


def test_images_the_node_cannot_take(cv_model):
    node = open_node(cv_model)
    left, right = shifted_pair(2)
    with pytest.raises(InputError, match="left and right images differ in size"):
        node(left=left, right=right[:, :-2])
    with pytest.raises(
        InputError, match=r"input 'right': expected an HxW gray or HxWx3 BGR image, got shape \(48, 96, 2\)"
    ):
        node(left=left, right=right[:, :, :2])


# --------------------------------------------------------------------------- params


@pytest.mark.parametrize(
    "values, message",
    [
        ({"mean": [0.1, 0.2]}, "mean: 2 values for 3 channel(s)"),
        ({"channels": "gray"}, "mean: 3 values for 1 channel(s) of channels 'gray' (e.g. [0.449])"),
        ({"std": [0.2, 0.0, 0.2]}, "std: expected values in 1e-6..1e4"),
        (
            {"mean": [float("nan")]},
            "finite number",
        ),  # every float param: NaN and infinities refused (NodeParams)
        ({"resize": (4, 100)}, "resize: expected [height, width], each 8..8192 pixels, got [4, 100]"),
        ({"resize": (100,)}, "resize"),
        ({"output_factor": 0.0}, "output_factor: expected a non-zero factor"),
        ({"right_input": "left"}, "left_input and right_input are both 'left'"),
        ({"pad_to": 0}, "pad_to"),
        ({"providers": "gpu"}, "providers"),
        ({"layout": "CHW"}, "layout"),
    ],
)
def test_params_reject_bad_values_with_a_clear_message(values, message):
    with pytest.raises(ValidationError) as info:
        ld.OnnxParams(**values)
    assert message in str(info.value), str(info.value)


def test_stacked_input_may_share_the_default_names():
    assert ld.OnnxParams(stacked_input="pair", left_input="x", right_input="x").stacked_input == "pair"


# --------------------------------------------------------------------------- in a graph, in place of SGBM


class _Spy:
    """Keeps the source's and the disparity node's outputs per frame."""

    def __init__(self) -> None:
        self.outputs: dict[str, dict] = {}

    @hookimpl
    def lanegraph_after_node(self, node_id, frame, outputs):
        if frame is not None and outputs and node_id in ("src", "disp"):
            self.outputs.setdefault(frame, {})[node_id] = outputs


def test_graph_run_with_the_node_in_place_of_sgbm(tmp_path, monkeypatch):
    """graphs/paper_onnx.yaml on the synthetic scene, with the cost volume at half resolution:
    one session for the run, and a disparity that matches the scene's exact one on the road."""
    model = save(cost_volume_model(48, window=5), tmp_path / "cv48.onnx")
    made = []

    class Counting(ort.InferenceSession):
        def __init__(self, *args, **kwargs):
            made.append(args[0])
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(ort, "InferenceSession", Counting)
    pm, spy = get_plugin_manager(), _Spy()
    pm.register(spy)
    try:
        r = CliRunner().invoke(
            main,
            [
                "run",
                ONNX_GRAPH,
                "--out",
                str(tmp_path / "out"),
                "--frames",
                "0:3",
                "--quiet",
                "--set",
                f"disp.model={model}",
                "--set",
                "disp.resize=[188, 622]",
                "--set",
                "disp.providers=cpu",
            ],
        )
    finally:
        pm.unregister(spy)
    assert r.exit_code == 0, r.output
    assert made == [model]
    timings = json.loads((tmp_path / "out" / "timings.json").read_text())
    assert timings["frames"] == 3 and timings["nodes"]["disp"]["type"] == "disparity.onnx"
    assert timings["nodes"]["disp"]["calls"] == 3
    assert len((tmp_path / "out" / "lanes.jsonl").read_text().splitlines()) == 3
    # the summary line names the files the run wrote, and only those (not the model's output "disparity")
    line = next(ln for ln in r.output.splitlines() if "frame(s) processed -> " in ln)
    named = line.split(" -> ", 1)[1].split(" (median")[0].split(", ")
    assert str(tmp_path / "out" / "lanes.jsonl") in named
    assert all(Path(f).is_file() for f in named), named
    assert len(spy.outputs) == 3
    for frame, out in spy.outputs.items():
        d, gt, road = out["disp"]["disparity"], out["src"]["gt_disparity"], out["src"]["gt_road_mask"]
        assert d.shape == gt.shape
        err = np.abs(d - gt)[road & (gt > 0)]
        assert np.median(err) < 0.75 and np.mean(err < 1.0) > 0.75, (
            frame,
            np.median(err),
            np.mean(err < 1.0),
        )


def test_onnx_graph_without_a_model_exits_2_before_any_frame(tmp_path):
    r = CliRunner().invoke(main, ["run", ONNX_GRAPH, "--out", str(tmp_path / "out"), "--quiet"])
    assert r.exit_code == 2, r.output
    assert "paper_onnx.yaml: node 'disp' (disparity.onnx): params.model: no model given" in r.output
    assert "hint: --set disp.model=path/to/model.onnx" in r.output
    assert (
        not (tmp_path / "out" / "lanes.jsonl").exists() or not (tmp_path / "out" / "lanes.jsonl").read_text()
    )


def test_onnx_graph_with_a_model_of_other_inputs_exits_2(tmp_path):
    model = add_model(tmp_path / "ab.onnx", [1, 3, "h", "w"], names=("a", "b"), out_shape=[1, "h", "w"])
    r = CliRunner().invoke(
        main, ["run", ONNX_GRAPH, "--out", str(tmp_path / "out"), "--quiet", "--set", f"disp.model={model}"]
    )
    assert r.exit_code == 2, r.output
    assert "node 'disp' (disparity.onnx): params.left_input: the model has no input 'left'" in r.output
    assert "params.right_input: the model has no input 'right'" in r.output


def test_onnx_graph_with_a_fixed_size_model_fails_on_the_first_frame(tmp_path):
    model = save(fixed_size(cost_volume_model(4), 32, 48), tmp_path / "fixed.onnx")
    r = CliRunner().invoke(
        main,
        [
            "run",
            ONNX_GRAPH,
            "--out",
            str(tmp_path / "out"),
            "--quiet",
            "--frames",
            "0:2",
            "--set",
            f"disp.model={model}",
        ],
    )
    assert r.exit_code == 1, r.output
    assert "node 'disp' (disparity.onnx) failed on frame 0000000000: InputError:" in r.output
    assert "model input 'left' has the fixed shape [1, 3, 32, 48]" in r.output


@pytest.mark.parametrize("elem", [TensorProto.INT64, TensorProto.INT32])
def test_an_integer_index_output_is_refused_when_the_run_opens(tmp_path, elem):
    """Issue 31, item 9: an int64 output was taken as a disparity; the only sign was a road
    invalid on every frame."""
    inputs = [
        helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, 3, "h", "w"]) for n in ("left", "right")
    ]
    nodes = [
        helper.make_node("ReduceMean", ["left"], ["m"], axes=[1], keepdims=0),
        helper.make_node("Cast", ["m"], ["disparity"], to=elem),
    ]
    model = make_model(nodes, inputs, [helper.make_tensor_value_info("disparity", elem, [1, "h", "w"])])
    model.opset_import[0].version = 13
    path = save(model, tmp_path / "index.onnx")
    with pytest.raises(GraphError) as info:
        open_node(path)
    text = str(info.value)
    assert "node 'disp' (disparity.onnx): params.output: model output 'disparity'" in text, text
    assert "holds indices or labels, not a disparity in pixels" in text, text


def test_a_one_pixel_output_is_refused_at_the_first_frame(tmp_path):
    """Issue 31, item 9: a 1x1 output passed the aspect check and became a constant disparity."""
    inputs = [
        helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, 3, "h", "w"]) for n in ("left", "right")
    ]
    nodes = [helper.make_node("ReduceMean", ["left"], ["disparity"], axes=[1, 2, 3], keepdims=1)]
    model = make_model(
        nodes, inputs, [helper.make_tensor_value_info("disparity", TensorProto.FLOAT, [1, 1, 1, 1])]
    )
    model.opset_import[0].version = 13
    path = save(model, tmp_path / "one.onnx")
    left, right = shifted_pair(2)
    with pytest.raises(InputError) as info:
        open_node(path)(left=left, right=right)
    text = str(info.value)
    assert text.startswith(f"{path}: model output 'disparity' is a 1x1 map for a 64x96 network input"), text
    assert "at least 1/16 of the input's size (4x6 here)" in text, text
