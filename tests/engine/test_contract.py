"""The declared node contract (lanegraph.lifecycle): a node class declares what it implements,
registration checks it, and the engine reads the declaration instead of probing."""

from __future__ import annotations

import ast
import warnings
from pathlib import Path

import pytest

import lanegraph
from lanegraph import NodeParams, RunContext, hookimpl, node_type
from lanegraph.lifecycle import ATTRIBUTES, CAPABILITIES, Resumable, SinkNode, constants_of
from lanegraph.plugins import PluginManager
from lanegraph.run.executor import Executor

from .toyplugin import Count

PACKAGE = Path(lanegraph.__file__).resolve().parent


def _plugin(*node_types):
    class Plugin:
        @staticmethod
        @hookimpl
        def lanegraph_node_types():
            return list(node_types)

    return Plugin


def _register(*node_types) -> PluginManager:
    pm = PluginManager()
    pm.register(_plugin(*node_types), name="mine")
    pm.node_types  # noqa: B018 - build the registries
    return pm


# --------------------------------------------------------------------------- registration checks
def test_a_misspelt_restore_on_a_sink_that_declares_resume_is_a_plugin_error_naming_the_plugin():
    @node_type("my.sink", sink=True, inputs={"frame": "frame_id"}, implements=("resume",))
    class Sink:
        """Keeps its state."""

        def __init__(self, params: NodeParams, context: RunContext):
            pass

        def __call__(self, frame):
            return {}

        def state(self):
            return {}

        def restor(self, state):  # misspelt
            pass

    pm = _register(Sink)
    assert "my.sink" not in pm.node_types
    [err] = pm.plugin_errors
    assert err.plugin == "mine" and err.node_types == ("my.sink",)
    assert "node type 'my.sink'" in str(err)
    assert "declares 'resume' but defines no restore() (did you mean 'restor'?)" in str(err)


def test_a_base_class_declares_and_its_stub_does_not_count_as_the_method():
    @node_type("my.sink", sink=True, inputs={"frame": "frame_id"})
    class Sink(SinkNode, Resumable):
        """Declares resume by its base class, implements only state."""

        def __call__(self, frame):
            return {}

        def state(self):
            return {}

    nt = Sink.node_type
    assert {"close", "outputs", "resume"} <= nt.capabilities
    assert nt.contract_problems() == ["declares 'resume' but defines no restore()"]
    assert "my.sink" not in _register(Sink).node_types


def test_an_attribute_capability_must_be_annotated_and_a_capability_fit_its_kind():
    @node_type("my.src", source=True, outputs={"frame": "frame_id"}, implements=("skip", "result_files"))
    class Src:
        """Declares skip without the attribute, and a sink's capability."""

        def __init__(self, params: NodeParams, context: RunContext):
            self.skipped = 0

        def __iter__(self):
            yield {"frame": "0"}

        @staticmethod
        def result_files(params):
            return {}

    problems = Src.node_type.contract_problems()
    assert any("declares 'skip' but does not declare its attribute 'skipped'" in p for p in problems)
    assert "declares 'result_files', a capability of a sink (declare sink=True)" in problems


def test_an_unknown_capability_or_one_declared_by_a_function_is_refused_where_it_is_declared():
    with pytest.raises(ValueError, match=r"'restor' is not a capability \(did you mean 'resume'\?\)"):

        @node_type("my.sink", sink=True, implements=("restor",))
        class Sink:
            def __init__(self, params: NodeParams, context: RunContext):
                pass

    with pytest.raises(ValueError, match="declared by a node class, not a function"):

        @node_type("my.fn", implements=("close",))
        def fn(params: NodeParams):
            return {}


def test_methods_defined_without_being_declared_are_still_used_with_a_deprecation_warning():
    closed = []

    @node_type("my.sink", sink=True, inputs={"frame": "frame_id"})
    class Old:
        """Written before the declared contract."""

        def __init__(self, params: NodeParams, context: RunContext):
            pass

        def __call__(self, frame):
            return {}

        def close(self):
            closed.append(True)

    assert Old.node_type.undeclared == {"close"} and "close" in Old.node_type.capabilities
    with pytest.warns(DeprecationWarning, match=r"'my.sink' defines the methods of close without declaring"):
        pm = _register(Old)
    assert "my.sink" in pm.node_types and pm.plugin_errors == []
    from lanegraph.lifecycle import close

    close(Old(NodeParams(), RunContext()))
    assert closed == [True]


def test_what_is_not_declared_is_not_called():
    class Bare:
        def constants(self):  # not a node type: nothing declares it
            raise AssertionError("called")

    assert constants_of(Bare()) == {}
    source = Count(Count.node_type.params(n=2), RunContext())
    assert constants_of(source) == {"calib": "CAL"}  # Count declares constants


