"""Plugins' kernels shipped as machine code (lanegraph.kernels.bundle): each built-in plugin's bundle
matches its sources, a kernel is loaded from its bundle when first called (not compiled) and
computes what the compiled one does, types a bundle does not hold are compiled with a notice, a
bundle that does not fit (other versions, other sources, turned off) is never used, and a
third-party plugin ships its own through the ``lanegraph_kernels`` hook."""

from __future__ import annotations

import importlib
import json
import os
import pickle
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

from lanegraph.kernels import bundle, first_run
from lanegraph.kernels.first_run import KernelSet

from .test_kernel_cache import _GOOD as _KTH  # kth_smallest's list entry
from .test_kernel_cache import _LANES

ROOT = Path(__file__).resolve().parents[2]


def _py(code: str, cache: Path, *args: str, cwd: Path = ROOT, **env: str) -> subprocess.CompletedProcess:
    full = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "LANEGRAPH_PRECOMPILE": "0", **env}
    out = subprocess.run(
        [sys.executable, "-c", code, *args], env=full, capture_output=True, text=True, timeout=300, cwd=cwd
    )
    assert out.returncode == 0, out.stderr
    return out


def test_the_shipped_bundles_are_made_from_these_sources(installed_pm):
    """Every kernel of each built-in plugin's list has its entry in the plugin's bundle, made from
    the sources installed here: else a first run compiles them all again."""
    sets = [s for s in first_run.kernel_sets(installed_pm) if s.entries]
    assert sets
    for s in sets:
        if not bundle.applies(s.bundle_path):
            header = bundle.read_header(s.bundle_path)
            pytest.skip(f"{s.bundle_path} was made for {header}, this is {bundle.environment()}")
        entries = bundle._entries(s.bundle_path)
        assert entries is not None, f"{s.bundle_path}: the entries cannot be read"
        assert set(entries) == {bundle.entry_key(e) for e in s.entries}
        for entry in s.entries:
            kernel = getattr(importlib.import_module(entry["module"]), entry["name"])
            assert entries[bundle.entry_key(entry)][0] == bundle._digest(kernel), (
                f"{entry['module']}.{entry['name']}: the bundle was made from other sources; "
                "remake it: python benchmarks/record_kernels.py --bundle-only"
            )
        assert bundle.keys(s.bundle_path) == set(entries)


#: a subprocess's lines that list in ``compiled`` the functions numba compiles from here on (by
#: qualified name; not numba's own implementations)
_COUNT_COMPILES = """
from numba.core import event

compiled = []
class _Count(event.Listener):
    def on_start(self, ev):
        func = ev.data["dispatcher"].py_func
        if not func.__module__.startswith("numba"):
            compiled.append(func.__qualname__)
    def on_end(self, ev):
        pass
event.register("numba:compile", _Count())
"""


_MAKE = """
import json, sys
from pathlib import Path
from lanegraph.kernels.bundle import write_bundle
print(write_bundle([json.loads(sys.argv[1])], Path(sys.argv[2])))
"""

_USE = (
    """
import json, sys
from pathlib import Path
import numpy as np
from lanegraph.kernels import bundle
from lanegraph.kernels.bundle import decode_type
import lanegraph_lanes._select as sel

"""
    + _COUNT_COMPILES
    + """
entry = json.loads(sys.argv[1])
sig = tuple(decode_type(a) for a in entry["args"])
installed = bundle.install(sel.kth_smallest, sig, entry, Path(sys.argv[2]))
a = np.random.default_rng(7).normal(size=1001)
got = [sel.kth_smallest(a.copy(), a.size, k) for k in (0, 17, 500, 1000)]
hits = sel.kth_smallest.stats.cache_hits.get(sel.kth_smallest.signatures[0], 0)
print(json.dumps({"installed": installed, "compiled": compiled, "got": got,
                  "want": [float(np.sort(a)[k]) for k in (0, 17, 500, 1000)], "hits": hits}))
"""
)


