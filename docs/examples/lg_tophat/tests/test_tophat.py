"""Tests of features.tophat through lanegraph's public testing API only (lanegraph.testing).

The ``lanegraph_pm`` fixture comes from lanegraph's pytest plugin: a plugin manager that has not
discovered any installed plugin, so the test sees exactly the plugin it registers.
"""

from __future__ import annotations

import math

import lg_tophat
import numpy as np
import pytest

from lanegraph.testing import check_node_type, make_bev_image, run_node


@pytest.fixture
def pm(lanegraph_pm):
    lanegraph_pm.register(lg_tophat, name="lg_tophat")
    return lanegraph_pm


def features(pm, image, **params):
    return run_node("features.tophat", {"image": image}, pm=pm, **params)["features"]


def test_features_on_the_markings_only(pm):
    image = make_bev_image(lane_cols=(50.0, 110.0), width_px=3.0)
    f = features(pm, image)
    cols = np.nonzero(f.mask)[1]
    assert cols.size > 0
    near = np.minimum(np.abs(cols - 50), np.abs(cols - 110))
    assert near.max() <= 2, "a feature off the markings"
    for c in (50, 110):  # every row finds each marking
        assert f.mask[:, c - 2 : c + 3].any(axis=1).mean() == 1.0


def test_no_features_on_a_flat_image(pm):
    f = features(pm, make_bev_image(lane_cols=()))
    assert not f.mask.any()
    assert (f.orientation == -1).all()


def test_threshold_is_monotonic(pm):
    image = make_bev_image(noise=8.0, paint=150)
    masks = [features(pm, image, threshold=t).mask for t in (0, 5, 10, 20, 40, 60, 80)]
    counts = [int(m.sum()) for m in masks]
    assert counts == sorted(counts, reverse=True) and counts[0] > counts[-1]
    for low, high in zip(masks, masks[1:]):
        assert not (high & ~low).any(), "a higher threshold found a feature a lower one did not"


def test_conformance(pm):
    check_node_type(lg_tophat.tophat, {"image": make_bev_image()}, {"width": 11}, pm=pm)


def test_registered_through_the_hooks(pm):
    assert set(pm.node_types) == {"features.tophat"}
    nt = pm.node_types["features.tophat"]
    assert nt.inputs["image"].type == "bev_image" and nt.outputs["features"].type == "features"
    assert (
        nt.outputs["response"].type == "bev_response"
        and pm.port_types["bev_response"] is lg_tophat.BEV_RESPONSE
    )


def test_a_plain_function(pm):
    """The node is the function itself: no engine needed to call it."""
    image = make_bev_image()
    out = lg_tophat.tophat(lg_tophat.TophatParams(), image=image)
    assert np.array_equal(out["features"].mask, features(pm, image).mask)
    assert out["response"].dtype == np.float32 and out["response"].shape == image.shape


def vertical_runs_twin(mask, min_run):
    """The kernel's plain NumPy twin: run lengths from the run starts and ends of each column."""
    padded = np.pad(mask, ((1, 1), (0, 0))).astype(np.int8)
    out = np.zeros_like(mask)
    for c in range(mask.shape[1]):
        edges = np.diff(padded[:, c])
        for start, end in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
            if end - start >= min_run:
                out[start:end, c] = True
    return out


@pytest.mark.parametrize("min_run", [1, 2, 3, 7, 40])
@pytest.mark.parametrize("density", [0.1, 0.5, 0.9])
def test_vertical_runs_matches_its_twin(min_run, density):
    rng = np.random.default_rng(min_run * 10 + int(density * 10))
    mask = rng.random((37, 23)) < density
    assert np.array_equal(lg_tophat.vertical_runs(mask, min_run), vertical_runs_twin(mask, min_run))
    assert not lg_tophat.vertical_runs(np.zeros((5, 4), bool), 2).any()
    assert (
        lg_tophat.vertical_runs(np.ones((5, 4), bool), 5).all()
        and not lg_tophat.vertical_runs(np.ones((5, 4), bool), 6).any()
    )


def test_min_run_drops_short_speckles_and_keeps_the_markings(pm):
    image = make_bev_image(noise=12.0, paint=200)
    loose, strict = features(pm, image), features(pm, image, min_run=20)
    assert strict.mask.sum() < loose.mask.sum() and not (strict.mask & ~loose.mask).any()
    for c in (50, 110):  # the markings run the whole height: they stay
        assert strict.mask[:, c - 2 : c + 3].any(axis=1).mean() == 1.0
    with pytest.raises(ValueError, match="bool mask"):
        lg_tophat.vertical_runs(np.zeros((4, 4), np.uint8), 2)


def test_wider_than_the_element_is_not_a_marking(pm):
    """Top-hat keeps only what is narrower than the structuring element."""
    wide = make_bev_image(lane_cols=(80.0,), width_px=15.0)
    assert not features(pm, wide, width=9).mask[:, 76:85].any()
    assert features(pm, wide, width=31).mask[:, 76:85].any()


@pytest.mark.parametrize("slope", [0.0, 0.15, -0.25])
def test_orientation_follows_the_marking(pm, slope):
    f = features(pm, make_bev_image(slope=slope))
    want = math.atan2(1.0, slope)  # from +x towards up; straight ahead is pi/2
    got = f.orientation[f.mask]
    assert (got >= 0).all() and (got < math.pi).all()
    assert abs(float(np.median(got)) - want) < math.radians(3)


def test_orientation_modes(pm):
    image = make_bev_image()
    vertical = features(pm, image, orientation="vertical")
    assert np.allclose(vertical.orientation[vertical.mask], math.pi / 2)
    assert features(pm, image, orientation="none").orientation is None


def test_params_are_bounded(pm):
    with pytest.raises(ValueError):
        features(pm, make_bev_image(), width=1)
    with pytest.raises(ValueError):
        features(pm, make_bev_image(), orientation="diagonal")
