"""Property-based tests (hypothesis): whatever they are given, the graph loader and the node
wrappers of the numba kernels either succeed with a well-formed result or raise one of lanegraph's
own errors (:class:`~lanegraph.errors.LanegraphError`) -- never an IndexError, a ZeroDivisionError, a
numba TypingError or a crash inside a kernel.

Budget: the module runs in well under 40 s on 2 cores with a warm numba cache. Set
``LANEGRAPH_HYPOTHESIS_PROFILE=lanegraph-thorough`` for a longer search (10x the examples).
"""

from __future__ import annotations

import copy
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, assume, event, example, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from lanegraph.errors import GraphError, InputError, LanegraphError
from lanegraph.graph.loader import parse_text
from lanegraph.graph.model import parse_set
from lanegraph.graph.validation import load_graph, validate_raw
from lanegraph.plugins import PluginManager
from lanegraph.testing import make_disparity, run_node
from lanegraph.types import BevGeometry, Calibration, FeatureMap, Lane, Line, RoadModel

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "graphs" / "paper_base.yaml"  # the whole graph (paper.yaml extends it with tuned params)

_HC = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much]
settings.register_profile("lanegraph-quick", max_examples=40, deadline=None, suppress_health_check=_HC)
settings.register_profile("lanegraph-thorough", max_examples=400, deadline=None, suppress_health_check=_HC)
PROFILE = settings.get_profile(os.environ.get("LANEGRAPH_HYPOTHESIS_PROFILE", "lanegraph-quick"))
QUICK = settings(PROFILE)
#: the costlier properties (disparity matching, the road profile, the IPM) run half the examples
FEW = settings(PROFILE, max_examples=max(10, PROFILE.max_examples // 2))


def _pm() -> PluginManager:
    """The installed plugins, in a manager of their own (other tests swap the process-wide one)."""
    pm = PluginManager()
    pm.load_entrypoints()
    assert not pm.load_errors, pm.load_errors
    return pm


PM = _pm()


def call(node: str, inputs: dict, **params):
    """Run ``node`` once; lanegraph's own errors are an allowed outcome and are returned, every other
    exception propagates (and fails the property). ``params`` must be valid for the node type."""
    try:
        return run_node(node, inputs, pm=PM, **params)
    except LanegraphError as exc:
        assert str(exc).strip(), f"{node}: {type(exc).__name__} without a message"
        return exc


def valid_params(node: str, params: dict) -> dict:
    """``params`` when the node's params model accepts them; the example is rejected otherwise."""
    try:
        PM.get_node_type(node).params.model_validate(params)
    except ValidationError:
        assume(False)
    return params


# ============================================================================ the graph loader
PAPER_RAW = yaml.safe_load(PAPER.read_text())
HUGE = 10**5000  # more digits than int() / repr() convert by default (sys.get_int_max_str_digits)
TEXT = st.text(st.characters(blacklist_categories=("Cs",)), max_size=12)  # any unicode but lone surrogates
SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    st.sampled_from([2**63, -(2**63) - 1, 2**64 + 1, 10**30]),
    st.floats(allow_nan=True, allow_infinity=True),
    TEXT,
    st.sampled_from(
        [
            "src.left",
            "verify.lanes@prev",
            "io.auto",
            "fit.irls",
            "nope.port",
            "a.b.c",
            "",
            " ",
            "🚗.ü",
            "x" * 300,
            "-1",
            "1e999",
            "skip",
        ]
    ),
)
JUNK = st.recursive(
    SCALARS,
    lambda kids: st.lists(kids, max_size=3) | st.dictionaries(TEXT | st.integers(), kids, max_size=3),
    max_leaves=8,
)


def _paths(obj, prefix=()):
    """Every key path into nested dicts and lists, the root included."""
    yield prefix
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else ()
    for k, v in items:
        yield from _paths(v, (*prefix, k))


@st.composite
def mutated(draw, base):
    """``base`` after 1-4 random mutations: a key dropped, a value replaced by junk (wrong types,
    random strings, nested lists, big ints, NaN, unicode), a junk key inserted, a value wrapped in a list."""
    g = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 4))):
        path = draw(st.sampled_from(list(_paths(g))))
        op = draw(st.sampled_from(["drop", "replace", "insert", "wrap"]))
        if not path:
            if op == "replace":
                g = draw(JUNK)
            elif op == "insert" and isinstance(g, dict):
                g[draw(TEXT)] = draw(JUNK)
            continue
        parent = g
        for k in path[:-1]:
            parent = parent[k]
        key = path[-1]
        if op == "drop":
            del parent[key]
        elif op == "replace":
            parent[key] = draw(JUNK)
        elif op == "wrap":
            parent[key] = [parent[key]]
        elif isinstance(parent[key], dict):
            parent[key][draw(TEXT)] = draw(JUNK)
        else:
            parent[key] = {draw(TEXT): parent[key]}
    return g


def _check_loaded(g) -> None:
    assert g.nodes and sorted(g.order) == sorted(g.nodes)
    assert sum(n.type.source for n in g.nodes.values()) == 1
    for n in g.nodes.values():
        for e in n.inputs.values():
            assert e.src_node in g.nodes


