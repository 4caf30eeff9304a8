"""The content-addressed result cache: a changed param or input invalidates exactly what is downstream."""

from __future__ import annotations

import copy

import yaml

from lanegraph.cache import ResultCache
from lanegraph.executor import Executor
from lanegraph.graph import load_graph
from lanegraph.nodes import RunContext

from . import toyplugin
from .test_graph import VALID

# src -> double -> acc (feedback) -> sink ; k depends on the constant calibration only
CHAIN = copy.deepcopy(VALID)
CHAIN["nodes"]["triple"] = {"type": "toy.scale", "params": {"factor": 3}, "inputs": {"x": "src.value"}}


def run(tmp_path, pm, cache, data=CHAIN, sets=()):
    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump(data))
    res = Executor(load_graph(p, sets=list(sets), pm=pm), RunContext(), pm, cache=cache).run()
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
