"""lanegraph: stereo lane-marking detection as validated, plugin-based processing graphs."""

from __future__ import annotations

from .errors import GraphError, InputError, LanegraphError, NodeError, Problem, UsageError
from .hookspecs import hookimpl, hookspec
from .nodes import NodeParams, NodeType, NoParams, Port, RunContext, node_type
from .types import BevGeometry, Calibration, FeatureMap, Lane, Line, RoadModel

__version__ = "0.1.0"

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
    "Problem",
    "RoadModel",
    "RunContext",
    "UsageError",
    "hookimpl",
    "hookspec",
    "node_type",
]
