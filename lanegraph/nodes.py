"""How a node type is declared.

A node type is a plain function plus a pydantic params model::

    class BlurParams(NodeParams):
        ksize: int = Field(5, ge=1, le=99, description="Gaussian kernel size, pixels (odd)")

    @node_type("image.blur", inputs={"image": "image"}, outputs={"image": "image"})
    def blur(params: BlurParams, image):
        return {"image": cv2.GaussianBlur(image, (params.ksize,) * 2, 0)}

    blur(BlurParams(ksize=3), image=img)     # still the plain function
    node_type_of(blur).name                  # "image.blur": the record the registry keeps

``@node_type`` returns the function itself with its :class:`NodeType` attached (``blur.node_type``,
or :func:`node_type_of`); plugins return such functions (or classes) from the
``lanegraph_node_types`` hook.

A *stateless* node function is called as ``func(params, **inputs)`` and returns a dict mapping
output port names to values; a *stateful* one (``stateful=True``) is a class with the life cycle of
:mod:`lanegraph.lifecycle`, where what a class implements is declared (``implements=``). A
stateless node whose work releases the GIL (stereo matching) may declare ``ahead=True``: the
executor may compute it for the next frame on a thread (:mod:`lanegraph.run.ahead`), so it must keep
nothing between calls and be thread-safe. The contract in full: docs/writing-plugins.md.
"""

from __future__ import annotations

import functools
import inspect
import re
import typing
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator

from .lifecycle import (
    SINK_ONLY,
    SOURCE_ONLY,
    contract_problems,
    declared_by_bases,
    undeclared_capabilities,
    unknown_capabilities,
)

F = TypeVar("F", bound=Callable[..., Any])


def _numeric_not_bool(annotation: Any) -> bool:
    """Whether a field of this annotation holds a number (int or float, optionally None) and not a bool."""
    args = typing.get_args(annotation) if typing.get_origin(annotation) is not None else (annotation,)
    return bool(args) and bool(set(args) & {int, float}) and bool not in args


