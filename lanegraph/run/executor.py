"""The streaming executor: validate and compile once, then stream frames through the plan.

- Stateful nodes (sources, sinks, trackers) are instantiated once per run with their params and a
  :class:`~lanegraph.nodes.RunContext`.
- Nodes whose inputs are all constant-rate (e.g. computed from the calibration only) run once.
- Feedback edges (``@prev``) deliver the previous frame's value, ``None`` on the first frame.
- Every node is timed on every frame; ``lanegraph_before_node`` / ``lanegraph_after_node`` hooks
  fire around each call (tracing, profiling).
- A source that cannot read one frame raises (ending the stream) or *yields* an
  :class:`~lanegraph.errors.InputError` for it and goes on with the next frame.
- Error policy per node: ``fail`` stops the run, ``skip`` drops the frame (sinks do not see it),
  ``empty`` passes ``None`` on for the node's outputs. A node that runs once for the whole run
  (constant inputs) has no frame to drop: under ``skip`` its failure stops the run like ``fail``.
- Running ahead: a node type declared ``ahead=True`` (stereo matching) is computed for the next
  frame on a thread while this frame's later nodes run, with the same results
  (:mod:`lanegraph.run.ahead`).
- A run first tunes glibc's allocator so that the large per-frame arrays reuse memory instead of
  faulting in fresh pages every frame (:mod:`lanegraph._runtime`; ``LANEGRAPH_MALLOC_TUNING=0``
  turns it off).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from .. import interrupts
from .._runtime import tune_allocator
from ..errors import HookError, InputError, LanegraphError, NodeError
from ..graph.model import Graph, GraphNode
from ..lifecycle import close_all, constants_of, verify_all
from ..nodes import RunContext
from ..plugins import PluginManager, call_hook, get_plugin_manager
from ..records.checkpointing import Checkpointer, OpenedInput, run_identity
from ..records.results import graph_result_files
from ..records.resume import input_identity
from ..storage import Codecs
from .ahead import Lookahead, RunAhead, checked, count_valid
from .cache import Caching, digest
from .outcome import FrameFailure, RunResult
from .plan import Step, frame_plan
from .prefetch import Prefetch
from .sources import chosen_params, select_source
from .warmup import WarmUp


class _SkipFrame(Exception):
    pass


#: the hooks fired around every node call
_NODE_HOOKS = frozenset({"lanegraph_before_node", "lanegraph_after_node"})


@dataclass
class _Position:
    """How far a run's stream got: frames of the selection consumed, the last frame done, and the
    feedback edges' values (and cache keys) for the next frame."""

    position: int = 0
    last_frame: str | None = None
    previous: dict[tuple[str, str], Any] = field(default_factory=dict)
    prev_keys: dict[tuple[str, str], str | None] = field(default_factory=dict)


