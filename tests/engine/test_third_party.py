"""A third-party plugin distribution, found through its entry-point metadata, runs in a graph
with no change to lanegraph's code."""

from __future__ import annotations

import sys
import textwrap

import yaml

from lanegraph.graph.validation import load_graph
from lanegraph.nodes import RunContext
from lanegraph.plugins import PluginManager
from lanegraph.run.executor import Executor

PLUGIN = textwrap.dedent(
    '''
    from pydantic import Field
    from lanegraph import NodeParams, hookimpl, node_type

    class NegParams(NodeParams):
        offset: float = Field(0.0, ge=-10, le=10, description="added after negation")

    @node_type("thirdparty.negate", inputs={"x": "number"}, outputs={"y": "number"})
    def negate(params: NegParams, x):
        """y = -x + offset."""
        return {"y": -x + params.offset}

    @hookimpl
    def lanegraph_node_types():
        return [negate]
    '''
)


def test_third_party_distribution_on_path(tmp_path, monkeypatch):
    site = tmp_path / "site"
    site.mkdir()
    (site / "lg_thirdparty.py").write_text(PLUGIN)
    dist = site / "lg_thirdparty-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: lg-thirdparty\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[lanegraph.plugins]\nthirdparty = lg_thirdparty\n")
    monkeypatch.syspath_prepend(str(site))

    pm = PluginManager()
    pm.load_entrypoints()
    assert "thirdparty.negate" in pm.node_types, pm.load_errors
    assert pm.node_types["thirdparty.negate"].plugin == "thirdparty"

    from . import toyplugin

    pm.register(toyplugin, name="toy")
    g = {
        "nodes": {
            "src": {"type": "toy.count", "params": {"n": 3}},
            "neg": {"type": "thirdparty.negate", "params": {"offset": 1}, "inputs": {"x": "src.value"}},
            "sink": {"type": "toy.collect", "inputs": {"frame": "src.frame", "x": "neg.y"}},
        }
    }
    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump(g))
    Executor(load_graph(p, pm=pm), RunContext(), pm).run()
    assert [x for _, x in toyplugin.Collect.out] == [1.0, 0.0, -1.0]
    sys.modules.pop("lg_thirdparty", None)
