"""Where compiled kernels are kept (one folder for every LANEGRAPH_CACHE_DIR) and the first run's
notice that they are being compiled (lanegraph.kernel_cache). Nothing is compiled here."""

from __future__ import annotations

import os

import pytest

from lanegraph import kernel_cache


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.delenv("LANEGRAPH_KERNEL_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "home-cache"))
    monkeypatch.setenv("LANEGRAPH_CACHE_DIR", str(tmp_path / "results-a"))
    monkeypatch.setattr(kernel_cache, "_STATE", {"said": False, "armed": False})
    monkeypatch.setattr(kernel_cache, "_listen", lambda where: None)
    stamps = []
    monkeypatch.setattr(kernel_cache.atexit, "register", lambda fn, *a: stamps.append((fn, a)))
    return stamps


def test_one_kernel_folder_for_every_cache_folder(fresh, tmp_path, monkeypatch):
    shared = tmp_path / "home-cache" / "lanegraph" / "kernels"
    assert kernel_cache.kernel_cache_dir() == shared
    monkeypatch.setenv("LANEGRAPH_CACHE_DIR", str(tmp_path / "results-b"))
    assert kernel_cache.kernel_cache_dir() == shared  # a new cache folder does not compile again
    monkeypatch.setenv("LANEGRAPH_KERNEL_CACHE", str(tmp_path / "k"))
    assert kernel_cache.kernel_cache_dir() == tmp_path / "k"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "n"))
    assert kernel_cache.kernel_cache_dir() == tmp_path / "n"


def test_unwritable_user_cache_falls_back_to_the_cache_folder(fresh, tmp_path, monkeypatch):
    (tmp_path / "home-cache").write_text("a file where the user cache folder should be")
    assert kernel_cache.kernel_cache_dir() == tmp_path / "results-a" / "numba"


def test_first_run_notice_once_per_machine(fresh, tmp_path, capsys):
    kernel_cache.first_run_notice()
    err = capsys.readouterr().err
    where = tmp_path / "home-cache" / "lanegraph" / "kernels"
    assert "compiling the numba kernels for this machine" in err and str(where) in err
    assert err.count("\n") == 1
    ((write, args),) = fresh
    write(*args)  # at exit: the stamp
    assert any(p.name.startswith(".compiled-") for p in where.iterdir())
    kernel_cache._STATE.update(said=False, armed=False)
    kernel_cache.first_run_notice()
    assert capsys.readouterr().err == ""  # compiled on this machine: nothing said
    kernel_cache._STATE.update(said=False, armed=False)
    kernel_cache.first_run_notice(quiet=True)
    assert capsys.readouterr().err == ""


def test_the_stamp_names_the_versions(monkeypatch):
    key = kernel_cache._machine_key()
    monkeypatch.setattr("lanegraph._version.__version__", "0.0.0-other")
    assert kernel_cache._machine_key() != key and len(key) == 16


def test_cli_run_says_it_before_loading_anything(fresh, tmp_path, monkeypatch):
    """The notice comes first, before the graph is even read (a bad graph: exit 2 after it)."""
    from click.testing import CliRunner

    from lanegraph.cli import main

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, ["run", "nope.yaml", "--out", str(tmp_path / "o")])
    assert r.exit_code == 2
    assert r.output.splitlines()[0].startswith("lanegraph: compiling the numba kernels")
    assert os.path.basename(str(tmp_path / "o")) not in os.listdir(tmp_path)
