"""What the executor works out once per run instead of on every frame."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..graph.model import Graph, GraphNode

#: output types that carry no ``valid`` flag (``RunResult.invalid_outputs`` counts the others' flags)
NO_VALID_FLAG = frozenset({np.ndarray, list, tuple, dict, str, int, float, bool, type(None)})


class Step(NamedTuple):
    """A per-frame node with its wiring: ``wiring`` holds ``(port, (src node, src port),
    feedback edge?)`` for each connected input, ``unwired`` the optional inputs left unconnected
    (they get None)."""

    id: str
    node: GraphNode
    wiring: tuple[tuple[str, tuple[str, str], bool], ...]
    unwired: tuple[str, ...]
    sink: bool


def frame_plan(graph: Graph, constant_nodes: set[str]) -> list[Step]:
    """The nodes that run on every frame (all but the source and the nodes of constant inputs), in
    execution order, each with its wiring."""
    source = graph.source.id
    steps = []
    for nid in graph.order:
        if nid == source or nid in constant_nodes:
            continue
        n = graph.nodes[nid]
        wiring = tuple((p, (e.src_node, e.src_port), e.previous) for p, e in n.inputs.items())
        unwired = tuple(p for p, port in n.type.inputs.items() if p not in n.inputs and port.optional)
        steps.append(Step(nid, n, wiring, unwired, bool(n.type.sink)))
    return steps