def _make(tmp_path: Path, entry: dict, out: Path, **env: str) -> subprocess.CompletedProcess:
    """A bundle of ``entry`` made as record_kernels.py makes one (the baseline CPU)."""
    return _py(
        _MAKE, tmp_path / "maker", json.dumps(entry), str(out), LANEGRAPH_KERNEL_BUNDLE="0",
        NUMBA_CPU_NAME="x86-64-v3", NUMBA_CPU_FEATURES="", **env,
    )  # fmt: skip


def test_a_bundle_is_made_for_one_cpu_only(tmp_path):
    """Its machine code must run on every x86-64-v3 machine: a process that would make it for its own
    CPU (AVX-512, say) refuses to."""
    out = subprocess.run(
        [sys.executable, "-c", _MAKE, json.dumps(_KTH), str(tmp_path / "host.bundle")],
        env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "k"), "LANEGRAPH_KERNEL_BUNDLE": "0"},
        capture_output=True, text=True, timeout=300, cwd=ROOT,
    )  # fmt: skip
    assert out.returncode != 0 and "NUMBA_CPU_NAME=x86-64-v3" in out.stderr
    assert not (tmp_path / "host.bundle").exists()


def test_a_kernel_from_the_bundle_is_not_compiled_and_computes_the_same(tmp_path):
    made_bundle = tmp_path / "one.bundle"
    made = _make(tmp_path, _KTH, made_bundle)
    assert made.stdout.split() == ["1"] and bundle.read_header(made_bundle)["triple"]
    kernels = tmp_path / "kernels"  # empty: a first run on this machine
    first = json.loads(_py(_USE, kernels, json.dumps(_KTH), str(made_bundle)).stdout)
    assert first["installed"] is True
    assert first["compiled"] == []  # loaded from the machine code: numba compiled nothing
    assert first["got"] == first["want"]
    assert any(kernels.rglob("*.nbi")), "the kernel was not saved to the kernel folder"
    # the next process loads it from the kernel folder, as a compiled kernel (the bundle not used)
    again = json.loads(_py(_USE, kernels, json.dumps(_KTH), str(tmp_path / "none.bundle")).stdout)
    assert again["installed"] is False and again["compiled"] == [] and again["hits"] == 1
    assert again["got"] == first["want"]


_LAZY = (
    """
import json, sys
from pathlib import Path
import numpy as np
from lanegraph.kernels import bundle
from lanegraph.kernels.first_run import KernelSet
import lanegraph_lanes._select as sel

"""
    + _COUNT_COMPILES
    + """
entry = json.loads(sys.argv[1])
bundle.register([KernelSet("lanegraph_lanes", Path(sys.argv[2]).with_suffix(".json"), (entry,))])
a = np.random.default_rng(7).normal(size=1001)
got = [sel.kth_smallest(a.copy(), a.size, k) for k in (0, 17, 500)]
got32 = sel.kth_smallest(a.astype(np.float32), a.size, 3)  # types the bundle does not hold
hits = {str(s): sel.kth_smallest.stats.cache_hits.get(s, 0) for s in sel.kth_smallest.signatures}
print(json.dumps({"compiled": compiled, "got": got, "want": [float(np.sort(a)[k]) for k in (0, 17, 500)],
                  "got32": float(got32), "want32": float(np.sort(a.astype(np.float32))[3]), "hits": hits}))
"""
)


def test_a_kernel_is_loaded_from_its_bundle_when_first_called(tmp_path):
    """Issue 47: no kernel is made ahead; the first call of a kernel whose types the plugin's bundle
    holds loads its machine code (numba compiles nothing, a cache hit) and saves it to the kernel
    folder; other types compile when called, as before, with the same results as the NumPy sort."""
    made_bundle = tmp_path / "kernels.bundle"
    _make(tmp_path, _KTH, made_bundle)
    kernels = tmp_path / "kernels"
    got = json.loads(_py(_LAZY, kernels, json.dumps(_KTH), str(made_bundle)).stdout)
    assert got["got"] == got["want"] and got["got32"] == got["want32"]
    assert got["compiled"] == ["kth_smallest"]  # the float32 call only
    assert sorted(got["hits"].values()) == [0, 1]  # float64: from the bundle, as from numba's cache
    assert len(list(kernels.rglob("*.nbc"))) == 2  # both kept for the next run
    # no registered bundle (a process that never read the plugins' lists): compiled as before
    again = json.loads(_py(_LAZY, tmp_path / "k2", json.dumps(_KTH), str(tmp_path / "none.bundle")).stdout)
    assert again["compiled"] == ["kth_smallest", "kth_smallest"] and again["got"] == got["want"]


