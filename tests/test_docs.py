"""The docs are tested: their ``python`` blocks run, their ``yaml`` graphs validate, excerpts match
the files they are taken from, every hook is documented and ``docs/nodes.md`` is what
``lanegraph nodes --markdown --builtin`` generates.

Markers, an HTML comment on the line(s) just above a fenced block:

- ``<!-- notest -->``: the block is not executed or validated;
- ``<!-- from: PATH -->``: the block is a verbatim excerpt of ``PATH`` (relative to the repository
  root); a graph so marked is validated at that location, ``extends`` and allowed roots included.

``python`` blocks of one page run in order in one namespace (a walkthrough builds on its earlier
blocks), from the repository root, with the example plugin ``docs/examples/lg_tophat`` importable
whether or not it is installed. A ``yaml`` block with ``nodes`` is a graph: it is loaded and
validated whole when it is complete (it ``extends`` a base, or every input it wires comes from one
of its own nodes) and checked node by node (known type, valid params) when it is a fragment.
"""

from __future__ import annotations

import difflib
import re
import sys
import traceback
import types
from pathlib import Path

import pytest
import yaml

from lanegraph import hookspecs
from lanegraph.cli import allowed_roots, builtin_node_types, nodes_markdown
from lanegraph.graph.model import GraphSpec
from lanegraph.graph.validation import load_graph
from lanegraph.plugins import PluginManager

from ._doc_shell import ShellBlock as Block
from ._doc_shell import doc_files, parse

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "docs" / "examples" / "lg_tophat"
DOC_FILES = doc_files()

#: doc blocks known to be wrong, keyed by (doc file, text in the block): a strict xfail giving the
#: reason. Fix the doc, then delete the entry (it is inert once the text no longer matches).
KNOWN_BROKEN = {}

_REF = re.compile(r"^([A-Za-z_][\w-]*)\.\w+(@prev)?$")


ALL_BLOCKS = [b for doc in DOC_FILES for b in parse(doc)]


def _mark(block: Block):
    for (doc, needle), reason in KNOWN_BROKEN.items():
        if block.doc == doc and needle in block.text:
            return pytest.param(
                block, id=block.id, marks=pytest.mark.xfail(strict=True, reason=f"{block.id}: {reason}")
            )
    return pytest.param(block, id=block.id)


@pytest.fixture
def at_root(monkeypatch):
    """Run from the repository root, with the example plugin importable."""
    monkeypatch.chdir(ROOT)
    monkeypatch.syspath_prepend(str(EXAMPLE))


@pytest.fixture
def docs_pm(monkeypatch, at_root) -> PluginManager:
    """lanegraph's own plugins and the example plugin: no other installed plugin."""
    import lg_tophat

    monkeypatch.setenv("LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD", "1")
    monkeypatch.delenv("LANEGRAPH_PLUGINS", raising=False)
    pm = PluginManager()
    pm.load_entrypoints()
    pm.register(lg_tophat, name="lg_tophat")
    return pm


# --------------------------------------------------------------------------- python blocks
PY_DOCS = sorted({b.doc for b in ALL_BLOCKS if b.lang == "python" and not b.notest})


def test_the_walkthrough_has_code():
    langs = {b.lang for b in ALL_BLOCKS if b.doc == "docs/writing-plugins.md"}
    assert {"python", "toml", "yaml"} <= langs


@pytest.mark.parametrize("doc", PY_DOCS)
def test_python_blocks_run(doc, at_root, monkeypatch):
    # a real module, so that pydantic resolves the postponed annotations of models defined in it
    module = types.ModuleType("docs_" + re.sub(r"\W", "_", Path(doc).stem))
    monkeypatch.setitem(sys.modules, module.__name__, module)
    namespace = module.__dict__
    for block in (b for b in ALL_BLOCKS if b.doc == doc and b.lang == "python" and not b.notest):
        # padded so that tracebacks and the failure point at the markdown file's own line numbers
        code = compile("\n" * (block.line - 1) + block.text, doc, "exec")
        try:
            exec(code, namespace)
        except Exception as exc:  # noqa: BLE001 - reported with its location in the doc
            tb = traceback.extract_tb(exc.__traceback__)
            line = next((f.lineno for f in reversed(tb) if f.filename == doc), block.line)
            pytest.fail(
                f"{doc}:{line}: {type(exc).__name__}: {exc}\n(python block starting at line {block.line})\n"
                + "".join(traceback.format_exception(exc)[-6:]),
                pytrace=False,
            )


