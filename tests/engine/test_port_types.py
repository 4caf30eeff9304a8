"""Port types are an open registry: a plugin adds its own through ``lanegraph_port_types``; a graph
wires through them (a sub-type feeds its parent's ports), and a port of a type nobody registers is a
located problem of the graph that wires it, never an import error."""

from __future__ import annotations

import numpy as np
import pytest

from lanegraph import GraphError, NodeParams, Port, PortType, RunContext, hookimpl, node_type
from lanegraph.graph.validation import validate_raw
from lanegraph.plugins import PluginManager
from lanegraph.run.executor import Executor
from lanegraph.run.prefetch import Prefetch
from lanegraph.testing import check_node_type

from . import toyplugin


@node_type(
    "cloud.points", inputs={"x": "number"}, outputs={"cloud": Port("point_cloud", "N x 3 points, metres")}
)
def points(params: NodeParams, x):
    """A cloud of ``x + 1`` points on a line."""
    n = int(x) + 1
    return {"cloud": np.stack([np.arange(n, dtype=float)] * 3, axis=1)}


@node_type(
    "cloud.ground", inputs={"x": "number"}, outputs={"cloud": Port("ground_cloud", "points on the road")}
)
def ground(params: NodeParams, x):
    """A cloud of road points (a ground_cloud is a point_cloud)."""
    return {"cloud": np.zeros((int(x) + 2, 3))}


@node_type("cloud.count", inputs={"cloud": Port("point_cloud")}, outputs={"n": "number"})
def count(params: NodeParams, cloud):
    """The number of points."""
    return {"n": float(len(cloud))}


@node_type("cloud.lidar", inputs={"scan": Port("lidar_scan")}, outputs={"n": "number"})
def lidar(params: NodeParams, scan):
    """Uses a port type that no installed plugin registers."""
    return {"n": 0.0}


class CloudPlugin:
    @staticmethod
    @hookimpl
    def lanegraph_port_types():
        return [
            PortType("point_cloud", "3-D points, N x 3 float64 metres"),
            PortType("ground_cloud", "3-D points on the road plane", parent="point_cloud"),
        ]

    @staticmethod
    @hookimpl
    def lanegraph_node_types():
        return [points, ground, count, lidar]


@pytest.fixture
def pm() -> PluginManager:
    m = PluginManager()
    m.register(toyplugin, name="toy")
    m.register(CloudPlugin, name="cloud")
    return m


def graph(pm: PluginManager, nodes: dict) -> object:
    return validate_raw(
        {"nodes": {"src": {"type": "toy.count", "params": {"n": 3}}, **nodes}}, {}, "g.yaml", pm
    )


def test_a_plugin_port_type_is_registered_beside_lanegraphs_own(pm):
    assert pm.port_types["point_cloud"].description.startswith("3-D points")
    assert pm.port_types["ground_cloud"].parent == "point_cloud"
    assert "image" in pm.port_types and not pm.plugin_errors


def test_a_graph_wires_through_a_plugin_port_type_and_its_subtype(pm):
    g = graph(
        pm,
        {
            "pts": {"type": "cloud.points", "inputs": {"x": "src.value"}},
            "gnd": {"type": "cloud.ground", "inputs": {"x": "src.value"}},
            "n1": {"type": "cloud.count", "inputs": {"cloud": "pts.cloud"}},
            "n2": {
                "type": "cloud.count",
                "inputs": {"cloud": "gnd.cloud"},
            },  # a ground_cloud is a point_cloud
            "out": {"type": "toy.collect", "inputs": {"frame": "src.frame", "x": "n2.n"}},
        },
    )
    Executor(g, RunContext(), pm, prefetcher=Prefetch(0)).run()
    assert [x for _, x in toyplugin.Collect.out] == [2.0, 3.0, 4.0]


def test_a_wrong_wiring_of_a_plugin_port_type_is_a_located_problem(pm):
    with pytest.raises(GraphError) as info:
        graph(
            pm,
            {
                "pts": {"type": "cloud.points", "inputs": {"x": "src.value"}},
                "wrong": {"type": "toy.scale", "inputs": {"x": "pts.cloud"}},  # a point_cloud is not a number
                "up": {"type": "cloud.count", "inputs": {"cloud": "src.value"}},
            },
        )
    text = str(info.value)
    assert (
        "g.yaml: node 'wrong' (toy.scale): inputs.x: port type mismatch: expected 'number', got 'point_cloud' from pts.cloud"
        in text
    )
    assert (
        "g.yaml: node 'up' (cloud.count): inputs.cloud: port type mismatch: expected 'point_cloud', got 'number' from src.value"
        in text
    )


