"""Where compiled kernels are kept (one folder for every LANEGRAPH_CACHE_DIR) and the first run's
notice that they are being compiled, and the helper process that compiles the default run's kernels
beside the first run (lanegraph.kernel_cache). One small kernel is compiled here."""

from __future__ import annotations

import gc
import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lanegraph import kernel_cache


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.delenv("LANEGRAPH_KERNEL_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "home-cache"))
    monkeypatch.setenv("LANEGRAPH_CACHE_DIR", str(tmp_path / "results-a"))
    monkeypatch.setattr(
        kernel_cache, "_STATE", {"said": False, "armed": False, "helper": None, "claims": None}
    )
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


def test_the_first_run_starts_the_helper_beside_it(fresh, monkeypatch):
    started = []

    class _Popen:
        def __init__(self, cmd, **kwargs):
            started.append(cmd)
            # -m imports from the working folder first: never the user's (an input folder, say)
            assert kwargs["cwd"] == str(Path(kernel_cache.__file__).resolve().parent.parent)

    monkeypatch.setenv("LANEGRAPH_PRECOMPILE", "1")
    monkeypatch.setattr(kernel_cache.subprocess, "Popen", _Popen)
    monkeypatch.setattr("lanegraph._runtime.available_cpus", lambda: 2)
    kernel_cache.first_run_notice(quiet=True)
    claims = kernel_cache._STATE["claims"]
    assert started == [
        [sys.executable, "-m", "lanegraph.kernel_cache", str(kernel_cache.KERNEL_LIST), claims]
    ]
    assert Path(claims).is_dir() and not os.listdir(claims)  # the claims folder, made by the run
    assert [fn for fn, _ in fresh] == [kernel_cache._stop_helper, kernel_cache._write_stamp]
    os.rmdir(claims)
    kernel_cache._STATE["helper"] = None
    started.clear()
    monkeypatch.setattr("lanegraph._runtime.available_cpus", lambda: 1)  # it would take the run's CPU
    kernel_cache._STATE.update(said=False, armed=False)
    kernel_cache.first_run_notice(quiet=True)
    monkeypatch.setattr("lanegraph._runtime.available_cpus", lambda: 2)
    monkeypatch.setenv("LANEGRAPH_PRECOMPILE", "0")
    kernel_cache._STATE.update(said=False, armed=False)
    kernel_cache.first_run_notice(quiet=True)
    assert started == []


def test_the_run_stops_the_helper_at_exit(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    (tmp_path / "claims").mkdir()
    kernel_cache._stop_helper(proc, str(tmp_path / "claims"))
    assert proc.poll() is not None
    assert not (tmp_path / "claims").exists()  # the claims folder goes with it


_GOOD = {
    "module": "lanegraph_lanes._select",
    "name": "kth_smallest",
    "args": ["array(float64, 1, C)", "int64", "int64"],
}


def test_two_processes_share_the_list_through_claims(tmp_path):
    """Each entry is compiled by the one process that claims it first; every entry ends done."""
    claims = tmp_path / "claims"
    claims.mkdir()
    (claims / "1").write_bytes(b"")  # the other process has entry 1
    stale = {"module": "lanegraph_lanes._select", "name": "no_such_kernel", "args": []}
    assert kernel_cache.precompile([_GOOD, _GOOD, stale], claims) == 1
    assert sorted(os.listdir(claims)) == ["0", "0.done", "1", "2", "2.done"]  # a stale entry is done too
    assert kernel_cache.precompile([_GOOD, _GOOD, stale], claims) == 0  # all taken: nothing twice


def test_the_run_takes_its_part_then_waits_for_the_helper(fresh, tmp_path, monkeypatch):
    """compile_share: the run compiles what the helper has not claimed, then waits while the helper
    compiles what it has; at once without a helper."""
    assert kernel_cache.compile_share() == 0
    listed = tmp_path / "kernels.json"
    listed.write_text(json.dumps([_GOOD, _GOOD]), encoding="utf-8")
    monkeypatch.setattr(kernel_cache, "KERNEL_LIST", listed)
    claims = tmp_path / "claims"
    claims.mkdir()
    (claims / "0").write_bytes(b"")  # the helper compiles entry 0: done when it ends
    helper = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"import time, pathlib; time.sleep(0.5); pathlib.Path({str(claims / '0.done')!r}).touch()",
        ]
    )
    kernel_cache._STATE.update(helper=helper, claims=str(claims))
    try:
        assert kernel_cache.compile_share() == 1  # entry 1
        assert (claims / "0.done").exists() and (claims / "1.done").exists()
        assert kernel_cache.compile_share() == 0  # once
    finally:
        helper.wait()


