"""The streaming executor: order, feedback edges, constant nodes, timings, hooks (with the error of a
failed node), error policies, a source that selects another, the sinks' result files."""

from __future__ import annotations

import pytest
import yaml
from pydantic import Field

from lanegraph import NodeParams, Port, hookimpl, node_type
from lanegraph.errors import GraphError, NodeError
from lanegraph.graph.validation import load_graph
from lanegraph.nodes import RunContext
from lanegraph.run.executor import Executor
from lanegraph.run.prefetch import Prefetch
from lanegraph.run.warmup import WarmUp

from . import toyplugin
from .test_graph import VALID


def load(tmp_path, pm, data=VALID, sets=()):
    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump(data))
    return load_graph(p, sets=list(sets), pm=pm)


def test_feedback_edge_delivers_previous_frame(tmp_path, pm):
    res = Executor(load(tmp_path, pm), RunContext(), pm).run()
    # acc = 2*value + acc(prev): 0, 2, 6, 12
    assert toyplugin.Collect.out == [("0000", 0.0), ("0001", 2.0), ("0002", 6.0), ("0003", 12.0)]
    assert res.frames == 4


def test_constant_node_runs_once(tmp_path, pm):
    toyplugin.CALLS["const"] = 0
    ex = Executor(load(tmp_path, pm), RunContext(), pm)
    assert "k" in ex.constant_nodes and "double" not in ex.constant_nodes
    ex.run()
    assert toyplugin.CALLS["const"] == 1


def test_frame_selection_and_len(tmp_path, pm):
    ex = Executor(load(tmp_path, pm), RunContext(frames=slice(1, 3)), pm)
    ex.open()
    assert len(ex) == 2
    ex.run()
    assert [f for f, _ in toyplugin.Collect.out] == ["0001", "0002"]


def test_timings_per_node(tmp_path, pm):
    res = Executor(load(tmp_path, pm), RunContext(), pm).run()
    t = res.timings_json()
    assert t["frames"] == 4
    assert set(t["nodes"]) == {"src", "k", "double", "acc", "sink"}
    assert t["nodes"]["double"]["type"] == "toy.scale"
    assert t["nodes"]["double"]["calls"] == 4 and t["nodes"]["k"]["calls"] == 1
    assert t["nodes"]["acc"]["p90_ms"] >= t["nodes"]["acc"]["median_ms"] >= 0


def test_hooks_fire_around_every_node(tmp_path, pm):
    seen = []

    class Tracer:
        @hookimpl
        def lanegraph_before_node(self, node_id, frame):
            seen.append(("before", node_id, frame))

        @hookimpl
        def lanegraph_after_node(self, node_id, elapsed_ms):
            seen.append(("after", node_id, elapsed_ms >= 0))

    pm.register(Tracer())
    Executor(load(tmp_path, pm), RunContext(), pm).run()
    befores = [s for s in seen if s[0] == "before"]
    assert ("before", "double", "0002") in befores
    assert len(befores) == 1 + 4 * 3  # constant node once, three per-frame nodes (sink included) x 4
    assert all(s[2] for s in seen if s[0] == "after")


def test_a_node_hook_registered_between_frames_is_called_from_the_next_frame(tmp_path, pm):
    """Only the node hooks some plugin implements are called, looked up every frame: a tracer
    registered after frame 0001 and unregistered after 0002 sees frame 0002 alone (its after-node
    hook, the one it has)."""
    seen = []

    class AfterOnly:
        @hookimpl
        def lanegraph_after_node(self, node_id, frame):
            seen.append((node_id, frame))

    tracer = AfterOnly()

    def on_frame(index, frame):
        if frame == "0001":
            pm.register(tracer)
        elif frame == "0002":
            pm.unregister(tracer)

    ex = Executor(load(tmp_path, pm), RunContext(), pm)
    ex.run(on_frame=on_frame)
    assert {f for _, f in seen} == {"0002"}
    # the source's after-node, then the three per-frame nodes
    assert [n for n, _ in seen] == ["src", "double", "acc", "sink"]
    assert ex._node_hooks == frozenset()


def test_failure_policy_fail_names_node_and_frame(tmp_path, pm):
    g = load(tmp_path, pm, sets=["double.fail_on=2"])
    with pytest.raises(NodeError) as info:
        Executor(g, RunContext(), pm).run()
    assert "node 'double' (toy.scale)" in str(info.value) and "frame 0002" in str(info.value)
    assert "boom" in str(info.value)
    assert [f for f, _ in toyplugin.Collect.out] == ["0000", "0001"]  # earlier frames were delivered


