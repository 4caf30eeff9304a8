"""Graph validation: start from a valid graph, break one thing, assert the located message."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
import yaml

from lanegraph.errors import GraphError
from lanegraph.graph.model import graph_json_schema
from lanegraph.graph.validation import load_graph

VALID = {
    "name": "toy",
    "nodes": {
        "src": {"type": "toy.count", "params": {"n": 4}},
        "k": {"type": "toy.from_calib", "inputs": {"calib": "src.calib"}},
        "double": {"type": "toy.scale", "params": {"factor": 2}, "inputs": {"x": "src.value"}},
        "acc": {"type": "toy.add", "inputs": {"a": "double.y", "b": "acc.y@prev"}},
        "sink": {"type": "toy.collect", "inputs": {"frame": "src.frame", "x": "acc.y"}},
    },
}


def write(tmp_path: Path, data: dict, name: str = "g.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    return p


def errors_of(tmp_path, pm, data, name="g.yaml") -> GraphError:
    with pytest.raises(GraphError) as info:
        load_graph(write(tmp_path, data, name), pm=pm)
    return info.value


def mutate(fn):
    data = copy.deepcopy(VALID)
    fn(data)
    return data


def test_valid_graph_loads_in_topological_order(tmp_path, pm):
    g = load_graph(write(tmp_path, VALID), pm=pm)
    assert g.order.index("double") < g.order.index("acc") < g.order.index("sink")
    assert [e for e in g.edges if e.previous] == [g.nodes["acc"].inputs["b"]]
    assert g.nodes["double"].params.factor == 2.0


@pytest.mark.parametrize(
    "mutator, node, field, words",
    [
        (
            lambda d: d["nodes"]["double"].update(type="toy.scael"),
            "double",
            "type",
            ["unknown node type", "did you mean 'toy.scale'"],
        ),
        (
            lambda d: d["nodes"]["double"]["inputs"].update(xx="src.value"),
            "double",
            "inputs.xx",
            ["unknown input port 'xx'"],
        ),
        (
            lambda d: d["nodes"]["double"].update(inputs={}),
            "double",
            "inputs.x",
            ["required input port 'x'", "not connected"],
        ),
        (
            lambda d: d["nodes"]["double"]["inputs"].update(x="src.valu"),
            "double",
            "inputs.x",
            ["no output port 'valu'", "did you mean 'value'"],
        ),
        (
            lambda d: d["nodes"]["double"]["inputs"].update(x="nosuch.y"),
            "double",
            "inputs.x",
            ["unknown node 'nosuch'"],
        ),
        (
            lambda d: d["nodes"]["double"]["inputs"].update(x="src.frame"),
            "double",
            "inputs.x",
            ["port type mismatch", "expected 'number'", "got 'frame_id'"],
        ),
        (
            lambda d: d["nodes"]["double"]["params"].update(factor=1000),
            "double",
            "params.factor",
            ["less than or equal to 100", "1000"],
        ),
        (
            lambda d: d["nodes"]["double"]["params"].update(factr=3),
            "double",
            "params.factr",
            ["unknown key", "did you mean 'factor'"],
        ),
        (
            lambda d: d["nodes"]["double"]["params"].update(factor="big"),
            "double",
            "params.factor",
            ["expected", "'big'"],
        ),
        (
            lambda d: d["nodes"]["double"]["inputs"].update(x="src.value.x"),
            "double",
            "inputs.x",
            ["expected 'node_id.port'"],
        ),
        (
            lambda d: d["nodes"]["acc"]["inputs"].update(b="acc.y"),
            "acc",
            "inputs",
            ["cycle without a feedback edge", "acc -> acc"],
        ),
        (lambda d: d["nodes"]["double"].update(colour="red"), "double", "colour", ["unknown key"]),
        (lambda d: d["nodes"].pop("src"), None, "nodes", ["exactly one source node"]),
        (
            lambda d: d["nodes"].update(src2={"type": "toy.count"}),
            None,
            "nodes",
            ["exactly one source", "src, src2"],
        ),
        (
            lambda d: d["nodes"].update({"bad id": {"type": "toy.count"}}),
            None,
            "nodes",
            ["must start with a letter"],
        ),
    ],
)
def test_each_graph_error_is_located(tmp_path, pm, mutator, node, field, words):
    err = errors_of(tmp_path, pm, mutate(mutator))
    text = str(err)
    assert "g.yaml" in text
    if node:
        assert f"node '{node}'" in text
    assert field in text
    for w in words:
        assert w in text, text


def test_cycle_through_two_nodes(tmp_path, pm):
    d = mutate(lambda d: d["nodes"]["double"]["inputs"].update(x="acc.y"))
    err = errors_of(tmp_path, pm, d)
    assert "cycle" in str(err) and "double" in str(err) and "acc" in str(err)


def test_all_problems_reported_at_once(tmp_path, pm):
    def breaks(d):
        d["nodes"]["double"]["params"]["factor"] = 1000
        d["nodes"]["acc"]["inputs"]["a"] = "nosuch.y"
        d["nodes"]["sink"]["type"] = "toy.colect"

    err = errors_of(tmp_path, pm, mutate(breaks))
    assert len(err.problems) == 3
    assert err.exit_code == 2


def test_duplicate_node_ids_rejected(tmp_path, pm):
    p = tmp_path / "dup.yaml"
    p.write_text("nodes:\n  src: {type: toy.count}\n  src: {type: toy.count}\n")
    with pytest.raises(GraphError) as info:
        load_graph(p, pm=pm)
    assert (
        "duplicate key 'src'" in str(info.value)
        and "dup.yaml" in str(info.value)
        and "line 3" in str(info.value)
    )


def test_python_tags_never_execute(tmp_path, pm):
    p = tmp_path / "evil.yaml"
    p.write_text("nodes: !!python/object/apply:os.system ['echo hacked > %s']\n" % (tmp_path / "x"))
    with pytest.raises(GraphError) as info:
        load_graph(p, pm=pm)
    assert "invalid YAML" in str(info.value)
    assert not (tmp_path / "x").exists()


def test_json_and_toml_graphs(tmp_path, pm):
    (tmp_path / "g.json").write_text(json.dumps(VALID))
    assert load_graph(tmp_path / "g.json", pm=pm).nodes["acc"].inputs["b"].previous
    toml = """name = "t"
