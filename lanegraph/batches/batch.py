"""Batches: runs planned as tasks (:mod:`lanegraph.run.task`), run one after another in this process or
in parallel by another runner (:mod:`lanegraph.batches.runners`: on a Dask cluster, say), with the
same outputs byte for byte, and finished (chunks merged, folders of runs that could not start
written, leftovers removed).

A unit of work (:class:`~lanegraph.run.task.RunTask`) is one graph on one sequence: the executor sees every frame of the
sequence in order, so feedback edges (``@prev``) and stateful nodes behave as in ``lanegraph run``.
With ``chunk_frames`` a sequence is split into chunks of that many frames, each run after up to
``warmup`` frames before it whose outputs are discarded (the sinks do not see them); the chunks'
outputs are concatenated in order.

A task of a batch writes into a temporary folder renamed into place when it ends (see
:mod:`lanegraph.run.task`), so workers need the data, the cache folder and lanegraph with the
graphs' plugins, not the graph files.

Nothing here imports Dask: without a scheduler a batch runs in this process.
"""

from __future__ import annotations

import re
import shutil
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import GraphError, InputError, NodeError, UsageError
from ..frames import selection_text
from ..graph.files import ResolvedGraph
from ..plugins import PluginManager
from ..records.record import Provenance, RunRecord, read_record, write_run_files
from ..records.resume import input_identity
from ..run.cache import ResultCache, digest
from ..run.outcome import RunResult
from ..run.sources import chosen_params, close_source, open_source, select_source
from ..run.task import (
    RunTask,
    TaskOutcome,
    chunks_dir,
    error_record,
    merge_chunks,
    place_dir,
    task_record,
    tmp_dir,
)
from ..runlog import progress_bar


# --------------------------------------------------------------------------- planning
def count_frames(
    graph: ResolvedGraph, input_path: Path | None, frames: slice | None, pm: PluginManager
) -> int | None:
    """The number of frames the graph's source delivers for this input and selection (``None``
    when the source cannot tell); opens the source only. Raises what opening it raises: an
    :class:`~lanegraph.errors.InputError` for an unusable input (no frames, no calibration ...)."""
    g = graph.validate(pm)
    src = g.source
    nt = select_source(pm, src.type, src.params, input_path, file=g.file, node=src.id)
    params = src.params if nt is src.type else chosen_params(nt, src.params, file=g.file, node=src.id)
    inst = open_source(nt, params, input_path, frames, src.id)  # with the params the run gives it
    try:
        return len(inst) if "len" in nt.capabilities else None
    finally:
        close_source(inst, nt)


def _as_slice(r: range) -> slice:
    stop: int | None = r.stop
    if r.step < 0 and r.stop < 0:
        stop = None
    return slice(r.start, stop, r.step)


def chunk_selections(
    n_input: int, selection: slice | None, chunk_frames: int, warmup: int
) -> list[tuple[slice, int, int, int]]:
    """Split the frames ``selection`` picks out of ``n_input`` into chunks of ``chunk_frames``;
    per chunk ``(slice over the input's frames, warm-up frames, first reported position, frames
    reported)``; the slice starts ``warm-up`` frames before the chunk (fewer for the first)."""
    picked = range(n_input)[selection if selection is not None else slice(None)]
    out = []
    for start in range(0, len(picked), chunk_frames):
        end = min(start + chunk_frames, len(picked))
        w = min(warmup, start)
        out.append((_as_slice(picked[start - w : end]), w, start, end - start))
    return out


@dataclass
class BatchRun:
    """One run of a batch (:meth:`lanegraph.service.Session.run_tasks`): ``graph`` (a variant) on a
    sequence's ``input`` (``None``: the synthetic scene) and ``frames``, into ``run_dir``;
    ``variant`` names it in messages (``None`` for ``run --dataset``); ``provenance``: how it is
    made (its run.json says it); ``debug_dir``: its ``--debug-dir`` folder."""

    variant: str | None
    sequence: str
    graph: ResolvedGraph
    input: Path | None
    frames: slice | None
    run_dir: Path
    provenance: Provenance | None = None
    debug_dir: Path | None = None


