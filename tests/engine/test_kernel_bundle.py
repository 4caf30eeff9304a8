"""The default run's kernels shipped as LLVM bitcode (lanegraph.kernel_bundle): the committed bundle
matches the sources, a kernel made from it is not compiled and computes what the compiled one does,
and a bundle that does not fit (other versions, other sources, turned off) is never used."""

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

from lanegraph import kernel_bundle, kernel_cache

from .test_kernel_cache import _GOOD as _KTH  # kth_smallest's list entry

ROOT = Path(__file__).resolve().parents[2]


def _py(code: str, cache: Path, *args: str, **env: str) -> subprocess.CompletedProcess:
    full = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "LANEGRAPH_PRECOMPILE": "0", **env}
    out = subprocess.run(
        [sys.executable, "-c", code, *args], env=full, capture_output=True, text=True, timeout=300, cwd=ROOT
    )
    assert out.returncode == 0, out.stderr
    return out


def test_the_shipped_bundle_is_made_from_these_sources():
    """Every kernel of the list has its entry, made from the sources installed here: else a first
    run compiles them all again (about 3.5x a warm run instead of 1.5x on 2 cores)."""
    if not kernel_bundle.applies():
        header = kernel_bundle.read_header()
        pytest.skip(f"the bundle was made for {header}, this is {kernel_bundle.environment()}")
    entries = kernel_bundle._entries(kernel_bundle.BUNDLE)
    assert entries is not None, "the bundle's entries cannot be read"
    listed = kernel_cache._read_list(kernel_cache.KERNEL_LIST)
    assert set(entries) == {kernel_bundle.entry_key(e) for e in listed}
    for entry in listed:
        kernel = getattr(importlib.import_module(entry["module"]), entry["name"])
        assert entries[kernel_bundle.entry_key(entry)][0] == kernel_bundle._digest(kernel), (
            f"{entry['module']}.{entry['name']}: the bundle was made from other sources; "
            "remake it: python benchmarks/record_kernels.py --bundle-only"
        )


_MAKE = """
import json, sys
from pathlib import Path
from lanegraph.kernel_bundle import write_bundle
print(write_bundle([json.loads(sys.argv[1])], Path(sys.argv[2])))
"""

_USE = """
import json, sys
from pathlib import Path
import numpy as np
from numba.core import event
from lanegraph import kernel_bundle
from lanegraph.kernel_cache import decode_type
import lanegraph_lanes._select as sel

compiled = []
class _Count(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass
event.register("numba:compile", _Count())
entry = json.loads(sys.argv[1])
sig = tuple(decode_type(a) for a in entry["args"])
installed = kernel_bundle.install(sel.kth_smallest, sig, entry, Path(sys.argv[2]))
a = np.random.default_rng(7).normal(size=1001)
got = [sel.kth_smallest(a.copy(), a.size, k) for k in (0, 17, 500, 1000)]
hits = sel.kth_smallest.stats.cache_hits.get(sel.kth_smallest.signatures[0], 0)
print(json.dumps({"installed": installed, "compiled": compiled, "got": got,
                  "want": [float(np.sort(a)[k]) for k in (0, 17, 500, 1000)], "hits": hits}))
"""


def test_a_kernel_from_the_bundle_is_not_compiled_and_computes_the_same(tmp_path):
    bundle = tmp_path / "one.bundle"
    made = _py(_MAKE, tmp_path / "maker-kernels", json.dumps(_KTH), str(bundle), LANEGRAPH_KERNEL_BUNDLE="0")
    assert made.stdout.split() == ["1"] and kernel_bundle.read_header(bundle)["triple"]
    kernels = tmp_path / "kernels"  # empty: a first run on this machine
    first = json.loads(_py(_USE, kernels, json.dumps(_KTH), str(bundle)).stdout)
    assert first["installed"] is True
    assert first["compiled"] == []  # made from the bitcode: numba compiled nothing
    assert first["got"] == first["want"]
    assert any(kernels.rglob("*.nbi")), "the kernel was not saved to the kernel folder"
    # the next process loads it from the kernel folder, as a compiled kernel (the bundle not used)
    again = json.loads(_py(_USE, kernels, json.dumps(_KTH), str(tmp_path / "none.bundle")).stdout)
    assert again["installed"] is False and again["compiled"] == [] and again["hits"] == 1
    assert again["got"] == first["want"]


def _write(path: Path, header: dict, entries: dict) -> Path:
    body = zlib.compress(pickle.dumps(entries))
    path.write_bytes(json.dumps(header).encode() + b"\n" + body)
    return path


