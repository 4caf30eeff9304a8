"""Checkpoints and resuming an interrupted run (``lanegraph run ... --resume``).

A run rewrites ``OUT/checkpoint.json`` atomically (a temporary file and a rename) before its first
frame and after every frame of the selection it has consumed, done or failed. The checkpoint is
data only -- JSON, arrays as base64 with their dtype and shape, a value of another class by the
port type that stores it (:mod:`lanegraph.storage`: its ``encode`` / ``decode``, lanegraph's own
and a plugin's alike); it can never run code -- and holds:

- ``format``/``version``: what the file is (checked before anything else is read);
- what the run was: the graph file, the SHA-256 of the resolved graph (every param, ``--set``
  included) and the resolved graph itself (to name the first param that differs), the ``--input``
  path and the digest of its files (:func:`input_identity`, or the source's own ``identity()``), the
  ``--frames`` selection and how many frames it selected;
- how far it got: ``position`` (frames of the selection consumed), ``frames_ok``, the last frame,
  ``complete``, the failures so far, the per-output invalid counts;
- what the next frame needs: the values of the feedback edges (``@prev``) with their cache keys,
  and the ``state()`` of every stateful node that has one (a sink's file length and digest).

``--resume`` reads and validates it (:func:`load_checkpoint`; a malformed one is refused with the
file and field, exit code 2), refuses it unless the graph, params, input and frame selection are
those of the checkpoint (:func:`check_identity`), refuses a feedback value that its port type's
registered ``check`` refuses (:func:`check_feedback_types`), hands each stateful node its state back (the
lanes writer cuts its file back to the frames done) and continues with the next frame, so that
the final outputs equal those of an uninterrupted run however often it was interrupted. A
checkpoint of a complete run is not run again.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..errors import UsageError
from ..paths import write_bytes_atomic
from ..port_types import PORT_TYPES
from ..storage import StorageError, decode_value, digest, encode_value
from ..types import PortType

CHECKPOINT_NAME = "checkpoint.json"
LEGACY_NAME = "checkpoint.pkl"  # written by lanegraph before 0.1: never read (a pickle can run code)
FORMAT = "lanegraph-checkpoint"
#: 2: the lanes writer's state counts its frames (checked against frames_ok); 3: values are stored by
#: their port types (lanegraph.storage)
VERSION = 3
MAX_CHECKPOINT_BYTES = 1 << 30
_HINT = "; cannot resume (start over with --overwrite in place of --resume: it removes only what lanegraph wrote there; or choose another output folder)"

CheckpointValueError = StorageError  #: a value a checkpoint cannot hold, or a malformed stored one


# --------------------------------------------------------------------------- the file
class FailureRecord(BaseModel):
    """A failed frame as ``run.json`` lists it."""

    model_config = ConfigDict(extra="forbid")

    frame: str | None
    index: int = Field(ge=0)
    node: str
    type: str
    error: str


class FeedbackValue(BaseModel):
    """The value of one feedback edge's source port after the last frame done."""

    model_config = ConfigDict(extra="forbid")

    node: str
    port: str
    value: Any = None
    key: str | None = None