[nodes.src]
type = "toy.count"
[nodes.double]
type = "toy.scale"
inputs = { x = "src.value" }
"""
    (tmp_path / "g.toml").write_text(toml)
    assert load_graph(tmp_path / "g.toml", pm=pm).order[0] == "src"


def test_long_form_feedback_input(tmp_path, pm):
    d = mutate(lambda d: d["nodes"]["acc"]["inputs"].update(b={"from": "acc.y", "previous": True}))
    g = load_graph(write(tmp_path, d), pm=pm)
    assert g.nodes["acc"].inputs["b"].previous


# ---------------------------------------------------------------- extends and --set
def test_extends_overrides_params_type_and_removal(tmp_path, pm):
    write(tmp_path, VALID, "base.yaml")
    child = {
        "extends": "base.yaml",
        "name": "child",
        "nodes": {
            "double": {"params": {"factor": 3}},
            "acc": {"inputs": {"b": None}},
            "k": None,
            "triple": {"type": "toy.scale", "params": {"factor": 3}, "inputs": {"x": "acc.y"}},
            "sink": {"inputs": {"x": "triple.y"}},
        },
    }
    g = load_graph(write(tmp_path, child, "child.yaml"), pm=pm)
    assert g.name == "child"
    assert g.nodes["double"].params.factor == 3
    assert "b" not in g.nodes["acc"].inputs
    assert "k" not in g.nodes
    assert g.nodes["sink"].inputs["x"].src_node == "triple"


def test_extends_type_change_resets_params(tmp_path, pm):
    write(tmp_path, VALID, "base.yaml")
    child = {
        "extends": "base.yaml",
        "nodes": {"acc": {"type": "toy.scale", "inputs": {"x": "double.y", "a": None, "b": None}}},
    }
    g = load_graph(write(tmp_path, child, "child.yaml"), pm=pm)
    assert g.nodes["acc"].type.name == "toy.scale" and g.nodes["acc"].params.factor == 2.0


def test_error_in_base_graph_names_the_base_file(tmp_path, pm):
    bad = mutate(lambda d: d["nodes"]["double"]["params"].update(factor=1000))
    write(tmp_path, bad, "base.yaml")
    child = {"extends": "base.yaml", "nodes": {"acc": {"params": {}}}}
    err = errors_of(tmp_path, pm, child, "child.yaml")
    assert "base.yaml: node 'double'" in str(err)


def test_extends_cycle_rejected(tmp_path, pm):
    write(tmp_path, {"extends": "b.yaml", "nodes": {}}, "a.yaml")
    write(tmp_path, {"extends": "a.yaml", "nodes": {}}, "b.yaml")
    with pytest.raises(GraphError) as info:
        load_graph(tmp_path / "a.yaml", pm=pm)
    assert "extends cycle" in str(info.value)


def test_extends_outside_roots_rejected(tmp_path, pm):
    (tmp_path / "inner").mkdir()
    write(tmp_path, VALID, "base.yaml")
    child = write(tmp_path / "inner", {"extends": "../base.yaml"}, "c.yaml")
    with pytest.raises(GraphError) as info:
        load_graph(child, pm=pm, roots=[tmp_path / "inner"])
    assert "outside the allowed roots" in str(info.value)
    assert load_graph(child, pm=pm, roots=[tmp_path]).nodes


def test_remove_unknown_node_is_an_error(tmp_path, pm):
    write(tmp_path, VALID, "base.yaml")
    err = errors_of(tmp_path, pm, {"extends": "base.yaml", "nodes": {"nosuch": None}}, "c.yaml")
    assert "node 'nosuch'" in str(err) and "no such node" in str(err)


def test_set_overrides_are_validated(tmp_path, pm):
    p = write(tmp_path, VALID)
    g = load_graph(p, sets=["double.factor=5"], pm=pm)
    assert g.nodes["double"].params.factor == 5.0
    with pytest.raises(GraphError) as info:
        load_graph(p, sets=["double.factor=500"], pm=pm)
    assert "node 'double'" in str(info.value) and "params.factor" in str(info.value)
    with pytest.raises(GraphError) as info:
        load_graph(p, sets=["doubel.factor=5"], pm=pm)
    assert "did you mean 'double'" in str(info.value)
    with pytest.raises(GraphError):
        load_graph(p, sets=["factor5"], pm=pm)


def test_schema_includes_node_params(pm):
    schema = graph_json_schema(pm)
    assert "node_toy_scale" in schema["$defs"]
    props = schema["$defs"]["node_toy_scale"]["properties"]["params"]["properties"]
    assert props["factor"]["maximum"] == 100
    assert "description" in props["factor"]


def test_resolved_dict_round_trips(tmp_path, pm):
    g = load_graph(write(tmp_path, VALID), pm=pm)
    again = load_graph(write(tmp_path, g.resolved_dict(), "again.yaml"), pm=pm)
    assert again.resolved_dict() == g.resolved_dict()
