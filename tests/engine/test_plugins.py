"""Plugin discovery: entry points, broken plugins (a misspelt hook, a hookimpl that raises, a
node type another plugin provides) reported by every command and never fatal, allowlist."""

from __future__ import annotations

from importlib import metadata

import pytest
from click.testing import CliRunner

from lanegraph import NodeParams, hookimpl, node_type, node_type_of, plugins
from lanegraph.cli import main
from lanegraph.nodes import NodeType
from lanegraph.plugins import PluginManager


class FakeDist:
    def __init__(self, name):
        self.name = name


class FakeEP:
    def __init__(self, name, dist, target):
        self.name, self.dist, self._target = name, FakeDist(dist), target

    def load(self):
        if isinstance(self._target, Exception):
            raise self._target
        return self._target


class GoodPlugin:
    @staticmethod
    @hookimpl
    def lanegraph_node_types():
        @node_type("good.node", inputs={"x": "number"}, outputs={"y": "number"})
        def good(params: NodeParams, x):
            """A good node."""
            return {"y": x}

        return [good]


@pytest.fixture
def fake_eps(monkeypatch):
    eps = [
        FakeEP("good", "good-dist", GoodPlugin),
        FakeEP("broken", "broken-dist", ImportError("No module named 'missing_dep'")),
    ]
    monkeypatch.setattr(metadata, "entry_points", lambda group: eps if group == "lanegraph.plugins" else [])
    return eps


def test_broken_plugin_is_reported_not_fatal(fake_eps):
    pm = PluginManager()
    pm.load_entrypoints()
    assert "good.node" in pm.node_types
    assert len(pm.load_errors) == 1
    err = str(pm.load_errors[0])
    assert "broken" in err and "broken-dist" in err and "missing_dep" in err


def test_disable_autoload(fake_eps, monkeypatch):
    monkeypatch.setenv("LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD", "1")
    pm = PluginManager()
    pm.load_entrypoints()
    assert "good.node" not in pm.node_types and not pm.load_errors


def test_allowlist(fake_eps, monkeypatch):
    monkeypatch.setenv("LANEGRAPH_PLUGINS", "good")
    pm = PluginManager()
    pm.load_entrypoints()
    assert "good.node" in pm.node_types and not pm.load_errors


def test_duplicate_node_type_reported():
    pm = PluginManager()
    pm.register(GoodPlugin, name="a")

    class Again:
        lanegraph_node_types = GoodPlugin.lanegraph_node_types

    pm.register(Again, name="b")
    assert list(pm.node_types) == ["good.node"]
    assert pm.node_types["good.node"].plugin == "a"
    (err,) = pm.plugin_errors
    assert (
        err.plugin == "b" and "provided by both 'a' and 'b'" in str(err) and err.node_types == ("good.node",)
    )
    assert pm.get_plugin("b") is None, "the duplicating plugin is unregistered"


def test_suggest_did_you_mean():
    pm = PluginManager()
    pm.register(GoodPlugin, name="a")
    assert pm.suggest("good.nod") == "good.node"
    assert pm.suggest("zzz") is None


def test_builtin_plugins_discovered_through_entry_points():
    eps = {ep.name: ep for ep in metadata.entry_points(group="lanegraph.plugins")}
    assert {"lanegraph_io", "lanegraph_image", "lanegraph_disparity"} <= set(eps)
    pm = PluginManager()
    pm.load_entrypoints()
    assert "image.gray" in pm.node_types and pm.node_types["image.gray"].plugin == "lanegraph_image"


def test_node_type_name_must_be_family_dot_name():
    with pytest.raises(ValueError, match="family.name"):
        node_type("nofamily")(lambda params: {})


# --------------------------------------------------------------------------- the decorator returns the function
def test_node_type_returns_the_function_with_its_record():
    def double(params: NodeParams, x):
        """y = 2 x."""
        return {"y": 2 * x}

    decorated = node_type("toy.double", inputs={"x": "number"}, outputs={"y": "number"})(double)
    assert decorated is double and decorated(NodeParams(), x=4) == {"y": 8}  # still the plain function
    nt = node_type_of(double)
    assert (
        isinstance(nt, NodeType) and nt.name == "toy.double" and nt.func is double and double.node_type is nt
    )
    assert node_type_of(nt) is nt and node_type_of(len) is None and node_type_of(42) is None


