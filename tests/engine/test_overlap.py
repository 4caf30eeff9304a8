"""Running ahead: a node type declared ``ahead=True`` is computed for the next frame on a thread
while this frame's later nodes run; every result, timing, failure and after-node call is the one
of a run that computes one node at a time."""

from __future__ import annotations

import copy
import sys
import threading

import pytest
import yaml
from pydantic import Field

from lanegraph import NodeParams, Port, hookimpl, node_type
from lanegraph.errors import NodeError
from lanegraph.graph.validation import load_graph
from lanegraph.nodes import NodeType, RunContext
from lanegraph.run.cache import Caching, ResultCache
from lanegraph.run.executor import Executor
from lanegraph.run.prefetch import Prefetch
from lanegraph.run.warmup import WarmUp

from . import toyplugin

#: what the ahead node saw: (frame value, feedback value, thread name)
SEEN: list[tuple[float, float | None, str]] = []
#: frame value -> set by the ahead node when it starts on that frame
STARTED: dict[float, threading.Event] = {}
#: (frame value, whether the next frame's ahead node had started while this frame's tail waited)
OVERLAPPED: list[tuple[float, bool]] = []


class MatchParams(NodeParams):
    fail_on: float = Field(-1.0, description="raise on this frame value")


@node_type(
    "ovl.match",
    inputs={"x": "number", "p": Port("number", optional=True)},
    outputs={"y": "number"},
    ahead=True,
)
def match(params: MatchParams, x, p=None):
    """y = 10 x + p (the previous frame's value, 0 without one); records where it ran."""
    SEEN.append((x, p, threading.current_thread().name))
    STARTED.setdefault(x, threading.Event()).set()
    if x == params.fail_on:
        raise ValueError(f"no match on {x}")
    return {"y": 10.0 * x + (p or 0.0)}


class TailParams(NodeParams):
    wait_s: float = Field(0.0, ge=0, description="wait this long for the next frame's match to start")
    fail_on: float = Field(-1.0, description="raise on this frame value")


@node_type("ovl.tail", inputs={"x": "number", "y": "number"}, outputs={"z": "number"})
def tail(params: TailParams, x, y):
    """z = y + 1; waits up to ``wait_s`` for the next frame's ``ovl.match`` to have started."""
    if params.wait_s:
        OVERLAPPED.append((x, STARTED.setdefault(x + 1, threading.Event()).wait(params.wait_s)))
    if x == params.fail_on:
        raise ValueError(f"tail fails on {x}")
    return {"z": y + 1.0}


class _Ovl:
    @hookimpl
    def lanegraph_node_types(self):
        return [match, tail]


GRAPH = {
    "name": "ovl",
    "nodes": {
        "src": {"type": "toy.count", "params": {"n": 6}},
        "early": {"type": "toy.scale", "inputs": {"x": "src.value"}},  # before match in the plan
        "match": {"type": "ovl.match", "inputs": {"x": "src.value", "p": "fb.y@prev"}},
        "fb": {"type": "toy.add", "inputs": {"a": "match.y", "b": "early.y"}},
        "tail": {"type": "ovl.tail", "inputs": {"x": "src.value", "y": "fb.y"}},
        "sink": {"type": "toy.collect", "inputs": {"frame": "src.frame", "x": "tail.z"}},
    },
}


@pytest.fixture
def opm(pm):
    pm.register(_Ovl(), name="ovl")
    SEEN.clear()
    STARTED.clear()
    OVERLAPPED.clear()
    return pm


def load(tmp_path, pm, data=GRAPH, sets=()):
    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump(data))
    return load_graph(p, sets=list(sets), pm=pm)


def run(tmp_path, pm, data=GRAPH, sets=(), **kw):
    """(what the sink got, the run's result, the executor)."""
    ex = Executor(load(tmp_path, pm, data, sets), RunContext(), pm, **kw)
    res = ex.run()
    return list(toyplugin.Collect.out), res, ex


def threads() -> list[str]:
    return [t for _, _, t in SEEN]


