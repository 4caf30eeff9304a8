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


def _distribution(tmp_path, monkeypatch, module: str, text: str, entry_points: str) -> None:
    """A distribution on ``sys.path``: the module ``module`` (``text``) and its metadata, named like
    it (``lg_x`` -> ``lg-x``), with ``entry_points`` (the text of its ``entry_points.txt``)."""
    site = tmp_path / "site"
    site.mkdir()
    (site / f"{module}.py").write_text(text)
    dist = site / f"{module}-0.1.dist-info"
    dist.mkdir()
    name = module.replace("_", "-")
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(entry_points)
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.delitem(sys.modules, module, raising=False)


def test_third_party_distribution_on_path(tmp_path, monkeypatch):
    _distribution(
        tmp_path, monkeypatch, "lg_thirdparty", PLUGIN, "[lanegraph.plugins]\nthirdparty = lg_thirdparty\n"
    )

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


COMMAND = textwrap.dedent(
    '''
    import click
    from lanegraph.api import handled
    from lanegraph.errors import UsageError

    @click.command(name="hello")
    @click.argument("who")
    @handled()
    def hello(who):
        """Greet WHO."""
        if who == "nobody":
            raise UsageError("nobody to greet")
        click.echo(f"hello {who}")
        return 0

    not_a_command = 42
    '''
)


def _command_dist(tmp_path, monkeypatch, entries: str):
    """A distribution ``lg-hello`` on ``sys.path`` whose ``lanegraph.commands`` are ``entries``."""
    _distribution(tmp_path, monkeypatch, "lg_hello", COMMAND, "[lanegraph.commands]\n" + entries)
    monkeypatch.delenv("LANEGRAPH_PLUGINS", raising=False)
    monkeypatch.delenv("LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD", raising=False)


def test_a_third_party_command_runs_as_lanegraph_s_own(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from lanegraph.cli import main

    _command_dist(tmp_path, monkeypatch, "hello = lg_hello:hello\n")
    runner = CliRunner()
    listing = runner.invoke(main, ["--help"])
    assert listing.exit_code == 0 and "hello" in listing.output and "Greet WHO." in listing.output
    done = runner.invoke(main, ["hello", "world"])
    assert (done.exit_code, done.output) == (0, "hello world\n")
    refused = runner.invoke(main, ["hello", "nobody"])  # its typed error: one line, its exit code
    assert refused.exit_code == 2 and "error: nobody to greet" in refused.output
    # the environment's allowlist holds for commands as for node plugins
    monkeypatch.setenv("LANEGRAPH_PLUGINS", "somebody-else")
    assert "hello" not in runner.invoke(main, ["--help"]).output
    assert runner.invoke(main, ["hello", "world"]).exit_code == 2  # no such command
    monkeypatch.setenv("LANEGRAPH_PLUGINS", "lg-hello")
    assert runner.invoke(main, ["hello", "world"]).exit_code == 0
    monkeypatch.delenv("LANEGRAPH_PLUGINS")
    monkeypatch.setenv("LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD", "1")
    assert "hello" not in runner.invoke(main, ["--help"]).output
    assert "tune" in runner.invoke(main, ["--help"]).output  # lanegraph's own add-ons stay


def test_a_broken_third_party_command_is_named_and_the_others_still_run(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from lanegraph.cli import main

    _command_dist(
        tmp_path,
        monkeypatch,
        "gone = lg_hello:missing\nnumber = lg_hello:not_a_command\nrun = lg_hello:hello\n",
    )
    runner = CliRunner()
    listing = runner.invoke(main, ["--help"])
    assert listing.exit_code == 0 and "gone" in listing.output and "failed to load" in listing.output
    gone = runner.invoke(main, ["gone", "--whatever"])
    assert gone.exit_code == 2
    assert (
        "'gone' of lg-hello (entry point 'lg_hello:missing' in lanegraph.commands) failed to load"
        in gone.output
    )
    number = runner.invoke(main, ["number"])
    assert number.exit_code == 2 and "is a int, expected a click command" in number.output
    # a plugin cannot displace a command of lanegraph's own: `run` is still lanegraph's
    assert "Run GRAPH" in runner.invoke(main, ["run", "--help"]).output


def test_lanegraph_s_add_on_commands_come_through_the_entry_point_group():
    from lanegraph.cli import command_entry_points

    found = command_entry_points()
    assert {"tune", "report", "data"} <= set(found)
    assert {found[n].dist.name for n in ("tune", "report", "data")} == {"lanegraph"}


_HELP = """
import sys
from lanegraph.cli import main
try:
    main(["--help"])
except SystemExit:
    pass
heavy = ("numba", "cv2", "dask", "distributed", "optuna", "matplotlib", "mlflow", "lanegraph_io", "lanegraph_lanes")
print("HEAVY", sorted({m.split(".")[0] for m in sys.modules} & set(heavy)))
"""


def test_help_lists_every_command_and_loads_nothing_heavy():
    """``lanegraph --help`` imports the add-ons' command modules for their help lines, and nothing
    they import only to run: no numba, OpenCV, Dask, Optuna, matplotlib, MLflow or node plugin."""
    import subprocess

    p = subprocess.run([sys.executable, "-c", _HELP], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    listed = {line.split()[0] for line in p.stdout.splitlines() if line.startswith("  ") and line.split()}
    assert {"run", "ablate", "tune", "report", "eval", "data", "graphs", "nodes"} <= listed
    assert p.stdout.splitlines()[-1] == "HEAVY []"