def test_a_subclass_of_a_node_class_is_not_that_node_type():
    @node_type("toy.base", inputs={"x": "number"})
    class Base:
        """A stateful node."""

        def __init__(self, params: NodeParams, context):
            pass

    class Sub(Base):
        pass

    assert node_type_of(Base).name == "toy.base" and node_type_of(Sub) is None


# --------------------------------------------------------------------------- broken plugins
class Misspelt:
    """A plugin whose hook name lacks its final 's'."""

    @staticmethod
    @hookimpl
    def lanegraph_node_type():
        @node_type("misspelt.node", inputs={"x": "number"}, outputs={"y": "number"})
        def node(params: NodeParams, x):
            """Never registered."""
            return {"y": x}

        return [node]


@node_type("raising.node", inputs={"x": "number"}, outputs={"y": "number"})
def _raising_node(params: NodeParams, x):
    """Defined in the plugin's namespace, so a graph using it learns why it is missing."""
    return {"y": x}


class Raising:
    node = _raising_node

    @staticmethod
    @hookimpl
    def lanegraph_node_types():
        raise RuntimeError("the plugin's registry is broken")


class Duplicate:
    """A third-party plugin that provides the built-in image.gray again (and a type of its own)."""

    @staticmethod
    @hookimpl
    def lanegraph_node_types():
        @node_type("image.gray", inputs={"image": "image"}, outputs={"image": "gray"})
        def gray(params: NodeParams, image):
            """Not the built-in."""
            return {"image": image}

        @node_type("dup.other", inputs={"x": "number"}, outputs={"y": "number"})
        def other(params: NodeParams, x):
            """Goes with its plugin."""
            return {"y": x}

        return [gray, other]


class Unmarked:
    """A hook function without @hookimpl: pluggy would ignore it silently."""

    @staticmethod
    def lanegraph_node_types():
        return []


def test_misspelt_hook_is_reported_with_a_did_you_mean_and_the_plugin_left_out():
    pm = PluginManager()
    assert pm.register(Misspelt, name="misspelt") is None
    assert pm.get_plugin("misspelt") is None and "misspelt.node" not in pm.node_types
    (err,) = pm.plugin_errors
    assert "hook 'lanegraph_node_type' has no spec (did you mean 'lanegraph_node_types'?)" in str(err)
    pm.check_pending()  # nothing unspecced is left registered: pluggy's own check passes


def test_raising_hookimpl_is_reported_and_the_plugin_left_out():
    pm = PluginManager()
    pm.register(GoodPlugin, name="good")
    pm.register(Raising, name="raising")
    assert list(pm.node_types) == ["good.node"]
    (err,) = pm.plugin_errors
    assert "lanegraph_node_types hook raised RuntimeError: the plugin's registry is broken" in str(err)
    assert err.node_types == ("raising.node",) and pm.get_plugin("raising") is None


def test_unmarked_hook_function_is_reported():
    pm = PluginManager()
    assert pm.register(Unmarked, name="unmarked") is None
    assert "'lanegraph_node_types' is not marked with @lanegraph.hookimpl" in str(pm.plugin_errors[0])


def test_a_plugin_returning_something_else_than_node_types_is_left_out():
    class Wrong:
        @staticmethod
        @hookimpl
        def lanegraph_node_types():
            return ["image.gray"]

    pm = PluginManager()
    pm.register(GoodPlugin, name="good")
    pm.register(Wrong, name="wrong")
    assert list(pm.node_types) == ["good.node"]
    assert "returned 'image.gray', expected a function or class decorated with @lanegraph.node_type" in str(
        pm.plugin_errors[0]
    )


def test_hookimpls_may_still_return_node_type_records():
    class Records:
        @staticmethod
        @hookimpl
        def lanegraph_node_types():
            return [node_type_of(_raising_node)]

    pm = PluginManager()
    pm.register(Records, name="records")
    assert "raising.node" in pm.node_types and not pm.plugin_errors


@pytest.fixture
def broken_eps(monkeypatch):
    """The installed entry points plus three broken third-party plugins, in a fresh process-wide
    plugin manager. The broken ones sort before the built-ins by name."""
    real = list(metadata.entry_points(group="lanegraph.plugins"))
    eps = [
        *real,
        FakeEP("a_misspelt", "lg-misspelt", Misspelt),
        FakeEP("a_raising", "lg-raising", Raising),
        FakeEP("a_dup", "lg-dup", Duplicate),
    ]
    monkeypatch.setattr(metadata, "entry_points", lambda group: eps if group == "lanegraph.plugins" else [])
    monkeypatch.setattr(plugins, "_default", None)
    yield
    plugins.set_plugin_manager(None)


