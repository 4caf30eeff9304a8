"""lanegraph.testing, the plugin authors' kit."""

from __future__ import annotations

import lanegraph_image
import numpy as np
import pytest

from lanegraph import NodeParams, node_type
from lanegraph.testing import check_node_type, make_bev_image, make_disparity, make_stereo_pair, run_node


def test_fixture_has_no_autoloaded_plugins(lanegraph_pm):
    assert lanegraph_pm.node_types == {}
    lanegraph_pm.register(lanegraph_image)
    assert set(lanegraph_pm.node_types) == {"image.gray", "image.blur", "image.rectify"}


def test_run_node_validates_params_and_inputs(lanegraph_pm):
    lanegraph_pm.register(lanegraph_image)
    img = np.full((4, 5, 3), 100, np.uint8)
    out = run_node("image.gray", {"image": img}, pm=lanegraph_pm, dtype="float32")
    assert out["image"].dtype == np.float32 and out["image"].shape == (4, 5)
    with pytest.raises(Exception, match="dtype"):
        run_node("image.gray", {"image": img}, pm=lanegraph_pm, dtype="int7")
    with pytest.raises(TypeError, match="unknown input"):
        run_node("image.gray", {"imag": img}, pm=lanegraph_pm)


def test_factories_have_known_answers():
    left, right, calib = make_stereo_pair(disparity=5)
    assert np.array_equal(left[:, 5:], right[:, :-5])  # left (r, x) is right (r, x - d): d > 0
    disp, calib = make_disparity(pitch_deg=0.0, cam_height=1.5)
    v = int(calib.cy) + 10
    assert disp[v, 3] == pytest.approx(calib.baseline / 1.5 * (v - calib.cy), rel=1e-5)
    assert (disp[: int(calib.cy)] == 0).all()
    bev = make_bev_image(lane_cols=(40.0,), width_px=3)
    assert bev[-1, 40] > 150 and bev[-1, 80] < 120


def test_conformance_passes_for_builtin_nodes():
    img = make_bev_image()
    check_node_type(lanegraph_image.gray, {"image": np.dstack([img] * 3)})
    check_node_type(lanegraph_image.blur, {"image": img}, {"ksize": 3})


class _Loose(NodeParams):
    k: int = 3  # no description, no bounds


@node_type("bad.undocumented", inputs={"x": "number"}, outputs={"y": "number"})
def undocumented(params: _Loose, x):
    """Doubles x."""
    return {"y": 2 * x}


class _P(NodeParams):
    pass


@node_type("bad.mutates", inputs={"image": "image"}, outputs={"image": "image"})
def mutates(params: _P, image):
    """Writes into its input."""
    image[0, 0] = 255
    return {"image": image}


_calls = [0]


@node_type("bad.random", inputs={"x": "number"}, outputs={"y": "number"})
def nondeterministic(params: _P, x):
    """Depends on a call counter."""
    _calls[0] += 1
    return {"y": x + _calls[0]}


@pytest.mark.parametrize(
    "nt, inputs, words",
    [
        (undocumented, {"x": 1.0}, "no description"),
        (mutates, {"image": np.zeros((3, 3), np.uint8)}, "mutated its inputs"),
        (nondeterministic, {"x": 1.0}, "not deterministic"),
    ],
)
def test_conformance_catches_each_rule(nt, inputs, words):
    with pytest.raises(AssertionError, match=words):
        check_node_type(nt, inputs)


@pytest.mark.parametrize("d", [4, 9])
def test_sgbm_recovers_the_disparity_of_make_stereo_pair(d):
    """The pair's disparity is +d, as its docstring says: OpenCV's SGBM finds d on nearly every
    pixel it can match (issue 31: it used to be a pair of disparity -d, matched on 36 %)."""
    import cv2

    left, right, _ = make_stereo_pair(height=80, width=160, disparity=d, seed=3)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=16, blockSize=5, uniquenessRatio=5)
    disp = sgbm.compute(left, right).astype(np.float32) / 16.0
    inner = disp[8:-8, 16 + 8 : -8]  # away from the borders and the columns the right camera misses
    valid = inner > 0
    assert valid.mean() > 0.9, valid.mean()
    assert np.abs(inner[valid] - d).mean() < 0.25
    assert np.median(inner[valid]) == pytest.approx(d, abs=0.1)
