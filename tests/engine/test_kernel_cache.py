"""Where compiled kernels are kept (one folder of the user's own for every LANEGRAPH_CACHE_DIR), the
first run's notice and the helper process that makes the plugins' listed kernels beside the first
run (lanegraph.kernels.folder, .first_run). Small kernels are compiled here."""

from __future__ import annotations

import gc
import importlib
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from lanegraph.kernels import compat, first_run, folder
from lanegraph.kernels.bundle import decode_type, encode_type
from lanegraph.kernels.first_run import KernelSet


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.delenv("LANEGRAPH_KERNEL_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "home-cache"))
    monkeypatch.setenv("LANEGRAPH_CACHE_DIR", str(tmp_path / "results-a"))
    monkeypatch.setattr(
        first_run,
        "_STATE",
        {
            "said": False,
            "armed": False,
            "helper": None,
            "claims": None,
            "first": False,
            "folder": None,
            "compiling": False,
            "quiet": False,
        },
    )
    monkeypatch.setattr(first_run, "_listen", lambda where: None)
    monkeypatch.setattr(folder, "_REFUSED", {})
    stamps = []
    monkeypatch.setattr(first_run.atexit, "register", lambda fn, *a: stamps.append((fn, a)))
    return stamps


def test_one_kernel_folder_for_every_cache_folder(fresh, tmp_path, monkeypatch):
    shared = tmp_path / "home-cache" / "lanegraph" / "kernels"
    assert folder.kernel_folder() == shared
    monkeypatch.setenv("LANEGRAPH_CACHE_DIR", str(tmp_path / "results-b"))
    assert folder.kernel_folder() == shared  # a new cache folder does not compile again
    monkeypatch.setenv("LANEGRAPH_KERNEL_CACHE", str(tmp_path / "k"))
    assert folder.kernel_folder() == tmp_path / "k"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "n"))
    assert folder.kernel_folder() == tmp_path / "n"


def test_the_results_cache_never_holds_kernels(fresh, tmp_path):
    """Issue 46: where the user cache cannot be made, the kernels are not kept under
    LANEGRAPH_CACHE_DIR (a results cache may be shared between users): no cache, with a warning."""
    (tmp_path / "home-cache").write_text("a file where the user cache folder should be")
    with pytest.warns(folder.KernelCacheWarning, match="no kernel cache"):
        assert folder.kernel_folder() is None
    assert not (tmp_path / "results-a").exists()


@pytest.mark.parametrize("home", ["", "/"])
def test_no_kernel_cache_at_the_root_when_home_is_empty(fresh, monkeypatch, home):
    """Issue 46: HOME empty and XDG_CACHE_HOME unset: no folder at all (was /.cache/lanegraph)."""
    monkeypatch.setenv("HOME", home)
    monkeypatch.delenv("XDG_CACHE_HOME")
    with pytest.warns(folder.KernelCacheWarning, match="HOME is empty"):
        assert folder.kernel_folder() is None
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/cache")  # not absolute either
    assert folder.user_cache_home() is None


def test_a_kernel_folder_others_can_write_to_is_made_private(fresh, tmp_path, monkeypatch):
    k = tmp_path / "k"
    k.mkdir()
    os.chmod(k, 0o777)
    monkeypatch.setenv("LANEGRAPH_KERNEL_CACHE", str(k))
    assert folder.kernel_folder() == k
    assert os.stat(k).st_mode & 0o022 == 0


@pytest.mark.skipif(os.geteuid() != 0, reason="making a folder another user's needs root")
def test_another_users_kernel_folder_is_never_used(fresh, tmp_path, monkeypatch):
    k = tmp_path / "theirs"
    k.mkdir()
    os.chown(k, 12345, 12345)
    monkeypatch.setenv("LANEGRAPH_KERNEL_CACHE", str(k))
    with pytest.warns(folder.KernelCacheWarning, match="another user"):
        assert folder.kernel_folder() is None


