"""Testing helpers for plugin authors, shipped as a pytest plugin (entry point ``pytest11``).

Fixtures
--------
``lanegraph_pm``
    A fresh :class:`~lanegraph.plugins.PluginManager` with auto-discovery blocked: register only
    the plugin under test (``lanegraph_pm.register(my_plugin)``).

Functions
---------
:func:`run_node`
    Run one node type on given inputs without a graph.
:func:`make_stereo_pair`, :func:`make_disparity`, :func:`make_bev_image`
    Small synthetic inputs with known answers.
:func:`check_node_type`
    The conformance check: typed ports, documented params with bounds, deterministic, does not
    mutate its inputs, round-trips through a graph file.
"""

from __future__ import annotations

import copy
import dataclasses
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import Field

from .hookspecs import hookimpl
from .lifecycle import closing, constants_of
from .nodes import NodeParams, NodeType, Port, RunContext, node_type, node_type_of
from .plugins import PluginManager
from .types import Calibration, PortType

try:  # the fixture is only defined when pytest is importable
    import pytest
except ImportError:  # pragma: no cover
    pytest = None  # type: ignore[assignment]


# --------------------------------------------------------------------------- running one node
def _resolve(node: Any, pm: PluginManager | None) -> NodeType:
    """The record of a node given as its function or class (decorated with ``@node_type``), its
    :class:`NodeType` or its registered name."""
    if not isinstance(node, str):
        nt = node_type_of(node)
        if nt is None:
            raise TypeError(
                f"{node!r} is not a node type (a function or class decorated with @lanegraph.node_type)"
            )
        return nt
    from .plugins import get_plugin_manager

    nt = (pm or get_plugin_manager()).get_node_type(node)
    if nt is None:
        raise KeyError(f"node type {node!r} is not registered")
    return nt


def run_node(
    node: Any,
    inputs: Mapping[str, Any] | None = None,
    *,
    pm: PluginManager | None = None,
    context: RunContext | None = None,
    **params: Any,
) -> dict[str, Any]:
    """Run one node type once, without a graph, and return its outputs. ``node``: its function or
    class, its :class:`NodeType`, or its registered name (looked up in ``pm``).

    ``params`` are validated by the node type's params model; unconnected optional inputs get
    ``None``. A stateful node is instantiated with ``context`` (a temporary output folder by
    default), called once and closed; a source returns its constants merged with its first frame.
    """
    nt = _resolve(node, pm)
    p = nt.params.model_validate(params)
    ins = {k: None for k, port in nt.inputs.items() if port.optional}
    ins.update(inputs or {})
    unknown = set(ins) - set(nt.inputs)
    if unknown:
        raise TypeError(f"{nt.name}: unknown input port(s) {sorted(unknown)}; inputs: {list(nt.inputs)}")
    missing = [k for k in nt.inputs if k not in ins]
    if missing:
        raise TypeError(f"{nt.name}: required input port(s) {missing} not given")
    if not nt.stateful:
        return nt.func(p, **ins)
    if context is not None:
        return _one_frame(nt, p, context, ins)
    # a sink's files go to a temporary folder, removed afterwards (nothing left in the temporary folder)
    with tempfile.TemporaryDirectory(prefix="lanegraph-") as tmp:
        return _one_frame(nt, p, RunContext(out_dir=Path(tmp)), ins)


def _one_frame(nt: Any, p: Any, ctx: RunContext, ins: dict[str, Any]) -> dict[str, Any]:
    with closing(nt.func(p, ctx), nt) as obj:  # open, process one frame, close
        if nt.source:
            out = constants_of(obj, nt)
            out.update(next(iter(obj)))
            return out
        return obj(**ins) or {}


# --------------------------------------------------------------------------- synthetic inputs
def make_stereo_pair(
    height: int = 60, width: int = 96, disparity: int = 6, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, Calibration]:
    """A random-texture rectified pair whose true disparity is ``disparity`` px everywhere
    (except the ``disparity`` leftmost columns, which the right camera does not see), and a
    matching calibration.

    Disparity is positive as in every rectified pair: the pixel ``(row, x)`` of the left image is
    the pixel ``(row, x - disparity)`` of the right one (``left[:, d:] == right[:, :-d]``), so a
    block matcher such as ``cv2.StereoSGBM`` finds ``+disparity``."""
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (height, width + disparity), dtype=np.uint8)
    import cv2

    base = cv2.GaussianBlur(base, (3, 3), 0)
    left = base[:, :width].copy()
    right = base[:, disparity:].copy()
    calib = Calibration(f=width * 0.8, cx=width / 2, cy=height / 2, baseline=0.5, width=width, height=height)
    return left, right, calib


