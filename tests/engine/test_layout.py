"""The layout of lanegraph/ and plugins/: no import circle (imports inside functions included), no
module over 600 lines, a command line of thin command modules, no import up the layers, and plugins
that import only lanegraph's public surface."""

from __future__ import annotations

import ast
from pathlib import Path

import lanegraph

PACKAGE = Path(lanegraph.__file__).resolve().parent
ROOT = PACKAGE.parent
PLUGINS = ROOT / "plugins"
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


def foreign_imports(path: Path) -> set[str]:
    """The top-level packages other than lanegraph that a file imports, anywhere in it."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module.split(".")[0])
    return out - {"lanegraph"}


def test_the_engine_imports_no_add_on():
    """Dask is a plugin's (``lanegraph_dask``, the ``distributed`` extra): no module of lanegraph/
    imports Dask or a built-in plugin, anywhere in it (a function's import counts)."""
    assert "dask" in foreign_imports(PLUGINS / "lanegraph_dask" / "cluster.py")  # the check sees it
    found = {
        (name, pkg)
        for name, path in _modules().items()
        for pkg in foreign_imports(path)
        if pkg in ("dask", "distributed") or pkg.startswith("lanegraph_")
    }
    assert found == set()


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
    assert (
        "lanegraph.cli._errors" in graph["lanegraph.api"]
    )  # an add-on's commands handle errors the same way
    users = {
        m
        for m, edges in graph.items()
        if not m.startswith("lanegraph.cli")
        and m not in ("lanegraph.__main__", "lanegraph.api")
        and any(e.startswith("lanegraph.cli") for e in edges)
    }
    assert users == set()


#: the layers of lanegraph/, lowest first (docs/architecture.md): a module imports only from its own
#: layer and the ones below it; the two front ends stand side by side (neither imports the other):
#: ``cli`` (with ``python -m lanegraph``) and ``testing`` (the pytest plugin and conformance check,
#: which runs a node in a graph); ``api`` (:mod:`lanegraph.api`,
#: what an add-on imports) stands above them all
LAYERS = {
    "core": 0,
    "graph": 1,
    "records": 2,
    "run": 3,
    "batches": 4,
    "evaluation": 5,
    "presentation": 6,
    "service": 7,
    "cli": 8,
    "testing": 8,
    "api": 9,
}
#: the imports that cross the layers upwards on purpose, each with its reason (a new one fails the test)
UPWARD_ON_PURPOSE: dict[tuple[str, str], str] = {}
#: the top-level modules that are a layer of their own
_FRONT_ENDS = {"lanegraph.__main__": "cli", "lanegraph.testing": "testing", "lanegraph.api": "api"}


#: sub-packages of the core layer (the plugin author's contract): ``lanegraph.jit`` and its kernel cache
CORE_PACKAGES = {"kernels"}


def layer_of(module: str) -> str:
    """``core`` for ``lanegraph``, its top-level modules and :data:`CORE_PACKAGES`, else the
    sub-package (``run``, ``cli`` ...)."""
    if module in _FRONT_ENDS:
        return _FRONT_ENDS[module]
    parts = module.split(".")
    if len(parts) > 1 and parts[1] in CORE_PACKAGES:
        return "core"
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


def test_every_folder_of_modules_is_a_package():
    """A folder of modules without ``__init__.py`` imports (a namespace package) but is left out
    of the wheel (setuptools' ``packages.find``)."""
    folders = {p.parent for p in PACKAGE.rglob("*.py")}
    assert sorted(str(f.relative_to(ROOT)) for f in folders if not (f / "__init__.py").is_file()) == []


def test_every_subpackage_is_a_layer():
    assert {layer_of(m) for m in import_graph()} == set(LAYERS)


def test_the_layer_check_finds_a_core_module_importing_evaluation():
    # lanegraph/kitti_data.py was a core module that imported the ground truth reader of evaluation/
    graph = {"lanegraph.kitti_data": {"lanegraph.evaluation.metrics", "lanegraph.paths"}}
    assert upward_imports(graph) == {("lanegraph.kitti_data", "lanegraph.evaluation.metrics")}
    assert upward_imports({"lanegraph.service.x": {"lanegraph.evaluation.metrics"}}) == set()
    assert upward_imports({"lanegraph.evaluation.x": {"lanegraph.presentation.render"}}) != set()
    assert upward_imports({"lanegraph.cli.x": {"lanegraph.api"}}) != set()  # nothing imports the add-ons' API


def test_a_module_imports_only_from_its_layer_and_the_ones_below():
    assert upward_imports(import_graph()) == set(UPWARD_ON_PURPOSE) == set()


# --------------------------------------------------------------------------- plugins/
#: plugin modules over the 600-line cap for now, each with who is cutting it (a new one fails the
#: test; an entry that is no longer over the cap fails it too, so the list only shrinks)
TEMPORARILY_LONG: dict[str, str] = {}  # _verify.py and _follow.py split by concern (issue 44)
#: private engine imports of plugins for now, with who removes them (the list only shrinks)
TEMPORARILY_PRIVATE: dict[tuple[str, str], str] = {}
#: the engine modules below the core that a plugin may import besides the core's public ones
PUBLIC_BEYOND_CORE = {
    "lanegraph.presentation.render": "the drawing functions (a plugin's lanegraph_render, an overlay sink)",
}


def plugin_modules() -> dict[str, Path]:
    """``lanegraph_x/y.py`` -> path, for the built-in plugins and the example third-party plugin."""
    found = {str(p.relative_to(PLUGINS)): p for p in sorted(PLUGINS.glob("lanegraph_*/**/*.py"))}
    example = ROOT / "docs" / "examples"
    found.update({str(p.relative_to(example)): p for p in sorted(example.glob("*/*/**/*.py"))})
    return found


def is_public(module: str) -> bool:
    """Whether a plugin may import ``module``: ``lanegraph`` itself, a core module whose name does
    not start with ``_`` (nodes, lifecycle, types, errors, paths, frames, storage, threads ...),
    ``lanegraph.testing`` (a plugin's tests), ``lanegraph.api`` (an add-on: a command, a runner), or
    one of :data:`PUBLIC_BEYOND_CORE`."""
    parts = module.split(".")
    if module == "lanegraph" or module in PUBLIC_BEYOND_CORE:
        return True
    return len(parts) == 2 and layer_of(module) in ("core", "testing", "api") and not parts[1].startswith("_")


def engine_imports(path: Path) -> set[str]:
    """The lanegraph modules (or names) a file imports, anywhere in it."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == "lanegraph")
        elif (
            isinstance(node, ast.ImportFrom)
            and not node.level
            and (node.module or "").split(".")[0] == "lanegraph"
        ):
            mod = node.module or ""
            modules = _modules()
            out.update(f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names)
    return out


def test_the_public_surface_check_tells_private_from_public():
    assert is_public("lanegraph") and is_public("lanegraph.types") and is_public("lanegraph.storage")
    assert is_public("lanegraph.threads") and is_public("lanegraph.presentation.render")
    assert is_public("lanegraph.api") and not is_public("lanegraph.cli._common")
    for private in ("lanegraph._runtime", "lanegraph._numba", "lanegraph.run.cache", "lanegraph.graph.model"):
        assert not is_public(private), private


def test_plugins_import_only_lanegraphs_public_surface():
    private = {
        (name, m) for name, path in plugin_modules().items() for m in engine_imports(path) if not is_public(m)
    }
    assert private == set(TEMPORARILY_PRIVATE)


def test_no_plugin_module_is_over_600_lines():
    long = {
        name
        for name, path in plugin_modules().items()
        if len(path.read_text(encoding="utf-8").splitlines()) > MAX_LINES
    }
    assert long == set(TEMPORARILY_LONG)