@pytest.mark.parametrize("dangling", [True, False])
def test_the_stamp_is_never_written_through_a_link(fresh, tmp_path, dangling):
    """Issue 46: kernels/.compiled-KEY as a link: the stamp replaces the link, the target is neither
    created nor changed."""
    k = folder.kernel_folder()
    target = tmp_path / "outside.txt"
    if not dangling:
        target.write_text("the user's file")
    stamp = k / f".compiled-{first_run._install_key()}"
    stamp.symlink_to(target)
    first_run.first_run_notice(quiet=True)
    assert first_run._STATE["first"]  # a link is no stamp
    ((write, args),) = [(fn, a) for fn, a in fresh if fn is first_run._write_stamp]
    write(*args)
    assert not stamp.is_symlink() and stamp.is_file()
    if dangling:
        assert not target.exists()
    else:
        assert target.read_text() == "the user's file"


def test_first_run_notice_once_per_installation(fresh, tmp_path, capsys):
    """The notice comes from compile_share (before the first frame), with its figure; a later run of
    the same installation says nothing."""
    first_run.first_run_notice()
    assert capsys.readouterr().err == ""  # not yet: the figure needs the plugins' lists
    first_run.compile_share()
    err = capsys.readouterr().err
    where = tmp_path / "home-cache" / "lanegraph" / "kernels"
    assert err.startswith("lanegraph: first run of this installation on this machine")
    assert str(where) in err and err.count("\n") == 1
    # the built-in plugins' kernels: loaded from their machine code when called, with the figure
    assert "loading each of its numba kernels from the plugins' machine code when first called" in err
    assert " s at most)" in err
    ((write, args),) = [(fn, a) for fn, a in fresh if fn is first_run._write_stamp]
    write(*args)  # at exit: the stamp
    assert any(p.name.startswith(".compiled-") for p in where.iterdir())
    first_run._STATE.update(said=False, armed=False, first=False)
    first_run.first_run_notice()
    assert first_run.compile_share() == 0
    assert capsys.readouterr().err == ""  # made by this installation on this machine: nothing said


def test_the_stamp_names_the_installation_and_versions(monkeypatch, tmp_path):
    """Issue 47: a second install (a wheel beside an editable checkout) makes its own decision."""
    key = first_run._install_key()
    monkeypatch.setattr(first_run, "_PACKAGE_ROOT", tmp_path / "site-packages")
    assert first_run._install_key() != key
    monkeypatch.undo()
    monkeypatch.setattr("lanegraph._version.__version__", "0.0.0-other")
    assert first_run._install_key() != key and len(key) == 16