def test_the_next_frame_runs_ahead_with_the_same_results(tmp_path, opm):
    seq, res_seq, ex_seq = run(tmp_path, opm, overlap=False)
    assert set(threads()) == {threading.current_thread().name}
    SEEN.clear()
    got, res, ex = run(tmp_path, opm)
    assert got == seq and len(got) == 6
    assert set(ex.ahead.nodes) == {"match"} and set(ex_seq.ahead.nodes) == set()
    # frame 0 in turn, every later frame on the ahead thread, with the previous frame's value
    main = threading.current_thread().name
    assert threads()[0] == main and all(t.startswith("lanegraph-ahead") for t in threads()[1:])
    assert [p for _, p, _ in SEEN] == [None] + [z - 1.0 for _, z in seq[:-1]]  # z = fb.y + 1
    assert len(res.timings_ms["match"]) == 6 and res.frames == res_seq.frames == 6
    assert res.timings_json()["nodes"].keys() == res_seq.timings_json()["nodes"].keys()
    # timings.json says which calls ran ahead (their time overlaps the frame before's later nodes)
    assert res.timings_json()["nodes"]["match"]["ahead"] == 5
    assert "ahead" not in res_seq.timings_json()["nodes"]["match"]


def test_the_next_frames_node_runs_while_this_frames_later_nodes_run(tmp_path, opm):
    """tail waits for the next frame's match to start: it does within the wait on every frame
    but the last (one node at a time, it never could)."""
    STARTED[6.0] = threading.Event()
    STARTED[6.0].set()  # the last frame has no next one to wait for
    run(tmp_path, opm, sets=["tail.wait_s=10"])
    assert OVERLAPPED[:-1] == [(float(i), True) for i in range(5)]


@pytest.mark.parametrize(
    "why",
    ["overlap=False", "prefetch=0", "env", "cache", "before_node"],
)
def test_nothing_runs_ahead_where_it_must_not(tmp_path, opm, monkeypatch, why):
    kw: dict = {}
    if why == "overlap=False":
        kw["overlap"] = False
    elif why == "prefetch=0":
        kw["prefetcher"] = Prefetch(0)
    elif why == "env":
        monkeypatch.setenv("LANEGRAPH_OVERLAP", "0")
    elif why == "cache":
        kw["caching"] = Caching(ResultCache(tmp_path / "cache"))
    else:

        class Before:
            @hookimpl
            def lanegraph_before_node(self, node_id):
                pass

        opm.register(Before())
    got, _, _ = run(tmp_path, opm, **kw)
    assert len(got) == 6
    assert set(threads()) == {threading.current_thread().name}


def test_after_node_calls_come_in_frame_and_node_order(tmp_path, opm):
    seen = []

    class After:
        @hookimpl
        def lanegraph_after_node(self, node_id, frame, outputs, error):
            seen.append((node_id, frame, None if outputs is None else dict(outputs), error))

    opm.register(After())
    run(tmp_path, opm, overlap=False)
    sequential, seen[:] = list(seen), []
    run(tmp_path, opm)
    assert seen == sequential  # early before match on every frame, match computed ahead or not
    assert [n for n, f, _, _ in seen if f == "0003"] == ["src", "early", "match", "fb", "tail", "sink"]
    assert any(t.startswith("lanegraph-ahead") for t in threads())


def test_a_dropped_frame_has_the_next_frame_computed_again_without_its_value(tmp_path, opm):
    """tail fails on frame 2 under ``skip``: frame 3 was computed ahead with frame 2's value, is
    computed again in turn with none (a dropped frame hands no feedback on), as one at a time."""
    d = copy.deepcopy(GRAPH)
    d["nodes"]["tail"]["on_error"] = "skip"
    seq, res_seq, _ = run(tmp_path, opm, d, sets=["tail.fail_on=2"], overlap=False)
    SEEN.clear()
    got, res, _ = run(tmp_path, opm, d, sets=["tail.fail_on=2"])
    assert got == seq and [f for f, _ in got] == ["0000", "0001", "0003", "0004", "0005"]
    assert [(f.frame, f.node_id) for f in res.failures] == [(f.frame, f.node_id) for f in res_seq.failures]
    on_3 = [(p, t) for x, p, t in SEEN if x == 3.0]
    assert len(on_3) == 2 and on_3[0][0] is not None and on_3[1] == (None, threading.current_thread().name)
    assert len(res.timings_ms["match"]) == 6  # the frame computed again counts once


