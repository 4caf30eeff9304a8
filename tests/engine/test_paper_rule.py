"""One rule for every threshold of the paper graph (issue 44): ``graphs/paper.yaml`` is the file
``lanegraph tune`` writes (``benchmarks/tune_paper.py``), extending ``graphs/paper_base.yaml`` with
exactly the params of ``graphs/spaces/paper.yaml``, each inside its range; ``paper_base.yaml``
sets no other threshold by hand. No data needed: the files are read as they are."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import yaml
from lanegraph_tune.space import load_space

from lanegraph.builtin import find_graph, graph_names, graphs_dir
from lanegraph.graph.files import load_graph_named

ROOT = Path(__file__).resolve().parents[2]
GRAPHS = ROOT / "graphs"

#: what paper_base.yaml may set by hand besides the space's params: how the input is read and the
#: disparity matcher's search (its range, block, mode and where it starts; the uniqueness ratio that
#: leaves an ambiguous match without a disparity). None decides between a lane and no lane on a
#: candidate, and a trial changing one would recompute every frame's disparity (the cache shares it
#: between the trials now): they are the method's setting, not its thresholds.
NOT_TUNED = {
    "src.read_nice": "the decoding threads' nice step: changes no result",
    "disp.num_disparities": "the disparity range (96 reaches objects 4 m away on KITTI)",
    "disp.block_size": "SGBM's block",
    "disp.mode": "SGBM's mode",
    "disp.top_fraction": "the first frame's full-range band",
    "disp.uniqueness_ratio": "SGBM's uniqueness ratio (the road mask reads a missing disparity as road)",
}


def _raw(name: str) -> dict:
    return yaml.safe_load((GRAPHS / name).read_text(encoding="utf-8"))


def _set_params(raw: dict) -> dict[str, object]:
    return {
        f"{node_id}.{param}": value
        for node_id, node in (raw.get("nodes") or {}).items()
        for param, value in ((node or {}).get("params") or {}).items()
    }


def test_paper_yaml_sets_exactly_the_space_params_each_inside_its_range():
    paper = _raw("paper.yaml")
    assert paper["name"] == "paper" and paper["extends"] == "paper_base.yaml"
    assert set(paper) == {"name", "description", "extends", "nodes"}, "paper.yaml only sets params"
    for node_id, node in paper["nodes"].items():
        assert set(node) == {"params"}, f"paper.yaml: node {node_id}: only its params, not {sorted(node)}"
    sets = _set_params(paper)
    base = load_graph_named(GRAPHS / "paper_base.yaml")
    space = load_space(GRAPHS / "spaces" / "paper.yaml", base)  # every key a param of the graph
    assert sorted(sets) == sorted(space.keys), "a param paper.yaml sets escapes the tune, or one is not set"
    for p in space.params:
        v = sets[p.key]
        if p.kind == "choice":
            assert v in p.choices, f"paper.yaml: {p.key} = {v!r}: not one of {p.choices}"
        else:
            assert isinstance(v, int if p.kind == "int" else (int, float)) and not isinstance(v, bool), p.key
            assert p.low <= v <= p.high, f"paper.yaml: {p.key} = {v}: outside the space's [{p.low}, {p.high}]"


def test_the_resolved_paper_graph_has_the_tuned_values_and_the_base_no_other_threshold():
    paper = load_graph_named("paper")  # the built-in name, from any folder
    assert paper.name == "paper"
    for key, value in _set_params(_raw("paper.yaml")).items():
        node_id, _, param = key.partition(".")
        assert getattr(paper.nodes[node_id].params, param) == value, key
    space_keys = set(load_space(GRAPHS / "spaces" / "paper.yaml", paper).keys)
    escaped = sorted(set(_set_params(_raw("paper_base.yaml"))) - space_keys - set(NOT_TUNED))
    assert not escaped, (
        f"paper_base.yaml sets thresholds by hand that graphs/spaces/paper.yaml does not search: {escaped}"
    )
    # the base is the same graph: every node of paper.yaml's comes from it
    base = load_graph_named("paper_base")
    assert list(base.nodes) == list(paper.nodes)


def test_paper_yaml_names_the_command_that_writes_it():
    """The description holds the exact search benchmarks/tune_paper.py runs and its left-out figure."""
    spec = importlib.util.spec_from_file_location("tune_paper", ROOT / "benchmarks" / "tune_paper.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    text = (GRAPHS / "paper.yaml").read_text(encoding="utf-8")
    assert text.startswith(module.HEADER)
    description = " ".join(yaml.safe_load(text)["description"].split())
    assert f"`lanegraph {' '.join(module.TUNE)}`" in description
    assert re.search(r"Left out \(.*\), pooled: \d+\.\d % detection ratio \(precision", description)


def test_paper_and_its_base_are_built_in_graphs_found_from_anywhere(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert {"paper", "paper_base"} <= set(graph_names())
    assert find_graph("paper").resolve() == (graphs_dir() / "paper.yaml").resolve()
    # a user's graph extending paper.yaml outside the checkout: the chain to paper_base.yaml resolves
    (tmp_path / "mine.yaml").write_text(
        "extends: paper.yaml\nname: mine\nnodes:\n  merge: {params: {min_support_ratio: 1.5}}\n"
    )
    g = load_graph_named(tmp_path / "mine.yaml")
    assert g.name == "mine" and g.nodes["merge"].params.min_support_ratio == 1.5
    assert (
        g.nodes["verify"].params.min_paint_contrast
        == load_graph_named("paper").nodes["verify"].params.min_paint_contrast
    )