def test_a_bundle_that_does_not_fit_is_never_used(tmp_path, monkeypatch):
    from lanegraph_lanes._select import kth_smallest
    from llvmlite import binding as ll
    from numba.core import types

    sig = (types.Array(types.float64, 1, "C"), types.int64, types.int64)
    here = {**kernel_bundle.environment(), "triple": ll.get_process_triple()}
    key = kernel_bundle.entry_key(_KTH)
    # other sources: the digest differs, and the payload (not a pickle here) is never read
    stale = _write(tmp_path / "stale.bundle", here, {key: ("0" * 64, b"never unpickled")})
    assert kernel_bundle.applies(stale)
    assert kernel_bundle.install(kth_smallest, sig, _KTH, stale) is False
    # another numba, another triple, a file that is no bundle: nothing is read past the header
    other = _write(
        tmp_path / "numba.bundle",
        {**here, "numba": "0.1"},
        {key: (kernel_bundle._digest(kth_smallest), b"x")},
    )
    assert not kernel_bundle.applies(other) and kernel_bundle.install(kth_smallest, sig, _KTH, other) is False
    triple = _write(tmp_path / "triple.bundle", {**here, "triple": "riscv64-unknown-none"}, {key: ("", b"")})
    assert kernel_bundle.install(kth_smallest, sig, _KTH, triple) is False
    junk = tmp_path / "junk.bundle"
    junk.write_bytes(b"\x89PNG not a bundle")
    assert not kernel_bundle.applies(junk) and kernel_bundle.install(kth_smallest, sig, _KTH, junk) is False
    assert not kernel_bundle.applies(tmp_path / "missing.bundle")
    # turned off, or kernels not compiled at all
    for name, value in (("LANEGRAPH_KERNEL_BUNDLE", "0"), ("NUMBA_DISABLE_JIT", "1")):
        with monkeypatch.context() as m:
            m.setenv(name, value)
            assert not kernel_bundle.enabled() and not kernel_bundle.applies(stale)


def test_a_first_run_without_a_helper_makes_the_list_from_the_bundle(monkeypatch):
    """One CPU (no helper): the run itself makes the list's kernels where the bundle applies, once;
    not with LANEGRAPH_PRECOMPILE=0, nor when the bundle does not apply, nor on a later run."""
    calls = []
    monkeypatch.setattr(
        kernel_cache, "precompile", lambda entries, claims=None: calls.append(len(entries)) or 7
    )
    monkeypatch.setattr(kernel_cache, "_STATE", {"said": True, "armed": True, "helper": None, "claims": None})
    monkeypatch.setenv("LANEGRAPH_PRECOMPILE", "1")
    monkeypatch.setattr(kernel_bundle, "applies", lambda path=None: True)
    assert kernel_cache.compile_share() == 0 and calls == []  # not a first run
    kernel_cache._STATE["first"] = True
    monkeypatch.setenv("LANEGRAPH_PRECOMPILE", "0")
    assert kernel_cache.compile_share() == 0 and calls == []
    monkeypatch.setenv("LANEGRAPH_PRECOMPILE", "1")
    monkeypatch.setattr(kernel_bundle, "applies", lambda path=None: False)
    assert kernel_cache.compile_share() == 0 and calls == []
    monkeypatch.setattr(kernel_bundle, "applies", lambda path=None: True)
    assert kernel_cache.compile_share() == 7
    assert calls == [len(kernel_cache._read_list(kernel_cache.KERNEL_LIST))]
    assert kernel_cache.compile_share() == 0 and len(calls) == 1  # once


@pytest.mark.parametrize("fits", [True, False])
def test_the_notice_says_what_the_first_run_costs(monkeypatch, capsys, tmp_path, fits):
    monkeypatch.setattr(
        kernel_cache, "_STATE", {"said": False, "armed": False, "helper": None, "claims": None}
    )
    monkeypatch.setattr(kernel_bundle, "applies", lambda path=None: fits)
    kernel_cache._say(tmp_path)
    err = capsys.readouterr().err
    assert err.startswith("lanegraph: compiling the numba kernels for this machine")
    assert ("LLVM bitcode: about a second" in err) is fits
    assert ("about seven seconds" in err) is not fits


def test_a_first_run_from_the_bundle_gives_the_lanes_of_compiled_kernels(tmp_path):
    """The default ``lanegraph run`` on an empty kernel folder (the helper and the run making the
    kernels from the bundle) writes the lanes this test session's compiled kernels write."""
    if not kernel_bundle.applies():
        pytest.skip("the shipped bundle was not made for this Python, numba and machine")
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
        env=env, capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert cold.returncode == 0, cold.stderr
    assert "LLVM bitcode" in cold.stderr.splitlines()[0]
    assert (tmp_path / "cold" / "lanes.jsonl").read_bytes() == (
        tmp_path / "here" / "lanes.jsonl"
    ).read_bytes()