def test_cli_run_says_it_before_any_frame(fresh, tmp_path, monkeypatch):
    """Issue 47: the notice is the first line, before the progress of any frame."""
    from click.testing import CliRunner

    from lanegraph.cli import main

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, ["run", "--frames", "0:1", "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    # (a broken third-party plugin in the environment may warn first: not a frame)
    lines = [line for line in r.output.splitlines() if not line.startswith("warning: plugin ")]
    assert lines[0].startswith("lanegraph: first run of this installation on this machine"), lines[:3]
    assert " kernels" in lines[0] and " s " in lines[0] and not any("frames" in line for line in lines[:1])


def test_the_first_run_starts_the_helper_beside_it(fresh, monkeypatch):
    """Where no bundle holds the default run's kernels, compile_share starts the helper (two CPUs)
    to compile them beside the run; not with one CPU, LANEGRAPH_PRECOMPILE=0, nor when the bundles
    hold them all (each kernel is then loaded when called)."""
    started = []

    class _Popen:
        def __init__(self, cmd, **kwargs):
            started.append(cmd)
            # -m imports from the working folder first: never the user's (an input folder, say)
            assert kwargs["cwd"] == str(first_run._PACKAGE_ROOT)

        def poll(self):
            return 0

    monkeypatch.setenv("LANEGRAPH_PRECOMPILE", "1")
    monkeypatch.setattr(first_run.subprocess, "Popen", _Popen)
    monkeypatch.setattr(first_run, "kernel_sets", lambda pm=None: [_LANES])
    monkeypatch.setattr(first_run, "precompile", lambda items, claims=None, compile_missing=True: len(items))
    split = {"lazy": [], "ahead": [(_LANES, _GOOD)]}
    monkeypatch.setattr(first_run, "_split", lambda sets: (split["lazy"], split["ahead"]))

    def share(cpus: int, **env: str) -> tuple[int, list]:
        monkeypatch.setattr("lanegraph._runtime.available_cpus", lambda: cpus)
        for k, v in env.items():
            monkeypatch.setenv(k, v)
        first_run._STATE.update(said=True, armed=False, helper=None, claims=None)
        first_run.first_run_notice(quiet=True)
        started.clear()
        return first_run.compile_share(), list(started)

    made, cmds = share(2)
    claims = first_run._STATE["claims"]
    assert made == 1 and cmds == [[sys.executable, "-m", "lanegraph.kernels", "helper", claims]]
    assert Path(claims).is_dir()  # the claims folder, made by the run
    ours = (first_run._write_stamp, first_run._stop_helper)
    assert [fn for fn, _ in fresh if fn in ours] == list(ours)
    os.rmdir(claims)
    assert share(1) == (0, [])  # it would take the run's CPU
    assert share(2, LANEGRAPH_PRECOMPILE="0") == (0, [])
    split.update(lazy=[(_LANES, _GOOD)], ahead=[])
    assert share(2, LANEGRAPH_PRECOMPILE="1") == (0, [])  # all in the bundles: loaded when called


def test_the_run_stops_the_helper_at_exit(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    (tmp_path / "claims").mkdir()
    first_run._stop_helper(proc, str(tmp_path / "claims"))
    assert proc.poll() is not None
    assert not (tmp_path / "claims").exists()  # the claims folder goes with it


_GOOD = {
    "module": "lanegraph_lanes._select",
    "name": "kth_smallest",
    "args": ["array(float64, 1, C)", "int64", "int64"],
}
_LANES = KernelSet("lanegraph_lanes", Path("/nonexistent/kernels.json"), ())


def test_two_processes_share_the_lists_through_claims(tmp_path):
    """Each entry is made by the one process that claims it first; every entry ends done."""
    claims = tmp_path / "claims"
    claims.mkdir()
    other = {**_GOOD, "args": ["array(float32, 1, C)", "int64", "int64"]}
    (claims / first_run.claim_name(other)).write_bytes(b"")  # the other process has it
    stale = {"module": "lanegraph_lanes._select", "name": "no_such_kernel", "args": []}
    items = [(_LANES, _GOOD), (_LANES, other), (_LANES, stale)]
    assert first_run.precompile(items, claims) == 1
    names = {first_run.claim_name(e) for _, e in items}
    assert set(os.listdir(claims)) == names | {f"{first_run.claim_name(e)}.done" for e in (_GOOD, stale)}
    assert first_run.precompile(items, claims) == 0  # all taken: nothing twice


def test_the_run_takes_its_part_then_waits_for_the_helper(fresh, tmp_path, monkeypatch):
    """compile_share: the run makes what the helper has not claimed, then waits while the helper
    makes what it has; at once on a later run."""
    assert first_run.compile_share() == 0  # not a first run
    other = {**_GOOD, "args": ["array(float32, 1, C)", "int64", "int64"]}
    monkeypatch.setattr(first_run, "_split", lambda sets: ([], [(_LANES, other), (_LANES, _GOOD)]))
    monkeypatch.setattr(first_run, "kernel_sets", lambda pm=None: [_LANES])
    claims = tmp_path / "claims"
    claims.mkdir()
    taken = claims / first_run.claim_name(other)
    taken.write_bytes(b"")  # the helper makes it: done when it ends
    helper = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"import time, pathlib; time.sleep(0.5); pathlib.Path({str(taken)!r} + '.done').touch()",
        ]
    )
    monkeypatch.setattr(
        first_run, "_start_helper", lambda: first_run._STATE.update(helper=helper, claims=str(claims))
    )
    monkeypatch.setenv("LANEGRAPH_PRECOMPILE", "1")
    first_run._STATE.update(first=True, said=True, folder=tmp_path)
    try:
        assert first_run.compile_share() == 1  # _GOOD
        assert Path(f"{taken}.done").exists()
        assert first_run.compile_share() == 0  # once
    finally:
        helper.wait()