class Checkpoint(BaseModel):
    """The schema of ``checkpoint.json`` (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")

    format: Literal["lanegraph-checkpoint"]
    version: Literal[3]
    graph: str
    graph_digest: str = Field(pattern=r"^[0-9a-f]{64}$")
    resolved: dict[str, Any]
    input: str | None
    input_identity: str
    frames: str
    total: int | None = Field(ge=0)
    position: int = Field(ge=0)
    frames_ok: int = Field(ge=0)
    last_frame: str | None
    complete: bool
    failures: list[FailureRecord]
    invalid_outputs: dict[str, list[int]]
    feedback: list[FeedbackValue]
    states: dict[str, Any]
    unresumable: str | None = None


def graph_identity(resolved: dict[str, Any]) -> str:
    """The digest of a resolved graph (every node, type, param and wire)."""
    return digest(resolved)


def input_identity(input_path: Path | None, exclude: Path | None = None) -> str:
    """Digest of the files under ``input_path`` (path, size, modification time), ``exclude`` (the
    output folder, when it lies inside the input) left out; ``"synthetic"`` without an input."""
    if input_path is None:
        return "synthetic"
    root = Path(input_path)
    ex = exclude.resolve() if exclude is not None else None
    files = sorted(
        p for p in root.rglob("*") if p.is_file() and not (ex is not None and p.resolve().is_relative_to(ex))
    )
    return digest([(str(p), p.stat().st_size, p.stat().st_mtime_ns) for p in files])


def resolved_input(input_path: Path | None) -> str | None:
    if input_path is None:
        return None
    try:
        return str(Path(input_path).resolve())
    except (OSError, RuntimeError):
        return str(input_path)


def load_checkpoint(path: Path) -> Checkpoint:
    """Read and validate a checkpoint; any problem is a :class:`UsageError` (exit code 2) naming the
    file and the field."""
    try:
        size = path.stat().st_size
        if size > MAX_CHECKPOINT_BYTES:
            raise UsageError(
                f"{path}: {size} bytes, more than a checkpoint may hold ({MAX_CHECKPOINT_BYTES}){_HINT}"
            )
        text = path.read_text(encoding="utf-8")
    except UsageError:
        raise
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: cannot read the checkpoint ({exc}){_HINT}") from None
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        where = f" at line {exc.lineno}" if isinstance(exc, json.JSONDecodeError) else ""
        raise UsageError(f"{path}: not a valid JSON checkpoint{where} ({exc}){_HINT}") from None
    if not isinstance(data, dict):
        raise UsageError(
            f"{path}: expected a JSON object (a lanegraph checkpoint), got {type(data).__name__}{_HINT}"
        )
    if data.get("format") != FORMAT:
        raise UsageError(
            f"{path}: format: expected {FORMAT!r}, got {str(data.get('format'))[:60]!r}: not a lanegraph checkpoint{_HINT}"
        )
    if data.get("version") != VERSION:
        raise UsageError(
            f"{path}: version: expected {VERSION}, got {str(data.get('version'))[:20]} (written by another lanegraph version"
            + ("; version 3 stores values by their port types" if data.get("version") == 2 else "")
            + f"){_HINT}"
        )
    try:
        ckpt = Checkpoint.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(x) for x in err["loc"]) or "(top level)"
        more = f" (and {exc.error_count() - 1} more problem(s))" if exc.error_count() > 1 else ""
        raise UsageError(
            f"{path}: {loc}: {err['msg']}, got {str(err.get('input'))[:80]}{more}{_HINT}"
        ) from None
    if ckpt.frames_ok > ckpt.position or (ckpt.total is not None and ckpt.position > ckpt.total):
        raise UsageError(
            f"{path}: position {ckpt.position}, frames_ok {ckpt.frames_ok} and total {ckpt.total} do not fit together{_HINT}"
        )
    problem = checkpoint_problem(ckpt)
    if problem is not None:
        raise UsageError(f"{path}: {problem}: the checkpoint does not agree with itself{_HINT}")
    return ckpt


def checkpoint_problem(ckpt: Checkpoint) -> str | None:
    """The first way the fields of ``ckpt`` contradict each other, or None.

    A run writes its checkpoint after every frame it consumes, so that: a complete run consumed
    every frame of its selection; a frame consumed and not done failed (``failures`` lists at
    least one entry per such frame), at an index before ``position``; a run that did a frame
    knows the last one; an output counted invalid on at most the frames that ran; and a stateful
    node whose state counts its ``frames`` (the lanes writer: one line per frame done) saw
    exactly the frames done. The lanes writer then checks its file against its state (length,
    SHA-256, lines) when it is handed back."""
    if ckpt.complete and ckpt.total is not None and ckpt.position != ckpt.total:
        return f"complete: true, but position {ckpt.position} of {ckpt.total} frame(s)"
    if ckpt.position - ckpt.frames_ok > len(ckpt.failures):
        return (
            f"position {ckpt.position} and frames_ok {ckpt.frames_ok}: {ckpt.position - ckpt.frames_ok} "
            f"frame(s) not done, but {len(ckpt.failures)} failure(s) recorded"
        )
    late = next((f for f in ckpt.failures if f.index >= ckpt.position), None)
    if late is not None:
        return f"failures: frame index {late.index} is not before position {ckpt.position}"
    if ckpt.frames_ok and ckpt.last_frame is None:
        return f"frames_ok {ckpt.frames_ok} but no last_frame"
    for name, counts in ckpt.invalid_outputs.items():
        if not (len(counts) == 2 and 0 <= counts[0] <= counts[1] <= ckpt.position):
            return f"invalid_outputs.{name}: expected [invalid, of frames] with 0 <= invalid <= frames <= position {ckpt.position}, got {counts}"
    for nid, state in ckpt.states.items():
        if isinstance(state, dict) and "frames" in state:
            n = state["frames"]
            if not isinstance(n, int) or isinstance(n, bool) or n != ckpt.frames_ok:
                return f"states.{nid}.frames: {str(n)[:20]}, but frames_ok {ckpt.frames_ok}"
    return None


def decode_feedback(
    ckpt: Checkpoint, path: Path, port_types: Mapping[str, PortType] | None = None
) -> tuple[dict[tuple[str, str], Any], dict[tuple[str, str], str | None]]:
    """The feedback values and their cache keys of a checkpoint, decoded by the registered
    ``port_types`` (default: lanegraph's own; errors name the entry)."""
    values, keys, types = {}, {}, PORT_TYPES if port_types is None else port_types
    for i, fb in enumerate(ckpt.feedback):
        try:
            values[(fb.node, fb.port)] = decode_value(fb.value, f"feedback[{i}] ({fb.node}.{fb.port})", types)
        except CheckpointValueError as exc:
            raise UsageError(f"{path}: {exc}{_HINT}") from None
        except RecursionError:
            raise UsageError(
                f"{path}: feedback[{i}] ({fb.node}.{fb.port}): nested too deeply{_HINT}"
            ) from None
        keys[(fb.node, fb.port)] = fb.key
    return values, keys


def feedback_type_problem(
    values: dict[tuple[str, str], Any], graph: Any, types: Mapping[str, PortType]
) -> str | None:
    """The first feedback value that is not a value of its port's type, as ``"(node.port): not a
    value of port type 'lanes' (what its check says)"``, or None.

    ``types``: the registered port types by name (a plugin manager's ``port_types``: lanegraph's
    own, :mod:`lanegraph.port_types`, and every plugin's); a value is checked by its
    port type's own ``check``, or by that of its nearest ancestor through ``parent`` that has one
    (``any`` and a type without one take anything). ``None`` (a node that failed under ``on_error:
    empty``) is a value of every type; a ``check`` that raises says no."""
    for (node, port), value in values.items():
        gnode = graph.nodes.get(node)
        out = gnode.type.outputs.get(port) if gnode is not None else None
        if value is None or out is None:
            continue
        name, pt, seen = out.type, None, set()
        while name is not None and name not in seen:
            seen.add(name)
            pt = types.get(name)
            if pt is None or pt.check is not None:
                break
            name = pt.parent
        if pt is None or pt.check is None:
            continue
        try:
            problem = pt.check(value)
        except Exception as exc:  # noqa: BLE001 - a plugin's check: its failure is a refusal, located
            problem = f"port type {pt.name!r}'s check raised {type(exc).__name__}: {str(exc)[:80]}"
        if problem is not None:
            return f"({node}.{port}): not a value of port type {out.type!r} ({str(problem)[:160]})"
    return None


def check_feedback_types(
    values: dict[tuple[str, str], Any],
    graph: Any,
    path: Path,
    types: Mapping[str, PortType],
    frame: str | None = None,
) -> None:
    """Refuse (:class:`UsageError`) a feedback value read back from a checkpoint that is not a
    value of its port's type (a string where lanes belong: :func:`feedback_type_problem`), before
    any node sees it; the error names the file, the node, the port and ``frame`` (the checkpoint's
    last frame)."""
    problem = feedback_type_problem(values, graph, types)
    if problem is not None:
        node_port, _, what = problem.partition(": ")
        of = f" of frame {frame}" if frame is not None else ""
        raise UsageError(f"{path}: feedback {node_port}{of}: {what}{_HINT}")


def check_identity(
    ckpt: Checkpoint,
    path: Path,
    *,
    graph_digest: str,
    resolved: dict[str, Any],
    input: str | None,
    frames: str,
) -> None:  # noqa: A002
    """Refuse (:class:`UsageError`) a resume whose graph, params, ``--input`` or ``--frames`` are not
    the checkpoint's, naming the first difference."""
    if ckpt.unresumable:
        raise UsageError(f"{path}: the run in this folder cannot be resumed: {ckpt.unresumable}{_HINT}")
    if ckpt.graph_digest != graph_digest:
        what = _first_difference(ckpt.resolved, resolved) or "the resolved graphs differ"
        raise UsageError(
            f"{path}: the checkpoint's run used another graph or params ({what}; graph {ckpt.graph!r}){_HINT}"
        )
    if ckpt.input != input:
        raise UsageError(
            f"{path}: --input differs: the checkpoint's run read {ckpt.input or '(none: the synthetic scene)'}, "
            f"this one {input or '(none: the synthetic scene)'}{_HINT}"
        )
    if ckpt.frames != frames:
        raise UsageError(
            f"{path}: --frames differs: the checkpoint's run selected {ckpt.frames or '(all)'!s}, this one {frames or '(all)'}{_HINT}"
        )


def _first_difference(a: Any, b: Any, where: str = "") -> str | None:
    """``"nodes.fit.params.iterations: 10 in the checkpoint, 3 now"`` for the first difference."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in list(a) + [k for k in b if k not in a]:
            sub = f"{where}.{k}" if where else str(k)
            if k not in a:
                return f"{sub}: absent in the checkpoint, {str(b[k])[:60]} now"
            if k not in b:
                return f"{sub}: {str(a[k])[:60]} in the checkpoint, absent now"
            d = _first_difference(a[k], b[k], sub)
            if d:
                return d
        return None
    if a != b:
        return f"{where or 'graph'}: {str(a)[:60]} in the checkpoint, {str(b)[:60]} now"
    return None


def save_checkpoint(path: Path, data: dict[str, Any]) -> None:
    """Write a checkpoint atomically (a temporary file, then a rename: never half a file)."""
    write_bytes_atomic(path, json.dumps(data, separators=(",", ":"), allow_nan=False).encode("utf-8"))


def feedback_entries(
    values: dict[tuple[str, str], Any],
    keys: dict[tuple[str, str], str | None],
    port_types: Mapping[str, PortType] | None = None,
) -> list[dict[str, Any]]:
    """The ``feedback`` list of a checkpoint, encoded by the registered ``port_types`` (raises
    :class:`CheckpointValueError` for a value it cannot hold)."""
    types = PORT_TYPES if port_types is None else port_types
    return [
        {
            "node": n,
            "port": p,
            "value": encode_value(values[(n, p)], f"{n}.{p}", types),
            "key": keys.get((n, p)),
        }
        for (n, p) in sorted(values)
    ]