def test_the_kernel_list_names_kernels_and_types_it_can_read():
    """Every entry of the shipped list is a lanegraph kernel with one type per argument, written
    back as read (the list is a hint: a stale one costs time, not results)."""
    entries = json.loads(kernel_cache.KERNEL_LIST.read_text(encoding="utf-8"))
    assert len(entries) >= 10
    for e in entries:
        kernel = getattr(importlib.import_module(e["module"]), e["name"])
        assert hasattr(kernel, "compile"), e["name"]
        sig = tuple(kernel_cache.decode_type(a) for a in e["args"])
        assert [kernel_cache.encode_type(t) for t in sig] == e["args"]
        assert len(sig) == kernel.py_func.__code__.co_argcount, e["name"]
    seconds = [e["seconds"] for e in entries]  # longest compilation first: the two processes balance
    assert seconds == sorted(seconds, reverse=True)


def test_precompile_skips_what_it_cannot_resolve():
    good = _GOOD
    bad = [
        {"module": "lanegraph_no_such_module", "name": "k", "args": []},
        {"module": "lanegraph_lanes._select", "name": "no_such_kernel", "args": []},
        {"module": "lanegraph_lanes._select", "name": "kth_smallest", "args": ["complex128"]},
        {"module": "lanegraph_lanes._select", "name": "math", "args": []},  # not a kernel
    ]
    assert kernel_cache.precompile([*bad, good]) == 1
    from lanegraph_lanes._select import kth_smallest
    from numba.core import types

    assert (types.Array(types.float64, 1, "C"), types.int64, types.int64) in kth_smallest.signatures
    with pytest.raises(ValueError):
        kernel_cache.decode_type("object")