def _warnings(output: str) -> list[str]:
    return [line for line in output.splitlines() if line.startswith("warning: plugin")]


def test_broken_plugins_leave_every_command_working_with_a_warning(broken_eps, tmp_path):
    pm = plugins.get_plugin_manager()
    assert {e.plugin for e in pm.plugin_errors} == {"a_misspelt", "a_raising", "a_dup"}
    assert pm.node_types["image.gray"].plugin == "lanegraph_image", (
        "a third-party plugin never displaces a built-in type"
    )
    assert "dup.other" not in pm.node_types
    runner = CliRunner()
    demo = "graphs/demo_sgbm.yaml"
    r = runner.invoke(main, ["run", demo, "--out", str(tmp_path / "out"), "--frames", "0:1", "--quiet"])
    assert r.exit_code == 0, r.output
    assert "Traceback" not in r.output and len(_warnings(r.output)) == 3, r.output
    assert (
        "(did you mean 'lanegraph_node_types'?)" in r.output
        and "provided by both 'lanegraph_image' and 'a_dup'" in r.output
    )
    assert (tmp_path / "out" / "lanes.jsonl").is_file()
    for args in (["validate", demo], ["show", demo], ["schema"]):
        r = runner.invoke(main, args)
        assert r.exit_code == 0 and len(_warnings(r.output)) == 3, (args, r.output)
    r = runner.invoke(main, ["nodes"])
    assert r.exit_code == 0 and "plugins not loaded:" in r.output and "a_raising" in r.output
    r = runner.invoke(main, ["nodes", "--json"])
    assert len(__import__("json").loads(r.output)["plugin_errors"]) == 3


def test_a_graph_using_a_type_of_a_broken_plugin_says_so(broken_eps, tmp_path):
    g = tmp_path / "g.yaml"
    g.write_text(
        "nodes:\n  src: {type: io.auto}\n"
        "  a: {type: raising.node, inputs: {x: src.frame}}\n"
        "  b: {type: dup.other, inputs: {x: src.frame}}\n"
        "  c: {type: no.such, inputs: {x: src.frame}}\n"
    )
    r = CliRunner().invoke(main, ["validate", str(g)])
    assert r.exit_code == 2, r.output
    assert (
        "node 'a': type: unknown node type 'raising.node' (hint: it is a node type of plugin 'a_raising', which is not loaded: its lanegraph_node_types hook raised"
        in r.output
    )
    assert (
        "node 'b': type: unknown node type 'dup.other' (hint: it is a node type of plugin 'a_dup', which is not loaded: node type 'image.gray' is provided by both"
        in r.output
    )
    assert (
        "node 'c': type: unknown node type 'no.such'" in r.output
        and "could not be loaded (see the warnings): one may provide it" in r.output
    )


def test_a_calibration_plugin_s_input_error_reaches_the_user_as_it_is(tmp_path):
    """The hook's contract: a malformed file of the plugin's format is an InputError naming it;
    read_calibration passes it on unchanged, while any other exception of the plugin is
    a HookError naming the plugin and the hook."""
    from lanegraph.errors import HookError, InputError
    from lanegraph.run.sources import read_calibration

    class Reader:
        @hookimpl
        def lanegraph_read_calibration(self, path):
            if path.suffix != ".mine":
                return None
            if path.read_text() == "bug":
                raise ValueError("a bug")
            raise InputError("line 2: expected 12 numbers", path=str(path))

    pm = PluginManager()
    pm.register(Reader(), name="mine")
    bad = tmp_path / "c.mine"
    bad.write_text("1 2 3")
    with pytest.raises(InputError) as caught:
        read_calibration(pm, bad)
    assert type(caught.value) is InputError and "line 2: expected 12 numbers" in str(caught.value)
    bad.write_text("bug")
    with pytest.raises(HookError, match="mine.*lanegraph_read_calibration.*a bug"):
        read_calibration(pm, bad)
    other = tmp_path / "c.txt"
    other.write_text("x")
    with pytest.raises(InputError, match="no installed plugin reads this calibration file"):
        read_calibration(pm, other)
