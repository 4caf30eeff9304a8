"""The generated blocks of README.md and docs/tutorial.md (benchmarks/doc_figures.py): every block is
one the script writes, and its tables leave out the machine's ms/frame. The figures themselves
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


def test_tables_leave_out_the_machine_dependent_column(tmp_path):
    df = _script()
    md = tmp_path / "results.md"
    md.write_text(
        "All sequences pooled (x; 3 frames):\n\n"
        "| variant | detection ratio | ms/frame |\n|---|---|---|\n| paper | 100.0 % | 144.62 |\n\nMedian ...\n"
    )
    assert df.pooled_table(md) == "| variant | detection ratio |\n|---|---|\n| paper | 100.0 % |\n"
    assert df.comparable("x", "| a |  \n") == df.comparable("x", "| a |\n")
