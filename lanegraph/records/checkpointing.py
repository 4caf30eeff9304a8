"""The checkpoint piece of a run: what ``lanegraph run`` keeps after every frame and what
``--resume`` continues from (the file format and its checks: :mod:`lanegraph.records.resume`).

A :class:`Checkpointer` is handed to the executor (``checkpointer=``): it checks a checkpoint to resume against the graph, params, input and frame selection before
anything opens, against the opened source and hands the stateful nodes their states after the
nodes open (:meth:`Checkpointer.resume_nodes`), and writes the checkpoint after every frame
consumed (:meth:`Checkpointer.write`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import InputError, LanegraphError, UsageError
from ..frames import selection_text
from ..types import PortType
from .record import read_record
from .results import LANES, find_result
from .resume import (
    _HINT,
    CHECKPOINT_NAME,
    FORMAT,
    LEGACY_NAME,
    VERSION,
    Checkpoint,
    CheckpointValueError,
    check_feedback_types,
    check_identity,
    decode_feedback,
    feedback_entries,
    feedback_type_problem,
    graph_identity,
    load_checkpoint,
    resolved_input,
    save_checkpoint,
)


@dataclass(frozen=True)
class OpenedInput:
    """What the opened source says about its input: its identity and how many frames it holds."""

    identity: str
    total: int | None


def run_identity(graph: Any, context: Any) -> dict[str, Any]:
    """What a checkpoint's run is: its graph (resolved, with its digest), input and frame selection;
    taken before a selecting source is replaced: what the user's graph says."""
    resolved = graph.resolved_dict()
    return {
        "graph": graph.file,
        "graph_digest": graph_identity(resolved),
        "resolved": resolved,
        "input": resolved_input(context.input_path),
        "frames": selection_text(context.frames),
    }


class Checkpointer:
    """Keeps the checkpoint of one run in ``path`` (``None``: none kept), resuming ``resume``.

    ``port_types``: the registered port types (a plugin manager's ``port_types``; default: the
    installed plugins'): every feedback value read back from ``resume`` must pass its port type's
    ``check`` (:func:`~lanegraph.records.resume.check_feedback_types`), a plugin's port type's too,
    before anything opens."""

    def __init__(
        self,
        graph: Any,
        context: Any,
        path: Path | None,
        resume: Checkpoint | None = None,
        identity: dict[str, Any] | None = None,
        port_types: Mapping[str, PortType] | None = None,
    ):
        self.path = path
        self.resume = resume
        self.unresumable: str | None = None
        self.identity = identity if identity is not None else run_identity(graph, context)
        self.resumed_feedback: tuple[dict, dict] = ({}, {})
        if port_types is None:
            from ..plugins import get_plugin_manager

            port_types = get_plugin_manager().port_types
        self.graph, self.port_types = graph, port_types
        if resume is not None:
            where = self.where
            check_identity(resume, where, **{k: v for k, v in self.identity.items() if k != "graph"})
            if context.skip != resume.position:
                raise UsageError(
                    f"{where}: the run context skips {context.skip} frame(s), the checkpoint has done {resume.position}"
                )
            sources = {(e.src_node, e.src_port) for e in graph.edges if e.previous}
            for i, fb in enumerate(resume.feedback):
                if (fb.node, fb.port) not in sources:
                    raise UsageError(
                        f"{where}: feedback[{i}]: no feedback edge of the graph comes from {fb.node}.{fb.port}{_HINT}"
                    )
            # a malformed value: refused before anything opens
            self.resumed_feedback = decode_feedback(resume, where, port_types)
            # lanes are lanes, not a string: checked by the registered port types, a plugin's too
            check_feedback_types(self.resumed_feedback[0], graph, where, port_types, resume.last_frame)

    @property
    def where(self) -> Path:
        return self.path or Path("checkpoint")

    def resume_nodes(self, graph: Any, instances: dict[str, Any], opened: OpenedInput) -> None:
        """Resuming: the input checked against the checkpoint's, and every node that declares ``resume``
        handed its checkpointed state (a :class:`UsageError` or the node's
        :class:`InputError` when that is not possible)."""
        ck = self.resume
        if ck is None:
            return
        where = self.where
        if ck.input_identity != opened.identity:
            raise UsageError(
                f"{where}: the input files changed since the checkpoint (another file, size or modification time){_HINT}"
            )
        if ck.total is not None and opened.total is not None and opened.total != ck.total:
            raise UsageError(
                f"{where}: the frame selection now has {opened.total} frame(s), the checkpoint's run had {ck.total}{_HINT}"
            )
        for nid, inst in instances.items():
            if "resume" in graph.nodes[nid].type.capabilities:
                try:
                    inst.restore(ck.states.get(nid))
                except LanegraphError:
                    raise
                except Exception as exc:  # noqa: BLE001
                    n = graph.nodes[nid]
                    raise InputError(
                        f"node '{nid}' ({n.type.name}): cannot restore its checkpointed state: {type(exc).__name__}: {exc}",
                        path=str(where),
                    ) from exc

    def write(
        self,
        result: Any,
        instances: dict[str, Any],
        position: int,
        frame: str | None,
        previous: dict,
        prev_keys: dict,
        opened: OpenedInput,
        complete: bool = False,
    ) -> None:
        """After a frame is consumed (done -- its sinks have written -- or failed): how far the run
        got, its failures, the values of the feedback edges and the stateful nodes' states, so that
        a resumed run continues exactly where this one stopped (:mod:`lanegraph.records.resume`)."""
        assert self.path is not None
        feedback: list[dict[str, Any]] = []
        if self.unresumable is None:
            # a value off its port type's contract would be refused by --resume: said now
            problem = feedback_type_problem(previous, self.graph, self.port_types)
            reason = None if problem is None else f"frame {frame}: feedback {problem}"
            try:
                feedback = feedback_entries(previous, prev_keys, self.port_types)
            except CheckpointValueError as exc:
                reason = f"a feedback value cannot be stored ({exc})"
            if reason is not None:
                self.unresumable, feedback = reason, []
                result.notes.append(f"--resume will not be possible for this run: {self.unresumable}")
        nodes = self.graph.nodes
        states = {
            nid: inst.state() for nid, inst in instances.items() if "resume" in nodes[nid].type.capabilities
        }
        data = {
            "format": FORMAT,
            "version": VERSION,
            **self.identity,
            "input_identity": opened.identity,
            "total": opened.total,
            "position": position,
            "frames_ok": result.frames,
            "last_frame": None if frame is None else str(frame),
            "complete": complete,
            "failures": [f.to_json() for f in result.failures],
            "invalid_outputs": result.invalid_outputs,
            "feedback": feedback,
            "states": states,
            "unresumable": self.unresumable,
        }
        try:
            save_checkpoint(self.path, data)
        except ValueError as exc:  # a state that JSON cannot hold (a plugin's)
            self.unresumable = f"a node's state cannot be stored ({exc})"
            data.update(states={}, feedback=[], unresumable=self.unresumable)
            result.notes.append(f"--resume will not be possible for this run: {self.unresumable}")
            save_checkpoint(self.path, data)


