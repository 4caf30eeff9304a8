"""Graph files: the pydantic format, ``extends`` resolution, ``--set`` overrides and whole-graph validation.

A graph file (YAML, JSON or TOML)::

    name: paper
    description: The paper's pipeline.
    nodes:
      src:   {type: io.auto}
      gray:  {type: image.gray, inputs: {image: src.left}}
      tmask:
        type: lanes.temporal_mask
        inputs: {previous: fit.lanes@prev}     # a feedback edge: the previous frame's value

An ablation variant extends a base and overrides a few nodes::

    extends: ../paper.yaml
    nodes:
      features: {type: features.slt}           # another type: its params start from defaults
      fit: {params: {iterations: 3}}           # the same type: params are merged
      tmask: null                              # remove a node
      mask: {inputs: {temporal: null}}         # unwire an (optional) input

Everything is checked before any frame runs; every problem names the file, node id and field.
"""

from __future__ import annotations

import copy
import re
import reprlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, StringConstraints, ValidationError, field_validator

from .builtin import builtin_base
from .errors import GraphError, Problem, did_you_mean
from .loader import read_graph_file
from .nodes import NodeParams, NodeType
from .paths import output_fields, output_problems
from .plugins import PluginManager, get_plugin_manager
from .types import port_compatible

#: a node's error policy: ``fail`` stops the run, ``skip`` drops the frame, ``empty`` passes None on
ON_ERROR_CHOICES = ("fail", "skip", "empty")
OnError = Annotated[str, StringConstraints(pattern=f"^({'|'.join(ON_ERROR_CHOICES)})$")]

_REF = re.compile(r"^(?P<node>[A-Za-z_][\w-]*)\.(?P<port>[A-Za-z_]\w*)(?P<prev>@prev)?$")
_ID = r"^[A-Za-z_][\w-]*$"


