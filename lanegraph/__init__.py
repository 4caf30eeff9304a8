"""lanegraph: stereo lane-marking detection as validated, plugin-based processing graphs.

What a plugin author needs is importable from here: :func:`node_type` (a node stays a plain
function), :class:`NodeParams`, :class:`Port` and :class:`PortType`, :data:`hookimpl`, the value
types of :mod:`lanegraph.types`, the errors, and :func:`jit` / :data:`prange` for numba kernels with
the project's flags (imported on first use: ``import lanegraph`` does not load numba). Beside it, a
plugin imports only the core's public modules: :mod:`lanegraph.lifecycle` (what a node class
declares), :mod:`lanegraph.storage` (how its port types store their values),
:mod:`lanegraph.threads` (CPUs and thread pools), :mod:`lanegraph.paths`, :mod:`lanegraph.frames`,
:mod:`lanegraph.testing` in its tests (``tests/engine/test_layout.py`` checks it).
"""

from __future__ import annotations

from typing import Any

from ._version import __version__ as __version__
from .errors import GraphError, InputError, LanegraphError, NodeError, Problem, UsageError
from .hookspecs import hookimpl, hookspec
from .nodes import NodeParams, NodeType, NoParams, Port, RunContext, node_type, node_type_of
from .types import BevGeometry, Calibration, FeatureMap, Lane, Line, PortType, RoadModel

__all__ = [
    "BevGeometry",
    "Calibration",
    "FeatureMap",
    "GraphError",
    "InputError",
    "Lane",
    "LanegraphError",
    "Line",
    "NodeError",
    "NodeParams",
    "NodeType",
    "NoParams",
    "Port",
    "PortType",
    "Problem",
    "RoadModel",
    "RunContext",
    "UsageError",
    "hookimpl",
    "hookspec",
    "jit",
    "node_type",
    "node_type_of",
    "prange",
]


def __getattr__(name: str) -> Any:
    """``lanegraph.jit`` and ``lanegraph.prange``: numba's, with the project's flags and kernel
    cache (:mod:`lanegraph.kernels.decorator`), loaded when first asked for."""
    if name in ("jit", "prange"):
        from .kernels import decorator

        return getattr(decorator, name)
    raise AttributeError(f"module 'lanegraph' has no attribute {name!r}")