def test_failure_policy_skip_and_empty(tmp_path, pm):
    import copy

    d = copy.deepcopy(VALID)
    d["nodes"]["double"]["on_error"] = "skip"
    res = Executor(load(tmp_path, pm, d, sets=["double.fail_on=2"]), RunContext(), pm).run()
    assert [f for f, _ in toyplugin.Collect.out] == ["0000", "0001", "0003"]
    assert [(f.frame, f.node_id) for f in res.failures] == [("0002", "double")]
    assert res.frames == 3

    d["nodes"]["double"]["on_error"] = "empty"
    d["nodes"]["acc"]["type"] = "toy.add"
    with pytest.raises(NodeError):  # acc receives None and fails: policy fail
        Executor(load(tmp_path, pm, d, sets=["double.fail_on=2"]), RunContext(), pm).run()


@pytest.mark.parametrize("prefetch", [0, 1, 3])
def test_prefetch_gives_the_same_frames(tmp_path, pm, prefetch):
    Executor(load(tmp_path, pm), RunContext(), pm, prefetcher=Prefetch(prefetch)).run()
    assert [x for _, x in toyplugin.Collect.out] == [0.0, 2.0, 6.0, 12.0]


@pytest.mark.parametrize("prefetch", [0, 1])
def test_source_read_error_located_and_policy(tmp_path, pm, prefetch):
    import copy

    d = copy.deepcopy(VALID)
    d["nodes"]["src"] = {"type": "toy.flaky", "params": {"n": 4, "bad": 1}}
    d["nodes"].pop("k")
    with pytest.raises(NodeError) as info:
        Executor(load(tmp_path, pm, d), RunContext(), pm, prefetcher=Prefetch(prefetch)).run()
    assert "frame 0001" in str(info.value) and "/data/0001.png" in str(info.value)
    # a generator cannot resume after raising: later frames are lost, the failure is recorded
    d["nodes"]["src"]["on_error"] = "skip"
    res = Executor(load(tmp_path, pm, d), RunContext(), pm, prefetcher=Prefetch(prefetch)).run()
    assert [(f.frame, f.node_id) for f in res.failures] == [("0001", "src")]
    assert [f for f, _ in toyplugin.Collect.out] == ["0000"]


@pytest.mark.parametrize("prefetch", [0, 1])
def test_source_yielding_an_error_goes_on(tmp_path, pm, prefetch):
    import copy

    d = copy.deepcopy(VALID)
    d["nodes"]["src"] = {
        "type": "toy.flaky",
        "params": {"n": 4, "bad": 1, "resume": True},
        "on_error": "skip",
    }
    d["nodes"].pop("k")
    res = Executor(load(tmp_path, pm, d), RunContext(), pm, prefetcher=Prefetch(prefetch)).run()
    assert [f for f, _ in toyplugin.Collect.out] == ["0000", "0002", "0003"]
    assert res.failures[0].frame == "0001" and res.frames == 3


def test_warmup_frames_feed_the_feedback_edges_but_no_sink(tmp_path, pm):
    import copy

    d = copy.deepcopy(VALID)
    d["nodes"]["src"]["params"]["n"] = 6
    seen = []
    res = Executor(load(tmp_path, pm, d), RunContext(frames=slice(1, 6)), pm, warming=WarmUp(2)).run(
        on_frame=lambda i, f: seen.append((i, f))
    )
    # frames 1 and 2 only warm up acc (2, then 2 + 4); the sink and on_frame see 3, 4, 5
    assert toyplugin.Collect.out == [("0003", 12.0), ("0004", 20.0), ("0005", 30.0)]
    assert seen == [(2, "0003"), (3, "0004"), (4, "0005")]
    t = res.timings_json()
    assert res.frames == 3 and t["nodes"]["double"]["calls"] == 3 and t["nodes"]["src"]["calls"] == 3
    # without warm-up the same selection starts acc afresh
    Executor(load(tmp_path, pm, d), RunContext(frames=slice(3, 6)), pm).run()
    assert toyplugin.Collect.out == [("0003", 6.0), ("0004", 14.0), ("0005", 24.0)]


def test_failures_of_warmup_frames_are_not_recorded(tmp_path, pm):
    import copy

    d = copy.deepcopy(VALID)
    d["nodes"]["src"]["params"]["n"] = 5
    d["nodes"]["double"]["params"]["fail_on"] = 1.0
    d["nodes"]["double"]["on_error"] = "empty"
    d["nodes"]["acc"]["on_error"] = "empty"
    res = Executor(load(tmp_path, pm, d), RunContext(), pm, warming=WarmUp(2)).run()
    assert res.failures == [] and res.frames == 3
    res = Executor(load(tmp_path, pm, d), RunContext(), pm, warming=WarmUp(1)).run()
    assert [(f.frame, f.index, f.node_id) for f in res.failures] == [
        ("0001", 1, "double"),
        ("0001", 1, "acc"),
    ]