class InputSpec(BaseModel):
    """The long form of an input wiring: ``{from: node.port, previous: true}``."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    from_: str = Field(alias="from", description="the producing node's output: 'node_id.port'")
    previous: bool = Field(
        False,
        strict=True,
        description="a feedback edge: deliver the previous frame's value (None on the first frame)",
    )


class NodeSpec(BaseModel):
    """One node of a graph."""

    model_config = ConfigDict(extra="forbid")

    type: str = Field(description="node type name, 'family.name' (see `lanegraph nodes`)")
    params: dict[str, Any] = Field(
        default_factory=dict, description="the node type's params (validated by its model)"
    )
    inputs: dict[str, str | InputSpec | None] = Field(
        default_factory=dict,
        description="input port -> 'node_id.port' (append '@prev' for the previous frame's value) or the long form",
    )
    doc: str = Field("", description="free text: why this node is here")
    on_error: OnError | None = Field(
        None, description=f"error policy for this node: {' | '.join(ON_ERROR_CHOICES)}"
    )


class GraphSpec(BaseModel):
    """A graph file."""

    model_config = ConfigDict(extra="forbid")

    version: int = Field(1, ge=1, le=1, strict=True, description="graph format version")
    name: str = Field("", description="short name of the graph")
    description: str = Field("", description="what the graph does")
    extends: str | None = Field(None, description="base graph file, relative to this file")
    on_error: OnError = Field("fail", description="default error policy of every node")
    nodes: dict[str, NodeSpec | None] = Field(default_factory=dict, description="node id -> node")
    remove: list[str] = Field(default_factory=list, description="ids of base-graph nodes to remove")

    @field_validator("nodes")
    @classmethod
    def _ids(cls, v: dict[str, Any]) -> dict[str, Any]:
        for k in v:
            if not re.match(_ID, k):
                raise ValueError(
                    f"node id {k!r} must start with a letter or '_' and contain only letters, digits, '_', '-'"
                )
        return v


@dataclass(frozen=True)
class Edge:
    """``src_node.src_port -> dst_node.dst_port``; ``previous`` marks a feedback edge."""

    src_node: str
    src_port: str
    dst_node: str
    dst_port: str
    previous: bool = False


@dataclass
class GraphNode:
    """A validated node: its type, params instance and where it was defined."""

    id: str
    type: NodeType
    params: NodeParams
    inputs: dict[str, Edge]
    file: str
    doc: str = ""
    on_error: str = "fail"


@dataclass
class Graph:
    """A validated, resolved graph, in execution (topological) order."""

    name: str
    description: str
    file: str
    nodes: dict[str, GraphNode]
    order: list[str]
    raw: dict[str, Any] = field(default_factory=dict)
    on_error: str = "fail"

    @property
    def edges(self) -> list[Edge]:
        return [e for n in self.nodes.values() for e in n.inputs.values()]

    @property
    def source(self) -> GraphNode:
        return next(n for n in self.nodes.values() if n.type.source)

    def resolved_dict(self) -> dict[str, Any]:
        """The graph after extends/overrides, as a plain dict with every param spelt out."""
        nodes: dict[str, Any] = {}
        for nid in self.order:
            n = self.nodes[nid]
            spec: dict[str, Any] = {"type": n.type.name}
            params = n.params.model_dump(mode="json")
            if params:
                spec["params"] = params
            if n.inputs:
                spec["inputs"] = {
                    p: f"{e.src_node}.{e.src_port}" + ("@prev" if e.previous else "")
                    for p, e in n.inputs.items()
                }
            if n.on_error != self.on_error:
                spec["on_error"] = n.on_error
            if n.doc:
                spec["doc"] = n.doc
            nodes[nid] = spec
        out: dict[str, Any] = {"name": self.name}
        if self.description:
            out["description"] = self.description
        if self.on_error != "fail":
            out["on_error"] = self.on_error
        out["nodes"] = nodes
        return out


# --------------------------------------------------------------------------- loading
def _merge_node(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    if "type" in over and over["type"] != base.get("type"):
        out["type"] = over["type"]
        out["params"] = {}  # another node type: its own params, from its defaults
    for key, value in over.items():
        if key == "type":
            continue
        if key in ("params", "inputs") and isinstance(value, dict) and isinstance(out.get(key), dict):
            merged = dict(out[key])
            for k, v in value.items():
                if key == "inputs" and v is None:
                    merged.pop(k, None)
                else:
                    merged[k] = v
            out[key] = merged
        else:
            out[key] = copy.deepcopy(value)
    return out


def _resolve(
    path: Path, display: str, chain: tuple[Path, ...], roots: list[Path] | None
) -> tuple[dict[str, Any], dict[str, str]]:
    """Return (merged raw graph dict, node id -> file that last defined it)."""
    data = read_graph_file(path, display)
    origin: dict[str, str] = {}
    base_raw: dict[str, Any] = {"nodes": {}}
    ext = data.get("extends")
    if ext is not None:
        base_path, base_display = _base_file(ext, path, display, chain, roots)
        base_raw, origin = _resolve(base_path, base_display, (*chain, path.resolve()), roots)
    merged = {k: v for k, v in base_raw.items() if k not in ("extends", "remove")}
    for key, value in data.items():
        if key in ("nodes", "extends", "remove"):
            continue
        merged[key] = value
    nodes = dict(merged.get("nodes") or {})
    own_nodes = data.get("nodes") or {}
    if not isinstance(own_nodes, dict):
        raise GraphError(
            [
                Problem(
                    f"expected a mapping of node id -> node, got {type(own_nodes).__name__}",
                    file=display,
                    field="nodes",
                )
            ]
        )
    problems = _override_nodes(nodes, own_nodes, origin, display, extends=ext is not None)
    problems += _remove_nodes(nodes, data.get("remove") or [], origin, display)
    if problems:
        raise GraphError(problems)
    merged["nodes"] = nodes
    return merged, origin


def _base_file(
    ext: Any, path: Path, display: str, chain: tuple[Path, ...], roots: list[Path] | None
) -> tuple[Path, str]:
    """The file ``extends: EXT`` of graph file ``path`` names, checked: a path, no cycle, inside
    the allowed ``roots``, present. Returns (resolved path, how messages show it)."""

    def problem(message: str) -> GraphError:
        return GraphError([Problem(message, file=display, field="extends")])

    if not isinstance(ext, str):
        raise problem(f"expected a file path, got {_short(ext)}")
    try:
        base_path = (path.parent / ext).resolve()
        base_found = base_path.is_file()
    except (OSError, ValueError, RuntimeError) as exc:  # a NUL byte, a name too long, a symbolic link loop
        raise problem(f"invalid path {_short(ext)}: {exc}") from None
    if base_path in chain or base_path == path.resolve():
        raise problem("extends cycle: " + " -> ".join(str(p) for p in (*chain, path.resolve(), base_path)))
    if roots is not None and not any(base_path.is_relative_to(r) for r in roots):
        raise problem(
            f"{ext!r} resolves to {base_path}, outside the allowed roots ({', '.join(map(str, roots))})"
        )
    base_display = str(Path(display).parent / ext) if display else str(base_path)
    if not base_found and (builtin := builtin_base(ext)) is not None:  # extends: paper.yaml from anywhere
        base_path, base_display, base_found = builtin, f"{ext} (built-in: {builtin})", True
        if base_path in chain:
            raise problem(
                "extends cycle: " + " -> ".join(str(p) for p in (*chain, path.resolve(), base_path))
            )
    if not base_found:
        raise problem(f"base graph file not found: {base_display} (resolved to {base_path})")
    return base_path, base_display


def _override_nodes(
    nodes: dict[str, Any], own: dict[Any, Any], origin: dict[str, str], display: str, extends: bool
) -> list[Problem]:
    """Apply a file's own ``nodes`` to those of its base (in place): ``null`` removes a node, a
    mapping for a base node is merged into it, a new node needs a ``type``."""
    problems = []
    for nid, spec in own.items():
        if spec is None:
            if nid not in nodes:
                hint = did_you_mean(nid, nodes, listing="nodes")
                problems.append(
                    Problem(
                        "cannot remove: no such node in the base graph",
                        file=display,
                        node=str(nid),
                        hint=hint,
                    )
                )
            nodes.pop(nid, None)
            origin.pop(nid, None)
            origin[f"{nid}@removed"] = display
        elif isinstance(spec, dict) and isinstance(nodes.get(nid), dict):
            nodes[nid] = _merge_node(nodes[nid], spec)
            origin[nid] = display
        elif extends and isinstance(spec, dict) and "type" not in spec and nid not in nodes:
            problems.append(
                Problem(
                    "cannot override: no such node in the base graph (a new node needs a 'type')",
                    file=display,
                    node=str(nid),
                    hint=did_you_mean(nid, nodes, listing="nodes"),
                )
            )
        else:
            nodes[nid] = spec
            origin[nid] = display
    return problems


def _remove_nodes(nodes: dict[str, Any], removes: Any, origin: dict[str, str], display: str) -> list[Problem]:
    """Apply a file's ``remove: [ids]`` (in place)."""
    if not isinstance(removes, list):
        return [Problem(f"expected a list of node ids, got {removes!r}", file=display, field="remove")]
    problems = []
    for nid in removes:
        if not isinstance(nid, str):
            problems.append(Problem(f"expected a node id, got {nid!r}", file=display, field="remove"))
            continue
        if nid not in nodes:
            hint = did_you_mean(nid, nodes, listing="nodes")
            problems.append(
                Problem("cannot remove: no such node", file=display, node=nid, field="remove", hint=hint)
            )
        nodes.pop(nid, None)
        origin.pop(nid, None)
        origin[f"{nid}@removed"] = display
    return problems


