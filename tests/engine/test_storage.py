"""Port types store their own values (lanegraph.storage): a plugin's value type is cached by the
result cache and carried across ``@prev`` in a checkpoint, as data, never as a pickled object."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lanegraph.nodes import RunContext
from lanegraph.port_types import PORT_TYPES
from lanegraph.records.resume import load_checkpoint
from lanegraph.run.cache import Caching, ResultCache
from lanegraph.run.executor import Executor
from lanegraph.storage import StorageError, dataclass_storage, decode_value, encode_value

from . import toyplugin
from .test_resume import checkpointed
from .toyplugin import Tally, TallyPlugin

GRAPH = {
    "name": "tally",
    "nodes": {
        "src": {"type": "toy.count", "params": {"n": 4}},
        "t": {"type": "toy.tally", "inputs": {"x": "src.value", "prev": "t.tally@prev"}},
        "sink": {"type": "toy.collect", "inputs": {"frame": "src.frame", "x": "t.total"}},
    },
}


def _graph(tmp_path, pm):
    import yaml

    from lanegraph.graph.validation import load_graph

    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump(GRAPH))
    return load_graph(p, pm=pm)


@pytest.fixture
def tally_pm(pm):
    pm.register(TallyPlugin, name="tally")
    assert pm.plugin_errors == []
    return pm


def test_a_plugins_value_round_trips_by_its_port_types_encode_and_decode(tally_pm):
    t = Tally(3.0, np.array([1, 2], np.float32))
    for arrays in ("base64", "native"):
        data = encode_value({"a": [t, (t, 1)]}, "v", tally_pm.port_types, arrays=arrays)
        if arrays == "base64":
            data = json.loads(json.dumps(data))
            assert data["v"][0][1][0] == {"$t": "port", "type": "tally", "v": data["v"][0][1][0]["v"]}
        back = decode_value(data, "v", tally_pm.port_types)
        assert back == {"a": [t, (t, 1)]} and back["a"][0].seen.dtype == np.float32
    # without its port type registered, it is neither stored nor built
    with pytest.raises(StorageError, match=r"v\[0\]: a tests\.engine\.toyplugin\.Tally cannot be stored"):
        encode_value([t], "v", PORT_TYPES)
    data = encode_value(t, "v", tally_pm.port_types)
    with pytest.raises(StorageError, match="port type 'tally', which no installed plugin stores"):
        decode_value(data, "v", PORT_TYPES)
    data["v"]["v"][0][0] = "totl"  # the plugin's decode refuses what it would not have written
    with pytest.raises(StorageError, match=r"v: port type 'tally' cannot decode it \(ValueError"):
        decode_value(data, "v", tally_pm.port_types)


def test_a_port_types_storage_is_checked_at_registration(pm):
    from lanegraph import PortType, hookimpl

    class Broken:
        @staticmethod
        @hookimpl
        def lanegraph_port_types():
            return [
                PortType("half", "encode without decode", stores=Tally, encode=lambda v: {}),
            ]

    class Twice:
        @staticmethod
        @hookimpl
        def lanegraph_port_types():
            return [PortType("again", "the same class", **dataclass_storage(PORT_TYPES["lanes"].stores))]

    pm.register(Broken, name="broken")
    pm.register(Twice, name="twice")
    assert "half" not in pm.port_types and "again" not in pm.port_types
    errors = {e.plugin: e.error for e in pm.plugin_errors}
    assert "port type 'half': declares storage without decode" in errors["broken"]
    assert (
        "port type 'again': stores" in errors["twice"]
        and "which port type 'lanes' already stores" in errors["twice"]
    )


def test_a_graph_of_a_plugins_value_type_is_cached(tmp_path, tally_pm):
    cache = ResultCache(tmp_path / "cache")
    first = Executor(_graph(tmp_path, tally_pm), RunContext(), tally_pm, caching=Caching(cache)).run()
    out1 = list(toyplugin.Collect.out)
    assert out1 == [("0000", 0.0), ("0001", 1.0), ("0002", 3.0), ("0003", 6.0)]
    assert first.cache_misses.get("t") == 4 and not first.cache_hits
    calls = toyplugin.CALLS["tally"]
    again = Executor(
        _graph(tmp_path, tally_pm), RunContext(), tally_pm, caching=Caching(ResultCache(tmp_path / "cache"))
    ).run()
    assert toyplugin.Collect.out == out1
    assert again.cache_hits.get("t") == 4 and toyplugin.CALLS["tally"] == calls  # served, not computed
    # the entries are data: the restricted unpickler builds no class, the toy one included
    entries = sorted(cache.root.glob("*/*.pkl"))
    assert entries and all(b"toyplugin" not in p.read_bytes() for p in entries)


def test_a_plugins_value_on_a_feedback_edge_is_carried_across_a_resumed_checkpoint(tmp_path, tally_pm):
    from lanegraph import hookimpl

    Executor(_graph(tmp_path, tally_pm), RunContext(), tally_pm).run()
    uninterrupted = list(toyplugin.Collect.out)

    class Stop:
        @hookimpl
        def lanegraph_before_node(self, node_id, frame):
            if node_id == "sink" and frame == "0002":
                raise KeyboardInterrupt

    ck = tmp_path / "checkpoint.json"
    tally_pm.register(Stop(), name="stop")
    with pytest.raises(KeyboardInterrupt):
        checkpointed(_graph(tmp_path, tally_pm), RunContext(), tally_pm, ck).run()
    tally_pm.unregister(name="stop")
    before = list(toyplugin.Collect.out)
    state = load_checkpoint(ck)
    [fb] = state.feedback
    assert (fb.node, fb.port) == ("t", "tally") and fb.value["$t"] == "port" and fb.value["type"] == "tally"
    assert state.unresumable is None
    ex = checkpointed(
        _graph(tmp_path, tally_pm),
        RunContext(skip=state.position, extra={"resume": True}),
        tally_pm,
        ck,
        state,
    )
    res = ex.run()
    assert before + toyplugin.Collect.out == uninterrupted  # the tally went on from frame 1's
    assert res.resumed_frames == 2 and load_checkpoint(ck).complete