def test_every_plugin_list_names_kernels_and_types_it_can_read(installed_pm):
    """Every entry of the built-in plugins' lists is a kernel of that plugin with one type per
    argument, written back as read (a list is a hint: a stale one costs time, not results); the
    engine itself lists none."""
    sets = first_run.kernel_sets(installed_pm)
    assert {"lanegraph_lanes", "lanegraph_road"} <= {s.package for s in sets}
    assert all(s.list_path.parent.name == s.package for s in sets)  # beside the plugin's code
    assert sum(len(s.entries) for s in sets) >= 10
    for s in sets:
        raw = json.loads(s.list_path.read_text(encoding="utf-8"))
        assert len(raw) == len(s.entries), f"{s.list_path}: entries of another package"
        for e in s.entries:
            kernel = getattr(importlib.import_module(e["module"]), e["name"])
            assert hasattr(kernel, "compile"), e["name"]
            sig = tuple(decode_type(a) for a in e["args"])
            assert [encode_type(t) for t in sig] == e["args"]
            assert len(sig) == kernel.py_func.__code__.co_argcount, e["name"]
        seconds = [e["seconds"] for e in s.entries]  # longest compilation first: the processes balance
        assert seconds == sorted(seconds, reverse=True)
    assert any(e.get("default") for s in sets for e in s.entries)


