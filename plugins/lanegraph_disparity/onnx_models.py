"""Small stereo networks written with ``onnx.helper``, for ``disparity.onnx`` without a trained network.

:func:`cost_volume_model` is block matching as an ONNX graph: the tests, ``benchmarks/bench_disparity.py``
and the docs use it to run the node end to end. It needs the ``onnx`` package (the ``onnx`` extra),
imported when a model is built.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: opset and IR version of the models built here: read by every ONNX Runtime since 1.13
OPSET = 17
IR_VERSION = 8


def cost_volume_model(
    num_disparities: int = 16,
    window: int = 5,
    channels: int = 3,
    left: str = "left",
    right: str = "right",
    output: str = "disparity",
    downsample: int = 1,
) -> Any:
    """A stereo "network" that computes a real disparity: a SAD cost volume and winner-take-all.

    For each shift ``d`` in ``0 .. num_disparities - 1`` the right image, padded on the left by
    zeros, is shifted right by ``d`` (Pad, Slice); the cost is the sum over the channels of
    ``|left - shifted right|`` (Sub, Abs, ReduceSum), averaged over a ``window x window`` box
    (AveragePool); the disparity is the shift of least cost (Concat, ArgMin), as float. With
    ``downsample`` > 1 both images are first averaged over ``downsample x downsample`` blocks
    (AveragePool with that stride), as networks that output a reduced-resolution map.

    Parameters
    ----------
    num_disparities : int
        Number of shifts tried, 1..512.
    window : int
        Side of the averaging box, pixels (odd).
    channels : int
        Channels of each input image (3 colour, 1 grey).
    left, right, output : str
        Names of the inputs and of the output.
    downsample : int
        Resolution divisor of the matching and of the output map, 1..8.

    Returns
    -------
    onnx.ModelProto
        Inputs ``left`` and ``right``: float 1 x channels x H x W (H and W dynamic); output
        ``disparity``: float 1 x H x W (1 x H/downsample x W/downsample), integer values in
        pixels of the map it is (0 where the zero padding wins, at the left border).
    """
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    if not 1 <= num_disparities <= 512:
        raise ValueError(f"num_disparities: expected 1..512, got {num_disparities}")
    if not 1 <= downsample <= 8:
        raise ValueError(f"downsample: expected 1..8, got {downsample}")
    if window < 1 or window % 2 == 0:
        raise ValueError(f"window: expected an odd number of pixels, got {window}")
    inits = []

    def const(name: str, values: list[int]) -> str:
        inits.append(numpy_helper.from_array(np.asarray(values, np.int64), name))
        return name

    n = num_disparities
    a, b = left, right  # the images matched
    nodes = []
    if downsample > 1:
        k = [downsample, downsample]
        a, b = "left_small", "right_small"
        nodes += [
            helper.make_node("AveragePool", [left], [a], kernel_shape=k, strides=k),
            helper.make_node("AveragePool", [right], [b], kernel_shape=k, strides=k),
        ]
    nodes.append(helper.make_node("Pad", [b, const("pads", [0, 0, 0, n, 0, 0, 0, 0])], ["right_padded"]))
    axes_w, axes_c = const("axis_w", [3]), const("axis_c", [1])
    r = window // 2
    costs = []
    for d in range(n):
        # right_padded[..., n - d : W + n - d] is the right image shifted right by d
        end = const(f"end{d}", [-d if d else np.iinfo(np.int64).max])
        nodes += [
            helper.make_node(
                "Slice", ["right_padded", const(f"start{d}", [n - d]), end, axes_w], [f"shifted{d}"]
            ),
            helper.make_node("Sub", [a, f"shifted{d}"], [f"diff{d}"]),
            helper.make_node("Abs", [f"diff{d}"], [f"abs{d}"]),
            helper.make_node("ReduceSum", [f"abs{d}", axes_c], [f"sad{d}"], keepdims=1),
            helper.make_node(
                "AveragePool",
                [f"sad{d}"],
                [f"cost{d}"],
                kernel_shape=[window, window],
                pads=[r, r, r, r],
                count_include_pad=0,
            ),
        ]
        costs.append(f"cost{d}")
    nodes += [
        helper.make_node("Concat", costs, ["volume"], axis=1),
        helper.make_node("ArgMin", ["volume"], ["best"], axis=1, keepdims=0),
        helper.make_node("Cast", ["best"], [output], to=TensorProto.FLOAT),
    ]
    out_size = ["height", "width"] if downsample == 1 else ["out_height", "out_width"]
    graph = helper.make_graph(
        nodes,
        "cost_volume",
        [
            helper.make_tensor_value_info(left, TensorProto.FLOAT, [1, channels, "height", "width"]),
            helper.make_tensor_value_info(right, TensorProto.FLOAT, [1, channels, "height", "width"]),
        ],
        [helper.make_tensor_value_info(output, TensorProto.FLOAT, [1, *out_size])],
        inits,
    )
    model = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="lanegraph"
    )
    model.ir_version = IR_VERSION
    onnx.checker.check_model(model)
    return model