def parse_set(item: str) -> tuple[str, list[str], Any]:
    """Parse ``node.param=value`` (nested params with more dots); the value is read as YAML."""
    if "=" not in item:
        raise GraphError([Problem(f"--set {item!r}: expected node.param=value", field="--set")])
    key, _, value = item.partition("=")
    parts = key.strip().split(".")
    if len(parts) < 2 or not all(parts):
        raise GraphError([Problem(f"--set {item!r}: expected node.param=value", field="--set")])
    try:
        parsed = yaml.safe_load(value) if value.strip() else ""
    except (
        yaml.YAMLError,
        ValueError,
    ):  # ValueError: a value its tag cannot hold (!!int x, a 5000-digit int)
        parsed = value
    return parts[0], parts[1:], parsed


def _apply_sets(raw: dict[str, Any], sets: list[str], origin: dict[str, str]) -> None:
    problems = []
    nodes = raw.setdefault("nodes", {})
    if not isinstance(nodes, dict):  # reported by the validation; --set has nothing to apply to
        return
    names = [str(k) for k in nodes]
    for item in sets:
        nid, path, value = parse_set(item)
        spec = nodes.get(nid)
        if not isinstance(spec, dict):
            hint = did_you_mean(nid, names, listing="nodes")
            problems.append(
                Problem(f"--set {item!r}: no node with this id", node=nid, field="--set", hint=hint)
            )
            continue
        if path == ["type"]:
            spec.update(_merge_node(spec, {"type": value}))
            origin[nid] = "--set"
            continue
        target = spec.setdefault("params", {})
        depth = 0
        while depth < len(path) - 1 and isinstance(target, dict):
            target = target.setdefault(path[depth], {})
            depth += 1
        if not isinstance(target, dict):
            where = ".".join(["params", *path[:depth]])
            problems.append(
                Problem(
                    f"--set {item!r}: {where} is {target!r}, not a mapping of params; cannot set {'.'.join(path[depth:])} in it",
                    node=nid,
                    field="--set",
                )
            )
            continue
        target[path[-1]] = value
        origin[nid] = "--set"
    if problems:
        raise GraphError(problems)