def test_every_stateful_plugin_class_declares_what_it_implements():
    from lanegraph.plugins import get_plugin_manager

    pm = get_plugin_manager()
    stateful = {n: nt for n, nt in pm.node_types.items() if nt.stateful}
    assert {"io.write_lanes", "io.synthetic", "io.folder", "disparity.onnx"} <= set(stateful) | {
        n for n, nt in pm.node_types.items() if nt.capabilities
    }
    for name, nt in pm.node_types.items():
        assert nt.contract_problems() == [], name
        assert nt.undeclared == frozenset(), f"{name} defines {sorted(nt.undeclared)} without declaring them"
    assert {"resume", "verify", "close", "outputs", "result_files"} <= pm.node_types[
        "io.write_lanes"
    ].capabilities


# --------------------------------------------------------------------------- the engine reads the declaration
def test_a_source_that_does_not_declare_skip_is_given_no_skip_and_the_executor_drops_the_frames(tmp_path):
    seen = {}

    @node_type("my.src", source=True, outputs={"frame": "frame_id"}, implements=("len",))
    class Src:
        """Three frames; applies no skip itself."""

        def __init__(self, params: NodeParams, context: RunContext):
            seen["skip"] = context.skip

        def __len__(self):
            return 3

        def __iter__(self):
            for i in range(3):
                yield {"frame": f"{i}"}

    from lanegraph.graph.validation import load_graph

    pm = _register(Src)
    (tmp_path / "g.yaml").write_text("name: g\nnodes:\n  src: {type: my.src}\n")
    g = load_graph(tmp_path / "g.yaml", pm=pm)
    with Executor(g, RunContext(skip=2), pm) as ex:
        assert seen["skip"] == 0 and len(ex) == 3


# --------------------------------------------------------------------------- no probing in the engine
#: the names of lanegraph.lifecycle's declaring classes
_LIFECYCLE_CLASSES = {
    name for name, v in vars(__import__("lanegraph.lifecycle").lifecycle).items() if isinstance(v, type)
}
_MEMBERS = {m for members in CAPABILITIES.values() for m in members} | ATTRIBUTES


def probes(source: str) -> list[str]:
    """The probes of a node in a module's source: ``isinstance``/``issubclass`` against a class of
    :mod:`lanegraph.lifecycle` (imported from it, or as ``lifecycle.X``), ``getattr``/``hasattr``
    of a capability's member, and a runtime-checkable protocol of the life cycle."""
    tree = ast.parse(source)
    from_lifecycle = {
        a.asname or a.name
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[-1] == "lifecycle"
        for a in node.names
    }
    out = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.args):
            continue
        fn, args = node.func.id, node.args
        if fn in ("isinstance", "issubclass") and len(args) == 2:
            classes = args[1].elts if isinstance(args[1], ast.Tuple) else [args[1]]
            for c in classes:
                if isinstance(c, ast.Name) and c.id in from_lifecycle:
                    out.append(f"line {node.lineno}: {fn}(..., {c.id})")
                if isinstance(c, ast.Attribute) and c.attr in _LIFECYCLE_CLASSES:
                    out.append(f"line {node.lineno}: {fn}(..., {ast.unparse(c)})")
        if fn in ("getattr", "hasattr") and len(args) >= 2:
            name = args[1]
            if isinstance(name, ast.Constant) and name.value in _MEMBERS:
                out.append(f"line {node.lineno}: {fn}(..., {name.value!r})")
    return out


def test_the_scan_finds_the_probes_the_engine_used_to_make():
    source = (
        "from ..lifecycle import Resumable, Sized as S\n"
        "from .. import lifecycle\n"
        "a = isinstance(inst, Resumable)\n"
        "b = isinstance(src, (int, S))\n"
        "c = isinstance(src, lifecycle.KeyedFrames)\n"
        "d = getattr(node.func, 'select_source', None)\n"
        "e = hasattr(inst, 'close')\n"
        "f = isinstance(x, Resumable2)\n"
        "g = getattr(os, 'O_NOFOLLOW', 0)\n"
    )
    assert [p.split(":")[0] for p in probes(source)] == ["line 3", "line 4", "line 5", "line 6", "line 7"]


def test_the_engine_never_probes_a_node():
    found = {
        str(path.relative_to(PACKAGE.parent)): p
        for path in sorted(PACKAGE.rglob("*.py"))
        if (p := probes(path.read_text(encoding="utf-8")))
    }
    assert found == {}


def test_no_deprecation_warning_for_the_built_in_plugins():
    from lanegraph.plugins import PluginManager as PM

    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        pm = PM()
        pm.load_entrypoints()
        assert pm.node_types
