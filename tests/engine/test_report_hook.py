"""The report is a plugin: ``lanegraph report``, ``run --report`` and ``ablate --report`` write it
through the ``lanegraph_write_report`` hook (the built-in plugin ``lanegraph_report`` implements it),
and the engine never imports the plugin. Without a plugin that writes reports they say so before
anything runs; a third party's plugin writes them the same way."""

from __future__ import annotations

import ast
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from types import SimpleNamespace

import pytest
from click.testing import CliRunner

import lanegraph
from lanegraph import hookimpl, plugins
from lanegraph.cli import main
from lanegraph.errors import HookError, UsageError
from lanegraph.plugins import PluginManager, get_plugin_manager
from lanegraph.service import Session

ROOT = Path(__file__).resolve().parents[2]


def _without_reports() -> PluginManager:
    """The installed plugins but lanegraph_report."""
    full = get_plugin_manager()
    pm = PluginManager()
    for name, plugin in full.list_name_plugin():
        if name != "lanegraph_report" and plugin is not None and pm.get_plugin(name) is None:
            pm.register(plugin, name=name)
    return pm


@dataclass
class _Summary:
    index: Path

    def line(self) -> str:
        return f"report: {self.index} (by a third party)"


class ThirdPartyReport:
    """A report plugin of someone else's: writes one line into OUT/index.html."""

    def __init__(self) -> None:
        self.calls: list[dict] = []

    @hookimpl
    def lanegraph_write_report(self, run_dir, out_dir, frames, graph):
        self.calls.append({"run_dir": run_dir, "out_dir": out_dir, "frames": frames, "graph": graph})
        out = Path(out_dir or run_dir / "report")
        out.mkdir(parents=True, exist_ok=True)
        (out / "index.html").write_text("<p>lanes</p>\n")
        return _Summary(out / "index.html")


def _session(pm: PluginManager, said: list[str]) -> Session:
    return Session(pm, out=said.append, err=said.append, progress=False)


def test_the_engine_does_not_import_the_report_plugin():
    for path in Path(lanegraph.__file__).parent.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            assert not any(n.split(".")[0] == "lanegraph_report" for n in names), path


def test_the_built_in_plugin_implements_the_hook():
    pm = get_plugin_manager()
    assert "lanegraph_report" in [
        pm.get_name(i.plugin) for i in pm.hook.lanegraph_write_report.get_hookimpls()
    ]


def test_without_a_report_plugin_report_says_so(tmp_path):
    said: list[str] = []
    with pytest.raises(
        UsageError,
        match=r"^no installed plugin writes reports \(the lanegraph_write_report hook; lanegraph's own is "
        r"the plugin lanegraph_report\)$",
    ):
        _session(_without_reports(), said).report(tmp_path / "run")
    assert said == [] and not (tmp_path / "run").exists()


def test_a_third_party_plugin_writes_the_report(tmp_path):
    pm = _without_reports()
    plugin = ThirdPartyReport()
    pm.register(plugin, name="lg_other_report")
    said: list[str] = []
    summary = _session(pm, said).report(tmp_path / "run", out_dir=tmp_path / "r", frames=slice(0, 2))
    assert summary.index == tmp_path / "r" / "index.html" and summary.index.read_text() == "<p>lanes</p>\n"
    assert said == [f"report: {tmp_path / 'r' / 'index.html'} (by a third party)"]
    assert plugin.calls == [
        {"run_dir": tmp_path / "run", "out_dir": tmp_path / "r", "frames": slice(0, 2), "graph": None}
    ]


class Declining:
    @hookimpl
    def lanegraph_write_report(self, run_dir):
        return None


class Raising:
    def __init__(self, exc: BaseException) -> None:
        self.exc = exc

    @hookimpl
    def lanegraph_write_report(self, run_dir):
        raise self.exc


class WrongResult:
    @hookimpl
    def lanegraph_write_report(self, run_dir):
        return "done"


def test_a_report_plugins_failures_are_said_as_the_hooks_say_them(tmp_path):
    def session_with(plugin):
        pm = _without_reports()
        pm.register(plugin, name="lg_p")
        return _session(pm, [])

    with pytest.raises(UsageError, match=r"run: no installed plugin writes reports .*declined"):
        session_with(Declining()).report(tmp_path / "run")
    # the report's own error, as it is (exit 2 for a folder that does not fit)
    with pytest.raises(UsageError, match=r"^x: not a run folder$"):
        session_with(Raising(UsageError("x: not a run folder"))).report(tmp_path / "run")
    with pytest.raises(PermissionError):
        session_with(Raising(PermissionError(13, "Permission denied", "x"))).report(tmp_path / "run")
    # a bug of the plugin: located, never a traceback
    with pytest.raises(
        HookError, match=r"plugin 'lg_p': hook lanegraph_write_report: raised ValueError: oops"
    ):
        session_with(Raising(ValueError("oops"))).report(tmp_path / "run")
    with pytest.raises(HookError, match=r"returned str 'done', expected a report's summary"):
        session_with(WrongResult()).report(tmp_path / "run")


@pytest.fixture
def report_plugin_broken(monkeypatch):
    """The installed plugins in a fresh process-wide plugin manager, lanegraph_report's entry point
    failing to import (a broken installation)."""

    class Broken:
        name, group, dist = "lanegraph_report", "lanegraph.plugins", SimpleNamespace(name="lanegraph")

        def load(self):
            raise ImportError("No module named 'cv2'")

    eps = [ep for ep in metadata.entry_points(group="lanegraph.plugins") if ep.name != "lanegraph_report"]
    eps.append(Broken())
    real = metadata.entry_points
    monkeypatch.setattr(
        metadata, "entry_points", lambda group: eps if group == "lanegraph.plugins" else real(group=group)
    )
    monkeypatch.setattr(plugins, "_default", None)
    yield
    plugins.set_plugin_manager(None)


@pytest.mark.parametrize("command", ["run", "ablate"])
def test_report_option_without_a_report_plugin_is_refused_before_anything_runs(
    report_plugin_broken, tmp_path, command
):
    out = tmp_path / "out"
    graphs = [str(ROOT / "graphs/paper.yaml")]
    if command == "ablate":
        graphs.append(str(ROOT / "graphs/ablations/paper_literal.yaml"))
    r = CliRunner().invoke(
        main, [command, *graphs, "--frames", "0:2", "--out", str(out), "--report", "--quiet"]
    )
    assert r.exit_code == 2, r.output
    assert (
        "error: no installed plugin writes reports (the lanegraph_write_report hook; lanegraph's own is the "
        "plugin lanegraph_report); of the plugins installed, plugin 'lanegraph_report' from distribution "
        "'lanegraph' failed to load: ImportError: No module named 'cv2'" in r.output
    )
    assert not out.exists()  # nothing ran, nothing was written