class NodeParams(BaseModel):
    """Base of every params model: unknown keys are rejected, values are validated on assignment,
    a float is never NaN or infinite, a number is never given as a boolean (``true`` is not 1) and
    a boolean only as ``true`` / ``false`` (not 1 or ``"no"``)."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False, allow_inf_nan=False)

    @field_validator("*", mode="before", check_fields=False)
    @classmethod
    def _no_bool_for_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        f = cls.model_fields.get(info.field_name) if info.field_name is not None else None
        if f is None:
            return value
        if isinstance(value, bool) and _numeric_not_bool(f.annotation):
            raise ValueError(f"expected a number, got the boolean {value}")
        if f.annotation in (bool, bool | None) and not isinstance(value, bool) and value is not None:
            raise ValueError(f"expected true or false, got {value!r}")
        return value


class NoParams(NodeParams):
    """A node type without params."""


_PORT_TYPE_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class Port:
    """A typed input or output port.

    ``rate`` is ``"frame"`` (a new value every frame) or ``"constant"`` (one value for
    the whole run, e.g. calibration). ``optional`` inputs may be left unconnected
    (the node then receives ``None``).
    """

    type: str
    doc: str = ""
    optional: bool = False
    rate: str = "frame"

    def __post_init__(self) -> None:
        # any name: port types are an open registry (lanegraph_port_types); a graph that wires a
        # port whose type no installed plugin registers gets a located problem (lanegraph.graph.model)
        if not (isinstance(self.type, str) and _PORT_TYPE_NAME.match(self.type)):
            raise ValueError(
                f"port type must be a lower-case identifier such as 'image' or 'point_cloud', got {self.type!r}"
            )
        if self.rate not in ("frame", "constant"):
            raise ValueError(f"port rate must be 'frame' or 'constant', got {self.rate!r}")


def _as_ports(spec: Mapping[str, str | Port] | None) -> dict[str, Port]:
    return {k: (v if isinstance(v, Port) else Port(v)) for k, v in (spec or {}).items()}


@dataclass
class RunContext:
    """What a stateful node (source, sink) may know about the run.

    ``frames``: the frame selection (``--frames``). ``skip``: how many frames at the start of the
    selection to leave out -- a resumed run's frames already done. A source applies it and sets
    its attribute ``skipped`` to the number it left out; the executor drops the rest itself (reading
    them) from a source that does not. ``extra["resume"]`` is true in a resumed run: a node that
    keeps state across frames then gets its checkpointed ``state()`` back through ``restore()``.
    """

    input_path: Path | None = None
    out_dir: Path | None = None
    frames: slice | None = None
    graph_file: str | None = None
    node_id: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    skip: int = 0


@dataclass
class NodeType:
    """The declaration of one node type."""

    name: str
    func: Callable[..., Any]
    params: type[NodeParams] = NoParams
    inputs: dict[str, Port] = field(default_factory=dict)
    outputs: dict[str, Port] = field(default_factory=dict)
    doc: str = ""
    stateful: bool = False
    source: bool = False
    sink: bool = False
    #: may run for the next frame beside this frame's later nodes (see the module's text)
    ahead: bool = False
    #: the capabilities its class declares (``implements=``), besides those of its
    #: :mod:`lanegraph.lifecycle` base classes; see :attr:`capabilities`
    implements: frozenset[str] = frozenset()
    plugin: str = ""  # filled in by the registry: the distribution / module providing it

    def __post_init__(self) -> None:
        parts = self.name.split(".")
        if len(parts) != 2 or not all(p and p.replace("_", "").isalnum() and p[0].isalpha() for p in parts):
            raise ValueError(
                f"node type name must be 'family.name' (lower-case identifiers), got {self.name!r}"
            )
        self.inputs = _as_ports(self.inputs)
        self.outputs = _as_ports(self.outputs)
        if not (isinstance(self.params, type) and issubclass(self.params, BaseModel)):
            raise TypeError(f"{self.name}: params must be a pydantic model class")
        if self.source:
            self.stateful = True
        if self.ahead and (self.stateful or self.sink):
            raise ValueError(f"{self.name}: ahead=True is for stateless nodes that are not sinks")
        if not self.doc:
            self.doc = inspect.cleandoc(self.func.__doc__ or "")
        self.implements = frozenset(self.implements)
        problems = unknown_capabilities(sorted(self.implements))
        if problems:
            raise ValueError(f"{self.name}: implements: {'; '.join(problems)}")
        if self.implements and not inspect.isclass(self.func):
            raise ValueError(f"{self.name}: implements= is declared by a node class, not a function")
        declared = self.implements | (
            declared_by_bases(self.func) if inspect.isclass(self.func) else frozenset()
        )
        #: what the class defines without declaring it (lanegraph before 0.2 looked for these):
        #: still used, with a DeprecationWarning at registration
        self.undeclared: frozenset[str] = undeclared_capabilities(self.func, declared)
        #: everything the engine may call beyond the life cycle: declared (or, deprecated, undeclared)
        self.capabilities: frozenset[str] = declared | self.undeclared

    def contract_problems(self) -> list[str]:
        """What this node type declares and its class does not define, or a capability that is
        not its kind's (a sink's ``result_files`` on a source ...), one line each; checked at
        registration (:class:`lanegraph.plugins.PluginManager`)."""
        declared = self.capabilities - self.undeclared
        problems = contract_problems(self.func, sorted(declared))
        for cap, kind, ok in [(c, "source", self.source) for c in sorted(declared & SOURCE_ONLY)] + [
            (c, "sink", self.sink) for c in sorted(declared & SINK_ONLY)
        ]:
            if not ok:
                problems.append(f"declares {cap!r}, a capability of a {kind} (declare {kind}=True)")
        return problems

    @property
    def family(self) -> str:
        return self.name.split(".")[0]

    @property
    def code_version(self) -> str:
        """A digest of the code that computes this node: the source files of the top-level package
        (or module) that defines its function, and lanegraph's own source files (the engine's types
        and helpers a node calls, and the version). Cached results and reused runs are keyed by it,
        so that a changed plugin or engine (an upgrade, or an edit in a development install) never
        serves results its old code computed."""
        return _code_version(getattr(self.func, "__module__", "") or "")

    @property
    def summary(self) -> str:
        return self.doc.strip().splitlines()[0] if self.doc.strip() else ""

    @property
    def selects_source(self) -> bool:
        """Whether this source stands for others: it names the source type that reads an input
        (the ``select_source`` capability, see the module docstring)."""
        return self.source and "select_source" in self.capabilities

    def result_files(self, params: NodeParams) -> dict[str, str]:
        """The files this sink writes that other commands read back, ``{kind: path relative to the
        output folder}`` (the ``result_files`` capability; empty for a node without it)."""
        if not (self.sink and "result_files" in self.capabilities):
            return {}
        return {str(k): str(v) for k, v in (self.func.result_files(params) or {}).items()}


def _hash_sources(h: Any, folder: Path, files: list[Path]) -> None:
    for f in files:
        try:
            h.update(f.relative_to(folder).as_posix().encode() + b"\0" + f.read_bytes())
        except OSError:
            continue


@functools.cache
def _engine_version() -> str:
    """A digest of lanegraph's version and every source file of the ``lanegraph`` package."""
    import hashlib

    from ._version import __version__

    h = hashlib.sha256(__version__.encode())
    root = Path(__file__).resolve().parent
    _hash_sources(h, root, sorted(root.rglob("*.py")))
    return h.hexdigest()


