"""Running ahead: the piece of the executor that computes the next frame's ``ahead`` nodes on a
thread while this frame's later nodes run (:class:`RunAhead`).

A node type declared ``ahead=True`` (:func:`lanegraph.nodes.node_type`: stateless, its work
releases the GIL -- stereo matching) is computed for the next frame, with every node it needs within
that frame, as soon as this frame has computed them and their feedback inputs (``@prev``): on two
CPUs the SGBM bands of frame n+1 then run beside the road mask, BEV and lane nodes of frame n.
Every node sees the inputs it would see one node at a time, so the results are the same; each
node's timings, ``valid`` counts and ``lanegraph_after_node`` calls are taken in its turn in the
frame's plan (:meth:`RunAhead.take`): in frame and node order, as one node at a time gives them
(``--debug-dir`` writes the same files). A frame computed ahead is dropped and computed again in
its turn when its feedback inputs turned out different (the frame before it was dropped under
``on_error: skip``) or one of its nodes failed (its error then comes in turn, handled by the node's
policy). Nothing runs ahead with a result cache, with a ``lanegraph_before_node`` implementation
(it is called before the node), without a thread reading the source ahead (``prefetch`` 0: the
next frame would be read on the main thread), with ``Executor(overlap=False)`` or with
``LANEGRAPH_OVERLAP=0``.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from .. import interrupts
from ..graph.model import Graph, GraphNode
from ..threads import leave_signals_to_the_main_thread
from .outcome import RunResult
from .plan import NO_VALID_FLAG, Step


def checked(node: GraphNode, out: Any) -> dict:
    """A node function's return value as its outputs (None: none); a TypeError unless it is a dict
    holding every output port (a sink's need not)."""
    if out is None:
        return {}
    if not isinstance(out, dict):
        raise TypeError(f"node function returned {type(out).__name__}, expected a dict of output ports")
    if not node.type.sink and not out.keys() >= node.type.outputs.keys():
        missing = set(node.type.outputs) - set(out)
        raise TypeError(f"node function did not return output port(s) {sorted(missing)}")
    return out


def count_valid(res: RunResult, nid: str, out: dict) -> None:
    """Count the ``valid`` flags of a node's outputs (``RunResult.invalid_outputs``)."""
    for port, v in out.items():
        if type(v) in NO_VALID_FLAG:  # no `valid` flag to count (getattr would raise inside)
            continue
        valid = getattr(v, "valid", None)
        if isinstance(valid, bool):
            counts = res.invalid_outputs.setdefault(f"{nid}.{port}", [0, 0])
            counts[0] += not valid
            counts[1] += 1


class Lookahead:
    """The source's ``(kind, item, ms)`` entries, with a look at the next one before it is taken."""

    _EMPTY = object()

    def __init__(self, entries: Iterator[tuple[str, Any, float]]):
        self._entries = entries
        self._next: Any = self._EMPTY

    def __iter__(self) -> Lookahead:
        return self

    def __next__(self) -> tuple[str, Any, float]:
        if self._next is not self._EMPTY:
            entry, self._next = self._next, self._EMPTY
            return entry
        return next(self._entries)

    def peek(self) -> tuple[str, Any, float] | None:
        """The next entry, left to be taken; None at the end of the source."""
        if self._next is self._EMPTY:
            try:
                self._next = next(self._entries)
            except StopIteration:
                return None
        return self._next

    def close(self) -> None:
        self._entries.close()  # type: ignore[attr-defined]


class _Abandon(Exception):
    """A node failed on a frame computed ahead: the frame is computed again in its turn."""


@dataclass
class _Pending:
    """The next frame's nodes computed ahead: for the frame ``frame_out`` with the feedback values
    ``previous``; ``future`` gives ``[(step, outputs, ms)]``."""

    frame_out: dict[str, Any]
    previous: dict[tuple[str, str], Any]
    future: Any


class RunAhead:
    """The running-ahead piece of one run (see the module's text). ``enabled`` False (or
    ``LANEGRAPH_OVERLAP=0``): nothing runs ahead."""

    def __init__(self, enabled: bool = True):
        self.enabled = bool(enabled) and os.environ.get("LANEGRAPH_OVERLAP", "1") != "0"
        self.nodes: frozenset[str] = frozenset()  # the nodes computed ahead (plan())
        self.after = -1  # the step of this frame's plan before which the next frame's start
        self.source: Lookahead | None = None  # the source's entries while they are read ahead
        self._steps: list[Step] = []
        self._feedback: tuple[tuple[str, str], ...] = ()  # the feedback inputs of those nodes
        self._pending: _Pending | None = None
        #: what a signal made the run abandon on its thread (:meth:`drop`), in words
        self.abandoned: str | None = None

    def plan(self, graph: Graph, plan: list[Step], cached: bool) -> None:
        """Which nodes the next frame computes ahead, and from which step of this frame's plan on.

        The nodes of ``ahead`` types with every node they need within the frame (the source and the
        constant nodes apart), unless one of those is stateful or a sink; they start once this frame
        has computed them and every feedback input they take (before the step after the last of
        those). Nothing when that is the plan's end (nothing left to overlap), with a result cache
        (``cached``) or when not enabled."""
        self.nodes, self.after, self._steps, self._feedback = frozenset(), -1, [], ()
        if not self.enabled or cached or not plan:
            return
        at = {step.id: i for i, step in enumerate(plan)}
        chosen: set[str] = set()
        for step in plan:
            if not step.node.type.ahead:
                continue
            need: set[str] = set()
            todo, ok = [step.id], True
            while todo:
                nid = todo.pop()
                if nid in need:
                    continue
                need.add(nid)
                t = graph.nodes[nid].type
                if t.stateful or t.sink:
                    ok = False
                    break
                todo += [src for _, (src, _), prev in plan[at[nid]].wiring if not prev and src in at]
            if ok:
                chosen |= need
        if not chosen:
            return
        feedback = {out_of for step in plan if step.id in chosen for _, out_of, prev in step.wiring if prev}
        last = max(at[nid] for nid in chosen | {src for src, _ in feedback if src in at})
        if last + 1 >= len(plan):
            return
        self.nodes = frozenset(chosen)
        self.after = last + 1
        self._steps = [step for step in plan if step.id in chosen]
        self._feedback = tuple(sorted(feedback))

    def start(self, src_id: str, values: dict, cur: dict, hooks: frozenset[str]) -> None:
        """Start computing the next frame's ahead nodes on a thread, with this frame's feedback
        values from ``cur`` and the run's constants ``values``, when the source has read the next
        frame and no ``lanegraph_before_node`` is in ``hooks`` (the node hooks implemented)."""
        if self.source is None or self._pending is not None or "lanegraph_before_node" in hooks:
            return
        entry = self.source.peek()
        if entry is None or entry[0] != "item":
            return  # the end, or a frame that could not be read: nothing to compute ahead
        frame_out = entry[1]
        previous = {k: cur.get(k) for k in self._feedback}
        known = dict(values)
        for port, v in frame_out.items():
            known[(src_id, port)] = v
        steps = self._steps

        def compute() -> list[tuple[Step, dict, float]]:
            done = []
            for step in steps:
                ins = {p: (previous if prev else known).get(out_of) for p, out_of, prev in step.wiring}
                for p in step.unwired:
                    ins[p] = None
                t0 = time.perf_counter()
                try:
                    out = checked(step.node, step.node.type.func(step.node.params, **ins))
                except BaseException as exc:  # computed again in turn, where the error is handled
                    raise _Abandon() from exc
                ms = (time.perf_counter() - t0) * 1000.0
                for port, v in out.items():
                    known[(step.id, port)] = v
                done.append((step, out, ms))
            return done

        self._pending = _Pending(frame_out, previous, _on_a_thread(compute, [s.id for s in steps]))

    def take(self, frame_out: dict, previous: dict, hooks: frozenset[str]) -> dict[str, tuple[dict, float]]:
        """This frame's nodes computed ahead: node id -> (outputs, ms); none when nothing was
        computed ahead for ``frame_out`` with the feedback values ``previous``, when a node failed
        there, or when a ``lanegraph_before_node`` was registered since (in ``hooks``). The executor
        takes each in its turn in the plan (its after-node call among the others')."""
        pending, self._pending = self._pending, None
        if pending is None:
            return {}
        try:
            done = pending.future.result()
        except _Abandon:
            return {}
        except BaseException:  # a signal while it waits: drop() says what is abandoned
            self._pending = pending
            raise
        if pending.frame_out is not frame_out or any(
            previous.get(k) is not v for k, v in pending.previous.items()
        ):
            return {}  # another frame, or other feedback values (the frame before was dropped)
        if "lanegraph_before_node" in hooks:
            return {}  # it is called before the node: the node runs again in turn
        return {step.id: (out, ms) for step, out, ms in done}

    def drop(self) -> str | None:
        """Wait for a computation ahead that no frame will take (the stream ended or failed); when
        a signal is stopping the run, abandon it on its thread instead (it may never end: a node
        that hangs): returns what was abandoned, in words, for the record."""
        pending, self._pending = self._pending, None
        if pending is None:
            return None
        if interrupts.signalled() is not None and not pending.future.done():
            nodes = ", ".join(getattr(pending.future, "nodes", []))
            self.abandoned = (
                f"interrupted while the next frame's node(s) computed ahead ({nodes}) were still "
                "running: abandoned on their thread, not waited for"
            )
            return self.abandoned
        try:
            pending.future.result()
        except BaseException:  # noqa: BLE001 - a frame not taken: its errors are not the run's
            pass
        return None

    def stopped(self) -> list[str]:
        """:meth:`drop` when the run stops (an error, a signal): what was abandoned, as notes."""
        note = self.drop() or self.abandoned
        return [note] if note else []


def _on_a_thread(compute: Any, nodes: list[str]) -> Future:
    """``compute()`` on a daemon thread of its own: a node that never returns is abandoned there
    when a signal stops the run, and does not keep the process from exiting."""
    future: Future = Future()
    future.nodes = nodes  # type: ignore[attr-defined]

    def work() -> None:
        leave_signals_to_the_main_thread()
        if not future.set_running_or_notify_cancel():
            return
        try:
            future.set_result(compute())
        except BaseException as exc:  # noqa: BLE001 - handed to the frame that takes it
            future.set_exception(exc)

    threading.Thread(target=work, name="lanegraph-ahead", daemon=True).start()
    return future