def load_raw(
    path: str | Path, sets: list[str] | None = None, roots: list[Path] | None = None
) -> tuple[dict[str, Any], dict[str, str], str]:
    """Load a graph file with ``extends`` and ``--set`` applied, not yet validated."""
    p = Path(path)
    display = str(path)
    raw, origin = _resolve(p, display, (), roots)
    _apply_sets(raw, list(sets or []), origin)
    return raw, origin, display


# --------------------------------------------------------------------------- validation
def _loc_str(loc: tuple[Any, ...]) -> str:
    return ".".join(str(x) for x in loc)


def _short(value: Any, limit: int = 120) -> str:
    """``repr(value)``, cut to ``limit`` characters (a value may be a whole, huge subtree)."""
    r = reprlib.Repr()
    r.maxlevel, r.maxlist, r.maxdict, r.maxstring, r.maxother = 3, 8, 8, limit, limit
    try:
        text = r.repr(value)
    except ValueError:  # an int beyond sys.get_int_max_str_digits()
        text = f"<{type(value).__name__} too large to print>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _pydantic_problems(
    exc: ValidationError, file: str, node: str | None, ntype: str | None, prefix: str
) -> list[Problem]:
    out = []
    for err in exc.errors():
        loc = _loc_str(err["loc"])
        field_ = f"{prefix}.{loc}" if prefix and loc else (prefix or loc)
        got = err.get("input")
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        elif err["type"] == "value_error" and "error" in err.get("ctx", {}):
            text = str(err["ctx"]["error"])  # a validator's own message, without pydantic's "Value error, "
            msg = text if _short(got) in text else f"{text}; got {_short(got)}"
        elif err["type"] != "missing":
            msg = f"expected: {msg[0].lower() + msg[1:]}; got {_short(got)}"
        out.append(Problem(msg, file=file, node=node, node_type=ntype, field=field_))
    return out


def _param_hint(model: type[NodeParams], problems: list[Problem]) -> list[Problem]:
    fields = list(model.model_fields)
    out = []
    for p in problems:
        if p.message == "unknown key" and p.field:
            hint = did_you_mean(p.field.split(".")[-1], fields, listing="known params")
            p = Problem(p.message, p.file, p.node, p.node_type, p.field, hint)
        out.append(p)
    return out