@dataclass
class Planned:
    """A run (a graph on a sequence) of a batch: its tasks, or none when it is reused (``record``:
    the reused run's) or could not start (``outcome``: why)."""

    variant: str | None
    sequence: str
    run_dir: Path
    tasks: list[RunTask] = field(default_factory=list)
    reused: bool = False
    outcome: TaskOutcome | None = None
    record: RunRecord | None = None  # its run.json once it ran (or could not start), or the reused one's
    in_place: bool = False


def reusable(run_dir: Path, run_key: str) -> RunRecord | None:
    """The record of an earlier run in ``run_dir`` that this run would repeat (its ``run_key.txt``
    is ``run_key``: the same resolved graph, input files, frames and node code), else None."""
    stamp = run_dir / "run_key.txt"
    try:
        if not stamp.is_file() or stamp.read_text() != run_key:
            return None
    except OSError:
        return None
    record = read_record(run_dir)
    return record if record is not None and record.timings is not None else None


class Planner:
    """Turns (graph, sequence) runs into tasks: counts each run's frames (opening only its source,
    so an unusable input is found before anything runs) and splits it into chunks. ``reuse``: a
    run whose earlier result is in its folder (:func:`reusable`) is not run again."""

    def __init__(
        self,
        pm: PluginManager,
        chunk_frames: int | None = None,
        warmup: int = 0,
        cache: ResultCache | None = None,
        *,
        reuse: bool = False,
        verbose: bool = False,
    ):
        if chunk_frames is not None and chunk_frames < 1:
            raise UsageError(f"--chunk-frames: expected an integer >= 1, got {chunk_frames}")
        if warmup < 0:
            raise UsageError(f"--warmup: expected an integer >= 0, got {warmup}")
        if warmup and chunk_frames is None:
            raise UsageError(
                "--warmup is the number of frames run before each chunk: give --chunk-frames too"
            )
        self.pm = pm
        self.chunk_frames = chunk_frames
        self.warmup = warmup
        self.cache = cache
        self.reuse = reuse
        self.verbose = verbose
        self.tasks: list[RunTask] = []
        #: what the command says before the runs start (a graph whose state outlives the warm-up)
        self.warnings: list[str] = []
        self._counts: dict[str, int | None] = {}
        self._inputs: dict[str, str] = {}

    def _count(self, graph: ResolvedGraph, input_path: Path | None, frames: slice | None) -> int | None:
        g = graph.validate(self.pm)
        key = digest(g.resolved_dict()["nodes"][g.source.id], str(input_path), str(frames))
        if key not in self._counts:
            self._counts[key] = count_frames(graph, input_path, frames, self.pm)
        return self._counts[key]

    def run_key(self, graph: ResolvedGraph, input_path: Path | None, frames: slice | None) -> str:
        """What makes a run of a batch the same run again: the resolved graph, the input's files,
        the frames, the node types' code (an edited plugin runs again) and the chunking."""
        g = graph.validate(self.pm)
        if str(input_path) not in self._inputs:
            self._inputs[str(input_path)] = input_identity(input_path)
        code = sorted({n.type.code_version for n in g.nodes.values()})
        key = digest(g.resolved_dict(), self._inputs[str(input_path)], str(frames), code)
        return key if self.chunk_frames is None else digest(key, "chunks", self.chunk_frames, self.warmup)

    def _carried_state_note(self, graph: ResolvedGraph, chunks: list[tuple]) -> str | None:
        """What the graph carries from frame to frame (feedback edges, stateful nodes between source
        and sinks), said before the runs start and in each run.json, when a chunk's warm-up does not
        reach back to the selection's first frame: its lanes may differ from a whole run's. None
        for a graph that carries nothing or ``chunks`` that all start there (one chunk, a long
        enough warm-up): those are the whole run's frames from the whole run's state."""
        whole = all(warm == start for _, warm, start, _ in chunks)
        what = None if whole else graph.validate(self.pm).carried_state()
        if what is None:
            return None
        note = (
            f"{graph.display}: the graph carries state from frame to frame ({what}); a chunk of "
            f"{self.chunk_frames} frame(s) starts from {self.warmup} warm-up frame(s), not from the start of "
            "its sequence, so its lanes may differ from those of a whole run (more --warmup brings them closer; "
            "benchmarks/bench_distributed.py --chunk-sweep measures it)"
        )
        if note not in self.warnings:
            self.warnings.append(note)
        return note

    def add(
        self,
        variant: str | None,
        sequence: str,
        graph: ResolvedGraph,
        input_path: Path | None,
        frames: slice | None,
        run_dir: Path,
        *,
        provenance: Provenance | None = None,
        in_place: bool = False,
        resume: bool = False,
        identity: dict[str, Any] | None = None,
        debug_dir: Path | None = None,
        subscribers: tuple[Any, ...] = (),
    ) -> Planned:
        """Plan the run of ``graph`` on a sequence into ``run_dir`` (``in_place``: the user's own
        folder, written as the run goes and checkpointed; ``resume``: continued after its checkpoint)."""
        cache = self.cache
        run_key = None if in_place else self.run_key(graph, input_path, frames)
        plan = Planned(variant, sequence, run_dir, in_place=in_place)
        if run_key is not None and self.reuse:
            plan.record = reusable(run_dir, run_key)
            if plan.record is not None:
                plan.reused = True
                return plan
        common = {
            "variant": variant,
            "sequence": sequence,
            "graph": graph,
            "input": str(input_path) if input_path is not None else None,
            "run_dir": str(run_dir),
            "cache_dir": str(cache.root.resolve()) if cache is not None else None,
            "cache_max_bytes": cache.max_bytes if cache is not None else 0,
            "record_cache": cache is not None,
            "provenance": provenance,
            "identity": identity,
            "selection": selection_text(frames),
            "run_key": run_key,
            "in_place": in_place,
            "resume": resume,
            "debug_dir": str(debug_dir) if debug_dir is not None else None,
            "subscribers": subscribers,
            "verbose": self.verbose,
        }
        try:
            n = self._count(graph, input_path, frames)
        except (InputError, NodeError, GraphError) as exc:  # this run cannot start: the others still run
            task = RunTask(-1, frames=frames, **common)
            plan.outcome = TaskOutcome(-1, RunResult(), error_record(task, exc, "open"), exception=exc)
            return plan
        if self.chunk_frames is None:
            plan.tasks.append(RunTask(len(self.tasks), frames=frames, total=n, **common))
        else:
            n_input = self._count(graph, input_path, None)
            if n is None or n_input is None:
                raise UsageError(
                    f"--chunk-frames: the source of {graph.display} cannot tell how many frames {input_path} has"
                )
            chunks = chunk_selections(n_input, frames, self.chunk_frames, self.warmup)
            note = self._carried_state_note(graph, chunks)
            for k, (sel, w, start, count) in enumerate(chunks):
                plan.tasks.append(
                    RunTask(
                        len(self.tasks) + k,
                        frames=sel,
                        total=count,
                        chunk=k,
                        warmup=w,
                        offset=start,
                        notes=(note,) if note else (),
                        **common,
                    )
                )
        self.tasks += plan.tasks
        return plan


