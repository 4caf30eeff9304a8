"""The life cycle of a stateful node: open, process, close (MediaPipe's Open / Process / Close).

A stateless node is a plain function (:mod:`lanegraph.nodes`). A *stateful* node type is a class,
and the engine drives an instance through one life cycle per run:

open
    ``cls(params, context)``: once, before the first frame (a sink opens its files here, a source
    finds its frames). A node that raises here fails the run before any frame runs.
process
    ``obj(**inputs) -> {output port: value}``: once per frame (a source instead *yields* its
    frames: ``iter(obj)``, with ``obj.constants()`` for what does not change per frame).
close
    ``obj.close()``: once, after the last frame -- also when the run stops on an error or is
    interrupted, and for the nodes already opened when a later node fails to open. The executor is a
    context manager that guarantees it (``with Executor(...) as ex: ex.run()``).

The protocols below are what a class *declares* by defining the methods; the engine asks
``isinstance(obj, Closeable)`` and never probes for attributes. :class:`StatefulNode`,
:class:`SourceNode` and :class:`SinkNode` are optional base classes with the empty defaults.

Capabilities around the life cycle, each its own protocol:

:class:`Resumable`
    ``state() -> JSON-able`` after every frame, ``restore(state)`` after open when a run resumes
    (``lanegraph run --resume``; :mod:`lanegraph.run.resume`).
:class:`Sized` (a source)
    ``len(obj)``: the number of frames it will deliver (a progress bar's total, ``--chunk-frames``).
:class:`Identified` (a source)
    ``identity() -> str``: what a resumed run and the result cache compare its input by.
:class:`SkipsFrames`, :class:`KeyedFrames` (a source)
    ``skipped``: frames of a resumed run it left out itself; ``frame_key(frame)``: a frame's
    content key for the result cache.
:class:`Sink`
    ``outputs``: the files it wrote (printed at the end of ``lanegraph run``).
:class:`Verified`
    ``verify()`` after the last frame: raises when its output on disk is no longer the one it wrote.

Declarations made on the class itself, read before anything is instantiated (static methods; see
:mod:`lanegraph.nodes`): ``select_source(params, input_path, detect)`` (a source that stands for
others) and ``result_files(params)`` (a sink's files that other commands read back).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class Closeable(Protocol):
    """A node instance with something to release at the end of its run."""

    def close(self) -> None: ...


@runtime_checkable
class Stateful(Protocol):
    """A stateful node instance: processes one frame per call."""

    def __call__(self, **inputs: Any) -> dict[str, Any] | None: ...


@runtime_checkable
class Source(Protocol):
    """A source instance: its constant outputs, then one dict of outputs per frame (or an
    :class:`~lanegraph.errors.InputError` for a frame it could not read, yielded or raised)."""

    def constants(self) -> dict[str, Any]: ...

    def __iter__(self) -> Iterator[Any]: ...


@runtime_checkable
class Sink(Protocol):
    """A sink instance that says which files it wrote."""

    outputs: list[Any]


@runtime_checkable
class Resumable(Protocol):
    """A stateful node whose state a checkpoint keeps (JSON values only)."""

    def state(self) -> Any: ...

    def restore(self, state: Any) -> None: ...


@runtime_checkable
class Sized(Protocol):
    def __len__(self) -> int: ...


@runtime_checkable
class Identified(Protocol):
    def identity(self) -> str: ...


@runtime_checkable
class SkipsFrames(Protocol):
    """A source that leaves out the frames a resumed run did itself (``context.skip``): ``skipped``
    says how many (the executor drops the rest unseen)."""

    skipped: int


@runtime_checkable
class Verified(Protocol):
    """A node that can tell, after the last frame and before close, whether its outputs on disk
    are still those it wrote (``verify()`` raises when not: the lanes file was replaced during the
    run)."""

    def verify(self) -> None: ...


@runtime_checkable
class KeyedFrames(Protocol):
    """A source that names each frame's content for the result cache (``None``: not cacheable)."""

    def frame_key(self, frame: str) -> str | None: ...


class StatefulNode:
    """Optional base class of a stateful node: open in ``__init__``, process in ``__call__``, close
    in :meth:`close` (nothing by default)."""

    def __init__(self, params: Any, context: Any):
        self.params = params
        self.context = context

    def __call__(self, **inputs: Any) -> dict[str, Any] | None:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:
        """Release what :meth:`__init__` opened; called once, however the run ended."""


class SourceNode(StatefulNode):
    """Optional base class of a source: :meth:`constants` (none by default) and ``__iter__``."""

    def constants(self) -> dict[str, Any]:
        return {}

    def __iter__(self) -> Iterator[Any]:  # pragma: no cover - overridden
        raise NotImplementedError


class SinkNode(StatefulNode):
    """Optional base class of a sink: :attr:`outputs`, the files it wrote."""

    def __init__(self, params: Any, context: Any):
        super().__init__(params, context)
        self.outputs: list[Any] = []


def constants_of(source: Any) -> dict[str, Any]:
    """A source's constant outputs (none for one that declares no ``constants``)."""
    return dict(source.constants()) if isinstance(source, Source) else {}


def close(instance: Any) -> None:
    """Close one node instance (a no-op for one that declares no ``close``)."""
    if isinstance(instance, Closeable):
        instance.close()


@contextmanager
def closing(instance: Any) -> Iterator[Any]:
    """``with closing(cls(params, ctx)) as obj:``: the instance, closed when the block is left."""
    try:
        yield instance
    finally:
        close(instance)


def close_all(instances: Iterable[Any]) -> BaseException | None:
    """Close every instance, in order, each even when an earlier one's ``close`` raised; returns the
    first error a ``close`` raised (the caller decides whether it matters more than its own)."""
    first: BaseException | None = None
    for inst in instances:
        try:
            close(inst)
        except Exception as exc:  # noqa: BLE001 - the others are still closed
            first = first or exc
    return first


def verify_all(instances: dict[str, Any], graph: Any) -> None:
    """After the last frame: every :class:`Verified` node checks its outputs on disk; one that is
    no longer what it wrote raises (a :class:`~lanegraph.errors.LanegraphError`, exit 1; anything
    else it raises becomes a :class:`~lanegraph.errors.NodeError` naming it)."""
    from .errors import LanegraphError, NodeError

    for nid, inst in instances.items():
        if isinstance(inst, Verified):
            try:
                inst.verify()
            except LanegraphError:
                raise
            except Exception as exc:  # noqa: BLE001 - located
                raise NodeError(nid, graph.nodes[nid].type.name, None, exc) from exc