def test_a_parent_does_not_feed_its_subtype(pm):
    @node_type("cloud.ground_only", inputs={"cloud": Port("ground_cloud")}, outputs={"n": "number"})
    def ground_only(params: NodeParams, cloud):
        """Takes road points only."""
        return {"n": 0.0}

    class More:
        @staticmethod
        @hookimpl
        def lanegraph_node_types():
            return [ground_only]

    pm.register(More, name="more")
    with pytest.raises(GraphError, match="expected 'ground_cloud', got 'point_cloud' from pts.cloud"):
        graph(
            pm,
            {
                "pts": {"type": "cloud.points", "inputs": {"x": "src.value"}},
                "g": {"type": "cloud.ground_only", "inputs": {"cloud": "pts.cloud"}},
            },
        )


def test_an_unregistered_port_type_is_a_problem_of_the_graph_that_wires_it(pm):
    # the node type imports and registers; only wiring its port is a problem
    assert "cloud.lidar" in pm.node_types
    with pytest.raises(GraphError) as info:
        graph(pm, {"l": {"type": "cloud.lidar", "inputs": {"scan": "src.value"}}})
    assert str(info.value) == (
        "g.yaml: node 'l' (cloud.lidar): inputs.scan: unknown port type 'lidar_scan' (input port 'scan' of cloud.lidar) "
        "(hint: no installed plugin registers it (through the lanegraph_port_types hook))"
    )
    # without the cloud plugin's port types, its producers are located too, with a did-you-mean
    bare = PluginManager()
    bare.register(toyplugin, name="toy")

    class NodesOnly:
        @staticmethod
        @hookimpl
        def lanegraph_node_types():
            return [points, count]

    bare.register(NodesOnly, name="nodes")
    with pytest.raises(
        GraphError, match=r"node 'n' \(cloud.count\): inputs.cloud: unknown port type 'point_cloud'"
    ):
        graph(
            bare,
            {
                "p": {"type": "cloud.points", "inputs": {"x": "src.value"}},
                "n": {"type": "cloud.count", "inputs": {"cloud": "p.cloud"}},
            },
        )


def test_a_port_type_name_is_checked_when_declared():
    with pytest.raises(ValueError, match="lower-case identifier"):
        Port("Point Cloud")


@pytest.mark.parametrize(
    "provided, words",
    [
        (
            [PortType("image", "not lanegraph's image")],
            "port type 'image' is already registered by lanegraph",
        ),
        (
            [PortType("orphan", "a child of nothing", parent="nothing")],
            "port type 'orphan': its parent 'nothing' is not a registered port type",
        ),
        ([PortType("a", "x", parent="b"), PortType("b", "y", parent="a")], "closes a cycle"),
        (["point_cloud"], "expected a PortType"),
    ],
)
def test_a_broken_port_type_leaves_its_plugin_out(provided, words):
    class Broken:
        @staticmethod
        @hookimpl
        def lanegraph_port_types():
            return provided

        @staticmethod
        @hookimpl
        def lanegraph_node_types():
            return [count]

    pm = PluginManager()
    pm.register(Broken, name="broken")
    assert "cloud.count" not in pm.node_types and words in str(pm.plugin_errors[0])
    assert set(pm.port_types) == set(PluginManager().port_types)


def test_the_same_port_type_from_two_plugins_is_fine_when_equal(pm):
    class Again:
        @staticmethod
        @hookimpl
        def lanegraph_port_types():
            return [PortType("point_cloud", "3-D points, N x 3 float64 metres")]

    pm.register(Again, name="again")
    assert not pm.plugin_errors and pm.get_plugin("again") is not None


def test_conformance_knows_the_plugins_port_types(pm):
    check_node_type(count, {"cloud": np.zeros((4, 3))}, pm=pm)
    with pytest.raises(AssertionError, match="unknown type 'point_cloud'"):
        check_node_type(count, {"cloud": np.zeros((4, 3))}, pm=PluginManager())


def test_lanegraph_nodes_lists_the_port_types_plugins_add(pm, monkeypatch):
    import json

    from click.testing import CliRunner

    from lanegraph import plugins
    from lanegraph.cli import main

    monkeypatch.setattr(plugins, "_default", pm)
    r = CliRunner().invoke(main, ["nodes"])
    assert r.exit_code == 0, r.output
    assert "port types added by plugins:" in r.output
    assert "    ground_cloud (feeds point_cloud ports): 3-D points on the road plane" in r.output
    listed = {
        t["name"]: t for t in json.loads(CliRunner().invoke(main, ["nodes", "--json"]).output)["port_types"]
    }
    assert listed["ground_cloud"]["parent"] == "point_cloud" and "image" in listed
