"""The content-addressed result cache: a changed param or input invalidates exactly what is downstream."""

from __future__ import annotations

import copy

import yaml

from lanegraph.graph.validation import load_graph
from lanegraph.nodes import RunContext
from lanegraph.run.cache import Caching, ResultCache
from lanegraph.run.executor import Executor

from . import toyplugin
from .test_graph import VALID

# src -> double -> acc (feedback) -> sink ; k depends on the constant calibration only
CHAIN = copy.deepcopy(VALID)
CHAIN["nodes"]["triple"] = {"type": "toy.scale", "params": {"factor": 3}, "inputs": {"x": "src.value"}}


def run(tmp_path, pm, cache, data=CHAIN, sets=()):
    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump(data))
    res = Executor(load_graph(p, sets=list(sets), pm=pm), RunContext(), pm, caching=Caching(cache)).run()
    return res, list(toyplugin.Collect.out)


def test_rerun_recomputes_nothing(tmp_path, pm):
    cache = ResultCache(tmp_path / "cache")
    first, out1 = run(tmp_path, pm, cache)
    assert first.cache_hits == {} and first.cache_misses == {"k": 1, "double": 4, "acc": 4, "triple": 4}
    second, out2 = run(tmp_path, pm, cache)
    assert second.cache_misses == {} and second.cache_hits == {"k": 1, "double": 4, "acc": 4, "triple": 4}
    assert out1 == out2


def test_changed_param_invalidates_downstream_only(tmp_path, pm):
    cache = ResultCache(tmp_path / "cache")
    run(tmp_path, pm, cache)
    res, out = run(tmp_path, pm, cache, sets=["double.factor=5"])
    assert res.cache_misses == {"double": 4, "acc": 4}
    assert res.cache_hits == {"k": 1, "triple": 4}
    assert [x for _, x in out] == [0.0, 5.0, 15.0, 30.0]  # recomputed with the new factor


def test_changed_input_invalidates_per_frame_nodes(tmp_path, pm):
    cache = ResultCache(tmp_path / "cache")
    run(tmp_path, pm, cache)
    toyplugin.KEY_SALT["salt"] = "v2"  # the input files changed
    try:
        res, _ = run(tmp_path, pm, cache)
    finally:
        toyplugin.KEY_SALT["salt"] = "v1"
    assert res.cache_misses == {"double": 4, "acc": 4, "triple": 4} and res.cache_hits == {"k": 1}


def test_size_bound_evicts_least_recently_used(tmp_path):
    cache = ResultCache(tmp_path / "c", max_bytes=3000)
    for i in range(10):
        cache.put(f"{i:064x}", b"x" * 1000)
    assert cache.size_bytes <= 3000
    assert cache.get(f"{9:064x}") == b"x" * 1000
    assert cache.get(f"{0:064x}") is ResultCache.MISS