def validate_raw(
    raw: dict[str, Any], origin: dict[str, str], file: str, pm: PluginManager | None = None
) -> Graph:
    """Validate a resolved graph dict against the installed node types; raise one :class:`GraphError`
    listing every problem.

    The graph format is checked first (a malformed file stops there); then the passes of
    :data:`PASSES` run in turn on what the earlier ones established, each returning its problems.
    """
    pm = pm or get_plugin_manager()
    spec = _parse_spec(raw, origin, file)
    state = _Validation(spec, origin, file, pm, {k: v for k, v in spec.nodes.items() if v is not None})
    problems: list[Problem] = []
    for check in PASSES:
        problems += check(state)
    if problems:
        raise GraphError(_dedupe(problems))
    return Graph(
        spec.name or Path(file).stem, spec.description, file, state.nodes, state.order, raw, spec.on_error
    )


@dataclass
class _Validation:
    """What the validation passes share: the parsed graph and what the earlier passes found."""

    spec: GraphSpec
    origin: dict[str, str]
    file: str
    pm: PluginManager
    specs: dict[str, NodeSpec]  # the nodes that are not removed
    types: dict[str, NodeType] = field(default_factory=dict)  # node id -> its (known) type
    nodes: dict[str, GraphNode] = field(default_factory=dict)  # node id -> the validated node
    order: list[str] = field(default_factory=list)

    def file_of(self, nid: str) -> str:
        """The file that (last) defined node ``nid``."""
        return self.origin.get(nid, self.file)


# --------------------------------------------------------------------------- the graph format
def _parse_spec(raw: dict[str, Any], origin: dict[str, str], file: str) -> GraphSpec:
    """The graph format (:class:`GraphSpec`): every problem of a malformed file, located."""
    try:
        return GraphSpec.model_validate(raw)
    except ValidationError as exc:
        problems = [p for err in exc.errors() if (p := _format_problem(err, raw, origin, file)) is not None]
        raise GraphError(_dedupe(problems)) from None


def _format_problem(err: Any, raw: dict[str, Any], origin: dict[str, str], file: str) -> Problem | None:
    """One pydantic error of the graph format as a located problem (None for the union branch of
    an input's other form)."""
    loc = err["loc"]
    node = str(loc[1]) if len(loc) >= 2 and loc[0] == "nodes" else None
    rest = loc[2:] if node else loc
    # pydantic reports union branches; keep the informative one
    if node and len(rest) >= 1 and rest[0] == "NodeSpec":
        rest = rest[1:]
    model: type[BaseModel] = NodeSpec if node else GraphSpec
    msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"]
    if err["type"] not in ("extra_forbidden", "missing"):
        msg = f"expected: {msg[0].lower() + msg[1:]}; got {_short(err.get('input'))}"
    if node and len(rest) >= 3 and rest[0] == "inputs" and rest[2] in ("str", "InputSpec"):
        value = ((raw.get("nodes") or {}).get(loc[1]) or {}).get("inputs", {}).get(rest[1])
        if (rest[2] == "InputSpec") != isinstance(value, dict):
            return None  # the branch of the other form
        if rest[2] == "str":
            msg = f"expected 'node_id.port', 'node_id.port@prev' or {{from: node_id.port, previous: true}}; got {_short(value)}"
        rest, model = (*rest[:2], *rest[3:]), InputSpec
    hint = None
    if node and not rest and isinstance(err.get("input"), str):
        hint = f"a node is a mapping: {node}: {{type: {err['input']}}}"
    if err["type"] == "extra_forbidden" and rest:
        hint = did_you_mean(
            rest[-1], [f.alias or k for k, f in model.model_fields.items()], listing="known keys"
        )
    nfile = origin.get(node, file) if node else file
    return Problem(msg, file=nfile, node=node, field=_loc_str(rest) or None, hint=hint)