def load_or_error(fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, with lanegraph's own errors (with a message) as an allowed outcome."""
    try:
        return fn(*args, **kwargs)
    except LanegraphError as exc:
        assert isinstance(exc, GraphError), (
            f"the loader raised {type(exc).__name__}, expected a GraphError: {exc}"
        )
        assert str(exc).strip() and exc.problems
        return exc


@QUICK
@given(raw=mutated(PAPER_RAW))
@example(raw={**PAPER_RAW, "nodes": [PAPER_RAW["nodes"]]})
@example(raw={**PAPER_RAW, "remove": [["src"]]})
def test_validate_raw_loads_or_raises_graph_error(raw):
    out = load_or_error(validate_raw, raw, {}, "paper.yaml", PM)
    if not isinstance(out, GraphError):
        _check_loaded(out)


def _no_known_bug(v) -> bool:
    """Every input is fair now: the loader bugs hypothesis found (LOADER_EDGE_CASES) are fixed."""
    return True


#: the extends values an overlay may carry: the base, paths out of the roots, itself, junk
EXTENDS = st.one_of(
    st.sampled_from(
        [
            "paper.yaml",
            "./paper.yaml",
            "sub/../paper.yaml",
            "../paper.yaml",
            "/etc/passwd",
            "nope.yaml",
            "child.yaml",
            "",
            ".",
        ]
    ),
    JUNK.filter(_no_known_bug),
)
SETS = st.lists(
    st.one_of(
        st.sampled_from(
            [
                "fit.iterations=3",
                "fit.iterations=x",
                "fit=1",
                "nope.x=1",
                "disp.type=disparity.bm",
                "src.type=io.nope",
                ".=",
                "=",
                "fit.loss.deep=1",
                "hough.select=[1]",
            ]
        ),
        TEXT,
    ),
    max_size=3,
)


@QUICK
@given(
    child=st.one_of(
        mutated(PAPER_RAW),
        st.fixed_dictionaries(
            {"extends": EXTENDS}, optional={"nodes": JUNK, "remove": JUNK, "on_error": JUNK}
        ),
    ),
    base=st.one_of(st.just(PAPER_RAW), mutated(PAPER_RAW)),
    fmt=st.sampled_from(["yaml", "json"]),
    sets=SETS,
)
@example(
    child={"extends": "paper.yaml", "nodes": {"fit": {"params": [1]}}},
    base=PAPER_RAW,
    fmt="yaml",
    sets=["fit.iterations=3"],
)
@example(
    child={"extends": "paper.yaml", "nodes": {"fit": {"params": {"loss": 5}}}},
    base=PAPER_RAW,
    fmt="yaml",
    sets=["fit.loss.deep=1"],
)
@example(child={"extends": "paper.yaml"}, base={**PAPER_RAW, "nodes": [1, 2]}, fmt="json", sets=[])
@example(child={"nodes": {0: False}}, base=PAPER_RAW, fmt="yaml", sets=["fit.iterations=3"])  # a non-str id
@example(child={"nodes": [1]}, base=PAPER_RAW, fmt="yaml", sets=["fit.iterations=3"])
def test_graph_files_load_or_raise_graph_error(child, base, fmt, sets):
    """A graph file (and an ``extends`` base, and ``--set`` overrides) that is not what the format
    says is a GraphError, through the whole file-loading path."""
    dump = (
        (lambda d: yaml.safe_dump(d, allow_unicode=True))
        if fmt == "yaml"
        else (lambda d: json.dumps(d, ensure_ascii=False))
    )
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "paper.yaml").write_text(yaml.safe_dump(base, allow_unicode=True), encoding="utf-8")
        path = root / f"child.{fmt}"
        path.write_text(dump(child), encoding="utf-8")
        out = load_or_error(load_graph, path, list(sets), PM, roots=[root.resolve()])
    if not isinstance(out, GraphError):
        _check_loaded(out)


def _child(tmp: Path, child: dict, sets: tuple[str, ...] = ()):
    (tmp / "paper.yaml").write_text(yaml.safe_dump(PAPER_RAW))
    (tmp / "child.yaml").write_text(yaml.safe_dump(child))
    return load_graph(tmp / "child.yaml", list(sets), PM, roots=[tmp.resolve()])


#: inputs hypothesis found escaping as other exceptions from lanegraph/graph.py (fixed): each must
#: give a GraphError
LOADER_EDGE_CASES = {
    "huge int in a param (repr in the message)": lambda tmp: validate_raw(
        {
            **PAPER_RAW,
            "nodes": {**PAPER_RAW["nodes"], "fit": {"type": "fit.irls", "params": {"iterations": HUGE}}},
        },
        {},
        "g",
        PM,
    ),
    "huge int as the version (repr in the message)": lambda tmp: validate_raw(
        {**PAPER_RAW, "version": HUGE}, {}, "g", PM
    ),
    "huge int in --set": lambda tmp: _child(
        tmp, {"extends": "paper.yaml"}, ("fit.iterations=" + "9" * 5000,)
    ),
    "--set value its YAML tag cannot hold": lambda tmp: _child(
        tmp, {"extends": "paper.yaml"}, ("fit.iterations=!!int x",)
    ),
    "extends with a NUL byte": lambda tmp: _child(tmp, {"extends": "paper.yaml\x00"}),
    "extends longer than a file name may be": lambda tmp: _child(tmp, {"extends": "p" * 400}),
}


@pytest.mark.parametrize("name", sorted(LOADER_EDGE_CASES))
def test_loader_edge_cases_found_by_hypothesis(name, tmp_path):
    assert isinstance(load_or_error(LOADER_EDGE_CASES[name], tmp_path), GraphError)


YAML_BITS = st.sampled_from(
    [
        "nodes:",
        "\n",
        "\n  ",
        "  ",
        "src:",
        "{type: io.auto}",
        "type: io.auto",
        "- ",
        ": ",
        "&a ",
        "*a",
        "<<: *a",
        "? [1, 2]\n: x",
        "!!python/object/apply:os.system ['true']",
        "extends: ",
        "extends: paper.yaml",
        "'",
        '"',
        "[",
        "]",
        "{",
        "}",
        ",",
        "#",
        "9" * 5000,
        "!!int abc",
        "2011-13-45",
        "\t",
        "%YAML 1.1\n---\n",
        "---\n",
        "...\n",
        "version: ",
        "on_error: ",
        "🚗",
        "\x00",
        "params: {iterations: ",
        "inputs: {image: src.left}",
        "= ",
        "[nodes.src]\n",
        'type = "io.auto"\n',
        "0x",
        "1e999",
        "null",
    ]
)