def test_edited_plugin_code_changes_the_keys(tmp_path, monkeypatch):
    """A node's results are keyed by its code too: an upgraded or edited plugin package never gets
    results its old code computed (the digest covers every source file of the package)."""
    import sys

    from lanegraph.nodes import NodeType, _code_version

    pkg = tmp_path / "lg_edited"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("from ._impl import double\n")
    (pkg / "_impl.py").write_text("def double(params, x):\n    return {'y': 2 * x}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("lg_edited", None)
    import lg_edited

    nt = NodeType("toy.edited", lg_edited.double)
    before = nt.code_version
    _code_version.cache_clear()
    assert NodeType("toy.edited", lg_edited.double).code_version == before  # stable while unchanged
    (pkg / "_helpers.py").write_text("SCALE = 3\n")  # any file of the package, not only the node's
    _code_version.cache_clear()
    assert nt.code_version != before
    _code_version.cache_clear()
    sys.modules.pop("lg_edited", None)
    sys.modules.pop("lg_edited._impl", None)


def test_edited_engine_code_changes_the_keys(tmp_path, monkeypatch):
    """A node's key covers lanegraph's own source files too (the types and helpers a plugin calls):
    an edited engine in a development install never serves results its old code computed."""
    from lanegraph import nodes
    from lanegraph.nodes import NodeType, _code_version, _engine_version

    engine = tmp_path / "lanegraph"
    (engine / "run").mkdir(parents=True)
    (engine / "types.py").write_text("SCALE = 2\n")
    (engine / "run" / "executor.py").write_text("pass\n")
    monkeypatch.setattr(nodes, "__file__", str(engine / "nodes.py"))
    _engine_version.cache_clear()
    first = _engine_version()
    _engine_version.cache_clear()
    assert _engine_version() == first  # stable while unchanged
    (engine / "run" / "executor.py").write_text("pass  # edited\n")  # any file, in any sub-package
    _engine_version.cache_clear()
    edited = _engine_version()
    assert edited != first

    def double(params, x):
        return {"y": 2 * x}

    _code_version.cache_clear()
    key = NodeType("toy.engine", double).code_version
    (engine / "types.py").write_text("SCALE = 3\n")
    _engine_version.cache_clear()
    _code_version.cache_clear()
    assert NodeType("toy.engine", double).code_version != key
    monkeypatch.undo()
    _engine_version.cache_clear()
    _code_version.cache_clear()


# -- a cache folder shared by several processes (the workers of a Dask cluster) ----------------------
class _Exploit:
    """Pickles as a call of os.system: what a crafted entry in a shared folder would hold."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        import os

        return (os.system, (f"touch {self.marker}",))


class _PluginValue:
    def __init__(self, v):
        self.v = v


def test_a_crafted_entry_runs_nothing_and_is_a_miss(tmp_path):
    import pickle

    import pytest

    from lanegraph.run.cache import CacheWarning

    cache = ResultCache(tmp_path / "cache")
    key = "ab" + "0" * 62
    marker = tmp_path / "pwned"
    cache._path(key).parent.mkdir(parents=True, exist_ok=True)
    cache._path(key).write_bytes(pickle.dumps({"outputs": {"y": _Exploit(marker)}, "ms": 1.0}, protocol=5))
    with pytest.warns(CacheWarning, match="system is not a type a cache entry may hold"):
        assert cache.get(key) is ResultCache.MISS
    assert not marker.exists() and cache.misses == 1
    # the plain pickle module would have run it: the entry is what the test says it is
    pickle.loads(cache._path(key).read_bytes())
    assert marker.exists()


def test_crafted_entries_are_recomputed_and_replaced(tmp_path, pm):
    import pickle
    import warnings

    from lanegraph.run.cache import CacheWarning

    cache = ResultCache(tmp_path / "cache")
    _, out1 = run(tmp_path, pm, cache)
    marker = tmp_path / "pwned"
    entries = sorted(cache.root.glob("*/*.pkl"))
    for p in entries:
        p.write_bytes(pickle.dumps(_Exploit(marker), protocol=5))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res, out2 = run(tmp_path, pm, ResultCache(tmp_path / "cache"))
    assert out2 == out1 and not marker.exists()
    assert res.cache_hits == {} and sum(res.cache_misses.values()) == len(entries)
    assert len([w for w in caught if issubclass(w.category, CacheWarning)]) == len(entries)
    third, _ = run(tmp_path, pm, ResultCache(tmp_path / "cache"))  # overwritten with good entries
    assert third.cache_misses == {} and sum(third.cache_hits.values()) == len(entries)


def test_port_values_round_trip_and_foreign_classes_are_not_stored(tmp_path):
    import numpy as np
    import pytest

    from lanegraph.run.cache import CacheWarning
    from lanegraph.types import Calibration, FeatureMap, Lane, Line, RoadModel

    cache = ResultCache(tmp_path / "c")
    fm = FeatureMap.from_points((4, 5), np.array([0, 3]), np.array([1, 4]), np.array([0.5, 1.5], np.float32))
    value = {
        "outputs": {
            "disparity": np.arange(12, dtype=np.float32).reshape(3, 4),
            "mask": np.eye(3, dtype=bool),
            "calib": Calibration(700.0, 600.0, 170.0, 0.54, 1242, 375),
            "road": RoadModel(1.0, 0.5, profile=np.array([-1, 2, 3])),
            "features": fm,
            "lines": [Line(10.0, 1.2, 3.0)],
            "lanes": [Lane((1.0, 0.1, 0.01), (0, 99), "left", 0.8, np.zeros((3, 2)))],
            "number": np.float64(2.5),
            "mixed": ({1, 2}, frozenset({3}), b"raw", 1 + 2j, None, True),
        },
        "ms": 3.0,
    }
    assert cache.put("k" * 64, value)
    got = cache.get("k" * 64)
    assert np.array_equal(got["outputs"]["disparity"], value["outputs"]["disparity"])
    assert got["outputs"]["calib"] == value["outputs"]["calib"]
    assert got["outputs"]["features"].mask.tolist() == fm.mask.tolist()
    assert got["outputs"]["lanes"][0].side == "left" and got["outputs"]["mixed"] == value["outputs"]["mixed"]

    # a plugin's own value class: not stored (a reader would refuse it), the run goes on without it
    with pytest.warns(CacheWarning, match="_PluginValue cannot be stored"):
        assert not cache.put("e" * 64, {"outputs": {"y": _PluginValue(3)}, "ms": 1.0})
    assert cache.get("e" * 64) is ResultCache.MISS


_WRITER = """
import sys
from lanegraph.run.cache import ResultCache
cache = ResultCache(sys.argv[1], 10**9)
value = {"outputs": {"y": bytes(range(256)) * 4000}, "ms": float(sys.argv[2])}
for _ in range(int(sys.argv[3])):
    cache.put("f" * 64, value)
"""


def test_two_processes_writing_one_entry_never_corrupt_it(tmp_path):
    import subprocess
    import sys

    root = tmp_path / "shared"
    cache = ResultCache(root, 10**9)
    writers = [
        subprocess.Popen([sys.executable, "-c", _WRITER, str(root), str(ms), "150"]) for ms in (1.0, 2.0)
    ]
    seen = set()
    try:
        while any(w.poll() is None for w in writers):
            got = cache.get("f" * 64)
            if got is not ResultCache.MISS:  # a whole entry of one writer or the other, never a mix
                assert got["outputs"]["y"] == bytes(range(256)) * 4000
                seen.add(got["ms"])
    finally:
        for w in writers:
            w.wait(timeout=60)
    assert all(w.returncode == 0 for w in writers)
    assert seen and seen <= {1.0, 2.0}
    assert list(root.glob("*/*.tmp")) == [] and len(list(root.glob("*/*.pkl"))) == 1


def test_size_bound_holds_across_processes_sharing_the_folder(tmp_path):
    # two caches on one folder stand for two worker processes: each sees the other's entries when
    # it rescans (every tenth of the bound it writes), so the folder stays within the bound
    a, b = ResultCache(tmp_path / "c", max_bytes=20_000), ResultCache(tmp_path / "c", max_bytes=20_000)
    for i in range(15):
        a.put(f"a{i:063x}", b"x" * 1000)
        b.put(f"b{i:063x}", b"x" * 1000)
    on_disk = sum(p.stat().st_size for p in (tmp_path / "c").glob("*/*.pkl"))
    assert on_disk <= 20_000 + 2 * 2 * 1100  # at most two entries each past the last rescan
    assert a.get(f"a{14:063x}") is not ResultCache.MISS and a.get(f"a{0:063x}") is ResultCache.MISS


def test_eviction_removes_stale_temporary_files_and_waits_for_no_one(tmp_path):
    import fcntl
    import os
    import time

    cache = ResultCache(tmp_path / "c", max_bytes=5000)
    for i in range(4):
        cache.put(f"{i:064x}", b"x" * 1000)
    stale, fresh = cache.root / "00" / ".dead.tmp", cache.root / "00" / ".writing.tmp"
    stale.write_bytes(b"half")
    fresh.write_bytes(b"half")
    old = time.time() - 2 * 3600
    os.utime(stale, (old, old))
    with open(cache.root / ".evict.lock", "a+b") as held:  # another process is evicting: skip
        fcntl.flock(held.fileno(), fcntl.LOCK_EX)
        cache.max_bytes = 1000
        cache.evict()
        assert len(list(cache.root.glob("*/*.pkl"))) == 4 and stale.exists()
    cache.evict()
    assert len(list(cache.root.glob("*/*.pkl"))) <= 1 and not stale.exists() and fresh.exists()