def test_precompile_imports_lanegraph_modules_only(tmp_path, monkeypatch):
    """A kernel list names lanegraph's kernels; a module of another name (one lying in the user's
    folder, say) is never imported."""
    (tmp_path / "stranger_kernels.py").write_text("import os\nos.environ['STRANGER_RAN'] = '1'\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delenv("STRANGER_RAN", raising=False)
    assert kernel_cache.precompile([{"module": "stranger_kernels", "name": "k", "args": []}]) == 0
    assert "STRANGER_RAN" not in os.environ and "stranger_kernels" not in sys.modules


_CALLER = """
from lanegraph._numba import jit
from {pkg}.helper import step

@jit
def kernel(x):
    return step(x) * 10
"""

_HELPER = """
from lanegraph._numba import jit

@jit
def step(x):
    return x + {add}
"""


def _call_kernel(root: Path, pkg: str, cache: Path) -> tuple[int, bool]:
    """``kernel(1)`` of the package in a fresh process, and whether it came from the cache."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(root), "LANEGRAPH_PRECOMPILE": "0"}
    code = (
        f"from {pkg}.caller import kernel; v = kernel(1); "
        "print(v, kernel.stats.cache_hits.get(kernel.signatures[0], 0) > 0)"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    v, hit = out.stdout.split()
    return int(v), hit == "True"


def test_a_cached_kernel_is_compiled_again_when_a_function_it_calls_changes(tmp_path):
    """numba keeps a cached kernel while its own file is unchanged; the machine code of the functions
    it calls is compiled into it, so an edit of a callee in another file of the package must not
    leave the caller running the old callee (lanegraph._numba._PackageLocator)."""
    pkg = "lg_stale_probe"
    folder = tmp_path / "src" / pkg
    folder.mkdir(parents=True)
    (folder / "__init__.py").write_text("")
    (folder / "caller.py").write_text(_CALLER.format(pkg=pkg))
    (folder / "helper.py").write_text(_HELPER.format(add=1))
    cache = tmp_path / "kernels"
    assert _call_kernel(tmp_path / "src", pkg, cache) == (20, False)  # compiled
    assert _call_kernel(tmp_path / "src", pkg, cache) == (20, True)  # from the cache
    (folder / "helper.py").write_text(_HELPER.format(add=2))  # caller.py itself unchanged
    assert _call_kernel(tmp_path / "src", pkg, cache) == (30, False)  # not the stale 20
    assert _call_kernel(tmp_path / "src", pkg, cache) == (30, True)


def test_precompile_compiles_without_cyclic_garbage_collection(monkeypatch):
    """The kernel list is compiled with the cyclic collector off (numba's compiler makes millions of
    objects), and the collector is on again afterwards, also after an entry that failed."""
    seen = []
    decode = kernel_cache.decode_type

    def spy(text):
        seen.append(gc.isenabled())
        return decode(text)

    monkeypatch.setattr(kernel_cache, "decode_type", spy)
    assert gc.isenabled()
    stale = {"module": "lanegraph_lanes._select", "name": "kth_smallest", "args": ["complex128"]}
    assert kernel_cache.precompile([stale, _GOOD]) == 1
    assert seen and not any(seen)
    assert gc.isenabled()
    gc.disable()  # a caller that had it off keeps it off
    try:
        kernel_cache.precompile([_GOOD])
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_numba_keeps_the_signatures_it_resolved_while_lanegraph_compiles(monkeypatch):
    """Within lanegraph.kernel_cache.kept_call_types (the first run's precompile) each resolution of a
    built-in call (the same function and argument types) is kept: a repeat returns the kept
    signature without trying the function's typing templates again, and records its implementation
    as the first resolution did. Outside it numba's own method is back (a user's numba code is
    compiled as numba does it)."""
    import operator

    from numba.core import types
    from numba.core.registry import cpu_target
    from numba.core.types import functions
    from numba.core.typing import templates

    from lanegraph.kernel_cache import kept_call_types

    numbas = functions.BaseFunction.get_call_type
    assert not getattr(numbas, "_lanegraph_memo", False)
    ctx = cpu_target.typing_context
    ctx.refresh()
    add = ctx.resolve_value_type(operator.add)
    args = (types.int16, types.float32)
    tried = []
    for cls in (templates.AbstractTemplate, templates.ConcreteTemplate):
        apply = cls.apply
        monkeypatch.setattr(
            cls, "apply", lambda self, a, k, _apply=apply: tried.append(a) or _apply(self, a, k)
        )
    with kept_call_types() as kept:
        assert kept and getattr(functions.BaseFunction.get_call_type, "_lanegraph_memo", False)
        with kept_call_types():  # nested: still in place after the inner block
            pass
        assert getattr(functions.BaseFunction.get_call_type, "_lanegraph_memo", False)
        first = ctx.resolve_function_type(add, args, {})
        assert first is not None and first.return_type == types.float32
        tried.clear()
        monkeypatch.setattr(add, "_impl_keys", {})
        assert ctx.resolve_function_type(add, args, {}) == first
        assert tried == []  # no template tried again
        assert add.get_impl_key(first) is not None  # recorded for the lowering, as numba does
        other = ctx.resolve_function_type(add, (types.int8, types.complex64), {})  # a new one: resolved
        assert other is not None and tried
    assert functions.BaseFunction.get_call_type is numbas  # numba's own again
    tried.clear()
    assert ctx.resolve_function_type(add, args, {}) == first and tried  # resolved as numba does


def test_numba_resolutions_are_not_kept_when_turned_off(monkeypatch):
    from numba.core.types import functions

    from lanegraph.kernel_cache import kept_call_types

    monkeypatch.setenv("LANEGRAPH_NUMBA_CALL_MEMO", "0")
    with kept_call_types() as kept:
        assert not kept
        assert not getattr(functions.BaseFunction.get_call_type, "_lanegraph_memo", False)