class Executor:
    """Runs a validated :class:`~lanegraph.graph.model.Graph` over the frames of its source node."""

    def __init__(
        self,
        graph: Graph,
        context: RunContext | None = None,
        pm: PluginManager | None = None,
        checkpointer: Checkpointer | None = None,
        caching: Caching | None = None,
        prefetcher: Prefetch | None = None,
        warming: WarmUp | None = None,
        overlap: bool = True,
    ):
        """The jobs around execution are pieces passed in, each of :mod:`lanegraph.run`:

        - ``checkpointer``: the checkpoint (:class:`~lanegraph.records.checkpointing.Checkpointer`): a
          file rewritten (atomically) before the first frame and after every frame consumed, and
          the checkpoint of an interrupted run to continue -- refused (:class:`UsageError`) unless
          the graph, params, input and frame selection are its own (``context.skip`` must then be
          its ``position``);
        - ``caching``: the result cache (:class:`~lanegraph.run.cache.Caching`): results keyed by
          node type, params, upstream keys and the identity of the source's input files;
        - ``prefetcher``: the source read ahead on a thread (:class:`~lanegraph.run.prefetch.Prefetch`,
          default one frame ahead);
        - ``warming``: warm-up frames (:class:`~lanegraph.run.warmup.WarmUp`): the first frames only
          bring the feedback edges and stateful nodes up to date (a chunk of a longer sequence
          starts from the frames before it), unseen by the sinks, untimed, without ``on_frame``.

        A piece not given is not there (no checkpoint, no cache, no warm-up; one frame read ahead).
        ``overlap``: compute the next frame's ``ahead`` nodes while this frame's later nodes run
        (:mod:`lanegraph.run.ahead`; ``LANEGRAPH_OVERLAP=0`` turns it off too)."""
        self.graph = graph
        self.pm = pm or get_plugin_manager()
        #: how the result cache stores the values (the registered port types', a plugin's too)
        self.storage = Codecs(self.pm.port_types)
        ctx0 = context or RunContext()
        # what the run is (the graph as the user wrote it), checked before anything opens
        self.identity = checkpointer.identity if checkpointer is not None else run_identity(graph, ctx0)
        self.checkpointer = checkpointer
        self.checkpoint = checkpointer.path if checkpointer is not None else None
        self.resume = checkpointer.resume if checkpointer is not None else None
        self.caching = caching
        self.cache = caching.cache if caching is not None else None
        self.cache_nodes = caching.nodes_of(graph) if caching is not None else set()
        self.prefetcher = prefetcher if prefetcher is not None else Prefetch(1)
        self.warming = warming if warming is not None else WarmUp(0)
        self.context = context or RunContext()
        self._select_source()
        self.result_files = graph_result_files(graph)
        self.instances: dict[str, Any] = {}
        self.result: RunResult | None = None  # set when the run starts: a caller keeps it if the run stops
        self._closed = False
        self.constant_nodes: set[str] = self._constant_nodes()
        self._plan: list[Step] | None = None  # plan.frame_plan(), made by the first frame
        # the node hooks some plugin implements (_live_node_hooks(), looked up again every frame):
        # a call of a hook without implementations does nothing but costs 3-4 us a node
        self._node_hooks: frozenset[str] = _NODE_HOOKS
        self.ahead = RunAhead(overlap)  # the next frame's ahead nodes (lanegraph.run.ahead)

    # -- compile -------------------------------------------------------------
    def _select_source(self) -> None:
        """A source node that stands for others (``select_source``, e.g. ``io.auto``) is replaced
        by the source type it names for the input path (in the executor's own copy of the graph), with
        that type's default params and the fields of the node's params it shares with them (:func:`~lanegraph.run.sources.chosen_params`:
        ``io.auto``'s ``read_ahead``)."""
        src = self.graph.source
        nt = select_source(
            self.pm, src.type, src.params, self.context.input_path, file=self.graph.file, node=src.id
        )
        if nt is not src.type:  # the run's own copy of the graph: the validated one is never changed
            params = chosen_params(nt, src.params, file=self.graph.file, node=src.id)
            chosen = dataclasses.replace(src, type=nt, params=params)
            self.graph = dataclasses.replace(self.graph, nodes={**self.graph.nodes, src.id: chosen})

    def _constant_nodes(self) -> set[str]:
        const: set[str] = set()
        for nid in self.graph.order:
            n = self.graph.nodes[nid]
            if n.type.stateful or not n.type.outputs:
                continue
            ok = True
            for e in n.inputs.values():
                src = self.graph.nodes[e.src_node]
                port_const = src.type.outputs[e.src_port].rate == "constant"
                if e.previous or not (port_const or e.src_node in const):
                    ok = False
                    break
            if ok:
                const.add(nid)
        return const

    # -- run -------------------------------------------------------------------
    def _call(
        self,
        node: GraphNode,
        inputs: dict[str, Any],
        frame: str | None,
        index: int,
        result: RunResult,
        key: str | None = None,
    ) -> dict:
        if "lanegraph_before_node" in self._node_hooks:
            self._hook(
                "lanegraph_before_node", node_id=node.id, node_type=node.type.name, frame=frame, inputs=inputs
            )
        use_cache = self.cache is not None and key is not None and node.id in self.cache_nodes
        if use_cache:
            hit = self.cache.get(key, self.storage)
            if hit is not self.cache.MISS:
                result.timings_ms.setdefault(node.id, []).append(hit["ms"])  # the time it took to compute
                result.cache_hits[node.id] = result.cache_hits.get(node.id, 0) + 1
                self._after_node(node, frame, hit["outputs"], hit["ms"], None)
                return hit["outputs"]
        t0 = time.perf_counter()
        try:
            if node.type.stateful:
                out = self.instances[node.id](**inputs)
            else:
                out = node.type.func(node.params, **inputs)
            out = checked(node, out)
        except BaseException as exc:  # SystemExit, KeyboardInterrupt too: the node's failure, located
            if interrupts.is_interruption(exc):
                raise
            err = exc
        else:
            err = None
        elapsed = (time.perf_counter() - t0) * 1000.0
        result.timings_ms.setdefault(node.id, []).append(elapsed)
        if err is not None:
            self._after_node(node, frame, None, elapsed, err)
            if node.on_error == "fail" or (node.on_error == "skip" and index < 0):  # index -1: runs once
                raise NodeError(node.id, node.type.name, frame, err) from err
            result.failures.append(
                FrameFailure(frame, index, node.id, node.type.name, f"{type(err).__name__}: {err}")
            )
            if node.on_error == "skip":
                raise _SkipFrame()
            return {p: None for p in node.type.outputs}
        if use_cache:
            self.cache.put(key, {"outputs": out, "ms": elapsed}, self.storage)
            result.cache_misses[node.id] = result.cache_misses.get(node.id, 0) + 1
        self._after_node(node, frame, out, elapsed, None)
        return out

    def _after_node(self, node: GraphNode, frame: str | None, outputs: Any, ms: float, error: Any) -> None:
        if "lanegraph_after_node" not in self._node_hooks:
            return
        kw = {"node_id": node.id, "node_type": node.type.name, "frame": frame, "outputs": outputs}
        self._hook("lanegraph_after_node", **kw, elapsed_ms=ms, error=error)

    def _write_checkpoint(
        self, position: int, frame: str | None, previous: dict, prev_keys: dict, complete: bool = False
    ) -> None:
        """After a frame is consumed: the checkpoint (:meth:`Checkpointer.write`)."""
        assert self.checkpointer is not None and self.result is not None
        self.checkpointer.write(
            self.result, self.instances, position, frame, previous, prev_keys, self._opened, complete
        )

    @property
    def unresumable(self) -> str | None:
        """Why the run cannot be resumed (a value a checkpoint cannot hold), or None."""
        return self.checkpointer.unresumable if self.checkpointer is not None else None

    def open(self) -> None:
        """Instantiate the stateful nodes (sources, sinks); done by :meth:`run` if not yet done.

        Resuming, it checks the input against the checkpoint's and hands every stateful node with a
        ``restore`` method its checkpointed state (a :class:`UsageError` or the node's
        :class:`InputError` when that is not possible)."""
        if self.instances:
            return
        try:
            self._open()
        except BaseException:
            # the nodes opened before the failing one
            close_all(reversed([(inst, self.graph.nodes[nid].type) for nid, inst in self.instances.items()]))
            self.instances.clear()
            raise

    def _open(self) -> None:
        g = self.graph
        for nid in g.order:
            n = g.nodes[nid]
            if n.type.stateful:
                ctx = RunContext(**{**self.context.__dict__, "node_id": nid, "graph_file": g.file})
                if "skip" not in n.type.capabilities:  # the executor drops a resumed run's frames itself
                    ctx.skip = 0
                try:
                    self.instances[nid] = n.type.func(n.params, ctx)
                except LanegraphError:
                    raise
                except OSError as exc:  # an output folder that cannot be written, say
                    raise InputError(
                        f"node '{nid}' ({n.type.name}): {exc.strerror or exc}", path=exc.filename
                    ) from exc
                except Exception as exc:  # noqa: BLE001
                    raise NodeError(nid, n.type.name, None, exc) from exc
        source, declared = self.instances[g.source.id], g.source.type.capabilities
        self._skipped = int(source.skipped or 0) if "skip" in declared else 0
        total = len(source) + self._skipped if "len" in declared else None
        identity = (
            str(source.identity())
            if "identity" in declared
            else input_identity(self.context.input_path, self.context.out_dir)
        )
        self._opened = OpenedInput(identity, total)
        if self.checkpointer is not None:
            self.checkpointer.resume_nodes(g, self.instances, self._opened)

    def run(self, on_frame: Callable[[int, str | None], None] | None = None) -> RunResult:
        """Stream every frame of the source through the graph."""
        tune_allocator()  # once per process; see lanegraph._runtime
        g = self.graph
        # kept on the executor so that a caller still has the partial result when the run stops
        self.result = result = RunResult(
            node_types={nid: n.type.name for nid, n in g.nodes.items()}, results=dict(self.result_files)
        )
        self.open()
        at = self._start()
        failed: BaseException | None = None
        try:
            self._hook("lanegraph_run_start", graph=g, context=self.context)
            values, keys = self._run_constants()
            if self.checkpoint is not None:
                self._write_checkpoint(at.position, at.last_frame, at.previous, at.prev_keys)
            self._stream(values, keys, at, on_frame)
            verify_all(self.instances, g)  # the lanes file on disk is still the one written
            if self.checkpoint is not None:
                self._write_checkpoint(at.position, at.last_frame, at.previous, at.prev_keys, complete=True)
        except BaseException as exc:
            failed = exc
            result.notes += self.ahead.stopped()  # a signal: what runs ahead is abandoned
            raise
        finally:
            self.close()  # an error of a close must not hide the run's own
            try:
                self._hook("lanegraph_run_end", graph=g, context=self.context, frames=result.frames)
            except HookError as exc:
                if failed is None:
                    raise  # the run's record says so (the session writes run.json, exit 1)
                result.notes.append(str(exc))  # the run's own error comes first
        return result

    def _live_node_hooks(self) -> frozenset[str]:
        """The node hooks (:data:`_NODE_HOOKS`) that some registered plugin implements: only those
        are called around the nodes. Looked up before the constant nodes and again before every
        frame, so a plugin registered between frames is called from the next one on; a hook without
        implementations has nothing to call (pluggy's tracing and monitoring see no call of it either)."""
        return frozenset(n for n in _NODE_HOOKS if getattr(self.pm.hook, n).get_hookimpls())

    def _hook(self, name: str, **kwargs: Any) -> Any:
        """Hook ``name`` called guarded (:func:`lanegraph.plugins.call_hook`): a hook implementation
        that raises or misbehaves is a :class:`~lanegraph.errors.HookError` naming its plugin."""
        return call_hook(self.pm, name, **kwargs)

    def _start(self) -> _Position:
        """Where the stream starts: the beginning, or where a resumed checkpoint left off (its
        frames, failures and feedback values taken over)."""
        ck, result = self.resume, self.result
        if ck is None:
            return _Position()
        result.frames = result.resumed_frames = ck.frames_ok
        result.failures = [FrameFailure(f.frame, f.index, f.node, f.type, f.error) for f in ck.failures]
        result.invalid_outputs = {k: list(v) for k, v in ck.invalid_outputs.items()}
        assert self.checkpointer is not None
        previous, prev_keys = self.checkpointer.resumed_feedback
        return _Position(ck.position, ck.last_frame, previous, prev_keys)

    def _run_constants(self) -> tuple[dict[tuple[str, str], Any], dict[tuple[str, str], str | None]]:
        """The source's constants and the outputs of the nodes that run once (constant inputs
        only), with their cache keys."""
        g, result = self.graph, self.result
        self._node_hooks = self._live_node_hooks()
        src = g.source
        source = self.instances[src.id]
        values: dict[tuple[str, str], Any] = {}
        keys: dict[tuple[str, str], str | None] = {}
        caching = self.cache is not None
        src_params = src.params.model_dump(mode="json")
        consts = constants_of(source, src.type)
        for port, v in consts.items():
            values[(src.id, port)] = v
            keys[(src.id, port)] = (
                digest(src.type.name, src.type.code_version, src_params, "constant", port, repr(v))
                if caching
                else None
            )
        if consts:
            self._hook(
                "lanegraph_after_node",
                node_id=src.id,
                node_type=src.type.name,
                frame=None,
                outputs=dict(consts),
                elapsed_ms=0.0,
                error=None,
            )
        for nid in g.order:
            if nid in self.constant_nodes:
                n = g.nodes[nid]
                ins = {p: values.get((e.src_node, e.src_port)) for p, e in n.inputs.items()}
                key = self.caching.key(n, keys, {}) if caching else None
                out = self._call(n, ins, None, -1, result, key)
                for port, v in out.items():
                    values[(nid, port)] = v
                    keys[(nid, port)] = None if key is None else digest(key, port)
        return values, keys

    def _stream(
        self, values: dict, keys: dict, at: _Position, on_frame: Callable[[int, str | None], None] | None
    ) -> None:
        """Every frame of the source through the graph, from ``at`` (updated as frames are consumed)."""
        g, result = self.graph, self.result
        source = self.instances[g.source.id]
        feedback = {(e.src_node, e.src_port) for e in g.edges if e.previous}
        warm = RunResult(node_types=result.node_types) if self.warming.frames else result
        drop = max(self.context.skip - self._skipped, 0)  # frames done that the source did not leave out
        frames = self._frames(source, g.source.id, result, at.position, drop)
        try:
            for index, frame_out in frames:
                at.position = index + 1
                if frame_out is None:  # the source could not read this frame (recorded as a failure)
                    at.previous, at.prev_keys = {}, {}
                    if (
                        not self.warming.warming(index)
                        and result.failures
                        and result.failures[-1].index == index
                    ):
                        result.frame_ids.append(str(result.failures[-1].frame))
                    self._consumed(at)
                    continue
                warming = self.warming.warming(index)
                frame = frame_out.get("frame")
                if not warming:
                    result.frame_ids.append(str(frame))
                t_frame = time.perf_counter()
                try:
                    cur, cur_keys = self._run_frame(
                        frame_out, values, keys, at.prev_keys, at.previous, index, warm if warming else result
                    )
                except _SkipFrame:
                    at.previous, at.prev_keys, at.last_frame = {}, {}, frame
                    self._consumed(at)
                    if on_frame and not warming:
                        on_frame(index, frame)
                    continue
                at.previous = {k: cur[k] for k in feedback if k in cur}
                at.prev_keys = {k: cur_keys.get(k) for k in feedback}
                if warming:
                    continue
                result.frames += 1
                at.last_frame = frame
                self._consumed(at)
                result.frame_ms.append((time.perf_counter() - t_frame) * 1000.0)
                if on_frame:
                    on_frame(index, frame)
        finally:
            frames.close()  # the read-ahead thread stops and is joined on every path (no abort at exit)

    def _consumed(self, at: _Position) -> None:
        if self.checkpoint is not None:
            self._write_checkpoint(at.position, at.last_frame, at.previous, at.prev_keys)

    def _run_frame(
        self,
        frame_out: dict[str, Any],
        values: dict,
        keys: dict,
        prev_keys: dict,
        previous: dict,
        index: int,
        res: RunResult,
    ) -> tuple[dict, dict]:
        """Run the per-frame nodes on one frame of the source; returns every output and its cache
        key. Raises :class:`_SkipFrame` when a node under ``on_error: skip`` failed."""
        g = self.graph
        src_id = g.source.id
        self._node_hooks = self._live_node_hooks()
        warming = self.warming.warming(index)
        frame = frame_out.get("frame")
        cur = dict(values)
        cur_keys = dict(keys)
        src = self.instances[src_id]
        keyed = self.cache is not None and "frame_key" in g.source.type.capabilities
        identity = src.frame_key(frame) if keyed else None
        src_params = g.source.params.model_dump(mode="json") if identity is not None else None
        for port, v in frame_out.items():
            cur[(src_id, port)] = v
            cur_keys[(src_id, port)] = (
                None
                if identity is None
                else digest(g.source.type.name, g.source.type.code_version, src_params, identity, port)
            )
        # the source is an iterator read ahead, so it fires only the after-node hook
        src_ms = (self.result.timings_ms.get(src_id) or [0.0])[-1]
        self._after_node(g.source, frame, frame_out, src_ms, None)
        caching = self.caching
        ahead = self.ahead
        if self._plan is None:
            self._plan = frame_plan(g, self.constant_nodes)
            ahead.plan(g, self._plan, caching is not None)
        done = ahead.take(frame_out, previous, self._node_hooks)  # this frame's nodes computed ahead
        for i, (nid, n, wiring, unwired, sink) in enumerate(self._plan):
            if i == ahead.after:
                ahead.start(src_id, values, cur, self._node_hooks)
            if nid in done:  # taken in its turn: timings, counts and after-node calls in plan order
                out, ms = done[nid]
                res.timings_ms.setdefault(nid, []).append(ms)
                res.ahead[nid] = res.ahead.get(nid, 0) + 1
                for port, v in out.items():
                    cur[(nid, port)] = v
                    cur_keys[(nid, port)] = None
                count_valid(res, nid, out)
                self._after_node(n, frame, out, ms, None)
                continue
            if warming and sink:
                continue
            ins = {p: (previous if prev else cur).get(out_of) for p, out_of, prev in wiring}
            for p in unwired:
                ins[p] = None
            key = caching.key(n, cur_keys, prev_keys) if caching is not None else None
            out = self._call(n, ins, frame, index, res, key)
            for port, v in out.items():
                cur[(nid, port)] = v
                cur_keys[(nid, port)] = None if key is None else digest(key, port)
            count_valid(res, nid, out)
        return cur, cur_keys

    def _frames(
        self, source: Any, src_id: str, result: RunResult, start: int = 0, drop: int = 0
    ) -> Iterator[tuple[int, dict[str, Any] | None]]:
        """Iterate the source as ``(index, frame outputs)``, recording per-frame read errors
        according to the source's policy (``None`` for a frame that could not be read). ``index``
        counts the frames of the selection from ``start``; the first ``drop`` items are consumed
        unseen (frames a resumed run has done, from a source that cannot leave them out).

        With ``prefetch > 0`` the source is read by a background thread that stays up to
        ``prefetch`` frames ahead, so decoding the next images overlaps computing this frame
        (image decoding releases the GIL).
        """
        node = self.graph.nodes[src_id]
        items = Lookahead(self.prefetcher.read(iter(source)))
        # the next frame is looked at ahead only while the source is read on its own thread
        self.ahead.source = items if self.prefetcher.depth > 0 else None
        try:
            index = start
            scratch = RunResult()  # what warm-up frames record
            for kind, item, elapsed in items:
                if drop > 0:
                    drop -= 1
                    if kind == "error" and not isinstance(item, LanegraphError):
                        raise NodeError(src_id, node.type.name, None, item) from item
                    continue
                rec = scratch if self.warming.warming(index) else result
                if kind == "error":
                    exc = item
                    frame = getattr(exc, "frame", None)
                    self._hook(
                        "lanegraph_after_node",
                        node_id=src_id,
                        node_type=node.type.name,
                        frame=frame,
                        outputs=None,
                        elapsed_ms=0.0,
                        error=exc,
                    )
                    if not isinstance(exc, LanegraphError):
                        raise NodeError(src_id, node.type.name, None, exc) from exc
                    if node.on_error == "fail":
                        raise NodeError(src_id, node.type.name, frame, exc) from exc
                    rec.failures.append(FrameFailure(frame, index, src_id, node.type.name, str(exc)))
                    index += 1
                    yield index - 1, None
                    continue
                rec.timings_ms.setdefault(src_id, []).append(elapsed)
                index += 1
                yield index - 1, item
        finally:
            self.ahead.source = None
            self.ahead.drop()  # no thread computes a frame once the stream has ended
            items.close()  # stop the read-ahead thread and join it, whatever ended the stream

    def __len__(self) -> int:
        src = self.instances.get(self.graph.source.id)
        return len(src) if src is not None and "len" in self.graph.source.type.capabilities else 0

    def outputs(self) -> list[Any]:
        """The files the sinks say they wrote (those that declare ``outputs``, :mod:`lanegraph.lifecycle`)."""
        nodes = self.graph.nodes
        return [
            p
            for nid, inst in self.instances.items()
            if "outputs" in nodes[nid].type.capabilities
            for p in inst.outputs
        ]

    # -- life cycle ------------------------------------------------------------
    def close(self) -> BaseException | None:
        """Close every open node instance, once (:func:`lanegraph.lifecycle.close_all`); returns
        the first error a ``close`` raised."""
        if self._closed or not self.instances:
            return None
        self._closed = True
        return close_all((inst, self.graph.nodes[nid].type) for nid, inst in self.instances.items())

    def __enter__(self) -> Executor:
        """Open the nodes; leaving the block closes them, however it is left."""
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