_WORKER = (
    """
import importlib, json
from lanegraph.kernels import bundle
from lanegraph.plugins import get_plugin_manager

"""
    + _COUNT_COMPILES
    + """
get_plugin_manager()  # a runner's worker: plugins loaded, no command's compile_share
from lanegraph.kernels.first_run import kernel_sets
(lanes,) = [s for s in kernel_sets() if s.package == "lanegraph_lanes"]
entry = lanes.entries[-1]
kernel = getattr(importlib.import_module(entry["module"]), entry["name"])
sig = tuple(bundle.decode_type(a) for a in entry["args"])
kernel.compile(sig)
print(json.dumps({"compiled": compiled, "hits": kernel.stats.cache_hits.get(sig, 0)}))
"""
)


def test_a_process_with_plugins_loads_kernels_from_their_bundles(tmp_path, installed_pm):
    """A process that runs nodes without a command (a runner's worker, lanegraph.testing) finds the
    bundles through its plugin manager at the first kernel it needs."""
    if not all(bundle.applies(s.bundle_path) for s in first_run.kernel_sets(installed_pm) if s.entries):
        pytest.skip("the shipped bundles were not made for this Python, numba and machine")
    got = json.loads(_py(_WORKER, tmp_path / "kernels").stdout)
    assert got == {"compiled": [], "hits": 1}


def test_a_compilation_says_so_before_it_starts(tmp_path):
    """A kernel whose types no bundle holds is compiled with a notice on stderr (once per process),
    naming the kernel."""
    code = (
        "import numpy as np\n"
        "from lanegraph.kernels import first_run\n"
        "first_run.first_run_notice()\n"
        "first_run._STATE['first'] = False\n"
        "import lanegraph_lanes._select as sel\n"
        "sel.kth_smallest(np.arange(5.0), 5, 1); sel.kth_smallest(np.arange(5, dtype=np.float32), 5, 1)\n"
    )
    err = _py(code, tmp_path / "k").stderr
    assert err.count("lanegraph: compiling numba kernel lanegraph_lanes._select.kth_smallest") == 1, err
    assert str(tmp_path / "k") in err


def _write(path: Path, header: dict, entries: dict) -> Path:
    body = zlib.compress(pickle.dumps(entries))
    path.write_bytes(json.dumps(header).encode() + b"\n" + body)
    return path


def test_a_bundle_that_does_not_fit_is_never_used(tmp_path, monkeypatch):
    from lanegraph_lanes._select import kth_smallest
    from llvmlite import binding as ll
    from numba.core import types

    sig = (types.Array(types.float64, 1, "C"), types.int64, types.int64)
    here = {**bundle.environment(), "triple": ll.get_process_triple()}
    key = bundle.entry_key(_KTH)
    # other sources: the digest differs, and the payload (not a pickle here) is never read
    stale = _write(tmp_path / "stale.bundle", here, {key: ("0" * 64, b"never unpickled")})
    assert bundle.applies(stale) and bundle.keys(stale) == set()
    assert bundle.install(kth_smallest, sig, _KTH, stale) is False
    monkeypatch.setattr(bundle, "_REGISTERED", {"lanegraph_lanes": stale})
    assert bundle.load(kth_smallest.py_func, sig, kth_smallest.targetctx) is None
    # another numba, another triple, a file that is no bundle: nothing is read past the header
    other = _write(
        tmp_path / "numba.bundle", {**here, "numba": "0.1"}, {key: (bundle._digest(kth_smallest), b"x")}
    )
    assert not bundle.applies(other) and bundle.install(kth_smallest, sig, _KTH, other) is False
    triple = _write(tmp_path / "triple.bundle", {**here, "triple": "riscv64-unknown-none"}, {key: ("", b"")})
    assert bundle.install(kth_smallest, sig, _KTH, triple) is False
    junk = tmp_path / "junk.bundle"
    junk.write_bytes(b"\x89PNG not a bundle")
    assert not bundle.applies(junk) and bundle.install(kth_smallest, sig, _KTH, junk) is False
    assert not bundle.applies(tmp_path / "missing.bundle")
    # a CPU without x86-64-v3's features (AVX2, FMA, ...): its kernels compile
    with monkeypatch.context() as m:
        m.setattr(bundle, "cpu_fits", lambda: False)
        assert not bundle.applies(stale)
    assert bundle.cpu_fits() == all(ll.get_host_cpu_features().get(f, False) for f in bundle.CPU_FEATURES)
    # turned off, or kernels not compiled at all
    for name, value in (("LANEGRAPH_KERNEL_BUNDLE", "0"), ("NUMBA_DISABLE_JIT", "1")):
        with monkeypatch.context() as m:
            m.setenv(name, value)
            assert not bundle.enabled() and not bundle.applies(stale)