def test_a_plugin_list_outside_its_folder_or_naming_others_is_ignored(tmp_path, monkeypatch):
    from lanegraph import hookimpl
    from lanegraph.plugins import PluginManager

    pkg = tmp_path / "lg_lister"
    pkg.mkdir()
    listed = [_GOOD, {"module": "lg_lister.k", "name": "k", "args": []}]
    (pkg / "kernels.json").write_text(json.dumps(listed))
    (tmp_path / "elsewhere.json").write_text(json.dumps(listed))
    (pkg / "__init__.py").write_text(
        "from pathlib import Path\nfrom lanegraph import hookimpl\n\n"
        "WHERE = 'kernels.json'\n\n@hookimpl\ndef lanegraph_kernels():\n"
        "    return Path(__file__).parent / WHERE\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("lg_lister")
    pm = PluginManager()
    pm.register(module, "lg_lister")

    class Raising:
        @hookimpl
        def lanegraph_kernels(self):
            raise RuntimeError("broken")

    pm.register(Raising(), "raising")
    (s,) = first_run.kernel_sets(pm)
    assert s.package == "lg_lister" and [e["name"] for e in s.entries] == ["k"]  # not lanegraph_lanes'
    module.WHERE = "../elsewhere.json"
    assert first_run.kernel_sets(pm) == []


def test_precompile_skips_what_it_cannot_resolve():
    bad = [
        {"module": "lanegraph_lanes.no_such_module", "name": "k", "args": []},
        {"module": "lanegraph_lanes._select", "name": "no_such_kernel", "args": []},
        {"module": "lanegraph_lanes._select", "name": "kth_smallest", "args": ["complex128"]},
        {"module": "lanegraph_lanes._select", "name": "math", "args": []},  # not a kernel
    ]
    assert first_run.precompile([*((_LANES, b) for b in bad), (_LANES, _GOOD)]) == 1
    from lanegraph_lanes._select import kth_smallest
    from numba.core import types

    assert (types.Array(types.float64, 1, "C"), types.int64, types.int64) in kth_smallest.signatures
    with pytest.raises(ValueError):
        decode_type("object")
    # without compile_missing, an entry no bundle holds is passed over
    assert (
        first_run.precompile(
            [(_LANES, {**_GOOD, "args": ["array(int32, 1, C)", "int64", "int64"]})], compile_missing=False
        )
        == 0
    )


def test_precompile_imports_the_plugins_own_modules_only(tmp_path, monkeypatch):
    """A list names its plugin's kernels; a module of another name (one lying in the user's folder,
    say) is never imported."""
    (tmp_path / "stranger_kernels.py").write_text("import os\nos.environ['STRANGER_RAN'] = '1'\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delenv("STRANGER_RAN", raising=False)
    assert first_run.precompile([(_LANES, {"module": "stranger_kernels", "name": "k", "args": []})]) == 0
    assert "STRANGER_RAN" not in os.environ and "stranger_kernels" not in sys.modules


def test_the_results_cache_does_not_load_numba():
    """Issue 45: numba stays out of the modules that do not compile (run/cache.py used to import it)."""
    code = "import sys, lanegraph.run.cache, lanegraph.kernels; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False"]


def test_precompile_compiles_without_cyclic_garbage_collection(monkeypatch):
    """The kernel lists are made with the cyclic collector off (numba's compiler makes millions of
    objects), and the collector is on again afterwards, also after an entry that failed."""
    seen = []

    def spy(text):
        seen.append(gc.isenabled())
        return decode_type(text)

    monkeypatch.setattr(first_run, "decode_type", spy)
    assert gc.isenabled()
    stale = {"module": "lanegraph_lanes._select", "name": "kth_smallest", "args": ["complex128"]}
    assert first_run.precompile([(_LANES, stale), (_LANES, _GOOD)]) == 1
    assert seen and not any(seen)
    assert gc.isenabled()
    gc.disable()  # a caller that had it off keeps it off
    try:
        first_run.precompile([(_LANES, _GOOD)])
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_numba_keeps_the_signatures_it_resolved_while_lanegraph_compiles(monkeypatch):
    """Within kept_call_types (the first run's precompile) each resolution of a built-in call (the
    same function and argument types) is kept: a repeat returns the kept signature without trying
    the function's typing templates again, and records its implementation as the first resolution
    did. Outside it numba's own method is back (a user's numba code is compiled as numba does it)."""
    import operator

    from numba.core import types
    from numba.core.registry import cpu_target
    from numba.core.types import functions
    from numba.core.typing import templates

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
    with compat.kept_call_types() as kept:
        assert kept and getattr(functions.BaseFunction.get_call_type, "_lanegraph_memo", False)
        with compat.kept_call_types():  # nested: still in place after the inner block
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

    monkeypatch.setenv("LANEGRAPH_NUMBA_CALL_MEMO", "0")
    with compat.kept_call_types() as kept:
        assert not kept
        assert not getattr(functions.BaseFunction.get_call_type, "_lanegraph_memo", False)


def test_an_untested_numba_gets_plain_numba_without_a_disk_cache(monkeypatch):
    """Issue 45: lanegraph's use of numba's internals is guarded by the versions it was tested with;
    elsewhere kernels are plain numba kernels (no disk cache, no kept resolutions, no bundle)."""
    from numba.core import caching
    from numba.core.types import functions

    from lanegraph.kernels import bundle, decorator, disk

    assert compat.internals_tested()  # pyproject.toml pins numba and llvmlite to the tested range
    monkeypatch.setitem(compat.TESTED, "numba", ((0, 1), (0, 2)))
    assert not compat.internals_tested()
    monkeypatch.setitem(decorator._WARNED, "untested", False)
    with pytest.warns(folder.KernelCacheWarning, match="tested with"):

        @decorator.jit
        def plain(x):
            return x + 1

    assert plain(1) == 2 and isinstance(plain._cache, caching.NullCache)
    assert not isinstance(plain._cache, disk.CheckedCache)
    with compat.kept_call_types() as kept:
        assert not kept and not getattr(functions.BaseFunction.get_call_type, "_lanegraph_memo", False)
    header = {**bundle.environment(), "triple": "x"}
    assert not bundle._fits(header)


_CALLER = """
from lanegraph import jit
from {pkg}.helper import step

@jit
def kernel(x):
    return step(x) * 10
"""

_HELPER = """
from lanegraph import jit

@jit
def step(x):
    return x + {add}
"""


def _call_kernel(root: Path, pkg: str, cache: Path) -> tuple[int, bool, str]:
    """``kernel(1)`` of the package in a fresh process, whether it came from the cache, and stderr."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(root), "LANEGRAPH_PRECOMPILE": "0"}
    code = (
        f"from {pkg}.caller import kernel; v = kernel(1); "
        "print(v, kernel.stats.cache_hits.get(kernel.signatures[0], 0) > 0)"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    v, hit = out.stdout.split()
    return int(v), hit == "True", out.stderr


@pytest.fixture
def probe(tmp_path):
    """A package with a kernel calling a helper kernel, and a kernel folder for it."""
    pkg = "lg_stale_probe"
    folder_ = tmp_path / "src" / pkg
    folder_.mkdir(parents=True)
    (folder_ / "__init__.py").write_text("")
    (folder_ / "caller.py").write_text(_CALLER.format(pkg=pkg))
    (folder_ / "helper.py").write_text(_HELPER.format(add=1))
    return tmp_path / "src", pkg, tmp_path / "kernels"


def test_a_cached_kernel_is_compiled_again_when_a_function_it_calls_changes(probe):
    """numba keeps a cached kernel while its own file is unchanged; the machine code of the functions
    it calls is compiled into it, so an edit of a callee in another file of the package must not
    leave the caller running the old callee (the disk cache's package stamp)."""
    root, pkg, cache = probe
    assert _call_kernel(root, pkg, cache)[:2] == (20, False)  # compiled
    assert _call_kernel(root, pkg, cache)[:2] == (20, True)  # from the cache
    (root / pkg / "helper.py").write_text(_HELPER.format(add=2))  # caller.py itself unchanged
    assert _call_kernel(root, pkg, cache)[:2] == (30, False)  # not the stale 20
    assert _call_kernel(root, pkg, cache)[:2] == (30, True)


class _Planted:
    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))  # unpickling it creates the file


