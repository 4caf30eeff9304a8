"""The layout of lanegraph/: no import circle (imports inside functions included), no module over
600 lines, a command line of thin command modules."""

from __future__ import annotations

import ast
from pathlib import Path

import lanegraph

PACKAGE = Path(lanegraph.__file__).resolve().parent
MAX_LINES = 600


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def import_graph() -> dict[str, set[str]]:
    """``module -> the lanegraph modules it imports`` (anywhere in it: a function's import counts)."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        edges: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                # ``from . import x`` imports the module x when there is one
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
            else:
                continue
            for t in targets:
                while t and t not in modules:  # lanegraph.x.y where y is a name in module x
                    t = t.rpartition(".")[0]
                if t and t != name:
                    edges.add(t)
        graph[name] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_walk_finds_a_circle_when_there_is_one():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_the_walk_sees_imports_inside_functions():
    graph = import_graph()
    # the run service imports the debug recorder only when a run records pictures
    assert "lanegraph.presentation.debug" in graph["lanegraph.service.session"]
    assert "lanegraph.run.distributed" in graph["lanegraph.run.runners"]


def test_lanegraph_has_no_import_circle():
    assert cycles(import_graph()) == []


def test_no_module_is_over_600_lines():
    long = {
        name: n
        for name, path in _modules().items()
        if (n := len(path.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert long == {}


def test_nothing_below_the_command_line_imports_it():
    graph = import_graph()
    users = {
        m
        for m, edges in graph.items()
        if not m.startswith("lanegraph.cli")
        and m != "lanegraph.__main__"
        and any(e.startswith("lanegraph.cli") for e in edges)
    }
    assert users == set()


#: the layers of lanegraph/, lowest first (docs/architecture.md): a module imports only from its own
#: layer and the ones below it; ``data`` and ``presentation`` stand side by side (neither imports the other)
LAYERS = {
    "core": 0,
    "graph": 1,
    "run": 2,
    "evaluation": 3,
    "presentation": 4,
    "data": 4,
    "service": 5,
    "cli": 6,
}
#: the imports that cross the layers upwards on purpose, each with its reason (a new one fails the test)
UPWARD_ON_PURPOSE = {
    ("lanegraph.__main__", "lanegraph.cli"): "python -m lanegraph is the command line",
    ("lanegraph.plugins", "lanegraph.presentation.port_types"): (
        "the plugin manager registers lanegraph's own port types first, as a built-in plugin"
    ),
    ("lanegraph.testing", "lanegraph.graph.validation"): "the conformance check runs a node in a graph",
    ("lanegraph.testing", "lanegraph.run.task"): "the conformance check runs a node in a graph",
    ("lanegraph.testing", "lanegraph.presentation.port_types"): "the conformance check's own port types",
    ("lanegraph.evaluation.ablate", "lanegraph.presentation.plots"): "an ablation writes its two plots",
}


def layer_of(module: str) -> str:
    """``core`` for ``lanegraph`` and its top-level modules, else the sub-package (``run``, ``cli`` ...)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and parts[1] in LAYERS) else "core"


def upward_imports(graph: dict[str, set[str]]) -> set[tuple[str, str]]:
    """``(module, imported)`` pairs where a module imports from a layer above its own (or from a
    layer beside it)."""
    out = set()
    for module, edges in graph.items():
        mine = layer_of(module)
        for e in edges:
            theirs = layer_of(e)
            if theirs != mine and LAYERS[theirs] >= LAYERS[mine]:
                out.add((module, e))
    return out


def test_every_subpackage_is_a_layer():
    assert {layer_of(m) for m in import_graph()} == set(LAYERS)


def test_the_layer_check_finds_a_core_module_importing_evaluation():
    # lanegraph/kitti_data.py was a core module that imported the ground truth reader of evaluation/
    graph = {"lanegraph.kitti_data": {"lanegraph.evaluation.metrics", "lanegraph.paths"}}
    assert upward_imports(graph) == {("lanegraph.kitti_data", "lanegraph.evaluation.metrics")}
    assert upward_imports({"lanegraph.data.kitti": {"lanegraph.evaluation.metrics"}}) == set()
    assert upward_imports({"lanegraph.data.kitti": {"lanegraph.presentation.render"}}) != set()


def test_a_module_imports_only_from_its_layer_and_the_ones_below():
    assert upward_imports(import_graph()) == set(UPWARD_ON_PURPOSE)
