"""Graph files: the pydantic format, ``extends`` resolution and ``--set`` overrides (whole-graph
validation: :mod:`lanegraph.graph.validation`).

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, StringConstraints, field_validator

from ..builtin import builtin_base
from ..errors import GraphError, Problem, did_you_mean
from ..nodes import NodeParams, NodeType
from ..plugins import PluginManager, get_plugin_manager
from .loader import read_graph_file

#: a node's error policy: ``fail`` stops the run, ``skip`` drops the frame, ``empty`` passes None on
ON_ERROR_CHOICES = ("fail", "skip", "empty")
#: the most graph files one ``extends`` chain may hold (the graph itself included)
MAX_EXTENDS = 32
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

    def carried_state(self) -> str | None:
        """What outlives a frame, as text: the feedback edges (``node.port@prev``) and the stateful
        nodes other than the source and the sinks; None when nothing does (a chunked run of such a
        graph may differ from a whole run: :mod:`lanegraph.batches.batch` says so)."""
        feedback = sorted({f"{e.src_node}.{e.src_port}@prev" for e in self.edges if e.previous})
        stateful = sorted(
            nid for nid, n in self.nodes.items() if n.type.stateful and not n.type.source and not n.type.sink
        )
        parts = [f"feedback edge(s) {', '.join(feedback)}"] if feedback else []
        parts += [f"stateful node(s) {', '.join(stateful)}"] if stateful else []
        return "; ".join(parts) or None

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
    if len(chain) + 1 >= MAX_EXTENDS:
        files = [*chain, path.resolve(), base_path]
        shown = [*map(str, files[:2]), "...", *map(str, files[-2:])]
        raise problem(
            f"an extends chain of more than {MAX_EXTENDS} files ({' -> '.join(shown)}): "
            "extend a graph that extends fewer"
        )
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


def load_raw(
    path: str | Path, sets: list[str] | None = None, roots: list[Path] | None = None
) -> tuple[dict[str, Any], dict[str, str], str]:
    """Load a graph file with ``extends`` and ``--set`` applied, not yet validated."""
    p = Path(path)
    display = str(path)
    raw, origin = _resolve(p, display, (), roots)
    _apply_sets(raw, list(sets or []), origin)
    return raw, origin, display


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