# --------------------------------------------------------------------------- the passes
def _node_types_pass(v: _Validation) -> list[Problem]:
    """Every node's type is installed and its params are valid for it."""
    problems: list[Problem] = []
    context = {"node_types": v.pm.node_types}  # params validators may look up other node types
    for nid, ns in v.specs.items():
        nt = v.pm.get_node_type(ns.type)
        if nt is None:
            problems.append(_unknown_type(v, nid, ns.type))
            continue
        v.types[nid] = nt
        try:
            params = nt.params.model_validate(ns.params, context=context)
        except ValidationError as exc:
            problems += _param_hint(
                nt.params, _pydantic_problems(exc, v.file_of(nid), nid, nt.name, "params")
            )
            params = None
        v.nodes[nid] = GraphNode(nid, nt, params, {}, v.file_of(nid), ns.doc, ns.on_error or v.spec.on_error)  # type: ignore[arg-type]
    return problems


def _unknown_type(v: _Validation, nid: str, name: str) -> Problem:
    sug = v.pm.suggest(name)
    hint = f"did you mean '{sug}'?" if sug else "run `lanegraph nodes` to list the installed types"
    missing = v.pm.missing_type_hint(name)
    if missing is not None:  # a plugin was not loaded: say so (it holds this type, or may)
        hint = missing if missing.startswith("it is a node type") else f"{hint}; {missing}"
    return Problem(f"unknown node type {name!r}", file=v.file_of(nid), node=nid, field="type", hint=hint)


def _wiring_pass(v: _Validation) -> list[Problem]:
    """Every input names a port of the node's type and an output of a node of the graph whose port
    type fits; every required input is connected."""
    problems: list[Problem] = []
    for nid, ns in v.specs.items():
        nt = v.types.get(nid)
        if nt is None:
            continue
        for port, ref in ns.inputs.items():
            problem, edge = _input_edge(v, nid, nt, port, ref)
            if problem is not None:
                problems.append(problem)
            elif edge is not None and nid in v.nodes:
                v.nodes[nid].inputs[port] = edge
        problems += _required_inputs(v, nid, nt, ns)
    return problems


def _input_edge(
    v: _Validation, nid: str, nt: NodeType, port: str, ref: Any
) -> tuple[Problem | None, Edge | None]:
    """The edge that feeds input ``port`` of node ``nid`` from ``ref``, or the problem with it."""
    where = {"file": v.file_of(nid), "node": nid, "node_type": nt.name, "field": f"inputs.{port}"}
    if port not in nt.inputs:
        return Problem(
            f"unknown input port {port!r}", **where, hint=did_you_mean(port, nt.inputs, listing="inputs")
        ), None
    if ref is None:
        return None, None
    text, previous = (ref.from_, ref.previous) if isinstance(ref, InputSpec) else (ref, False)
    m = _REF.match(text.strip())
    if not m:
        return Problem(f"expected 'node_id.port' or 'node_id.port@prev', got {text!r}", **where), None
    src, sport, previous = m["node"], m["port"], previous or bool(m["prev"])
    if src not in v.specs:
        hint = did_you_mean(src, v.specs)
        if f"{src}@removed" in v.origin:
            hint = (
                f"{v.origin[src + '@removed']} removes node {src!r}; unwire this input there "
                f"({nid}: {{inputs: {{{port}: null}}}}) or wire it to another node"
            )
        return Problem(f"refers to unknown node {src!r}", **where, hint=hint), None
    st = v.types.get(src)
    if st is None:
        return None, None  # already reported: unknown type
    if sport not in st.outputs:
        hint = did_you_mean(sport, st.outputs, listing="outputs")
        return Problem(f"node {src!r} ({st.name}) has no output port {sport!r}", **where, hint=hint), None
    produced, expected = st.outputs[sport].type, nt.inputs[port].type
    known = v.pm.port_types
    for ptype, what in (
        (expected, f"input port {port!r} of {nt.name}"),
        (produced, f"output {src}.{sport} of {st.name}"),
    ):
        if ptype not in known:
            hint = (
                did_you_mean(ptype, known)
                or "no installed plugin registers it (through the lanegraph_port_types hook)"
            )
            return Problem(f"unknown port type {ptype!r} ({what})", **where, hint=hint), None
    if not port_compatible(produced, expected, known):
        return Problem(
            f"port type mismatch: expected {expected!r}, got {produced!r} from {src}.{sport}", **where
        ), None
    return None, Edge(src, sport, nid, port, previous)