# --------------------------------------------------------------------------- excerpts
@pytest.mark.parametrize("block", [pytest.param(b, id=b.id) for b in ALL_BLOCKS if b.source])
def test_excerpts_match_their_files(block):
    target = ROOT / block.source
    if not target.is_file():
        pytest.fail(f"{block.id}: <!-- from: {block.source} -->: no such file", pytrace=False)
    if block.text not in target.read_text():
        pytest.fail(
            f"{block.id}: no longer an excerpt of {block.source}; copy it again from the file", pytrace=False
        )


# --------------------------------------------------------------------------- graphs
def _graph_blocks() -> list:
    out = []
    for b in ALL_BLOCKS:
        if b.lang not in ("yaml", "yml") or b.notest:
            continue
        try:
            data = yaml.safe_load(b.text)
        except yaml.YAMLError:
            data = None  # reported by the test
        if data is None or (isinstance(data, dict) and ("nodes" in data or "extends" in data)):
            out.append(_mark(b))
    return out


def _is_complete(data: dict) -> bool:
    if data.get("extends"):
        return True
    nodes = data.get("nodes") or {}
    for spec in nodes.values():
        for ref in ((spec or {}).get("inputs") or {}).values():
            ref = ref.get("from") if isinstance(ref, dict) else ref
            m = _REF.match(str(ref)) if ref is not None else None
            if m and m.group(1) not in nodes:
                return False
    return True


def _base_folder(block: Block, extends: str) -> Path:
    """Where a doc graph without a location would live: the first folder (the doc's own, then
    ``graphs/`` and its subfolders) in which its relative ``extends`` names a file."""
    candidates = [
        (ROOT / block.doc).parent,
        ROOT / "graphs",
        *sorted(p for p in (ROOT / "graphs").rglob("*") if p.is_dir()),
    ]
    for folder in candidates:
        if (folder / extends).is_file():
            return folder
    pytest.fail(
        f"{block.id}: extends {extends!r} names no file relative to {[str(c) for c in candidates]}",
        pytrace=False,
    )


@pytest.mark.parametrize("block", _graph_blocks())
def test_yaml_graphs_validate(block, docs_pm, tmp_path):
    try:
        data = yaml.safe_load(block.text)
    except yaml.YAMLError as exc:
        pytest.fail(f"{block.id}: not valid YAML: {exc}", pytrace=False)
    assert isinstance(data, dict), f"{block.id}: a graph is a mapping"
    if block.source:  # the graph file itself, where it lives
        path = ROOT / block.source
        load_graph(path, pm=docs_pm, roots=allowed_roots(path))
        return
    if _is_complete(data):
        if data.get("extends") and not Path(data["extends"]).is_absolute():
            data["extends"] = str((_base_folder(block, data["extends"]) / data["extends"]).resolve())
        path = tmp_path / "doc_graph.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        load_graph(path, pm=docs_pm)
        return
    # a fragment: the format, and every node's type and params
    GraphSpec.model_validate(data)
    for nid, spec in (data.get("nodes") or {}).items():
        if spec and "type" in spec:
            nt = docs_pm.get_node_type(spec["type"])
            assert nt is not None, f"{block.id}: node {nid!r}: unknown node type {spec['type']!r}"
            nt.params.model_validate(spec.get("params") or {})


# --------------------------------------------------------------------------- references
def test_node_reference_is_up_to_date(monkeypatch):
    monkeypatch.setenv("LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD", "1")
    pm = PluginManager()
    pm.load_entrypoints()
    want = nodes_markdown(builtin_node_types(pm))
    have = (ROOT / "docs" / "nodes.md").read_text()
    if have != want:
        diff = "".join(
            list(
                difflib.unified_diff(
                    have.splitlines(True), want.splitlines(True), "docs/nodes.md", "generated"
                )
            )[:60]
        )
        pytest.fail(
            "docs/nodes.md is out of date; regenerate it with `lanegraph nodes --markdown --builtin > docs/nodes.md`\n"
            + diff,
            pytrace=False,
        )


def test_node_reference_leaves_out_third_party_plugins(docs_pm):
    assert "features.tophat" in docs_pm.node_types
    assert "features.tophat" not in builtin_node_types(docs_pm)
    assert "features.eslt" in builtin_node_types(docs_pm)


def test_every_hook_is_documented():
    text = (ROOT / "docs" / "writing-plugins.md").read_text()
    hooks = [n for n in dir(hookspecs) if n.startswith("lanegraph_") and callable(getattr(hookspecs, n))]
    assert hooks
    missing = [h for h in hooks if f"`{h}(" not in text]
    assert not missing, f"docs/writing-plugins.md: hooks missing from the hooks table: {missing}"