@pytest.mark.parametrize("kind", ["nbi", "nbc"])
def test_a_pickle_planted_in_the_kernel_cache_never_runs(probe, tmp_path, kind):
    """Issue 46: a pickle planted in a cache file is never unpickled: the kernel is compiled again,
    with a warning, and saved over it."""
    import pickle

    root, pkg, cache = probe
    assert _call_kernel(root, pkg, cache)[:2] == (20, False)
    ran = tmp_path / "PLANTED-RAN"
    files = sorted(cache.rglob(f"caller.kernel-*.{kind}"))
    assert files, list(cache.rglob("*"))
    for f in files:
        if kind == "nbi":  # numba's own layout: its version pickled, then the rest
            import numba

            f.write_bytes(pickle.dumps(numba.__version__) + pickle.dumps(_Planted(str(ran))))
        else:
            f.write_bytes(pickle.dumps(_Planted(str(ran))))
    v, hit, err = _call_kernel(root, pkg, cache)
    assert (v, hit) == (20, False) and not ran.exists()
    assert "KernelCacheWarning" in err and "compiled again" in err
    assert _call_kernel(root, pkg, cache)[:2] == (20, True)  # saved over it: kept again


@pytest.mark.parametrize("damage", ["random index", "empty data", "cut data"])
def test_a_corrupt_kernel_cache_file_never_fails_a_run(probe, damage):
    """Issue 46: random index bytes, an empty or cut .nbc: compiled again with a warning, and the
    next run loads it from the cache again."""
    root, pkg, cache = probe
    _call_kernel(root, pkg, cache)
    if damage == "random index":
        for f in cache.rglob("caller.kernel-*.nbi"):
            f.write_bytes(os.urandom(300))
    else:
        for f in cache.rglob("caller.kernel-*.nbc"):
            f.write_bytes(b"" if damage == "empty data" else f.read_bytes()[:-20])
    v, hit, err = _call_kernel(root, pkg, cache)
    assert (v, hit) == (20, False) and "compiled again" in err
    assert _call_kernel(root, pkg, cache)[:2] == (20, True)


def test_kernel_cache_files_are_private_and_signed(probe):
    root, pkg, cache = probe
    _call_kernel(root, pkg, cache)
    from lanegraph.kernels.disk import KEY_NAME, MAGIC

    files = [f for f in cache.rglob("*") if f.is_file()]
    assert (cache / KEY_NAME).stat().st_mode & 0o077 == 0
    for f in files:
        assert f.stat().st_mode & 0o077 == 0, f
        if f.suffix in (".nbi", ".nbc"):
            assert f.read_bytes().startswith(MAGIC)


def test_a_full_disk_runs_without_a_kernel_cache(monkeypatch, tmp_path):
    """Issue 46: a kernel folder that cannot be written (no space left) means going on without the
    disk cache, with a warning, never a failed run."""
    import errno

    import numba

    from lanegraph.kernels import disk

    if disk.folder_and_key()[0] is None:
        pytest.skip("this process has no kernel folder")

    def full(path, data, mode=0o666):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(disk, "write_bytes_atomic", full)
    monkeypatch.setitem(disk._STATE, "off", False)
    monkeypatch.setitem(disk._STATE, "warned", set())

    def twice(x):
        return 2 * x + 0.5

    kernel = numba.jit(nopython=True)(twice)
    assert disk.attach(kernel)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert kernel(2.0) == 4.5
    assert disk._STATE["off"]
    assert any(
        "No space left" in str(w.message) and "without a kernel cache" in str(w.message) for w in caught
    )