def _required_inputs(v: _Validation, nid: str, nt: NodeType, ns: NodeSpec) -> list[Problem]:
    problems = []
    for port, p in nt.inputs.items():
        if p.optional:
            continue
        if port not in ns.inputs:
            what = "is not connected"
        elif ns.inputs.get(port) is None:
            what = "cannot be unwired"
        else:
            continue
        problems.append(
            Problem(
                f"required input port {port!r} ({p.type}) {what}",
                file=v.file_of(nid),
                node=nid,
                node_type=nt.name,
                field=f"inputs.{port}",
            )
        )
    return problems


def _source_pass(v: _Validation) -> list[Problem]:
    """Exactly one source node (when every node's type is known)."""
    sources = [nid for nid, t in v.types.items() if t.source]
    if len(sources) == 1 or len(v.types) < len(v.specs):
        return []
    installed = [(name, t) for name, t in v.pm.node_types.items() if t.source]
    families = " or ".join(
        sorted({f"an {t.family}.*" if t.family[0] in "aeiou" else f"a {t.family}.*" for _, t in installed})
    )
    example = next((n for n, t in installed if t.selects_source), installed[0][0] if installed else None)
    return [
        Problem(
            f"a graph needs exactly one source node ({families or 'a'} node type that produces frames), found "
            f"{len(sources)}" + (f": {', '.join(sources)}" if sources else ""),
            file=v.file,
            field="nodes",
            hint=f"add e.g. `src: {{type: {example}}}`" if not sources and example else None,
        )
    ]


def _sinks_pass(v: _Validation) -> list[Problem]:
    return _output_problems(v.nodes)


def _feedback_pass(v: _Validation) -> list[Problem]:
    return _feedback_only_problems(v.nodes)


def _order_pass(v: _Validation) -> list[Problem]:
    """An execution order: no cycle of same-frame edges."""
    v.order, cycle = _toposort(v.nodes)
    if not cycle:
        return []
    return [
        Problem(
            "cycle without a feedback edge: " + " -> ".join(cycle),
            file=v.file_of(cycle[0]),
            node=cycle[0],
            field="inputs",
            hint="mark an edge that carries the previous frame's value with '@prev'",
        )
    ]


#: the validation passes, in order; each returns its problems
PASSES: tuple[Callable[[_Validation], list[Problem]], ...] = (
    _node_types_pass,
    _wiring_pass,
    _source_pass,
    _sinks_pass,
    _feedback_pass,
    _order_pass,
)


def _output_problems(nodes: dict[str, GraphNode]) -> list[Problem]:
    """Sinks' output paths (params typed OutputFile / OutputDir): none is a file of the run itself,
    no two are the same file or lie one inside the other."""
    sinks = []
    for nid, n in nodes.items():
        if n.params is None:
            continue
        fields = {f: (kind, getattr(n.params, f)) for f, kind in output_fields(type(n.params)).items()}
        if fields:
            sinks.append((nid, n.type.name, fields))
    return [
        Problem(msg, file=nodes[nid].file, node=nid, node_type=nodes[nid].type.name, field=f"params.{fname}")
        for nid, fname, msg in output_problems(sinks)
    ]


def _feedback_only_problems(nodes: dict[str, GraphNode]) -> list[Problem]:
    """A required input fed by a feedback edge gets ``None`` on the first frame: the node could not
    run on it, so the graph cannot run. Only an optional input may take the previous frame's value."""
    out = []
    for nid, n in nodes.items():
        for port, e in n.inputs.items():
            p = n.type.inputs.get(port)
            if e.previous and p is not None and not p.optional:
                out.append(
                    Problem(
                        f"required input port {port!r} ({p.type}) is fed only by a feedback edge "
                        f"({e.src_node}.{e.src_port}@prev), which is None on the first frame",
                        file=n.file,
                        node=nid,
                        node_type=n.type.name,
                        field=f"inputs.{port}",
                        hint="feed it a value of the same frame, or use a node type whose input is optional",
                    )
                )
    return out