@functools.cache
def _code_version(module: str) -> str:
    import hashlib
    import importlib.util

    h = hashlib.sha256(_engine_version().encode())
    top = module.split(".")[0]
    try:
        spec = importlib.util.find_spec(top) if top else None
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.origin:
        origin = Path(spec.origin)
        files = sorted(origin.parent.rglob("*.py")) if spec.submodule_search_locations else [origin]
        _hash_sources(h, origin.parent, files)
    else:  # a function defined in __main__ or a test: its module's name only
        h.update(module.encode())
    return h.hexdigest()[:16]


def _params_from_annotation(func: Callable[..., Any]) -> type[NodeParams] | None:
    """The params model named by the annotation of the first parameter (after ``self`` for a class)."""
    target = func.__init__ if inspect.isclass(func) else func
    names = list(inspect.signature(target).parameters)
    if inspect.isclass(func):
        names = names[1:]
    if not names:
        return None
    try:
        hints = typing.get_type_hints(target)
    except Exception:  # noqa: BLE001 - unresolvable annotations: fall back to the raw one
        hints = {}
    ann = hints.get(names[0], inspect.signature(target).parameters[names[0]].annotation)
    if isinstance(ann, str):
        ann = getattr(inspect.getmodule(func), ann, None)
    return ann if isinstance(ann, type) and issubclass(ann, BaseModel) else None


def node_type_of(obj: Any) -> NodeType | None:
    """The :class:`NodeType` record of a node function or class decorated with :func:`node_type`
    (a :class:`NodeType` is returned as it is); None for anything else. A class's record is its
    own, never one inherited from a decorated base class."""
    if isinstance(obj, NodeType):
        return obj
    try:
        record = vars(obj).get("node_type")
    except TypeError:  # no __dict__
        return None
    return record if isinstance(record, NodeType) else None


def node_type(
    name: str,
    *,
    inputs: Mapping[str, str | Port] | None = None,
    outputs: Mapping[str, str | Port] | None = None,
    params: type[NodeParams] | None = None,
    stateful: bool = False,
    source: bool = False,
    sink: bool = False,
    ahead: bool = False,
    implements: Iterable[str] = (),
    doc: str = "",
) -> Callable[[F], F]:
    """Decorator declaring a function (or, for stateful nodes, a class) a node type.

    It returns the function (or class) unchanged, with its :class:`NodeType` record attached as
    ``func.node_type`` (see :func:`node_type_of`): the node stays a plain function, callable
    without the engine as ``func(params, **inputs)``. When ``params`` is omitted it is taken from
    the annotation of the function's first parameter. ``implements``: what a node class
    declares beyond the life cycle (:mod:`lanegraph.lifecycle`: ``"close"``, ``"resume"``, ...).
    """

    def wrap(func: F) -> F:
        p = params if params is not None else _params_from_annotation(func)
        func.node_type = NodeType(  # type: ignore[attr-defined]
            name=name,
            func=func,
            params=p or NoParams,
            inputs=dict(inputs or {}),
            outputs=dict(outputs or {}),
            doc=doc,
            stateful=stateful or source or inspect.isclass(func),
            source=source,
            sink=sink,
            ahead=ahead,
            implements=frozenset(implements),
        )
        return func

    return wrap