def checkpoint_for(out_dir: Path, resume: bool) -> tuple[Checkpoint | None, Path]:
    """The checkpoint to resume (with ``resume``, when OUT has one; validated) and where the run
    keeps its own; a checkpoint of an older lanegraph is never read."""
    checkpoint = out_dir / CHECKPOINT_NAME
    legacy = out_dir / LEGACY_NAME
    try:
        if resume and legacy.is_file() and not checkpoint.is_file():
            raise UsageError(
                f"{legacy}: a checkpoint of an older lanegraph (a pickle, which could run code); it is never read; "
                "cannot resume (start over with --overwrite in place of --resume: it removes only what lanegraph wrote there; or choose another output folder)"
            )
        # (a checkpoint.pkl of an older lanegraph is left where it is: never read, never removed by name)
        if checkpoint.exists() and not checkpoint.is_file():
            raise UsageError(f"{checkpoint}: exists and is not a file (lanegraph keeps its checkpoint there)")
        if resume and checkpoint.is_file():
            return load_checkpoint(checkpoint), checkpoint
        if not resume:
            checkpoint.unlink(missing_ok=True)
    except OSError as exc:
        raise UsageError(f"{out_dir}: {exc.strerror or exc}") from None
    return None, checkpoint


def resumed_frame_ids(out_dir: Path, ckpt: Checkpoint) -> list[str]:
    """The ids of the frames an interrupted run consumed before it is resumed (``ckpt.position``
    of them): its record's when it wrote one that far, else those of its lanes file and its failures."""
    record = read_record(out_dir)
    if record is not None and record.selection is not None and len(record.selection.ids) == ckpt.position:
        return list(record.selection.ids)
    ids: list[str] = []
    lanes = find_result(out_dir, LANES)
    if lanes is not None:
        try:
            ids = [
                str(json.loads(line).get("frame")) for line in lanes.read_text().splitlines() if line.strip()
            ]
        except Exception:  # noqa: BLE001 - an unreadable lanes file: the resume itself refuses it
            ids = []
    failed = [str(f.frame) for f in ckpt.failures if f.frame is not None]
    return list(dict.fromkeys([*ids, *failed]))
