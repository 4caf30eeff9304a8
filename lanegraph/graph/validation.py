"""Whole-graph validation: the graph format first, then a chain of named passes (node types,
wiring, the source, sinks, feedback edges, order), each on what the earlier ones established; one
:class:`~lanegraph.errors.GraphError` lists every problem with its file, node id and field."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from ..errors import GraphError, Problem, did_you_mean
from ..nodes import NodeParams, NodeType
from ..paths import output_fields, output_problems
from ..plugins import PluginManager, get_plugin_manager
from ..types import port_compatible
from .model import _REF, Edge, Graph, GraphNode, GraphSpec, InputSpec, NodeSpec, _loc_str, _short, load_raw


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
