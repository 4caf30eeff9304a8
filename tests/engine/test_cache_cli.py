"""``lanegraph cache info|clear``: where the result cache is and how big; clearing removes its own
entries and nothing else."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from lanegraph.cli import main
from lanegraph.run.cache import ResultCache


def test_info_and_clear_touch_only_the_caches_entries(tmp_path, monkeypatch):
    monkeypatch.setenv("LANEGRAPH_CACHE_DIR", str(tmp_path / "home"))
    root = tmp_path / "home" / "results"
    c = ResultCache()
    assert c.root == root
    for k in range(3):
        assert c.put(f"{k:02d}" + "ab" * 31, np.zeros(1000, np.uint8))
    (root / "mine.txt").write_text("keep")  # not an entry
    (root / "zz").mkdir()
    (root / "zz" / "notes.md").write_text("keep")
    r = CliRunner().invoke(main, ["cache", "info"])
    assert r.exit_code == 0, r.output
    assert str(root) in r.output and "entries:      3" in r.output
    r = CliRunner().invoke(main, ["cache", "clear"])
    assert r.exit_code == 0, r.output
    assert "removed 3 entries" in r.output
    assert not list(root.glob("*/*.pkl")) and not (root / "00").exists()
    assert (root / "mine.txt").read_text() == "keep" and (root / "zz" / "notes.md").read_text() == "keep"
    r = CliRunner().invoke(main, ["cache", "info", "--cache-dir", str(tmp_path / "other")])
    assert r.exit_code == 0 and "entries:      0" in r.output
