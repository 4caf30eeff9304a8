"""A corpus of broken graph files (tests/corpus/graphs/): each one must make `lanegraph validate`
exit with code 2 and a located message (the file, the node id, the field or port, what was
expected), never a traceback. The expected substrings live in tests/corpus/graphs/expected.yaml.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from lanegraph import plugins
from lanegraph.cli import main
from lanegraph.graph.loader import MAX_FILE_BYTES

CORPUS = Path(__file__).resolve().parent / "corpus" / "graphs"
EXPECTED: dict = yaml.safe_load((CORPUS / "expected.yaml").read_text())
CASE_FILES = sorted(p.name for p in CORPUS.iterdir() if p.is_file() and p.name != "expected.yaml")


def _case(name: str) -> tuple[Path, list[str], str, list[str]]:
    """(graph file, extra args, location the message must name, expected substrings)."""
    entry = EXPECTED[name]
    if isinstance(entry, list):
        entry = {"expect": entry}
    graph = CORPUS / entry.get("file", name)
    return graph, list(entry.get("args", [])), entry.get("shown", name), list(entry["expect"])


@pytest.fixture
def cli(installed_pm, monkeypatch, tmp_path) -> CliRunner:
    monkeypatch.setattr(plugins, "_default", installed_pm)
    monkeypatch.delenv("LANEGRAPH_GRAPH_ROOTS", raising=False)
    monkeypatch.chdir(tmp_path)  # the allowed roots: the graph's folder, tmp_path and lanegraph's graphs/
    return CliRunner()


def _check(output: str, exit_code: int, shown: str, expect: list[str]) -> None:
    assert exit_code == 2, output
    assert "Traceback" not in output, output
    assert output.startswith("error: "), output
    assert shown in output, output
    for words in expect:
        assert words in output, f"{words!r} not in:\n{output}"


def test_every_case_file_has_an_expectation_and_vice_versa():
    assert len(CASE_FILES) >= 30
    missing = [f for f in CASE_FILES if f not in EXPECTED]
    assert not missing, f"add these to expected.yaml: {missing}"
    for name in EXPECTED:
        graph, _, _, expect = _case(name)
        assert graph.is_file(), f"expected.yaml: {name}: no file {graph}"
        assert expect, f"expected.yaml: {name}: no expected substrings"


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_broken_graph_gives_a_located_error(cli, name):
    graph, args, shown, expect = _case(name)
    r = cli.invoke(main, ["validate", str(graph), *args])
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    _check(r.output, r.exit_code, shown, expect)


@pytest.mark.parametrize("good", ["good.yaml", "merge_keys.yaml"])
def test_helper_graphs_are_valid(cli, good):
    """The corpus' valid bases (and a graph using YAML merge keys) pass: each broken case breaks one thing."""
    r = cli.invoke(main, ["validate", str(CORPUS / "_parts" / good)])
    assert r.exit_code == 0, r.output


def test_too_large_file(cli, tmp_path):
    big = tmp_path / "too_large.yaml"
    big.write_text("nodes:\n  src: {type: io.auto}\n" + "#" * MAX_FILE_BYTES + "\n")
    r = cli.invoke(main, ["validate", str(big)])
    _check(r.output, r.exit_code, "too_large.yaml", [f"graph files are limited to {MAX_FILE_BYTES}", "bytes"])


def test_set_with_a_huge_int(cli):
    """A value with more digits than Python converts to an int, from the command line."""
    good = CORPUS / "_parts" / "good.yaml"
    r = cli.invoke(main, ["validate", str(good), "--set", "disp.num_disparities=" + "9" * 5000])
    _check(r.output, r.exit_code, "--set", ["node 'disp' (disparity.sgbm)", "params.num_disparities:", "..."])
    assert len(r.output) < 1000, "the value is cut in the message"


def test_python_tag_never_runs(cli, tmp_path):
    marker = tmp_path / "pwned"
    evil = tmp_path / "evil.yaml"
    evil.write_text(f"nodes: !!python/object/apply:os.system ['touch {marker}']\n")
    r = cli.invoke(main, ["validate", str(evil)])
    _check(r.output, r.exit_code, "evil.yaml", ["invalid YAML"])
    assert not marker.exists()


def _commands() -> list[list[str]]:
    cmds = [[sys.executable, "-m", "lanegraph.cli"]]
    script = shutil.which(
        "lanegraph", path=str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", "")
    )
    if script:
        cmds.append([script])
    return cmds


@pytest.mark.parametrize("name", ["python_tag.yaml", "billion_laughs.yaml", "removed_node_still_wired.yaml"])
def test_broken_graph_in_a_real_process(name, tmp_path):
    """A sample through real processes: the console script and ``python -m lanegraph.cli``."""
    graph, args, shown, expect = _case(name)
    env = {**os.environ, "LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD": "1"}
    env.pop("LANEGRAPH_GRAPH_ROOTS", None)
    for cmd in _commands()[: 1 if name != "python_tag.yaml" else None]:
        p = subprocess.run(
            [*cmd, "validate", str(graph), *args],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert p.stdout == "", p.stdout  # errors go to stderr
        _check(p.stderr, p.returncode, shown, expect)
