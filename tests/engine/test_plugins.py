"""Plugin discovery: entry points, broken plugins, allowlist, duplicates."""

from __future__ import annotations

from importlib import metadata

import pytest

from lanegraph import NodeParams, hookimpl, node_type
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
    assert any("provided by both" in e for e in pm.registry_errors)


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