@QUICK
@given(
    text=st.one_of(st.lists(YAML_BITS, max_size=20).map("".join), st.text(max_size=80)),
    suffix=st.sampled_from([".yaml", ".yml", ".json", ".toml"]),
)
@example(text="version: " + "9" * 5000 + "\nnodes: {}\n", suffix=".yaml")
@example(text='{"version": ' + "9" * 5000 + "}", suffix=".json")
@example(text="version = " + "9" * 5000 + "\n", suffix=".toml")
@example(text="[" * 50_000, suffix=".json")
@example(text="[" * 50_000, suffix=".yaml")
@example(
    text="a: &a [1, 1, 1, 1, 1, 1, 1, 1]\n"
    + "".join(
        f"{c}: &{c} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]\n"
        for p, c in zip("abcdefgh", "bcdefghi")
    ),
    suffix=".yaml",
)
@example(text="? [1, 2]\n: x\n", suffix=".yaml")
@example(text="!!python/object/apply:os.system ['false']\n", suffix=".yaml")
def test_graph_text_loads_or_raises_graph_error(text, suffix):
    """Arbitrary text in a graph file: parsed and validated, or one GraphError (never a crash, a
    RecursionError, an int-conversion ValueError or exponential work on YAML aliases)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"g{suffix}"
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
        out = load_or_error(load_graph, path, [], PM, roots=[Path(tmp).resolve()])
    if not isinstance(out, GraphError):
        _check_loaded(out)


@QUICK
@given(
    item=st.one_of(
        TEXT,
        st.lists(
            st.sampled_from(["a", ".", "=", "b", "[", "{", "9" * 40, "!!str x", "🚗", "@prev"]), max_size=8
        ).map("".join),
    )
)
def test_set_items_parse_or_raise_graph_error(item):
    out = load_or_error(parse_set, item)
    if not isinstance(out, GraphError):
        nid, path, _ = out
        assert nid and path and all(path)


@QUICK
@given(text=st.text(max_size=200), fmt=st.sampled_from(["yaml", "json", "toml"]))
def test_parse_text_returns_plain_data_or_raises_graph_error(text, fmt):
    out = load_or_error(parse_text, text, fmt, "g")
    if not isinstance(out, GraphError):
        json.dumps(out, default=str)  # plain data: dicts, lists, scalars (and dates from YAML/TOML)


# ============================================================================ input strategies
SIDE = st.integers(0, 24)
POS_SIDE = st.integers(1, 24)
KINDS_ALL = ("zeros", "const", "noise", "stripes", "nan", "inf", "mixed")


def _fill(
    rng: np.random.Generator, shape: tuple[int, ...], kind: str, dtype, hi: float = 255.0
) -> np.ndarray:
    """A test array: all zero, constant, noise, vertical stripes, all NaN, all inf or noise with
    NaN, +-inf and negative values sprinkled in (the non-finite kinds only for float dtypes)."""
    if np.dtype(dtype).kind != "f" and kind in ("nan", "inf", "mixed"):
        kind = "noise"
    if kind == "zeros":
        a = np.zeros(shape)
    elif kind == "const":
        a = np.full(shape, float(rng.uniform(0, hi)))
    elif kind == "stripes":
        a = np.full(shape, 0.3 * hi)
        if len(shape) >= 2 and shape[1]:
            a[:, :: max(2, shape[1] // 4)] = hi
        a = a + rng.normal(0, 2, shape)
    elif kind == "nan":
        a = np.full(shape, np.nan)
    elif kind == "inf":
        a = np.full(shape, np.inf)
    else:
        a = rng.uniform(0, hi, shape)
        if kind == "mixed":
            for v in (np.nan, np.inf, -np.inf, -1.0):
                a[rng.random(shape) < 0.1] = v
    if np.dtype(dtype).kind in "ui":
        info = np.iinfo(dtype)
        a = np.clip(np.nan_to_num(a), info.min, info.max)
    return a.astype(dtype)


@st.composite
def arrays2d(
    draw, dtypes=(np.uint8, np.float32, np.float64), kinds=KINDS_ALL, side=SIDE, hi=255.0, shape=None
):
    h, w = shape if shape is not None else (draw(side), draw(side))
    return _fill(
        np.random.default_rng(draw(st.integers(0, 2**16))),
        (h, w),
        draw(st.sampled_from(kinds)),
        draw(st.sampled_from(dtypes)),
        hi,
    )


@st.composite
def images(draw, side=SIDE, dtypes=(np.uint8, np.float32, np.float64)):
    """HxW gray or HxWx3 BGR images (uint8 or float), any content."""
    img = draw(arrays2d(dtypes=dtypes, side=side))
    if draw(st.booleans()):
        img = np.repeat(img[:, :, None], 3, axis=2)
        img[..., 0] = img[..., 0] // 2 if img.dtype.kind in "ui" else img[..., 0] * 0.5
    return img


#: arrays no image port accepts: a vector, a 4-D block, 2 channels
BAD_IMAGES = st.sampled_from(
    [np.zeros(5, np.uint8), np.zeros((2, 3, 3, 1), np.uint8), np.zeros((4, 5, 2), np.uint8)]
)


@st.composite
def feature_maps(draw, side=st.integers(0, 40), oriented=None):
    """A FeatureMap as the features nodes make it: a bool mask (sparse noise plus stripes) and,
    optionally, orientations in [0, pi) on the mask and -1 elsewhere."""
    rows, cols = draw(side), draw(side)
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    mask = rng.random((rows, cols)) < draw(st.sampled_from([0.0, 0.02, 0.2, 1.0]))
    for _ in range(draw(st.integers(0, 3))):
        if rows and cols:
            c0, slope = rng.uniform(0, cols), rng.uniform(-0.5, 0.5)
            r = np.arange(rows)
            c = np.round(c0 + slope * (rows - 1 - r)).astype(int)
            ok = (c >= 0) & (c < cols)
            mask[r[ok], c[ok]] = True
    has_ori = draw(st.booleans()) if oriented is None else oriented
    ori = None
    if has_ori:
        centre = draw(st.floats(0.0, math.pi, exclude_max=True))
        ori = np.where(mask, np.mod(centre + rng.normal(0, 0.05, mask.shape), math.pi), -1.0).astype(
            np.float32
        )
    return FeatureMap(mask=mask, orientation=ori)


def bev_geometry_for(rows: int, cols: int, res: float = 0.1) -> BevGeometry:
    return BevGeometry(-cols * res / 2, cols * res / 2, 5.0, 5.0 + rows * res, res, np.eye(3))


def calib_for(h: int, w: int, f_scale: float = 0.8) -> Calibration:
    return Calibration(f=max(1.0, w * f_scale), cx=w / 2, cy=h / 2, baseline=0.5, width=w, height=h)


@st.composite
def road_models(draw):
    """Road models as road.profile makes them: valid with finite pose, or invalid (zeros)."""
    if not draw(st.booleans()):
        return RoadModel(a0=0.0, a1=0.0, valid=False)
    a1 = draw(st.floats(0.01, 5.0))
    return RoadModel(
        a0=draw(st.floats(-200.0, 50.0)),
        a1=a1,
        a2=draw(st.sampled_from([0.0, 1e-4, -1e-4])),
        roll=draw(st.floats(-0.2, 0.2)),
        pitch=draw(st.floats(-0.3, 0.3)),
        height=draw(st.floats(0.2, 6.0)),
        valid=True,
    )


ANGLES = st.one_of(
    st.floats(0.0, math.pi, exclude_max=True), st.sampled_from([0.0, 1e-9, math.pi / 2, math.pi - 1e-9])
)


# ============================================================================ features.slt / .eslt / .mask
def _check_feature_map(fm: FeatureMap, shape: tuple[int, int], oriented: bool) -> None:
    assert isinstance(fm, FeatureMap)
    assert fm.mask.dtype == bool and fm.mask.shape == shape
    if not oriented:
        assert fm.orientation is None
        return
    o = fm.orientation
    assert o.dtype == np.float32 and o.shape == shape
    assert np.isfinite(o).all(), "orientation must be NaN-free"
    assert ((o == -1) | ((o >= 0) & (o < math.pi + 1e-6))).all()
    assert ((o >= 0) == fm.mask).all(), "an orientation exactly where there is a feature"


@QUICK
@given(
    image=st.one_of(images(), BAD_IMAGES),
    window=st.integers(1, 30),
    threshold=st.floats(0.0, 255.0),
    eslt=st.booleans(),
    max_angle=st.floats(0.5, 90.0),
    ksize=st.sampled_from([1, 3, 5, 7]),
)
@example(image=np.zeros((0, 5), np.uint8), window=3, threshold=0.0, eslt=True, max_angle=15.0, ksize=3)
@example(image=np.zeros((0, 0, 3), np.uint8), window=1, threshold=0.0, eslt=False, max_angle=15.0, ksize=3)
@example(
    image=np.full((1, 1), np.nan, np.float32), window=1, threshold=0.0, eslt=True, max_angle=15.0, ksize=3
)
@example(image=np.full((3, 7), np.inf), window=2, threshold=1.0, eslt=True, max_angle=15.0, ksize=1)
def test_features_slt_eslt(image, window, threshold, eslt, max_angle, ksize):
    params = {"window": window, "threshold": threshold}
    if eslt:
        params.update(max_angle_deg=max_angle, sobel_ksize=ksize)
    out = call("features.eslt" if eslt else "features.slt", {"image": image}, **params)
    not_an_image = image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3))
    if isinstance(out, LanegraphError):
        assert not_an_image and isinstance(out, InputError) and "image" in str(out), out
        return
    assert not not_an_image, "a vector, a 4-D block or a 2-channel array must be refused"
    _check_feature_map(out["features"], image.shape[:2], eslt)


@QUICK
@given(
    fm=feature_maps(side=st.integers(0, 16)),
    seed=st.integers(0, 99),
    erode=st.integers(0, 6),
    temporal=st.booleans(),
    mismatch=st.booleans(),
)
def test_features_mask(fm, seed, erode, temporal, mismatch):
    rng = np.random.default_rng(seed)
    shape = fm.mask.shape
    mshape = (shape[0] + 1, shape[1]) if mismatch else shape
    road = rng.random(mshape) < 0.7
    tmask = rng.random(shape) < 0.5 if temporal else None
    out = call("features.mask", {"features": fm, "mask": road, "temporal": tmask}, erode_px=erode)
    if isinstance(out, LanegraphError):
        assert mismatch and isinstance(out, InputError) and "mask" in str(out)
        return
    assert not mismatch, "a road mask of another shape than the features must be refused"
    res = out["features"]
    _check_feature_map(res, shape, fm.orientation is not None)
    assert not (res.mask & ~fm.mask).any() and not (res.mask & ~road).any()


# ============================================================================ lanes.orientation, hough.*
@QUICK
@given(
    fm=feature_maps(),
    bin_deg=st.floats(0.01, 10.0),
    smooth=st.floats(0.0, 20.0),
    max_dev=st.floats(0.01, 90.0),
    default=st.floats(1.0, 179.0),
    min_features=st.integers(1, 100),
)
@example(
    fm=FeatureMap(np.ones((3, 3), bool), np.full((3, 3), 1.5, np.float32)),
    bin_deg=10.0,
    smooth=20.0,
    max_dev=1.0,
    default=90.0,
    min_features=1,
)
def test_lanes_orientation(fm, bin_deg, smooth, max_dev, default, min_features):
    out = call(
        "lanes.orientation",
        {"features": fm},
        bin_deg=bin_deg,
        smooth_bins=smooth,
        max_deviation_deg=max_dev,
        default_deg=default,
        min_features=min_features,
    )
    assert not isinstance(out, LanegraphError), out
    theta = out["orientation"]
    assert isinstance(theta, float) and math.isfinite(theta) and 0.0 < theta < math.pi


def _hough_params(draw) -> dict:
    return {
        "select": draw(st.sampled_from(["nearest", "paper"])),
        "smooth_px": draw(st.floats(0.0, 50.0)),
        "min_separation_m": draw(st.floats(0.05, 20.0)),
        "min_votes": draw(st.sampled_from([0.0, 1.0, 5.0, 60.0])),
        "min_relative": draw(st.floats(0.0, 1.0)),
        "min_offset_m": draw(st.floats(0.0, 3.0)),
        "max_offset_m": draw(st.floats(0.1, 50.0)),
    }


def _check_lines(lines, cols: int) -> None:
    assert isinstance(lines, list) and len(lines) <= 2
    for ln in lines:
        assert isinstance(ln, Line)
        assert all(math.isfinite(v) for v in (ln.rho, ln.theta, ln.votes))
        assert -2 * cols <= ln.rho < 3 * cols, "rho outside the accumulator"
        assert ln.side in ("left", "right")


@QUICK
@given(
    data=st.data(),
    fm=feature_maps(),
    theta=st.one_of(ANGLES, st.sampled_from([math.nan, math.inf, -math.inf, 4.0, -1.0])),
    res=st.floats(0.02, 0.5),
)
@example(data=None, fm=FeatureMap(np.zeros((0, 0), bool)), theta=math.pi / 2, res=0.1)
@example(data=None, fm=FeatureMap(np.ones((3, 1), bool)), theta=math.pi / 2, res=0.1)
def test_hough_line1d(data, fm, theta, res):
    params = _hough_params(data.draw) if data is not None else {}
    rows, cols = fm.mask.shape
    out = call(
        "hough.line1d",
        {"features": fm, "orientation": theta, "geometry": bev_geometry_for(rows, cols, res)},
        **params,
    )
    if isinstance(out, LanegraphError):
        assert not (math.isfinite(theta) and 0 <= theta < math.pi), out
        assert isinstance(out, InputError) and "orientation" in str(out)
        return
    assert math.isfinite(theta), "a NaN or infinite orientation must be refused"
    event(f"hough.line1d: {len(out['lines'])} lines")
    _check_lines(out["lines"], cols)


@QUICK
@given(
    data=st.data(),
    fm=feature_maps(side=st.integers(0, 24)),
    rng_deg=st.floats(0.5, 89.0),
    step_deg=st.floats(0.5, 10.0),
    res=st.floats(0.02, 0.5),
)
def test_hough_line2d(data, fm, rng_deg, step_deg, res):
    params = _hough_params(data.draw)
    rows, cols = fm.mask.shape
    out = call(
        "hough.line2d",
        {"features": fm, "geometry": bev_geometry_for(rows, cols, res)},
        theta_range_deg=rng_deg,
        theta_step_deg=step_deg,
        **params,
    )
    assert not isinstance(out, LanegraphError), out
    _check_lines(out["lines"], cols)
    for ln in out["lines"]:
        assert abs(ln.theta - math.pi / 2) <= math.radians(rng_deg) + 1e-9


# ============================================================================ fit.irls / fit.ransac
@st.composite
def line_lists(draw, cols: int):
    n = draw(st.integers(0, 3))
    return [
        Line(
            rho=draw(st.floats(-cols - 1.0, 2.0 * cols + 1)),
            theta=draw(ANGLES),
            votes=1.0,
            side=draw(st.sampled_from(["left", "right"])),
        )
        for _ in range(n)
    ]


@QUICK
@given(
    data=st.data(),
    fm=feature_maps(side=st.integers(0, 60)),
    ransac=st.booleans(),
    roi=st.floats(1.5, 80.0),
    degree=st.integers(1, 3),
    min_inliers=st.integers(3, 40),
    min_extent=st.floats(0.0, 2.0),
    max_curv=st.floats(1e-4, 1.0),
    extend=st.booleans(),
    res=st.floats(0.02, 0.5),
)
@example(
    data=None,
    fm=FeatureMap(np.eye(3, dtype=bool)),
    ransac=True,
    roi=40.0,
    degree=3,
    min_inliers=3,
    min_extent=0.0,
    max_curv=1.0,
    extend=True,
    res=0.1,
)
def test_fit(data, fm, ransac, roi, degree, min_inliers, min_extent, max_curv, extend, res):
    rows, cols = fm.mask.shape
    lines = (
        data.draw(line_lists(cols)) if data is not None else [Line(rho=1.0, theta=math.pi / 4, side="left")]
    )
    params = dict(
        roi_width=roi,
        degree=degree,
        min_inliers=min_inliers,
        min_extent_m=min_extent,
        max_curvature=max_curv,
        extend_to_bottom=extend,
    )
    if ransac:
        if data is not None:
            params.update(
                iterations=data.draw(st.integers(1, 60)),
                inlier_px=data.draw(st.floats(0.1, 10.0)),
                seed=data.draw(st.integers(0, 9)),
            )
        node = "fit.ransac"
    else:
        if data is not None:
            params.update(
                iterations=data.draw(st.integers(1, 20)), loss=data.draw(st.sampled_from(["tukey", "huber"]))
            )
        node = "fit.irls"
    out = call(
        node, {"features": fm, "lines": lines, "geometry": bev_geometry_for(rows, cols, res)}, **params
    )
    assert not isinstance(out, LanegraphError), out
    lanes = out["lanes"]
    event(f"{node}: {min(len(lanes), 1)}+ lanes")  # --hypothesis-show-statistics: not vacuous
    assert isinstance(lanes, list) and len(lanes) <= len(lines)
    for ln in lanes:
        assert isinstance(ln, Lane)
        assert len(ln.coeffs) == 3 and all(math.isfinite(c) for c in ln.coeffs)
        r0, r1 = ln.bev_rows
        assert 0 <= r0 <= r1 <= rows - 1
        assert 0.0 <= ln.score <= 1.0 and ln.side in ("left", "right")
        assert ln.extra["support"] >= min_inliers


# ============================================================================ lanes.temporal_mask / verify / to_image
@st.composite
def lanes_on(draw, rows: int, cols: int):
    out = []
    for _ in range(draw(st.integers(0, 3))):
        r0 = draw(st.integers(0, max(0, rows - 1)))
        r1 = draw(st.integers(r0, max(r0, rows - 1)))
        c = (draw(st.floats(-cols, 2.0 * cols)), draw(st.floats(-2.0, 2.0)), draw(st.floats(-0.05, 0.05)))
        out.append(
            Lane(
                coeffs=c,
                bev_rows=(r0, r1),
                side=draw(st.sampled_from(["left", "right"])),
                score=draw(st.floats(0.0, 1.0)),
            )
        )
    return out


@QUICK
@given(data=st.data(), rows=st.integers(1, 40), cols=st.integers(1, 40), seed=st.integers(0, 99))
def test_lane_post_processing(data, rows, cols, seed):
    """temporal mask, verification and projection of arbitrary (well-formed) lanes."""
    from lanegraph_road.ipm import IpmParams, bev_geometry

    res = 0.5
    p = IpmParams(
        x_min=-cols * res / 2, x_max=cols * res / 2, z_min=4.0, z_max=4.0 + rows * res, resolution=res
    )
    calib = calib_for(60, 80, 2.0)
    geom = bev_geometry(p, calib, 0.02, 0.0, 1.6)
    assert (geom.rows, geom.cols) == (rows, cols)
    lanes = data.draw(lanes_on(rows, cols))
    rng = np.random.default_rng(seed)
    fm = FeatureMap(mask=rng.random((rows, cols)) < 0.1)
    out = call(
        "lanes.temporal_mask",
        {"previous": lanes, "geometry": geom, "features": fm},
        band_px=data.draw(st.floats(0.1, 50.0)),
    )
    assert out["mask"].dtype == bool and out["mask"].shape == (rows, cols)
    img = _fill(rng, (rows, cols), data.draw(st.sampled_from(["zeros", "noise", "stripes"])), np.uint8)
    gap = data.draw(st.integers(0, 10))  # band_px < gap_px + 2 (empty bands) is rejected by the params
    out = call(
        "lanes.verify",
        {"lanes": lanes, "image": img, "geometry": geom},
        gap_px=gap,
        band_px=data.draw(st.integers(max(2, gap + 2), 40)),
        max_texture=data.draw(st.sampled_from([None, 13.3])),
        max_distance_m=data.draw(st.floats(0.5, 60.0)),
        paint_band_m=data.draw(st.floats(0.1, 3.0)),
        paint_gap_m=data.draw(st.floats(0.05, 1.0)),
        align_m=data.draw(st.floats(0.0, 1.0)),
    )
    assert isinstance(out["lanes"], list) and len(out["lanes"]) <= len(lanes)
    out = call(
        "lanes.to_image",
        {"lanes": lanes, "geometry": geom, "calib": calib},
        row_step=data.draw(st.floats(0.5, 10.0)),
    )
    for ln in out["lanes"]:
        pts = ln.points
        assert pts.ndim == 2 and pts.shape[1] == 2 and len(pts) >= 1 and np.isfinite(pts).all()
        assert (pts[:, 0] >= 0).all() and (pts[:, 0] <= calib.width - 1).all()
        assert (np.abs(np.diff(pts[:, 1])) <= 10 + 1e-9).all()


# ============================================================================ road.vdisparity / road.profile / road.mask
DISP_DTYPES = (np.float32, np.float64, np.uint8, np.uint16)
BAD_DISPARITY = st.sampled_from(
    [
        np.zeros((0, 4), np.float32),
        np.zeros((3, 0), np.float32),
        np.zeros(6, np.float32),
        np.zeros((2, 2, 2), np.float32),
    ]
)


@QUICK
@given(
    disp=st.one_of(arrays2d(dtypes=DISP_DTYPES, hi=150.0), BAD_DISPARITY),
    max_d=st.floats(0.5, 300.0),
    bin_size=st.floats(0.25, 16.0),
)
def test_road_vdisparity(disp, max_d, bin_size):
    assume(max_d / bin_size <= 1024)
    out = call("road.vdisparity", {"disparity": disp}, max_disparity=max_d, bin_size=bin_size)
    if isinstance(out, LanegraphError):
        assert isinstance(out, InputError) and "disparity" in str(out)
        assert disp.ndim != 2 or disp.size == 0, out
        return
    vd = out["vdisparity"]
    assert vd.dtype == np.float32 and vd.shape == (disp.shape[0], max(1, math.ceil(max_d / bin_size)))
    assert np.isfinite(vd).all() and (vd >= 0).all()
    valid = np.isfinite(disp.astype(np.float32)) & (disp.astype(np.float32) > 0)
    assert vd.sum() <= valid.sum()


@st.composite
def road_disparities(draw, side=st.integers(1, 64)):
    """``(disparity, calibration)``: a flat road's disparity (make_disparity, focal length 0.8 to 3
    image widths) with noise and holes, or garbage, in any dtype; or a disparity no port accepts."""
    if draw(st.integers(0, 4)) == 0:
        d = draw(BAD_DISPARITY)
        return d, calib_for(*(max(n, 1) for n in (d.shape + (1, 1))[:2]))
    h, w = draw(side), draw(side)
    calib = calib_for(h, w, draw(st.floats(0.8, 3.0)))
    kind = draw(st.sampled_from(["road", "road", "holes", "zeros", "nan", "noise"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    if kind in ("road", "holes"):
        d, calib = make_disparity(h, w, draw(st.floats(-3, 3)), draw(st.floats(0.5, 3.0)), f=calib.f)
        d = d + rng.normal(0, draw(st.sampled_from([0.0, 0.1, 1.0])), d.shape)
        if kind == "holes":
            for v in (0.0, -1.0, np.nan, np.inf):
                d[rng.random(d.shape) < 0.1] = v
    elif kind == "zeros":
        d = np.zeros((h, w))
    elif kind == "nan":
        d = np.full((h, w), np.nan)
    else:
        d = rng.uniform(-5, 80, (h, w))
    dtype = draw(st.sampled_from([np.float32, np.float32, np.float64, np.uint8]))
    if dtype == np.uint8:
        d = np.clip(np.nan_to_num(d, posinf=0), 0, 255)
    return d.astype(dtype), calib


@FEW
@given(
    pair=road_disparities(),
    data=st.data(),
    model=st.sampled_from(["linear", "quadratic"]),
    roll=st.booleans(),
    give_vd=st.sampled_from([None, None, "match", "mismatch"]),
)
@example(
    pair=(np.zeros((1, 1), np.float32), calib_for(1, 1)), data=None, model="linear", roll=True, give_vd=None
)
def test_road_profile(pair, data, model, roll, give_vd):
    disp, calib = pair
    params = {"model": model, "estimate_roll": roll, "max_disparity": 64.0, "bin_size": 1.0}
    if data is not None:
        params.update(
            max_disparity=data.draw(st.floats(4.0, 128.0)),
            bin_size=data.draw(st.floats(0.25, 4.0)),
            smoothness=data.draw(st.floats(0.0, 2.0)),
            max_step=data.draw(st.integers(1, 8)),
            min_row_count=data.draw(st.integers(1, 12)),
            min_fit_rows=data.draw(st.integers(2, 12)),
            min_fit_disparity_px=data.draw(st.floats(0.0, 5.0)),
            ransac_iterations=data.draw(st.integers(1, 60)),
            road_band_m=data.draw(st.sampled_from([0.0, 0.3, 1.0])),
            roll_iterations=data.draw(st.integers(1, 3)),
            roll_subsample=data.draw(st.integers(1, 3)),
        )
    inputs = {"disparity": disp, "calib": calib}
    if give_vd is not None and disp.ndim == 2:
        vd = call(
            "road.vdisparity",
            {"disparity": disp},
            max_disparity=params["max_disparity"],
            bin_size=params["bin_size"],
        )
        if isinstance(vd, dict):
            inputs["vdisparity"] = vd["vdisparity"] if give_vd == "match" else vd["vdisparity"][:, :-1]
    out = call("road.profile", inputs, **params)
    event(f"road.profile: {type(out).__name__ if isinstance(out, LanegraphError) else 'ok'}")
    if isinstance(out, LanegraphError):
        assert isinstance(out, InputError) and ("disparity" in str(out) or "vdisparity" in str(out))
        assert disp.ndim != 2 or disp.size == 0 or give_vd == "mismatch", out
        return
    assert give_vd != "mismatch" or "vdisparity" not in inputs, (
        "a v-disparity of the wrong shape must be refused"
    )
    road, vd = out["road"], out["vdisparity"]
    event(f"road.profile: valid={road.valid}")
    assert (
        isinstance(road, RoadModel)
        and vd.dtype == np.float32
        and vd.ndim == 2
        and vd.shape[0] == disp.shape[0]
    )
    assert road.profile is not None and road.profile.shape == (disp.shape[0],)
    assert np.isfinite(road.profile).all()
    if road.valid:
        assert all(math.isfinite(x) for x in (road.a0, road.a1, road.a2, road.roll, road.pitch, road.height))
        assert road.height > 0 and 0 <= road.v_min < disp.shape[0]
        assert road.a1 > 0 or model == "quadratic"  # the pose comes from the line, always rising


@QUICK
@given(data=st.data(), pair=road_disparities(), road=road_models())
def test_road_mask(data, pair, road):
    disp, calib = pair
    params = dict(
        height_tolerance_m=data.draw(st.floats(0.01, 2.0)),
        min_disparity_tolerance_px=data.draw(st.floats(0.0, 4.0)),
        max_distance_m=data.draw(st.floats(1.0, 1000.0)),
        free_space=data.draw(st.booleans()),
        min_obstacle_run_px=data.draw(st.integers(1, 10)),
        open_px=data.draw(st.integers(0, 9)),
        close_px=data.draw(st.integers(0, 9)),
        fill_holes_max_above=data.draw(st.floats(0.0, 1.0)),
        keep=data.draw(st.sampled_from(["all", "bottom", "bottom_centre"])),
        bottom_band_frac=data.draw(st.floats(0.01, 1.0)),
        textureless_is_road=data.draw(st.booleans()),
        invalid_road=data.draw(st.sampled_from(["all", "none"])),
    )
    out = call("road.mask", {"disparity": disp, "road": road, "calib": calib}, **params)
    if isinstance(out, LanegraphError):
        assert isinstance(out, InputError) and "disparity" in str(out)
        assert disp.ndim != 2 or disp.size == 0, out
        return
    assert out["mask"].dtype == bool and out["mask"].shape == disp.shape


# ============================================================================ bev.ipm
@FEW
@given(
    data=st.data(),
    image=st.one_of(
        images(side=st.integers(1, 30), dtypes=(np.uint8, np.float32, np.float64)),
        BAD_IMAGES,
        st.just(np.zeros((0, 3), np.uint8)),
    ),
    road=road_models(),
    with_mask=st.sampled_from([None, "match", "mismatch"]),
)
@example(
    data=None, image=np.zeros((1, 1), np.uint8), road=RoadModel(0.0, 0.0, valid=False), with_mask="match"
)
def test_bev_ipm(data, image, road, with_mask):
    if data is None:
        params = {"x_min": -1.0, "x_max": 1.0, "z_min": 2.0, "z_max": 6.0, "resolution": 0.1}
    else:
        x0 = data.draw(st.floats(-20.0, 19.0))
        z0 = data.draw(st.floats(0.5, 40.0))
        params = {
            "x_min": x0,
            "x_max": x0 + data.draw(st.floats(0.001, 20.0)),
            "z_min": z0,
            "z_max": z0 + data.draw(st.floats(0.001, 40.0)),
            "resolution": data.draw(st.floats(0.002, 10.0)),
            "interpolation": data.draw(st.sampled_from(["nearest", "linear", "cubic"])),
            "color": data.draw(st.sampled_from(["gray", "keep"])),
            "use_roll": data.draw(st.booleans()),
            "fallback_pitch_deg": data.draw(st.floats(-30.0, 30.0)),
            "fallback_height_m": data.draw(st.floats(0.06, 20.0)),
        }
        valid_params("bev.ipm", params)
        assume(
            (params["x_max"] - params["x_min"])
            * (params["z_max"] - params["z_min"])
            / params["resolution"] ** 2
            < 40_000
        )
    h, w = (image.shape + (1, 1))[:2]
    inputs = {"image": image, "road": road, "calib": calib_for(max(h, 1), max(w, 1))}
    if with_mask is not None and image.ndim >= 2:
        inputs["mask"] = np.ones((h + (with_mask == "mismatch"), w), bool)
    out = call("bev.ipm", inputs, **params)
    if isinstance(out, LanegraphError):
        assert isinstance(out, InputError) and (
            "image" in str(out) or "mask" in str(out) or "BEV grid" in str(out)
        ), out
        bad_image = (
            image.ndim not in (2, 3) or image.size == 0 or (image.ndim == 3 and image.shape[2] not in (1, 3))
        )
        assert bad_image or with_mask == "mismatch" or "BEV grid" in str(out), out
        return
    geom = out["geometry"]
    assert isinstance(geom, BevGeometry) and geom.rows >= 1 and geom.cols >= 1
    bev, bmask = out["image"], out["mask"]
    assert bmask.dtype == bool and bmask.shape == (geom.rows, geom.cols)
    assert bev.shape[:2] == (geom.rows, geom.cols)
    if image.dtype == np.uint8:
        assert bev.dtype == np.uint8
    assert not bev[~bmask].any() if with_mask is None else True, "outside the image the BEV is 0"


# ============================================================================ disparity.sgm / .sgbm / .bm
@st.composite
def stereo_pairs(
    draw, side_h=st.integers(1, 10), side_w=st.integers(1, 24), dtypes=(np.uint8, np.float32, np.float64)
):
    h, w = draw(side_h), draw(side_w)
    left = draw(arrays2d(dtypes=dtypes, shape=(h, w)))
    shift = draw(st.integers(0, 4))
    right = np.roll(left, -shift, axis=1)
    if draw(st.booleans()):
        left, right = np.repeat(left[:, :, None], 3, axis=2), np.repeat(right[:, :, None], 3, axis=2)
    if draw(st.integers(0, 9)) == 0:
        right = right[:, :-1] if right.shape[1] > 1 else right[:-1]  # a mismatched pair
    return left, right


def _disparity_common(draw) -> dict:
    return {
        "scale": draw(st.sampled_from([1.0, 1.0, 0.5, 0.25])),
        "upsample": draw(st.sampled_from(["nearest", "linear"])),
        "lr_check": draw(st.booleans()),
        "top_fraction": draw(st.sampled_from([0.0, 0.3, 0.9])),
        "strips": draw(st.integers(1, 3)),
        "strip_overlap": draw(st.integers(0, 4)),
    }


def _check_disparity(out, left: np.ndarray, right: np.ndarray) -> None:
    event("disparity: " + ("InputError" if isinstance(out, LanegraphError) else "map"))
    if isinstance(out, LanegraphError):
        assert isinstance(out, InputError), out
        return
    d = out["disparity"]
    assert d.dtype == np.float32 and d.shape == left.shape[:2]
    assert np.isfinite(d).all() and (d >= 0).all()
    assert left.shape[:2] == right.shape[:2], "a pair of different sizes must be refused"


@FEW
@given(data=st.data(), pair=stereo_pairs())
def test_disparity_sgm(data, pair):
    left, right = pair
    cw = data.draw(st.sampled_from([1, 3, 5, 7, 9]))
    ch = data.draw(st.sampled_from([1, 3, 5, 7]))
    assume(1 <= cw * ch - 1 <= 64)
    p1 = data.draw(st.integers(0, 40))
    params = dict(
        _disparity_common(data.draw),
        num_disparities=data.draw(st.integers(2, 24)),
        paths=data.draw(st.sampled_from([4, 8])),
        p1=p1,
        p2=p1 + data.draw(st.integers(1, 100)),
        census_width=cw,
        census_height=ch,
        uniqueness_ratio=data.draw(st.sampled_from([0, 10, 50])),
        subpixel=data.draw(st.booleans()),
        median_size=data.draw(st.sampled_from([0, 3, 5])),
    )
    _check_disparity(call("disparity.sgm", {"left": left, "right": right}, **params), left, right)


@FEW
@given(
    data=st.data(),
    pair=stereo_pairs(
        side_h=st.one_of(st.integers(1, 12), st.integers(24, 48)),
        side_w=st.one_of(st.integers(1, 24), st.integers(40, 96)),
    ),
    bm=st.booleans(),
)
def test_disparity_opencv(data, pair, bm):
    left, right = pair
    params = dict(
        _disparity_common(data.draw),
        num_disparities=data.draw(st.sampled_from([16, 32])),
        min_disparity=data.draw(st.sampled_from([0, 2])),
        uniqueness_ratio=data.draw(st.sampled_from([0, 10])),
        speckle_window_size=data.draw(st.sampled_from([0, 100])),
    )
    if bm:
        params["block_size"] = data.draw(st.sampled_from([5, 7, 11, 21]))
    else:
        params["block_size"] = data.draw(st.sampled_from([1, 3, 5, 11]))
        params["mode"] = data.draw(st.sampled_from(["sgbm", "3way", "hh"]))
    _check_disparity(
        call("disparity.bm" if bm else "disparity.sgbm", {"left": left, "right": right}, **params),
        left,
        right,
    )