@pytest.mark.parametrize("policy", ["fail", "skip", "empty"])
def test_a_node_failing_ahead_fails_in_turn(tmp_path, opm, policy):
    d = copy.deepcopy(GRAPH)
    d["nodes"]["match"]["on_error"] = policy
    sets = ["match.fail_on=3"]
    if policy == "fail":
        with pytest.raises(NodeError) as info:
            run(tmp_path, opm, d, sets)
        assert "node 'match' (ovl.match)" in str(info.value) and "frame 0003" in str(info.value)
        assert [f for f, _ in toyplugin.Collect.out] == ["0000", "0001", "0002"]
        return
    if policy == "empty":  # None for match.y: toy.add and the later nodes then fail; skip those
        d["nodes"]["fb"]["on_error"] = "skip"
    seq, res_seq, _ = run(tmp_path, opm, d, sets, overlap=False)
    got, res, _ = run(tmp_path, opm, d, sets)
    assert got == seq
    assert [(f.frame, f.node_id, f.error) for f in res.failures] == [
        (f.frame, f.node_id, f.error) for f in res_seq.failures
    ]


def test_a_frame_the_source_cannot_read_is_never_computed_ahead(tmp_path, opm):
    d = copy.deepcopy(GRAPH)
    d["nodes"]["src"] = {
        "type": "toy.flaky",
        "params": {"n": 5, "bad": 2, "resume": True},
        "on_error": "skip",
    }
    seq, res_seq, _ = run(tmp_path, opm, d, overlap=False)
    SEEN.clear()
    got, res, _ = run(tmp_path, opm, d)
    assert got == seq and [f for f, _ in got] == ["0000", "0001", "0003", "0004"]
    assert [x for x, _, _ in SEEN] == [0.0, 1.0, 3.0, 4.0]
    assert res.frame_ids == res_seq.frame_ids


def test_warm_up_frames_run_ahead_too(tmp_path, opm):
    seq, _, _ = run(tmp_path, opm, warming=WarmUp(2), overlap=False)
    got, _, _ = run(tmp_path, opm, warming=WarmUp(2))
    assert got == seq and [f for f, _ in got] == ["0002", "0003", "0004", "0005"]


def test_only_stateless_nodes_and_what_they_need_run_ahead(tmp_path, opm):
    """An ahead node fed by a stateful node within the frame stays in turn; its feedback input's
    producer sets where the next frame starts."""
    g = load(tmp_path, opm)
    ex = Executor(g, RunContext(), opm)
    ex.open()
    ex.run()
    plan = [s.id for s in ex._plan]
    assert ex.ahead.after == plan.index("fb") + 1
    d = copy.deepcopy(GRAPH)
    d["nodes"]["gate"] = {"type": "toy.collect", "inputs": {"frame": "src.frame", "x": "src.value"}}
    d["nodes"]["match"]["inputs"]["x"] = "src.value"
    ex2 = Executor(load(tmp_path, opm, d), RunContext(), opm)
    ex2.run()
    assert set(ex2.ahead.nodes) == {"match"}  # a sink beside it changes nothing


def test_ahead_is_refused_for_a_stateful_or_sink_node_type():
    with pytest.raises(ValueError, match="stateless"):
        NodeType(name="ovl.bad", func=lambda p: {}, stateful=True, ahead=True)
    with pytest.raises(ValueError, match="stateless"):
        NodeType(name="ovl.bad", func=lambda p: {}, sink=True, ahead=True)


def test_the_paper_graph_gives_the_same_lanes_ahead(tmp_path):
    """The paper graph on the built-in synthetic scene: the disparity of the next frame runs ahead
    and the lanes are byte-identical."""
    from lanegraph.graph.files import load_graph_named
    from lanegraph.run.prefetch import Prefetch

    lanes = []
    for overlap in (False, True):
        out = tmp_path / str(overlap)
        ex = Executor(
            load_graph_named("paper"),
            RunContext(out_dir=out, frames=slice(0, 4)),
            overlap=overlap,
            prefetcher=Prefetch(1),
        )
        ex.run()
        assert set(ex.ahead.nodes) == ({"disp"} if overlap else set())
        lanes.append((out / "lanes.jsonl").read_bytes())
    assert lanes[0] == lanes[1] and lanes[0].count(b"\n") == 4


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
