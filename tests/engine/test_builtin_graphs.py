"""Built-in graphs found from any folder (issue 32): names, `lanegraph graphs`, did-you-mean,
``extends: paper.yaml`` in a user's own graph outside the checkout."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from lanegraph.builtin import find_graph, graph_names, graphs_dir
from lanegraph.cli import main
from lanegraph.errors import GraphError
from lanegraph.graph.model import load_raw

REPO_GRAPHS = Path(__file__).resolve().parents[2] / "graphs"


def test_graphs_dir_has_every_file_of_the_repository(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # nothing depends on the current folder
    names = graph_names()
    expected = sorted(
        p.relative_to(REPO_GRAPHS).with_suffix("").as_posix() for p in REPO_GRAPHS.rglob("*.yaml")
    )
    assert sorted(names + graph_names("datasets") + graph_names("spaces")) == expected
    assert "spaces/paper" in graph_names("spaces") and "spaces/paper" not in names
    assert "paper" in names and "ablations/slt" in names and "datasets/dev" in graph_names("datasets")
    assert find_graph("paper").resolve() == (graphs_dir() / "paper.yaml").resolve()
    assert find_graph("ablations/slt.yaml").name == "slt.yaml"


def test_unknown_name_gets_did_you_mean(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(GraphError, match=r"did you mean 'paper'\?"):
        find_graph("papr")
    r = CliRunner().invoke(main, ["run", "papr", "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "did you mean 'paper'?" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "o").exists()  # nothing written before the graph is found
    # a path (with a folder or a suffix) is reported where it is, as before
    r = CliRunner().invoke(main, ["validate", "nope/graph.yaml"])
    assert r.exit_code == 2 and "graph file not found" in r.output


def test_graphs_command_lists_graphs_and_datasets(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, ["graphs"])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert any(
        line.split()[0] == "ablations/slt" and "SLT instead of ESLT" in line
        for line in lines[1:]
        if line.strip()
    )
    assert any(line.strip().startswith("datasets/dev") for line in lines)
    r = CliRunner().invoke(main, ["graphs", "--paths"])
    assert all(Path(line.strip()).is_file() for line in r.output.splitlines() if not line.startswith("#"))


def test_user_graph_extends_builtin_from_another_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    mine = tmp_path / "mine.yaml"
    mine.write_text("extends: paper.yaml\nname: mine\nnodes:\n  hough: {params: {min_relative: 0.3}}\n")
    raw, origin, _ = load_raw(mine, roots=[tmp_path, graphs_dir().resolve()])
    assert raw["name"] == "mine" and raw["nodes"]["hough"]["params"]["min_relative"] == 0.3
    assert "disp" in raw["nodes"]  # the built-in paper graph's nodes
    r = CliRunner().invoke(main, ["validate", str(mine)])
    assert r.exit_code == 0, r.output
    # a file of that name beside the graph wins over the built-in one
    (tmp_path / "paper.yaml").write_text("name: local\nnodes: {hough: {type: toy.scale}}\n")
    raw, _, _ = load_raw(mine, roots=[tmp_path])
    assert "disp" not in raw["nodes"]
    # no escape through the fallback: '..' and absolute paths are never looked up among the built-ins
    up = tmp_path / "sub"
    up.mkdir()
    (up / "g.yaml").write_text("extends: ../../paper.yaml\nnodes: {}\n")
    with pytest.raises(GraphError, match="outside the allowed roots|not found"):
        load_raw(up / "g.yaml", roots=[up])


def test_checkout_paths_and_dataset_names_are_found_from_any_folder(tmp_path, monkeypatch):
    """``graphs/paper.yaml`` (as a checkout's docs write it) is the built-in graph where the
    current folder has none; ``datasets/kitti_lanes`` is found like every built-in name; a
    misspelt one gets the closest name; a dataset refused is exit 2 (before any frame)."""
    from lanegraph.builtin import find_dataset, find_graph, graphs_dir
    from lanegraph.errors import GraphError, InputError
    from lanegraph.evaluation.dataset import load_dataset

    monkeypatch.chdir(tmp_path)
    assert find_graph("graphs/paper.yaml") == graphs_dir() / "paper.yaml"
    assert find_graph("graphs/ablations/slt.yaml") == graphs_dir() / "ablations" / "slt.yaml"
    with pytest.raises(GraphError, match="did you mean 'paper'"):
        find_graph("graphs/papr.yaml")
    for name in ("datasets/kitti_lanes", "graphs/datasets/kitti_lanes.yaml"):
        assert find_dataset(name) == graphs_dir() / "datasets" / "kitti_lanes.yaml"
    with pytest.raises(InputError, match="did you mean 'datasets/kitti_lanes'") as err:
        load_dataset("datasets/kitti_lane")
    assert err.value.exit_code == 2
    with pytest.raises(InputError, match="no such folder") as err:  # its data is not downloaded here
        load_dataset("datasets/kitti_lanes")
    assert err.value.exit_code == 2