def make_disparity(
    height: int = 80,
    width: int = 120,
    pitch_deg: float = 1.0,
    cam_height: float = 1.6,
    f: float | None = None,
    baseline: float = 0.5,
) -> tuple[np.ndarray, Calibration]:
    """The exact disparity of a flat road (0 above the horizon) for a camera looking down by
    ``pitch_deg`` from ``cam_height`` metres, and its calibration."""
    f = f or width * 0.8
    calib = Calibration(f=f, cx=width / 2, cy=height / 2, baseline=baseline, width=width, height=height)
    th = np.radians(pitch_deg)
    v = np.arange(height, dtype=np.float64)[:, None]
    d = (baseline / cam_height) * (f * np.sin(th) + (v - calib.cy) * np.cos(th))
    disp = np.broadcast_to(np.where(d > 0, d, 0.0), (height, width)).astype(np.float32)
    return disp.copy(), calib


def make_bev_image(
    rows: int = 200,
    cols: int = 160,
    lane_cols: tuple[float, ...] = (50.0, 110.0),
    width_px: float = 3.0,
    slope: float = 0.0,
    background: int = 80,
    paint: int = 200,
    noise: float = 4.0,
    seed: int = 0,
) -> np.ndarray:
    """A BEV image (uint8) with bright vertical (``slope`` = column shift per row up) stripes at
    ``lane_cols`` on the bottom row."""
    rng = np.random.default_rng(seed)
    img = np.full((rows, cols), float(background))
    r = np.arange(rows)[:, None]
    c = np.arange(cols)[None, :]
    for c0 in lane_cols:
        centre = c0 + slope * (rows - 1 - r)
        cover = np.clip(width_px / 2 + 0.5 - np.abs(c - centre), 0.0, 1.0)  # anti-aliased stripe
        img = img * (1 - cover) + paint * cover
    img = img + rng.normal(0, noise, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------- conformance
class _FeedParams(NodeParams):
    frames: int = Field(2, ge=1, le=100, description="how many times the sample inputs are emitted")


def _feed_source(sample: Mapping[str, Any], types: Mapping[str, str]) -> type:
    outputs = {"frame": Port("frame_id")}
    outputs.update({k: Port(t) for k, t in types.items()})

    @node_type("testing.feed", source=True, outputs=outputs, implements=("len",))
    class Feed:
        """Emits the sample inputs of a conformance check as frames."""

        def __init__(self, params: _FeedParams, context: RunContext):
            self.n = params.frames

        def __len__(self) -> int:
            return self.n

        def __iter__(self):
            for i in range(self.n):
                yield {"frame": f"{i:06d}", **copy.deepcopy(dict(sample))}

    return Feed


def _equal(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.shape == b.shape
            and bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))
        )
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    if dataclasses.is_dataclass(a) and type(a) is type(b):
        # the compared fields only (not caches such as FeatureMap's feature points)
        return all(_equal(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a) if f.compare)
    if hasattr(a, "__dict__") and hasattr(b, "__dict__") and type(a) is type(b):
        return _equal(vars(a), vars(b))
    return bool(a == b)