def _dedupe(problems: list[Problem]) -> list[Problem]:
    seen, out = set(), []
    for p in problems:
        if str(p) not in seen:
            seen.add(str(p))
            out.append(p)
    return out


def _toposort(nodes: dict[str, GraphNode]) -> tuple[list[str], list[str] | None]:
    """Kahn's algorithm over same-frame edges; returns (order, a cycle or None)."""
    deps = {
        nid: {e.src_node for e in n.inputs.values() if not e.previous and e.src_node in nodes}
        for nid, n in nodes.items()
    }
    order: list[str] = []
    ready = [nid for nid in nodes if not deps[nid]]
    remaining = {nid: set(d) for nid, d in deps.items()}
    while ready:
        nid = ready.pop(0)
        order.append(nid)
        for other, d in remaining.items():
            if nid in d:
                d.discard(nid)
                if not d and other not in order and other not in ready:
                    ready.append(other)
    if len(order) == len(nodes):
        # sinks that feed nothing run last, so a frame that fails (or is skipped) in any other node
        # never reaches a sink: no line in a sink's file for a frame that did not complete
        feeding = {e.src_node for n in nodes.values() for e in n.inputs.values()}
        last = [nid for nid in order if nodes[nid].type.sink and nid not in feeding]
        return [nid for nid in order if nid not in last] + last, None
    # find one cycle among the rest
    rest = {nid for nid in nodes if nid not in order}
    start = sorted(rest)[0]
    path, seen = [start], {start}
    cur = start
    while True:
        nxt = sorted(d for d in deps[cur] if d in rest)[0]
        if nxt in seen:
            cyc = path[path.index(nxt) :] + [nxt]
            return order, cyc
        path.append(nxt)
        seen.add(nxt)
        cur = nxt


def load_graph(
    path: str | Path,
    sets: list[str] | None = None,
    pm: PluginManager | None = None,
    roots: list[Path] | None = None,
) -> Graph:
    """Load, resolve (``extends``, ``--set``) and validate a graph file."""
    raw, origin, display = load_raw(path, sets, roots)
    return validate_raw(raw, origin, display, pm)


def graph_json_schema(pm: PluginManager | None = None) -> dict[str, Any]:
    """JSON Schema of the graph format, with every installed node type's params."""
    pm = pm or get_plugin_manager()
    schema = GraphSpec.model_json_schema()
    defs = schema.setdefault("$defs", {})
    variants = []
    for name, nt in pm.node_types.items():
        pschema = nt.params.model_json_schema(ref_template="#/$defs/{model}")
        for k, v in pschema.pop("$defs", {}).items():
            defs.setdefault(k, v)
        key = "node_" + name.replace(".", "_")
        defs[key] = {
            "type": "object",
            "description": nt.summary,
            "properties": {
                "type": {"const": name},
                "params": pschema,
                "inputs": {
                    "type": "object",
                    "properties": {
                        p: {"type": ["string", "object", "null"], "description": f"{port.type}: {port.doc}"}
                        for p, port in nt.inputs.items()
                    },
                    "additionalProperties": False,
                },
                "doc": {"type": "string"},
                "on_error": {"enum": list(ON_ERROR_CHOICES)},
            },
            "required": ["type"],
            "additionalProperties": False,
        }
        variants.append({"$ref": f"#/$defs/{key}"})
    schema["properties"]["nodes"] = {
        "type": "object",
        "description": "node id -> node (null removes a base graph's node)",
        "additionalProperties": {"anyOf": [*variants, {"type": "null"}, {"$ref": "#/$defs/NodeSpec"}]},
    }
    schema["title"] = "lanegraph graph file"
    return schema