def test_a_first_run_registers_the_bundles_and_makes_nothing_ahead(monkeypatch):
    """Where the bundles hold the default run's kernels a first run compiles and loads nothing
    ahead (each kernel is loaded when called), on every run the bundles are registered."""
    calls, registered = [], []
    monkeypatch.setattr(
        first_run,
        "precompile",
        lambda items, claims=None, compile_missing=True: calls.append(compile_missing) or 7,
    )
    monkeypatch.setattr(bundle, "register", lambda sets: registered.append(list(sets)))
    state = {
        "said": True,
        "armed": True,
        "helper": None,
        "claims": None,
        "first": False,
        "folder": Path("/k"),
    }
    monkeypatch.setattr(first_run, "_STATE", state)
    monkeypatch.setenv("LANEGRAPH_PRECOMPILE", "1")
    monkeypatch.setattr(first_run, "_split", lambda sets: ([(_LANES, _KTH)], []))
    monkeypatch.setattr(first_run, "kernel_sets", lambda pm=None: [_LANES])
    assert first_run.compile_share() == 0 and calls == [] and registered == [[_LANES]]  # a later run
    state["first"] = True
    assert first_run.compile_share() == 0 and calls == [] and len(registered) == 2


@pytest.mark.parametrize("fits", [True, False])
def test_the_notice_says_what_the_first_run_costs(monkeypatch, capsys, tmp_path, fits):
    """Issue 47: the real figure: the machine code's load time of the kernels a bundle holds (each
    loaded when called), and the compilation of the default run's others, shared with the helper."""
    monkeypatch.setattr(
        first_run,
        "_STATE",
        {"said": False, "armed": False, "helper": None, "claims": None, "folder": tmp_path},
    )
    entries = [
        {**_KTH, "seconds": 6.0, "load_seconds": 0.25, "default": True},
        {**_KTH, "name": "other", "seconds": 4.0, "load_seconds": 0.1, "default": True},
    ]
    sets = [KernelSet("lanegraph_lanes", tmp_path / "kernels.json", tuple(entries))]
    monkeypatch.setattr(bundle, "applies", lambda path: fits)
    monkeypatch.setattr(bundle, "keys", lambda path: {bundle.entry_key(entries[0])})
    lazy, ahead = first_run._split(sets)
    first_run._say_plan(lazy, ahead, helper=True)
    err = capsys.readouterr().err
    assert err.startswith("lanegraph: first run of this installation on this machine")
    if fits:
        assert "when first called (1 kernels, 0.2 s at most) and compiling 1 numba kernels (about 2 s" in err
    else:
        assert lazy == [] and "compiling 2 numba kernels (about 5 s on 2 cores" in err
    assert str(tmp_path) in err


_TOY_INIT = """
from pathlib import Path
from lanegraph import hookimpl

@hookimpl
def lanegraph_kernels():
    return Path(__file__).with_name("kernels.json")
"""

_TOY_KERNELS = """
from lanegraph import jit

@jit
def _scaled_sum(a, k):
    s = 0.0
    for i in range(a.size):
        s += a[i] * k
    return s
"""