def check_node_type(
    node: Any,
    sample_inputs: Mapping[str, Any],
    params: Mapping[str, Any] | None = None,
    pm: PluginManager | None = None,
) -> None:
    """Assert that ``node`` (its function or class, or its :class:`NodeType`) follows the lanegraph
    node contract; raises AssertionError naming the rule.

    1. typed ports (every port type is lanegraph's own or registered by a plugin of ``pm``, default
       the installed plugins), a docstring;
    2. documented params: every field has a description, numeric fields have lower and upper bounds;
    3. deterministic: two calls on the same inputs give equal outputs;
    4. does not mutate its inputs;
    5. round-trips through a graph file: a graph feeding ``sample_inputs`` to it validates and runs;
    6. keeps its declared contract (:mod:`lanegraph.lifecycle`): a node class defines every member of
       what it declares (``implements=`` or its base classes) and declares every capability whose
       methods it defines (checked first, sources included).
    """
    node = _resolve(node, pm)
    if pm is None:
        from .plugins import get_plugin_manager

        pm = get_plugin_manager()
    port_types = pm.port_types
    problems = node.contract_problems()
    assert not problems, f"{node.name}: {'; '.join(problems)}"
    assert not node.undeclared, (
        f"{node.name}: defines the methods of {', '.join(sorted(node.undeclared))} without declaring them "
        f"(implements={tuple(sorted(node.undeclared))!r} in its @node_type)"
    )
    assert node.doc.strip(), f"{node.name}: no docstring"
    for where, ports in (("input", node.inputs), ("output", node.outputs)):
        for name, port in ports.items():
            assert port.type in port_types, (
                f"{node.name}: {where} port {name!r} has unknown type {port.type!r} (not registered by any plugin)"
            )
    for name, f in node.params.model_fields.items():
        assert f.description, f"{node.name}: param {name!r} has no description"
        ann = f.annotation
        if ann in (int, float):
            meta = [m for m in f.metadata if any(hasattr(m, a) for a in ("ge", "gt", "le", "lt"))]
            lower = any(hasattr(m, "ge") or hasattr(m, "gt") for m in meta)
            upper = any(hasattr(m, "le") or hasattr(m, "lt") for m in meta)
            assert lower and upper, (
                f"{node.name}: numeric param {name!r} needs lower and upper bounds (ge/le)"
            )
    if node.source:
        return
    params = dict(params or {})
    frozen = copy.deepcopy(dict(sample_inputs))
    first = run_node(node, copy.deepcopy(dict(sample_inputs)), **params)
    given = dict(sample_inputs)
    again = run_node(node, given, **params)
    assert _equal(first, again), f"{node.name}: not deterministic (two calls on the same inputs differ)"
    assert _equal(given, frozen), f"{node.name}: mutated its inputs"
    assert set(first) >= set(node.outputs) or node.sink, (
        f"{node.name}: missing outputs {set(node.outputs) - set(first)}"
    )

    _round_trip(node, sample_inputs, params, pm.port_types)


def _round_trip(
    node: NodeType,
    sample_inputs: Mapping[str, Any],
    params: Mapping[str, Any],
    port_types: Mapping[str, PortType],
) -> None:
    """The conformance check's last rule: a graph feeding ``sample_inputs`` to ``node`` validates,
    round-trips through a graph file and runs."""
    from .graph.validation import load_graph
    from .port_types import PORT_TYPES as own
    from .run.prefetch import Prefetch
    from .run.task import run_graph

    types = {k: node.inputs[k].type for k in sample_inputs}
    feed = _feed_source(sample_inputs, types)

    class _Plugin:
        @staticmethod
        @hookimpl
        def lanegraph_node_types():
            return [feed, node]

        @staticmethod
        @hookimpl
        def lanegraph_port_types() -> list[PortType]:
            return [pt for pt in port_types.values() if pt.name not in own]

    pm = PluginManager()
    pm.register(_Plugin, name="conformance")
    graph = {
        "name": "conformance",
        "nodes": {
            "src": {"type": "testing.feed"},
            "node": {
                "type": node.name,
                "params": dict(params),
                "inputs": {k: f"src.{k}" for k in sample_inputs},
            },
        },
    }
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "conformance.yaml"
        path.write_text(yaml.safe_dump(graph, sort_keys=False))
        g = load_graph(path, pm=pm)
        path2 = Path(tmp) / "resolved.yaml"
        path2.write_text(yaml.safe_dump(g.resolved_dict(), sort_keys=False))
        g2 = load_graph(path2, pm=pm)
        assert g2.resolved_dict() == g.resolved_dict(), f"{node.name}: graph file does not round-trip"
        res = run_graph(g2, RunContext(out_dir=Path(tmp)), pm, prefetcher=Prefetch(0))
        assert res.frames == 2, f"{node.name}: did not run in a graph"


if pytest is not None:

    @pytest.fixture
    def lanegraph_pm() -> PluginManager:
        """A plugin manager with auto-discovery blocked: register only the plugin under test."""
        return PluginManager()