# --------------------------------------------------------------------------- running
class Progress:
    """One progress bar over a batch: frames done of all frames, across workers. A task run again
    after its worker died starts its count anew."""

    def __init__(self, tasks: list[RunTask], enabled: bool = True, desc: str = "frames"):
        self.tasks = {t.index: t for t in tasks}
        total = sum(t.total or 0 for t in tasks)
        self._done: dict[int, tuple[str, int]] = {}
        self._finished = 0
        self._lock = threading.Lock()
        self.bar = progress_bar(total or None, desc, enabled=enabled)
        self._postfix()

    def _postfix(self) -> None:
        self.bar.set_postfix_str(f"{self._finished}/{len(self.tasks)} runs", refresh=False)

    def update(self, index: int, attempt: str, done: int) -> None:
        with self._lock:
            self._done[index] = (attempt, done)
            self.bar.n = sum(d for _, d in self._done.values())
            self.bar.refresh()

    def finish(self, index: int, frames: int) -> None:
        with self._lock:
            self._done[index] = ("done", frames)
            self._finished += 1
            self.bar.n = sum(d for _, d in self._done.values())
            self._postfix()
            self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


def clean_leftovers(run_dir: Path, in_place: bool = False) -> None:
    """Remove what tasks on ``run_dir`` left behind: temporary folders of tasks whose worker died,
    replaced folders, chunk folders (of a run in place: only its own chunk folder, inside it)."""
    if in_place:
        shutil.rmtree(chunks_dir(run_dir, True), ignore_errors=True)
        return
    parent = run_dir.parent
    if not parent.is_dir():
        return
    ours = re.compile(
        rf"\.{re.escape(run_dir.name)}\.(tmp-\d+-[0-9a-f]{{8}}|old-[0-9a-f]{{8}}|chunks)"
    )  # exactly the names tmp_dir, place_dir and chunks_dir give: a user's ".NAME.tmp-notes" is not ours
    for p in parent.iterdir():
        if ours.fullmatch(p.name) and p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)