_TOY_ENTRY = {
    "module": "lg_toy_kernels.k",
    "name": "_scaled_sum",
    "args": ["array(float64, 1, C)", "float64"],
}

_TOY_FIRST_RUN = (
    """
import json, sys
import numpy as np
import lg_toy_kernels
import lanegraph._runtime
from lanegraph import kernels
from lanegraph.plugins import PluginManager

lanegraph._runtime.available_cpus = lambda: 1  # no helper: this process makes the list itself

"""
    + _COUNT_COMPILES
    + """
pm = PluginManager()
pm.register(lg_toy_kernels, "lg_toy_kernels")
kernels.first_run_notice()
made = kernels.compile_share(pm)
from lg_toy_kernels.k import _scaled_sum
value = _scaled_sum(np.arange(4.0), 0.5)
print(json.dumps({"made": made, "compiled": compiled, "value": value}))
"""
)


def test_a_third_party_plugin_ships_its_kernels_through_the_hook(tmp_path):
    """Issue 45: a plugin's own list and bundle, named by lanegraph_kernels: its first run loads the
    kernel from the plugin's machine code (numba compiles nothing) and says so before any frame."""
    pkg = tmp_path / "src" / "lg_toy_kernels"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(_TOY_INIT)
    (pkg / "k.py").write_text(_TOY_KERNELS)
    (pkg / "kernels.json").write_text(json.dumps([{**_TOY_ENTRY, "seconds": 0.3, "load_seconds": 0.01}]))
    env = {"PYTHONPATH": os.pathsep.join([str(tmp_path / "src"), os.environ.get("PYTHONPATH", "")])}
    _make(tmp_path, _TOY_ENTRY, pkg / "kernels.bundle", **env)
    env["LANEGRAPH_PRECOMPILE"] = "1"
    out = _py(_TOY_FIRST_RUN, tmp_path / "kernels", cwd=tmp_path, **env)
    got = json.loads(out.stdout)
    assert got == {"made": 0, "compiled": [], "value": 3.0}  # loaded when called: nothing compiled
    assert "loading each of its numba kernels from the plugins' machine code when first called" in out.stderr
    # without the bundle, the same first run compiles it when called
    (pkg / "kernels.bundle").unlink()
    got = json.loads(_py(_TOY_FIRST_RUN, tmp_path / "kernels2", cwd=tmp_path, **env).stdout)
    assert got["made"] == 0 and got["compiled"] == ["_scaled_sum"] and got["value"] == 3.0


def test_a_first_run_from_the_bundles_gives_the_lanes_of_compiled_kernels(tmp_path, installed_pm):
    """The default ``lanegraph run`` on an empty kernel folder (each kernel loaded from its plugin's
    bundle when called) writes the lanes this test session's compiled kernels write."""
    if not all(bundle.applies(s.bundle_path) for s in first_run.kernel_sets(installed_pm) if s.entries):
        pytest.skip("the shipped bundles were not made for this Python, numba and machine")
    from click.testing import CliRunner

    from lanegraph.cli import main

    r = CliRunner().invoke(main, ["run", "--quiet", "--out", str(tmp_path / "here")])
    assert r.exit_code == 0, r.output
    env = {
        **os.environ,
        "NUMBA_CACHE_DIR": str(tmp_path / "kernels"),
        "LANEGRAPH_CACHE_DIR": str(tmp_path / "cache"),
        "LANEGRAPH_PRECOMPILE": "1",
    }
    cold = subprocess.run(
        [sys.executable, "-m", "lanegraph.cli", "run", "--out", str(tmp_path / "cold")],
        env=env, capture_output=True, text=True, timeout=600, cwd=tmp_path,
    )  # fmt: skip
    assert cold.returncode == 0, cold.stderr
    said = [line for line in cold.stderr.splitlines() if not line.startswith("warning: plugin ")]
    assert "from the plugins' machine code" in said[0]  # (a broken third-party plugin may warn first)
    assert "compiling numba kernel" not in cold.stderr  # every kernel it calls is in the bundles
    assert (tmp_path / "cold" / "lanes.jsonl").read_bytes() == (
        tmp_path / "here" / "lanes.jsonl"
    ).read_bytes()