# --------------------------------------------------------------------------- lanegraph_after_node sees failures
class AfterNode:
    """Records what lanegraph_after_node receives."""

    def __init__(self):
        self.calls = []

    @hookimpl
    def lanegraph_after_node(self, node_id, frame, outputs, error):
        self.calls.append((node_id, frame, outputs, error))


@pytest.mark.parametrize("policy", ["fail", "skip", "empty"])
def test_after_node_receives_the_error_of_a_failed_node(tmp_path, pm, policy):
    import copy

    spy = AfterNode()
    pm.register(spy)
    d = copy.deepcopy(VALID)
    d["nodes"]["double"]["on_error"] = policy
    d["nodes"]["acc"]["on_error"] = "empty"  # under 'empty' acc gets None and fails too
    ex = Executor(load(tmp_path, pm, d, sets=["double.fail_on=2"]), RunContext(), pm)
    if policy == "fail":
        with pytest.raises(NodeError):
            ex.run()
    else:
        ex.run()
    failed = [(n, f, o, e) for n, f, o, e in spy.calls if e is not None]
    node, frame, outputs, error = failed[0]
    assert (
        (node, frame, outputs) == ("double", "0002", None)
        and isinstance(error, ValueError)
        and "boom on 2" in str(error)
    )
    ok = [(n, f, o) for n, f, o, e in spy.calls if e is None and n == "double"]
    assert ok[:2] == [
        ("double", "0000", {"y": 0.0}),
        ("double", "0001", {"y": 2.0}),
    ]  # success: outputs, no error


def test_after_node_receives_the_error_of_a_frame_the_source_could_not_read(tmp_path, pm):
    import copy

    spy = AfterNode()
    pm.register(spy)
    d = copy.deepcopy(VALID)
    d["nodes"]["src"] = {
        "type": "toy.flaky",
        "params": {"n": 3, "bad": 1, "resume": True},
        "on_error": "skip",
    }
    d["nodes"].pop("k")
    Executor(load(tmp_path, pm, d), RunContext(), pm, prefetcher=Prefetch(0)).run()
    src = [(f, o is None, type(e).__name__ if e else None) for n, f, o, e in spy.calls if n == "src"]
    assert src == [("0000", False, None), ("0001", True, "InputError"), ("0002", False, None)]


# --------------------------------------------------------------------------- a source that selects another
class PickParams(NodeParams):
    default: str = Field("toy.count", description="the source without an input")


@node_type(
    "toy.pick",
    source=True,
    params=PickParams,
    outputs={"frame": "frame_id", "value": "number", "calib": Port("calibration", rate="constant")},
    implements=("select_source",),
)
class Pick:
    """Stands for toy.count (no input) or the source a plugin detects for the input."""

    @staticmethod
    def select_source(params, input_path, detect):
        if input_path is None:
            return params.default
        name = detect(input_path)
        if name is None:
            raise ValueError(f"nothing reads {input_path}")
        return name


class Picker:
    @staticmethod
    @hookimpl
    def lanegraph_node_types():
        return [Pick]

    @staticmethod
    @hookimpl
    def lanegraph_detect_source(path):
        return "toy.flaky" if str(path).endswith("flaky") else None


def test_a_selecting_source_is_replaced_by_the_source_it_names(tmp_path, pm):
    import copy

    pm.register(Picker, name="picker")
    d = copy.deepcopy(VALID)
    d["nodes"]["src"] = {"type": "toy.pick"}
    g = load(tmp_path, pm, d)
    ex = Executor(g, RunContext(), pm)
    assert (
        ex.graph.source.type.name == "toy.count" and ex.graph.source.params.n == 3
    )  # the chosen type's defaults
    assert ex.identity["resolved"]["nodes"]["src"]["type"] == "toy.pick"  # what the user's graph says
    assert g.source.type.name == "toy.pick"  # the graph it was given is left as it is
    d["nodes"].pop("k")
    g = load(tmp_path, pm, d)
    ex = Executor(g, RunContext(input_path=tmp_path / "flaky"), pm)
    assert ex.graph.source.type.name == "toy.flaky"
    with pytest.raises(GraphError) as info:
        Executor(load(tmp_path, pm, d), RunContext(input_path=tmp_path / "other"), pm)
    assert (
        str(info.value) == f"{tmp_path / 'g.yaml'}: node 'src' (toy.pick): nothing reads {tmp_path / 'other'}"
    )
    with pytest.raises(GraphError, match="source node type 'toy.scale' is not installed"):
        Executor(load(tmp_path, pm, d, sets=["src.default=toy.scale"]), RunContext(), pm)


