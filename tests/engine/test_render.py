"""Debug pictures: per-port-type rendering, the mosaic, and the --debug-dir recorder."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from lanegraph import hookimpl, plugins
from lanegraph.cli import main
from lanegraph.presentation.debug import DebugRecorder
from lanegraph.presentation.port_types import check_value, render_value
from lanegraph.presentation.render import (
    hough_1d,
    lane_columns,
    line_columns,
    mosaic,
    render_disparity,
    render_features,
    render_vdisparity,
    to_bgr,
)
from lanegraph.types import FeatureMap, Lane, Line, RoadModel

from .test_graph import VALID


def test_to_bgr_scales_floats_and_keeps_uint8():
    f = np.array([[0.0, 0.5], [1.0, np.nan]], np.float32)
    out = to_bgr(f)
    assert out.shape == (2, 2, 3) and out.dtype == np.uint8
    assert out[0, 0, 0] == 0 and out[1, 0, 0] == 255 and out[1, 1, 0] == 0
    u = np.arange(12, dtype=np.uint8).reshape(2, 2, 3)
    assert np.array_equal(to_bgr(u), u)
    with pytest.raises(ValueError, match="shape"):
        to_bgr(np.zeros((2, 2, 5)))


def test_disparity_colour_map_blacks_out_invalid_pixels():
    d = np.tile(np.linspace(1, 64, 32, dtype=np.float32), (8, 1))
    d[2, 3] = 0
    d[4, 5] = np.nan
    out = render_disparity(d)
    assert out.shape == (8, 32, 3)
    assert not out[2, 3].any() and not out[4, 5].any()
    assert out[0, 31].any()
    # near (large disparity) and far (small) get different colours
    assert not np.array_equal(out[0, 0], out[0, 31])


def test_features_coloured_by_orientation_hue():
    mask = np.zeros((4, 4), bool)
    mask[0, 0] = mask[1, 1] = mask[2, 2] = True
    o = np.full((4, 4), -1.0, np.float32)
    o[0, 0] = 0.0  # hue 0: red
    o[1, 1] = math.pi / 2  # hue 90 of 180: cyan
    out = render_features(FeatureMap(mask, o))
    assert tuple(out[0, 0]) == (0, 0, 255)
    b, g, r = (int(v) for v in out[1, 1])
    assert r < 10 and g > 200 and b > 200
    assert tuple(out[2, 2]) == (255, 255, 255)  # a feature of unknown orientation
    assert not out[3, 3].any()  # not a feature


def test_vdisparity_shows_dp_path_and_model():
    acc = np.ones((50, 40), np.float32)
    profile = np.full(50, -1.0)
    profile[20:] = np.arange(30) * 0.5 + 5
    road = RoadModel(a0=0.0, a1=0.5, v_min=20, profile=profile)  # the model lies 5 px right of the path
    out = render_vdisparity(acc, road)
    assert out.shape == (50, 40, 3)
    v = 30
    assert tuple(out[v, int(round(profile[v]))]) == (0, 0, 255)
    b, g, r = (int(c) for c in out[v, int(round(road.disparity_at(v)))])
    assert g > 100 and r < 100 and b < 100
    plain = render_vdisparity(acc)
    assert np.ptp(plain.reshape(-1, 3), axis=0).max() == 0  # uniform input: uniform picture


def test_hough_1d_peaks_at_the_line():
    rows, cols = 60, 50
    mask = np.zeros((rows, cols), bool)
    mask[:, 20] = True
    acc = hough_1d(FeatureMap(mask), math.pi / 2)
    assert int(np.argmax(acc)) - 2 * cols == 20 and acc.max() == rows
    # a slanted line crossing the bottom edge at column 10
    theta = math.radians(80)
    line = Line(rho=10.0, theta=theta)
    y = np.arange(rows)
    x = np.round(line_columns(line, rows, y)).astype(int)
    mask = np.zeros((rows, cols), bool)
    mask[y, x] = True
    acc = hough_1d(FeatureMap(mask), theta)
    assert abs(int(np.argmax(acc)) - 2 * cols - 10) <= 1


def test_lane_columns_follow_the_parabola():
    lane = Lane(coeffs=(10.0, 0.5, 0.01), bev_rows=(0, 99), side="left", score=1.0)
    assert lane_columns(lane, 100, np.array([99.0]))[0] == pytest.approx(10.0)
    assert lane_columns(lane, 100, np.array([89.0]))[0] == pytest.approx(10 + 5 + 1)


def test_render_value_every_port_type():
    img = np.full((40, 60, 3), 100, np.uint8)
    bev = np.full((80, 40), 90, np.uint8)
    mask = np.zeros((80, 40), bool)
    mask[:, 10] = True
    feats = FeatureMap(mask, np.where(mask, math.pi / 2, -1).astype(np.float32))
    lines = [Line(rho=10.0, theta=math.pi / 2, votes=80, side="left")]
    lanes = [Lane(coeffs=(10.0, 0.0, 0.0), bev_rows=(0, 79), side="left", score=0.9)]
    ctx = {"image": img, "bev_image": bev, "features": feats}
    for port_type, value, shape in [
        ("image", img, (40, 60)),
        ("gray", img[..., 0], (40, 60)),
        ("bev_image", bev, (80, 40)),
        ("mask", np.ones((40, 60), bool), (40, 60)),
        ("bev_mask", mask, (80, 40)),
        ("features", feats, (80, 40)),
        ("orientation", math.pi / 2, (80, 40)),
        ("lanes", lanes, (80, 40)),
    ]:
        out = render_value(port_type, value, ctx)
        assert out is not None and out.dtype == np.uint8 and out.shape[:2] == shape, port_type
    # lines: the BEV with the lines, the accumulator plot underneath
    out = render_value("lines", lines, ctx)
    assert out.shape[1] == 40 and out.shape[0] > 80
    assert tuple(out[40, 10]) != (90, 90, 90)  # the line is drawn over the BEV
    # the mask is drawn over the left image
    over = render_value("mask", np.ones((40, 60), bool), ctx)
    assert not np.array_equal(over, to_bgr(img))
    # lanes with image points: the final overlay on the left image
    lanes[0].points = np.array([[5.0, 39.0], [30.0, 10.0]])
    out = render_value("lanes", lanes, ctx)
    assert out.shape[:2] == (40, 60) and not np.array_equal(out, img)
    assert render_value("calibration", object()) is None
    assert render_value("image", None) is None


def test_mosaic_packs_tiles_in_rows():
    tiles = [(f"t{i}", np.full((100, 200, 3), i * 20, np.uint8)) for i in range(6)]
    m = mosaic(tiles, tile_height=100, max_row_width=650)
    # three 200-px tiles (+4 px gaps) per row, two rows of 100 + 20 (caption) + 4 px
    assert m.shape[1] == 3 * 204 and m.shape[0] == 2 * 124
    assert m.shape[2] == 3 and m.dtype == np.uint8
    assert mosaic([]).shape[2] == 3


@pytest.fixture
def cli(pm, monkeypatch):
    monkeypatch.setattr(plugins, "_default", pm)
    return CliRunner()


def test_debug_dir_writes_every_output_and_a_mosaic(cli, pm, tmp_path):
    graph = tmp_path / "g.yaml"
    graph.write_text(yaml.safe_dump(VALID))
    dbg = tmp_path / "dbg"
    r = cli.invoke(
        main,
        [
            "run",
            str(graph),
            "--out",
            str(tmp_path / "o"),
            "--quiet",
            "--frames",
            "0:3",
            "--debug-dir",
            str(dbg),
            "--debug-frames",
            "1",
        ],
    )
    assert r.exit_code == 0, r.output
    # only the chosen frame; the toy graph's numbers become text cards
    assert sorted(p.name for p in dbg.iterdir()) == ["0001"]
    names = sorted(p.name for p in (dbg / "0001").iterdir())
    assert "mosaic.png" in names and "double.y.png" in names
    assert cv2.imread(str(dbg / "0001" / "mosaic.png")) is not None


def test_plugin_render_hook_is_used(pm, tmp_path):
    from lanegraph.graph.validation import load_graph
    from lanegraph.nodes import RunContext
    from lanegraph.run.executor import Executor

    marker = np.full((7, 9, 3), (1, 2, 3), np.uint8)

    class Renderer:
        @hookimpl
        def lanegraph_render(self, node_type, port):
            return marker if node_type == "toy.scale" else None

    pm.register(Renderer())
    graph = tmp_path / "g.yaml"
    graph.write_text(yaml.safe_dump(VALID))
    rec = DebugRecorder(tmp_path / "dbg", None, pm)
    pm.register(rec)
    Executor(load_graph(graph, pm=pm), RunContext(out_dir=tmp_path / "o"), pm).run()
    frames = sorted(rec.written)
    assert frames and all((tmp_path / "dbg" / f / "mosaic.png").exists() for f in frames)
    saved = cv2.imread(str(tmp_path / "dbg" / frames[0] / "double.y.png"))
    assert np.array_equal(saved, marker)


def test_every_builtin_port_type_comes_through_the_hook_with_its_check_and_has_its_picture():
    from lanegraph.plugins import PluginManager
    from lanegraph.port_types import PORT_TYPES
    from lanegraph.presentation.port_types import picture_of

    pm = PluginManager()  # no plugin loaded: lanegraph's own port types only, through the hook
    assert set(pm.port_types) == set(PORT_TYPES)
    assert pm.get_plugin("lanegraph").lanegraph_port_types() == list(PORT_TYPES.values())
    drawn = {n for n, t in pm.port_types.items() if picture_of(t) is not None}
    assert {
        "image",
        "disparity",
        "mask",
        "bev_mask",
        "vdisparity",
        "road_model",
        "features",
        "lanes",
    } <= drawn
    assert check_value("disparity", np.zeros((4, 5), np.float32)) is None
    assert "float32" in check_value("disparity", np.zeros((4, 5), np.float64))
    assert check_value("mask", np.zeros((4, 5), bool)) is None and check_value("mask", [1]) is not None
    assert check_value("lanes", []) is None and "Lane" in check_value("lanes", [object()])


def test_a_plugins_port_type_draws_its_own_values():
    from lanegraph.types import PortType

    seen = []
    blob = PortType(
        "blob", "a test value", render=lambda v, ctx: seen.append(v) or np.zeros((3, 4, 3), np.uint8)
    )
    out = render_value("blob", 7, {}, {"blob": blob})
    assert seen == [7] and out.shape == (3, 4, 3)
    # a value its type does not draw is drawn by what it is: a number as a card
    assert render_value("blob", 7, {}, {"blob": PortType("blob", "no picture")}).ndim == 3


def test_mosaic_never_cuts_a_caption_and_widens_a_narrow_tile():
    """A v-disparity (375 rows x 60 bins) comes out at a readable width, and a long title whole."""
    import cv2

    name = "road.vdisparity_with_a_long_title"
    m = mosaic(
        [(name, np.full((375, 60), 128, np.uint8)), ("x", np.zeros((240, 320, 3), np.uint8))], tile_height=240
    )
    (text_w, _), _ = cv2.getTextSize(name, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
    first = m.shape[1] - (320 + 4) - 4  # the first tile's width: the whole minus the second tile and gaps
    assert first >= max(160, text_w + 8)
    assert (m[20:260, 60:160] == 128).all()  # the picture itself is stretched, not only padded
