"""The generated blocks of README.md and docs/tutorial.md (benchmarks/doc_figures.py): every block is
one the script writes, and its check ignores only the machine's ms/frame. The figures themselves
are checked by `.ci/run` (`doc_figures.py --check`: it runs the ablations)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location("doc_figures", ROOT / "benchmarks" / "doc_figures.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_every_block_in_the_docs_is_generated():
    df = _script()
    found = {}
    for doc, path in df.DOCS.items():
        text = path.read_text(encoding="utf-8")
        assert text.count("<!-- figures:") == text.count("<!-- /figures -->"), path
        for m in df.BLOCK.finditer(text):
            found[m["name"]] = doc
            assert m["body"].strip(), f"{path}: block {m['name']} is empty"
    assert set(found) == set(df.BLOCKS)
    assert all(name.startswith(doc + "/") for name, doc in found.items())


def test_check_ignores_only_the_ms_column():
    df = _script()
    a = "| variant | detection ratio | ms/frame |\n|---|---|---|\n| paper | 100.0 % | 144.62 |\n"
    b = a.replace("144.62", "99.00")
    assert df.comparable("tutorial/ablation-drive", a) == df.comparable("tutorial/ablation-drive", b)
    assert df.comparable("tutorial/ablation-drive", a) != df.comparable(
        "tutorial/ablation-drive", a.replace("100.0 %", "98.1 %")
    )
    assert df.comparable("readme/dev", a) != df.comparable("readme/dev", b)  # no timing column there