# --------------------------------------------------------------------------- sinks declare their result files
class WriterParams(NodeParams):
    filename: str = Field("values.txt", description="output file, relative to the output folder")


@node_type(
    "toy.write", sink=True, inputs={"frame": "frame_id", "x": "number"}, implements=("result_files", "close")
)
class Writer:
    """Writes one line per frame."""

    @staticmethod
    def result_files(params: WriterParams) -> dict[str, str]:
        return {"values": params.filename}

    def __init__(self, params: WriterParams, context: RunContext):
        self.fh = open(context.out_dir / params.filename, "w")  # noqa: SIM115 - closed by close()

    def __call__(self, frame, x):
        self.fh.write(f"{frame} {x}\n")
        return {}

    def close(self):
        self.fh.close()


def test_a_run_records_the_result_files_its_sinks_declare(tmp_path, pm):
    import copy

    from lanegraph.records.results import default_names, find_result, graph_result_files

    class Writers:
        @staticmethod
        @hookimpl
        def lanegraph_node_types():
            return [Writer]

    pm.register(Writers, name="writers")
    d = copy.deepcopy(VALID)
    d["nodes"]["w"] = {
        "type": "toy.write",
        "params": {"filename": "x.txt"},
        "inputs": {"frame": "src.frame", "x": "acc.y"},
    }
    g = load(tmp_path, pm, d)
    assert graph_result_files(g) == {"values": "x.txt"}
    res = Executor(g, RunContext(out_dir=tmp_path), pm).run()
    assert res.results == {"values": "x.txt"} and (tmp_path / "x.txt").read_text().count("\n") == 4
    assert default_names("values", pm) == ["values.txt"]
    # a folder is searched for what its run.json records, else for the sinks' default files
    (tmp_path / "run.json").write_text('{"results": {"values": "x.txt"}}')
    assert find_result(tmp_path, "values", pm) == tmp_path / "x.txt"
    (tmp_path / "run.json").unlink()
    assert find_result(tmp_path, "values", pm) is None
    (tmp_path / "values.txt").write_text("")
    assert find_result(tmp_path, "values", pm) == tmp_path / "values.txt"


def test_a_run_json_naming_a_result_outside_its_folder_is_refused(tmp_path, pm):
    from lanegraph.errors import UsageError
    from lanegraph.records.results import find_result

    run = tmp_path / "run"
    run.mkdir()
    (tmp_path / "secret.txt").write_text("not a run's")
    (run / "run.json").write_text('{"results": {"lanes": "../secret.txt"}}')
    with pytest.raises(UsageError, match="outside"):
        find_result(run, "lanes", pm)


def test_the_jobs_around_execution_are_pieces_passed_in(tmp_path, pm):
    """The result cache, the prefetch and the warm-up are pieces of lanegraph.run handed to the
    executor as the checkpoint is (``caching=``, ``prefetcher=``, ``warming=``, ``checkpointer=``;
    the executor has no flags that make them); a second run reads the first one's cache."""
    import copy
    import json

    from lanegraph.records.checkpointing import Checkpointer
    from lanegraph.run.cache import Caching, ResultCache

    d = copy.deepcopy(VALID)
    d["nodes"]["src"]["params"]["n"] = 6
    cache = ResultCache(tmp_path / "cache")
    outs = []
    for i in range(2):
        g, ctx, ck = load(tmp_path, pm, d), RunContext(frames=slice(1, 6)), tmp_path / f"checkpoint{i}.json"
        ex = Executor(
            g,
            ctx,
            pm,
            caching=Caching(cache, {"double"}),
            prefetcher=Prefetch(0),
            warming=WarmUp(2),
            checkpointer=Checkpointer(g, ctx, ck, port_types=pm.port_types),
        )
        assert ex.prefetcher == Prefetch(0) and ex.warming == WarmUp(2) and ex.cache_nodes == {"double"}
        res = ex.run()
        outs.append(list(toyplugin.Collect.out))
        assert res.frames == 3 and json.loads(ck.read_text())["complete"]  # the checkpoint piece wrote it
        hits = (res.cache_hits, res.cache_misses)
        # one cache (the warm-up frames' counts are not the run's)
        assert hits == (({}, {"double": 3}) if i == 0 else ({"double": 3}, {}))
    assert outs[0] == outs[1] == [("0003", 12.0), ("0004", 20.0), ("0005", 30.0)]
    for bad in (lambda: WarmUp(-1), lambda: Prefetch(-1), lambda: WarmUp(True)):
        with pytest.raises(ValueError, match="expected an integer >= 0"):
            bad()
    assert Executor(load(tmp_path, pm, d), RunContext(), pm).caching is None  # no cache unless given
