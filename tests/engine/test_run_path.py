"""One run path: one function builds every executor and every run record, each record is built in
one place, and a graph is validated once per task and never changed."""

from __future__ import annotations

import ast
from pathlib import Path

from click.testing import CliRunner

from lanegraph.cli import main
from lanegraph.graph import files
from lanegraph.graph.files import open_graph
from lanegraph.nodes import RunContext
from lanegraph.plugins import get_plugin_manager

ROOT = Path(__file__).resolve().parents[2]
PAPER = str(ROOT / "graphs" / "paper.yaml")

#: (qualified name, how it is called) -> the one module that may call it so
ONE_PLACE = {
    ("lanegraph.run.executor.Executor", "call"): "lanegraph/run/task.py",
    ("lanegraph.records.record.RunRecord", "call"): "lanegraph/records/record.py",
    ("lanegraph.records.record.RunRecord", "of"): "lanegraph/run/task.py",
    ("lanegraph.records.record.RunRecord", "model_validate"): "lanegraph/records/record.py",
    ("lanegraph.records.record.RunRecord", "model_construct"): "lanegraph/records/record.py",
    ("lanegraph.records.record.CommandRecord", "call"): "lanegraph/records/record.py",
    ("lanegraph.records.record.CommandRecord", "of"): "lanegraph/service/session.py",
    ("lanegraph.records.record.CommandRecord", "model_construct"): "lanegraph/records/record.py",
}


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts[1:] if rel.parts[0] == "plugins" else rel.parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported_names(tree: ast.Module, module: str, is_package: bool) -> dict[str, str]:
    """Each local name bound by an import (anywhere in the module), as the qualified name it stands for."""
    names: dict[str, str] = {}
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")
                parent = parent[: len(parent) - (node.level - 1)]
                base = ".".join([*parent, *([base] if base else [])])
            for alias in node.names:
                names[alias.asname or alias.name] = f"{base}.{alias.name}"
    return names


def _constructions() -> list[tuple[str, str, str, int]]:
    """Every call ``X(...)`` or ``X.method(...)`` of the watched classes in lanegraph/ and plugins/:
    (qualified class, how, file, line)."""
    found = []
    watched = {q for q, _ in ONE_PLACE}
    for path in sorted([*(ROOT / "lanegraph").rglob("*.py"), *(ROOT / "plugins").rglob("*.py")]):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        module = _module_name(path)
        names = _imported_names(tree, module, path.name == "__init__.py")
        for cls in ("Executor", "RunRecord", "CommandRecord"):  # defined here: its own name
            if any(isinstance(n, ast.ClassDef) and n.name == cls for n in tree.body):
                names[cls] = f"{module}.{cls}"
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            f, how = node.func, "call"
            if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name):
                how, f = f.attr, f.value
            if isinstance(f, ast.Name) and names.get(f.id) in watched:
                found.append((names[f.id], how, str(path.relative_to(ROOT)), node.lineno))
    return found


def test_one_function_builds_every_executor_and_every_record():
    found = _constructions()
    seen = {(q, how) for q, how, _, _ in found}
    # the scan finds the one places themselves (it would find the others)
    assert ("lanegraph.run.executor.Executor", "call") in seen
    assert ("lanegraph.records.record.RunRecord", "of") in seen
    assert ("lanegraph.records.record.CommandRecord", "of") in seen
    elsewhere = [
        f"{file}:{line}: {q}{'' if how == 'call' else '.' + how}(...)"
        for q, how, file, line in found
        if ONE_PLACE.get((q, how), file) != file
    ]
    assert not elsewhere, "built outside its one place:\n" + "\n".join(elsewhere)


def test_a_dataset_run_validates_its_graph_once(tmp_path, synthetic_dataset, monkeypatch):
    calls = []
    real = files.validate_raw

    def counted(*args, **kwargs):
        calls.append(args[2])
        return real(*args, **kwargs)

    monkeypatch.setattr(files, "validate_raw", counted)
    out = tmp_path / "out"
    r = CliRunner().invoke(
        main, ["run", PAPER, "--dataset", str(synthetic_dataset), "--frames", "0:1", "--out", str(out), "-q"]
    )
    assert r.exit_code == 0, r.output
    assert (out / "straight" / "lanes.jsonl").is_file() and (out / "curve" / "lanes.jsonl").is_file()
    assert len(calls) == 1, calls  # planned, counted, run twice: one validation


def test_the_executor_never_changes_the_graph_it_is_given(synthetic_dataset):
    from lanegraph.run.task import build_executor

    pm = get_plugin_manager()
    g = open_graph(PAPER).validate(pm)
    src = g.source
    before = (src.type, src.params.model_dump())
    ex = build_executor(g, RunContext(input_path=synthetic_dataset.parent / "a"), pm)
    assert ex.graph.source.type is not src.type  # io.auto stands for the folder source it chose
    assert (g.source is src) and (src.type, src.params.model_dump()) == before
    assert open_graph(PAPER).validate(pm) is not g  # another resolved graph: validated on its own
