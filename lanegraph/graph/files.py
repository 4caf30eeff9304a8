"""Finding and loading a graph file: the one way every command loads a graph.

A graph argument is a file or a name under ``graphs/`` (:func:`resolve_graph_path`); ``extends``
may only point into the folders of :func:`allowed_roots`; :func:`open_graph` gives the
:class:`ResolvedGraph` (``extends`` and ``--set`` applied), which validates into a fresh
:class:`~lanegraph.graph.model.Graph` each time it is asked (what a run, or a task sent to a
worker, carries).
"""

from __future__ import annotations

import copy
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..builtin import find_graph, graphs_dir
from ..errors import GraphError, Problem
from ..plugins import PluginManager, get_plugin_manager
from .model import Graph, load_raw
from .validation import validate_raw

REPO_GRAPHS = graphs_dir()  # the built-in graphs: lanegraph/graphs when installed, graphs/ in a checkout


#: a graph argument as a file: a path, or a name under ``graphs/`` (``paper``, ``ablations/slt``)
#: in the current folder, then among the built-in graphs (:func:`lanegraph.builtin.find_graph`)
resolve_graph_path = find_graph


def allowed_roots(graph_path: Path) -> list[Path]:
    """Where ``extends`` may point: the graph's own folder, the current folder, lanegraph's
    ``graphs/`` and the folders listed in ``LANEGRAPH_GRAPH_ROOTS`` (os.pathsep-separated)."""

    def resolved(p: Path, where: str, field: str | None = None) -> Path:
        try:
            return p.resolve()
        except (OSError, RuntimeError) as exc:  # a symbolic link loop
            raise GraphError(
                [
                    Problem(
                        f"cannot resolve {str(p)!r}: {exc} (a symbolic link loop?)", file=where, field=field
                    )
                ]
            ) from None

    roots = [
        resolved(graph_path, str(graph_path)).parent,
        resolved(Path.cwd(), "the current folder"),
        REPO_GRAPHS.resolve(),
    ]
    roots += [
        resolved(Path(p), "LANEGRAPH_GRAPH_ROOTS", p)
        for p in os.environ.get("LANEGRAPH_GRAPH_ROOTS", "").split(os.pathsep)
        if p
    ]
    return roots


@dataclass(frozen=True)
class ResolvedGraph:
    """A graph file with ``extends`` and ``--set`` applied, not yet validated (see
    :func:`lanegraph.graph.model.load_raw`): what a task carries to a worker."""

    raw: dict[str, Any]
    origin: dict[str, str]
    display: str
    sets: tuple[str, ...] = ()  # the --set overrides applied (recorded in run.json)

    @classmethod
    def load(
        cls, path: str | Path, sets: Iterable[str] = (), roots: list[Path] | None = None
    ) -> ResolvedGraph:
        raw, origin, display = load_raw(path, list(sets), roots)
        return cls(raw, origin, display, tuple(sets))

    def validate(self, pm: PluginManager | None = None) -> Graph:
        """The validated :class:`~lanegraph.graph.model.Graph`, once per plugin manager (nothing
        changes a validated graph: the executor runs a selecting source in a copy of its own); a
        task sent to a worker validates it there, once."""
        pm = pm or get_plugin_manager()
        memo: dict[int, tuple[PluginManager, Graph]] = self.__dict__.setdefault("_validated", {})
        kept = memo.get(id(pm))
        if kept is None or kept[0] is not pm:
            kept = memo[id(pm)] = (
                pm,
                validate_raw(copy.deepcopy(self.raw), dict(self.origin), self.display, pm),
            )
        return kept[1]

    def __getstate__(self) -> dict[str, Any]:  # a task travels without the validated graph
        return {k: v for k, v in self.__dict__.items() if k != "_validated"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)


def open_graph(name: str | Path, sets: Iterable[str] = ()) -> ResolvedGraph:
    """The graph ``name`` (a file, or a name under ``graphs/``) with ``sets`` applied; raises a
    :class:`~lanegraph.errors.GraphError` saying where it is wrong."""
    path = resolve_graph_path(str(name))
    return ResolvedGraph.load(path, sets, allowed_roots(path))


def load_graph_named(name: str | Path, sets: Iterable[str] = (), pm: PluginManager | None = None) -> Graph:
    """:func:`open_graph`, validated."""
    return open_graph(name, sets).validate(pm)
