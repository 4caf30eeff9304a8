"""``lanegraph run --dataset``: plan -> runner -> finish over the sequences of a dataset
(:meth:`lanegraph.service.Session.run_dataset`), through :meth:`Session.run_tasks` like ``ablate``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .. import interrupts
from ..batches.batch import BatchRun
from ..errors import LanegraphError, NotStarted
from ..graph.files import ResolvedGraph
from ..records.folder import check as check_folder
from ..tracking import CommandRecord as TrackedCommand
from .keeping import command_kept, dataset_identity, dataset_writes, debug_frames_option, tracked_run


def run_dataset(
    session: Any,
    graph: ResolvedGraph,
    dataset: Any,
    out_dir: Path,
    *,
    frames: slice | None = None,
    runner: Any = None,
    chunk_frames: int | None = None,
    warmup: int = 0,
    resume: bool = False,
    debug_dir: Path | None = None,
    debug_frames: str | None = None,
) -> int:
    """See :meth:`lanegraph.service.Session.run_dataset`. ``resume``: a sequence whose folder holds
    its finished run already is not run again; ``debug_frames``: ``--debug-frames`` as given."""
    chosen = debug_frames_option(debug_frames)
    g = graph.validate(session.pm)  # a GraphError before anything runs
    identity = dataset_identity("dataset", [g.name], dataset, frames)
    writes = dataset_writes(dataset)
    check_folder(out_dir, identity, overwrite=session.overwrite, writes=writes)
    made = session.provenance(g.file, list(graph.sets))
    runs = [
        BatchRun(None, seq.name, graph, seq.input, seq.frames if seq.frames is not None else frames,
                 out_dir / seq.name, made, debug_dir / seq.name if debug_dir is not None else None)
        for seq in dataset
    ]  # fmt: skip
    try:
        with interrupts.handling(), session.locked(out_dir, "run", (debug_dir, "--debug-dir")):
            tracked = TrackedCommand("run", f"run {g.name} --dataset -> {out_dir}", out_dir, list(made.command),
                                     {"graph": str(g.file), "frames": identity["frames"] or "all"})  # fmt: skip

            def keep(final: bool) -> None:  # command.json, written once
                if not final:
                    session.keep_command(out_dir, "dataset", made, identity, [s.name for s in dataset])

            with command_kept(session, out_dir, identity, writes, tracked, keep):
                batch = session.run_tasks(runs, runner, chunk_frames=chunk_frames, warmup=warmup,
                                          reuse=resume, debug_frames=chosen)  # fmt: skip
    except LanegraphError as exc:  # a usage error, an unusable input found before any frame ran
        if exc.exit_code == 2:
            raise
        raise NotStarted(exc) from exc
    if batch.interrupted is not None:
        session.tracking.end("interrupted")
        raise session.stopped(
            batch.interrupted, f"the finished sequences are in {out_dir}; continue with --resume"
        )
    status = _say(session, batch.plans, out_dir)
    if session.tracking.started:
        for seq, plan in zip(dataset, batch.plans):
            session.tracking.log_run(
                tracked_run(g, plan.run_dir, seq.name, seq.gt, list(graph.sets), plan.record)
            )
        session.tracking.end("failed" if status else "ok", [])
    return status if session.tracking.ok else max(status, 1)


def _say(session: Any, plans: list[Any], out_dir: Path) -> int:
    """A line per sequence, the failed frames and errors; 0, 1 when a frame failed or a sequence
    stopped, 2 when no sequence could start."""
    from ..run.task import describe_error

    status = 0
    not_started = 0
    for plan in plans:
        record = plan.record
        if plan.reused:
            session.out(
                f"{plan.sequence}: {record.frames_ok} frame(s) -> {plan.run_dir} (kept from the run before)"
            )
            continue
        out = plan.outcome
        error = out.error if out is not None else None
        started = error is None or not error.get("before_any_frame")
        files = [str(plan.run_dir / f) for f in (record.results.values() if started and record else [])]
        line = f"{plan.sequence}: {out.result.frames} frame(s) -> {', '.join(files) or plan.run_dir}"
        if not started:
            line = f"{plan.sequence}: not run (see {plan.run_dir}/run.json)"
            not_started += 1
        if out.result.failures:
            line += f", {len(out.result.failures)} frame(s) failed"
            status = 1
        session.out(line)
        for f in out.result.failures:
            session.err(f"  frame {f.frame} (#{f.index}): node '{f.node_id}' ({f.node_type}): {f.error}")
        if error is not None:
            session.err(f"error: {describe_error(error)}")
            status = 1
    if plans and not_started == len(plans):
        status = 2  # nothing ran at all: the inputs are unusable
    return status