def finish_runs(plans: list[Planned], outcomes: dict[int, TaskOutcome], partial: bool = False) -> None:
    """Give every planned run its outcome and record (merging chunked runs; a run of a batch that
    could not start gets a folder with its run.json), and remove what killed tasks left. ``partial``:
    after an interruption, only the runs whose tasks all ended."""
    for plan in plans:
        if plan.reused:
            continue
        if not plan.tasks:  # could not start: its outcome was set by the planner
            assert plan.outcome is not None
            if not plan.in_place:  # the user's own folder gets nothing from a run that did not start
                tmp = tmp_dir(plan.run_dir)
                tmp.mkdir(parents=True)
                plan.record = task_record(None, RunResult(), plan.outcome.error, timings={})
                write_run_files(tmp, plan.record, {})
                place_dir(tmp, plan.run_dir)
        elif any(t.index not in outcomes for t in plan.tasks):
            if not partial:
                raise KeyError(f"no outcome for a task of {plan.tasks[0].label}")
            clean_leftovers(plan.run_dir, plan.in_place)
            continue
        elif plan.tasks[0].chunk is not None:
            plan.outcome = merge_chunks(plan.tasks, [outcomes[t.index] for t in plan.tasks])
        else:
            plan.outcome = outcomes[plan.tasks[0].index]
        clean_leftovers(plan.run_dir, plan.in_place)
        if plan.tasks:
            # the record the run wrote; or, its workers having kept dying, one of its outcome
            plan.record = plan.outcome.record or task_record(
                None, plan.outcome.result, plan.outcome.error, timings={}
            )


@dataclass
class Batch:
    """A batch that ran: every planned run with its outcome and record; ``interrupted``: the
    interruption (Ctrl-C, SIGTERM, SIGHUP) that stopped it, the runs that ended kept."""

    plans: list[Planned]
    interrupted: BaseException | None = None


def run_planned(
    plans: list[Planned], tasks: list[RunTask], runner: Any, *, progress: bool = True, echo: Any = None
) -> Batch:
    """Run the planned runs' ``tasks`` on ``runner`` and finish them (:func:`finish_runs`); an
    interruption keeps the runs that ended (the others leave nothing) and is returned, not raised."""
    for plan in plans:
        if not plan.reused:
            clean_leftovers(plan.run_dir, plan.in_place)
    done: dict[int, TaskOutcome] = {}
    try:
        outcomes = runner.run(tasks, progress=progress, echo=echo, done=done)
    except KeyboardInterrupt as exc:
        finish_runs(plans, done, partial=True)
        return Batch(plans, exc)
    finish_runs(plans, outcomes)
    return Batch(plans)
