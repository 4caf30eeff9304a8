"""The life cycle of a stateful node -- open, process, close (MediaPipe's Open / Process / Close)
-- and the capabilities a node type *declares* (MediaPipe's ``GetContract``).

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

What a class implements beyond ``__init__`` / ``__call__`` / ``__iter__`` it declares, by name, in
``@node_type(..., implements=(...))`` or by subclassing the classes below, one a capability
(:data:`CAPABILITIES`: each capability and the members it requires; the table of what each is for
is in docs/writing-plugins.md). Registration (:class:`lanegraph.plugins.PluginManager`) checks that
a class defines every member of what it declares (:func:`contract_problems`: a misspelt ``restor``
is a plugin error naming the plugin, not a sink that silently cannot resume); the engine then reads
the declaration (:attr:`lanegraph.nodes.NodeType.capabilities`) and never asks ``isinstance`` or
``getattr`` of a node. A class that defines a capability's methods without declaring it still has
them used, with a ``DeprecationWarning`` at registration (:func:`undeclared_capabilities`).
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Collection, Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

from .errors import did_you_mean

#: every capability a node type may declare, and the members (methods, or the attributes of
#: :data:`ATTRIBUTES`) a class that declares it must define
CAPABILITIES: dict[str, tuple[str, ...]] = {
    "close": ("close",),
    "resume": ("state", "restore"),
    "constants": ("constants",),
    "len": ("__len__",),
    "identity": ("identity",),
    "skip": ("skipped",),
    "frame_key": ("frame_key",),
    "outputs": ("outputs",),
    "verify": ("verify",),
    "select_source": ("select_source",),
    "result_files": ("result_files",),
}
#: members that are instance attributes (set in ``__init__``): declared by a class-level annotation
#: (``outputs: list[Path]``) or a class attribute, as the base classes below do
ATTRIBUTES = frozenset({"skipped", "outputs"})
#: the capabilities only a source (``source=True``) or only a sink (``sink=True``) may declare
SOURCE_ONLY = frozenset({"constants", "len", "identity", "skip", "frame_key", "select_source"})
SINK_ONLY = frozenset({"outputs", "result_files"})

F = TypeVar("F", bound=Callable[..., Any])


def _required(func: F) -> F:
    """Marks a member of a declaring class that a subclass must define itself."""
    func.__lanegraph_required__ = True  # type: ignore[attr-defined]
    return func


def _found(cls: type, member: str) -> Any:
    """``member`` as the first class of ``cls``'s MRO that defines it holds it (a class attribute,
    or ``...`` for an annotation only), or None."""
    for klass in cls.__mro__:
        if klass is object:
            break
        own = vars(klass)
        if member in own:
            return own[member]
        if member in own.get("__annotations__", {}):
            return ...
    return None


def declared_by_bases(cls: type) -> frozenset[str]:
    """The capabilities ``cls`` declares by subclassing the classes of this module."""
    out: set[str] = set()
    for klass in cls.__mro__:
        out.update(vars(klass).get("__lanegraph_declares__", ()))
    return frozenset(out)


def unknown_capabilities(names: Iterable[str]) -> list[str]:
    """``'restor' is not a capability (did you mean 'resume'?)`` for each name not in
    :data:`CAPABILITIES` (a member's name, or one close to it, suggests its capability)."""
    by_member = {m: cap for cap, members in CAPABILITIES.items() for m in members if m != cap}
    out = []
    for name in names:
        if name in CAPABILITIES:
            continue
        close = difflib.get_close_matches(name, [*CAPABILITIES, *by_member], n=1, cutoff=0.6)
        hint = (
            f"did you mean {by_member.get(close[0], close[0])!r}?"
            if close
            else did_you_mean(name, CAPABILITIES, listing="capabilities")
        )
        out.append(f"{name!r} is not a capability ({hint})")
    return out


def contract_problems(cls: Any, capabilities: Collection[str]) -> list[str]:
    """What ``cls`` lacks of the ``capabilities`` it declares, one line each (``declares 'resume'
    but defines no restore() (did you mean 'restor'?)``); empty when it has it all."""
    problems = unknown_capabilities(capabilities)
    if not isinstance(cls, type):
        return problems
    names = sorted({n for k in cls.__mro__[:-1] for n in vars(k) if not n.startswith("__")})
    for cap in sorted(c for c in capabilities if c in CAPABILITIES):
        for member in CAPABILITIES[cap]:
            value = _found(cls, member)
            if member in ATTRIBUTES:
                if value is None:
                    problems.append(
                        f"declares {cap!r} but does not declare its attribute {member!r} "
                        f"(annotate it on the class: `{member}: ...`)"
                    )
                continue
            if value is None or value is ... or getattr(value, "__lanegraph_required__", False):
                hint = did_you_mean(member, [n for n in names if n != member])
                problems.append(
                    f"declares {cap!r} but defines no {member}()" + (f" ({hint})" if hint else "")
                )
            elif not callable(value):
                problems.append(f"declares {cap!r} but its {member} is not a method")
    return problems


def undeclared_capabilities(cls: Any, declared: Collection[str]) -> frozenset[str]:
    """The capabilities whose methods ``cls`` defines (all of them) without declaring them -- what
    lanegraph before the declared contract found by looking; attributes cannot be seen on a class."""
    if not isinstance(cls, type):
        return frozenset()
    found = set()
    for cap, members in CAPABILITIES.items():
        if cap in declared or any(m in ATTRIBUTES for m in members):
            continue
        values = [_found(cls, m) for m in members]
        if all(v is not None and v is not ... and callable(v) for v in values):
            found.add(cap)
    return frozenset(found)


# --------------------------------------------------------------------------- the declaring classes
class Closeable:
    """Declares ``close``: something to release at the end of the run."""

    __lanegraph_declares__ = ("close",)

    @_required
    def close(self) -> None:  # pragma: no cover - defined by the subclass
        raise NotImplementedError


class Stateful:
    """A stateful node instance: processes one frame per call (declares nothing)."""

    def __call__(self, **inputs: Any) -> dict[str, Any] | None:  # pragma: no cover - overridden
        raise NotImplementedError


class Source:
    """Declares ``constants``: a source's constant outputs, then one dict of outputs per frame from
    ``__iter__`` (or an :class:`~lanegraph.errors.InputError` for a frame it could not read,
    yielded or raised)."""

    __lanegraph_declares__ = ("constants",)

    @_required
    def constants(self) -> dict[str, Any]:  # pragma: no cover - defined by the subclass
        raise NotImplementedError

    def __iter__(self) -> Iterator[Any]:  # pragma: no cover - overridden
        raise NotImplementedError


class Sink:
    """Declares ``outputs``: a sink that says which files it wrote."""

    __lanegraph_declares__ = ("outputs",)
    outputs: list[Any]


class Resumable:
    """Declares ``resume``: a stateful node whose state a checkpoint keeps (JSON values only)."""

    __lanegraph_declares__ = ("resume",)

    @_required
    def state(self) -> Any:  # pragma: no cover - defined by the subclass
        raise NotImplementedError

    @_required
    def restore(self, state: Any) -> None:  # pragma: no cover - defined by the subclass
        raise NotImplementedError


class Sized:
    """Declares ``len``: a source that knows how many frames it will deliver."""

    __lanegraph_declares__ = ("len",)

    @_required
    def __len__(self) -> int:  # pragma: no cover - defined by the subclass
        raise NotImplementedError


class Identified:
    """Declares ``identity``: what a resumed run and the result cache compare the input by."""

    __lanegraph_declares__ = ("identity",)

    @_required
    def identity(self) -> str:  # pragma: no cover - defined by the subclass
        raise NotImplementedError


class SkipsFrames:
    """Declares ``skip``: a source that leaves out the frames a resumed run did itself
    (``context.skip``); ``skipped`` says how many (the executor drops the rest unseen)."""

    __lanegraph_declares__ = ("skip",)
    skipped: int = 0


class Verified:
    """Declares ``verify``: a node that can tell, after the last frame and before close, whether
    its outputs on disk are still those it wrote (``verify()`` raises when not: the lanes file was
    replaced during the run)."""

    __lanegraph_declares__ = ("verify",)

    @_required
    def verify(self) -> None:  # pragma: no cover - defined by the subclass
        raise NotImplementedError


class KeyedFrames:
    """Declares ``frame_key``: a source that names each frame's content for the result cache
    (``None``: not cacheable)."""

    __lanegraph_declares__ = ("frame_key",)

    @_required
    def frame_key(self, frame: str) -> str | None:  # pragma: no cover - defined by the subclass
        raise NotImplementedError


class StatefulNode(Closeable, Stateful):
    """Optional base class of a stateful node: open in ``__init__``, process in ``__call__``, close
    in :meth:`close` (nothing by default)."""

    def __init__(self, params: Any, context: Any):
        self.params = params
        self.context = context

    def close(self) -> None:
        """Release what :meth:`__init__` opened; called once, however the run ended."""


class SourceNode(StatefulNode, Source):
    """Optional base class of a source: :meth:`constants` (none by default) and ``__iter__``."""

    def constants(self) -> dict[str, Any]:
        return {}


class SinkNode(StatefulNode, Sink):
    """Optional base class of a sink: :attr:`outputs`, the files it wrote."""

    def __init__(self, params: Any, context: Any):
        super().__init__(params, context)
        self.outputs: list[Any] = []


# --------------------------------------------------------------------------- driving instances
def _capabilities(instance: Any, node_type: Any) -> Collection[str]:
    """What ``node_type`` (a :class:`~lanegraph.nodes.NodeType`; by default the record of the
    instance's own class) declares."""
    record = node_type if node_type is not None else vars(type(instance)).get("node_type")
    return record.capabilities if record is not None else ()


def constants_of(source: Any, node_type: Any = None) -> dict[str, Any]:
    """A source's constant outputs (none for one that does not declare ``constants``)."""
    return dict(source.constants()) if "constants" in _capabilities(source, node_type) else {}


def close(instance: Any, node_type: Any = None) -> None:
    """Close one node instance (a no-op for one that does not declare ``close``)."""
    if "close" in _capabilities(instance, node_type):
        instance.close()


@contextmanager
def closing(instance: Any, node_type: Any = None) -> Iterator[Any]:
    """``with closing(cls(params, ctx)) as obj:``: the instance, closed when the block is left."""
    try:
        yield instance
    finally:
        close(instance, node_type)


def close_all(instances: Iterable[Any]) -> BaseException | None:
    """Close every instance -- each given as itself or as ``(instance, node type)`` -- in order,
    each even when an earlier one's ``close`` raised; returns the first error a ``close`` raised
    (the caller decides whether it matters more than its own)."""
    first: BaseException | None = None
    for item in instances:
        inst, nt = item if isinstance(item, tuple) else (item, None)
        try:
            close(inst, nt)
        except Exception as exc:  # noqa: BLE001 - the others are still closed
            first = first or exc
    return first


def verify_all(instances: dict[str, Any], graph: Any) -> None:
    """After the last frame: every node that declares ``verify`` checks its outputs on disk; one
    that is no longer what it wrote raises (a :class:`~lanegraph.errors.LanegraphError`, exit 1;
    anything else it raises becomes a :class:`~lanegraph.errors.NodeError` naming it)."""
    from .errors import LanegraphError, NodeError

    for nid, inst in instances.items():
        nt = graph.nodes[nid].type
        if "verify" in nt.capabilities:
            try:
                inst.verify()
            except LanegraphError:
                raise
            except Exception as exc:  # noqa: BLE001 - located
                raise NodeError(nid, nt.name, None, exc) from exc
