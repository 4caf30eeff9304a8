"""Files follow the umask: what a run, an ablation and a report write (temporary files renamed into
place included) ends with the mode a plain ``open()`` / ``mkdir`` would give it."""

from __future__ import annotations

import os
import stat
from contextlib import contextmanager
from pathlib import Path

import pytest
from click.testing import CliRunner

from lanegraph.cli import main
from lanegraph.paths import create_new, new_temp_dir, new_temp_file, write_bytes_atomic, write_text_atomic
from lanegraph.run.cache import ResultCache

ROOT = Path(__file__).resolve().parents[2]
UMASKS = [0o022, 0o077, 0o002]


@contextmanager
def umask(mask: int):
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def mode(p: Path) -> int:
    return stat.S_IMODE(p.lstat().st_mode)


def plain_modes(folder: Path, mask: int) -> tuple[int, int]:
    """The modes ``open()`` and ``mkdir`` give under ``mask`` in ``folder`` (a default ACL would
    change them: measured, not assumed)."""
    with umask(mask):
        (folder / "plain.txt").write_text("x")
        (folder / "plain_dir").mkdir()
    out = mode(folder / "plain.txt"), mode(folder / "plain_dir")
    (folder / "plain.txt").unlink()
    (folder / "plain_dir").rmdir()
    return out


@pytest.mark.parametrize("mask", UMASKS, ids=oct)
def test_atomic_writes_and_new_files_take_the_umask(tmp_path, mask):
    want_file, want_dir = plain_modes(tmp_path, mask)
    assert want_file == 0o666 & ~mask and want_dir == 0o777 & ~mask
    with umask(mask):
        write_text_atomic(tmp_path / "a.json", "{}\n")
        write_bytes_atomic(tmp_path / "b.png", b"\x89PNG")
        write_text_atomic(tmp_path / "a.json", "{}\n")  # replaced: the new file's mode
        with create_new(tmp_path / "lanes.jsonl") as fh:
            fh.write(b"{}\n")
        fd, tmp = new_temp_file(tmp_path)
        os.close(fd)
        d = new_temp_dir(tmp_path, prefix=".assets-")
        cache = ResultCache(tmp_path / "cache", 10_000_000)
        assert cache.put("k" * 64, {"a": 1})
    for f in ("a.json", "b.png", "lanes.jsonl"):
        assert mode(tmp_path / f) == want_file, f
    assert mode(tmp) == want_file and mode(d) == want_dir
    entries = [p for p in (tmp_path / "cache").rglob("*") if p.is_file() and not p.name.startswith(".")]
    assert entries and all(mode(p) == want_file for p in entries)
    assert not list(tmp_path.glob(".a.json.*"))  # no temporary file left behind


def test_new_temp_file_never_follows_a_link(tmp_path):
    """A name taken (by a file or a planted link) is skipped, never opened."""
    target = tmp_path / "elsewhere"
    target.write_text("keep")
    fd, p = new_temp_file(tmp_path, prefix="t")
    os.close(fd)
    assert p.parent == tmp_path and p.name.startswith("t") and p.read_bytes() == b""
    assert target.read_text() == "keep"


def _all_paths(root: Path) -> list[Path]:
    return [root, *sorted(root.rglob("*"))]


def _check_tree(root: Path, want_file: int, want_dir: int) -> None:
    wrong = [
        f"{p.relative_to(root)}: {oct(mode(p))}"
        for p in _all_paths(root)
        if not p.is_symlink() and mode(p) != (want_dir if p.is_dir() else want_file)
    ]
    assert not wrong, f"not the umask's mode (files {oct(want_file)}, folders {oct(want_dir)}): {wrong}"


@pytest.mark.slow
@pytest.mark.parametrize("mask", [0o022, 0o077], ids=oct)
def test_run_ablation_and_report_follow_the_umask(tmp_path, mask):
    from lanegraph_synthetic import preset, write_sequence

    seq = write_sequence(preset("straight"), tmp_path / "seq", 2)
    want_file, want_dir = plain_modes(tmp_path, mask)
    run_out, abl_out = tmp_path / "run", tmp_path / "abl"
    with umask(mask):
        r = CliRunner().invoke(
            main,
            ["run", str(ROOT / "graphs/paper.yaml"), "--input", str(seq), "--out", str(run_out)]
            + ["--quiet", "--report", "--debug-dir", str(run_out / "debug"), "--debug-frames", "0"],
        )
        assert r.exit_code == 0, r.output
        r = CliRunner().invoke(
            main,
            ["ablate", str(ROOT / "graphs/paper.yaml"), str(ROOT / "graphs/ablations/slt.yaml")]
            + ["--input", str(seq), "--gt", str(seq / "lanes_gt.jsonl"), "--out", str(abl_out)]
            + ["--cache-dir", str(tmp_path / "cache"), "--quiet", "--report"],
        )
        assert r.exit_code == 0, r.output
    for f in ("lanes.jsonl", "run.json", "timings.json", "checkpoint.json", "report/index.html"):
        assert (run_out / f).is_file(), f
    assert any((run_out / "report" / "assets").iterdir())
    for f in ("results.csv", "results.md", "accuracy.png", "accuracy_vs_ms.png", "report/index.html"):
        assert (abl_out / f).is_file(), f
    for root in (run_out, abl_out, tmp_path / "cache"):
        _check_tree(root, want_file, want_dir)
