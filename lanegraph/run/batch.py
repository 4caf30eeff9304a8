"""Batch runs: graphs over the sequences of a dataset as independent units of work, run one after
another in this process or in parallel on a Dask cluster (:mod:`lanegraph.run.distributed`), with the
same outputs byte for byte.

A unit of work (:class:`RunTask`) is one graph on one sequence: the executor sees every frame of the
sequence in order, so feedback edges (``@prev``) and stateful nodes behave as in ``lanegraph run``.
With ``chunk_frames`` a sequence is split into chunks of that many frames, each run after up to
``warmup`` frames before it whose outputs are discarded (the sinks do not see them); the chunks'
outputs are concatenated in order.

A task writes into a temporary folder beside its run folder (``.<name>.tmp-<pid>-<id>``) and renames
it into place when it ends, so a task that is run again after its worker died never duplicates or
mixes lines, and a reader never sees half a run. The graph travels with the task as its resolved
dict (``extends`` and ``--set`` applied), so workers need the data, the cache folder and lanegraph
with the graphs' plugins, not the graph files.

Nothing here imports Dask: without a scheduler a batch runs in this process.
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import GraphError, InputError, LanegraphError, NodeError, UsageError
from ..frames import selection_text
from ..graph.files import ResolvedGraph
from ..nodes import RunContext
from ..plugins import PluginManager, get_plugin_manager
from ..runlog import RunLog, progress_bar
from .cache import Caching, ResultCache, digest
from .executor import Executor, FrameFailure, RunResult
from .provenance import refreshed, write_resolved_graph
from .record import RunRecord, Stopped, read_record, write_run_files
from .sources import close_source, open_source, select_source
from .warmup import WarmUp

_SCHEDULER = re.compile(r"^local(?::(?P<n>[^:]*))?$")


@dataclass(frozen=True)
class SchedulerSpec:
    """Where a batch runs: ``None`` in this process, ``local`` (``workers`` processes on this
    machine, ``None``: one per core) or ``address`` (an existing Dask scheduler)."""

    text: str
    workers: int | None = None
    address: str | None = None

    @property
    def local(self) -> bool:
        return self.address is None


def parse_scheduler(text: str | None) -> SchedulerSpec | None:
    """``--scheduler``: absent -> ``None`` (in this process); ``local`` or ``local:N``; anything else
    is a scheduler address for ``distributed.Client`` (``tcp://HOST:PORT``, ``tls://...``, a
    scheduler file ``*.json``). Raises :class:`~lanegraph.errors.UsageError` saying what was
    expected."""
    if text is None:
        return None
    text = text.strip()
    if not text:
        raise UsageError(
            "--scheduler: expected local, local:N or a scheduler address such as tcp://HOST:8786, got ''"
        )
    m = _SCHEDULER.match(text)
    if m:
        n = m.group("n")
        if n is None:
            return SchedulerSpec(text)
        if not n.isdigit() or int(n) < 1:
            raise UsageError(
                f"--scheduler {text}: expected local:N with N a number of worker processes >= 1, got {n!r}"
            )
        return SchedulerSpec(text, workers=int(n))
    return SchedulerSpec(text, address=text)


@dataclass
class RunTask:
    """One unit of work: a graph on a sequence (or on a chunk of one)."""

    index: int
    variant: str | None  # None for ``lanegraph run``
    sequence: str
    graph: ResolvedGraph
    input: str | None
    frames: slice | None  # the RunContext's selection
    run_dir: str
    cache_dir: str | None = None
    cache_max_bytes: int = 0
    run_key: str | None = None
    total: int | None = None  # frames this task reports (without warm-up)
    chunk: int | None = None
    warmup: int = 0  # frames run before the reported ones
    offset: int = 0  # the sequence index of the first reported frame
    record_cache: bool = False  # timings.json gets the cache's hits and misses
    record_extra: dict[str, Any] = field(default_factory=dict)  # what the run service adds to run.json
    notes: tuple[str, ...] = ()  # warnings for the run's run.json (a chunked run's carried state)
    selection: str = ""  # the run's --frames text (a chunk's task too: the run's, not the chunk's)

    @property
    def label(self) -> str:
        where = f"{self.variant} / {self.sequence}" if self.variant is not None else self.sequence
        return where if self.chunk is None else f"{where} (chunk {self.chunk})"


@dataclass
class TaskOutcome:
    """What a task did. ``error``: why it stopped (``variant``, ``sequence``, ``frame``, ``node``,
    ``message``, ``input`` -- whether the input was at fault)."""

    index: int
    result: RunResult = field(default_factory=RunResult)
    error: dict[str, Any] | None = None
    wall_s: float = 0.0
    worker: str | None = None
    placed: bool = True  # whether the task put its folder in place (not when its workers kept dying)


# --------------------------------------------------------------------------- one task
_CACHES: dict[tuple[str, int], ResultCache] = {}
_CACHES_LOCK = threading.Lock()


def shared_cache(root: str, max_bytes: int) -> ResultCache:
    """The process's :class:`ResultCache` on ``root`` (one per process, so its folder is scanned once)."""
    with _CACHES_LOCK:
        key = (str(root), int(max_bytes))
        if key not in _CACHES:
            _CACHES[key] = ResultCache(root, max_bytes)
        return _CACHES[key]


def _tmp_dir(dest: Path) -> Path:
    return dest.parent / f".{dest.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def place_dir(tmp: Path, dest: Path) -> None:
    """Rename the folder ``tmp`` to ``dest``, replacing a folder already there (a previous run, or
    the same task finished twice): ``dest`` holds one whole run at any time it exists."""
    olds = []
    try:
        for _ in range(20):
            try:
                os.rename(tmp, dest)
                return
            except OSError as exc:
                if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                    raise
            old = dest.parent / f".{dest.name}.old-{uuid.uuid4().hex[:8]}"
            try:
                os.rename(dest, old)
                olds.append(old)
            except FileNotFoundError:
                pass
        raise OSError(f"{dest}: could not be replaced (renamed by another process 20 times)")
    finally:
        for old in olds:
            shutil.rmtree(old, ignore_errors=True)


def clean_leftovers(run_dir: Path) -> None:
    """Remove what tasks on ``run_dir`` left behind: temporary folders of tasks whose worker died,
    replaced folders, chunk folders."""
    parent = run_dir.parent
    if not parent.is_dir():
        return
    for pattern in (f".{run_dir.name}.tmp-*", f".{run_dir.name}.old-*", f".{run_dir.name}.chunks"):
        for p in parent.glob(pattern):
            shutil.rmtree(p, ignore_errors=True)


def chunks_dir(run_dir: Path) -> Path:
    return run_dir.parent / f".{run_dir.name}.chunks"


def _error_record(task: RunTask, exc: BaseException) -> dict[str, Any]:
    cause = getattr(exc, "cause", None)
    return {
        "variant": task.variant,
        "sequence": task.sequence,
        "frame": getattr(exc, "frame", None),
        "node": getattr(exc, "node_id", None),
        "message": str(exc) if isinstance(exc, LanegraphError) else f"{type(exc).__name__}: {exc}",
        "input": isinstance(exc, InputError) or isinstance(cause, InputError),
    }


def task_record(
    graph_file: str | None,
    input_path: str | None,
    result: RunResult,
    error: dict[str, Any] | None = None,
    timings: dict[str, Any] | None = None,
    **extra: Any,
) -> RunRecord:
    """The :class:`~lanegraph.run.record.RunRecord` of a task's run (``error``: the task's error
    record, when it stopped)."""
    stop = Stopped(error=error["message"], node=error["node"], frame=error["frame"]) if error else None
    before = bool(error.get("before_any_frame")) if error is not None else False
    return RunRecord.of(result, graph=graph_file, input=input_path, stopped=stop, timings=timings,
                        before_any_frame=before, **extra)  # fmt: skip


def _write_run_files(
    folder: Path, task: RunTask, result: RunResult, error: dict[str, Any] | None, graph_file: str | None
) -> None:
    timings = result.timings_json()
    if task.record_cache:
        timings["cache"] = {"hits": result.cache_hits, "misses": result.cache_misses}
    extra = refreshed(task.record_extra, get_plugin_manager())  # the versions of what the run loaded
    record = task_record(
        graph_file, task.input, result, error, timings, sequence=task.sequence, frames=task.selection, **extra
    )
    write_run_files(folder, record, timings)
    if task.run_key is not None and error is None:
        (folder / "run_key.txt").write_text(task.run_key)


def execute_task(
    task: RunTask,
    cache: ResultCache | None = None,
    progress: Callable[[int], None] | None = None,
    pm: PluginManager | None = None,
) -> TaskOutcome:
    """Run ``task`` (in this process) and put its folder in place; never raises for a failure of
    the run: the outcome says where it stopped. ``progress(n)`` is called with the number of frames
    done after each frame. ``cache``: the cache to use (default: the task's ``cache_dir``)."""
    t0 = time.perf_counter()
    pm = pm or get_plugin_manager()
    run_dir = Path(task.run_dir)
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_dir(run_dir)
    tmp.mkdir()
    ex: Executor | None = None
    error = None
    graph_file = task.graph.display
    result = RunResult()
    done = 0
    started = False

    def on_frame(index: int, frame: str | None) -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done)

    try:
        g = task.graph.validate(pm)
        graph_file = g.file
        if cache is None and task.cache_dir:
            cache = shared_cache(task.cache_dir, task.cache_max_bytes)
        ctx = RunContext(
            input_path=Path(task.input) if task.input else None,
            out_dir=tmp,
            frames=task.frames,
            graph_file=g.file,
        )
        if task.chunk is None:  # the resolved graph beside the run's results (a chunk's: the run's)
            write_resolved_graph(tmp, g.resolved_dict())
        ex = Executor(g, ctx, pm, caching=cache and Caching(cache), warming=WarmUp(task.warmup))
        with ex, RunLog(tmp, pm=pm):  # the nodes opened are closed, however the run ends
            started = True
            result = ex.run(on_frame=on_frame)
    except Exception as exc:  # noqa: BLE001 - reported with variant, sequence and frame; the others go on
        error = _error_record(task, exc)
        error["before_any_frame"] = not started
        result = (ex.result if ex is not None else None) or RunResult()
    shift = task.offset - task.warmup  # executor indices count from the first warm-up frame
    if shift:
        result.failures = [
            FrameFailure(f.frame, f.index + shift, f.node_id, f.node_type, f.error) for f in result.failures
        ]
    if task.chunk is None:
        _write_run_files(tmp, task, result, error, graph_file)
        place_dir(tmp, run_dir)
    else:
        chunks = chunks_dir(run_dir)
        chunks.mkdir(exist_ok=True)
        place_dir(tmp, chunks / f"{task.chunk:06d}")
    return TaskOutcome(task.index, result, error, round(time.perf_counter() - t0, 3))


def merge_chunks(tasks: list[RunTask], outcomes: list[TaskOutcome]) -> TaskOutcome:
    """Put a chunked run's folder together: every file of the chunk folders, in chunk order (a file
    several chunks wrote, such as the lanes, is their concatenation), ``timings.json`` and
    ``run.json`` over all chunks."""
    first = tasks[0]
    run_dir = Path(first.run_dir)
    src = chunks_dir(run_dir)
    tmp = _tmp_dir(run_dir)
    tmp.mkdir()
    merged = RunResult(notes=list(first.notes))
    error = None
    for task, out in sorted(zip(tasks, outcomes), key=lambda p: p[0].chunk or 0):
        folder = src / f"{task.chunk:06d}"
        for f in sorted(p for p in folder.rglob("*") if p.is_file()) if folder.is_dir() else []:
            dest = tmp / f.relative_to(folder)
            dest.parent.mkdir(parents=True, exist_ok=True)
            with f.open("rb") as fin, dest.open("ab") as fout:
                shutil.copyfileobj(fin, fout)
        r = out.result
        merged.frames += r.frames
        merged.node_types.update(r.node_types)
        merged.results = merged.results or dict(r.results)
        for nid, ts in r.timings_ms.items():
            merged.timings_ms.setdefault(nid, []).extend(ts)
        merged.failures += r.failures
        merged.frame_ids += r.frame_ids
        merged.frame_ms += r.frame_ms
        for src_counts, dst_counts in (
            (r.cache_hits, merged.cache_hits),
            (r.cache_misses, merged.cache_misses),
        ):
            for nid, k in src_counts.items():
                dst_counts[nid] = dst_counts.get(nid, 0) + k
        if out.error is not None and error is None:
            error = out.error
    _write_run_files(tmp, first, merged, error, first.graph.display)
    place_dir(tmp, run_dir)
    shutil.rmtree(src, ignore_errors=True)
    return TaskOutcome(first.index, merged, error, round(sum(o.wall_s for o in outcomes), 3))


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
    inst = open_source(nt, src.params if nt is src.type else nt.params(), input_path, frames, src.id)
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
class Planned:
    """A run (a graph on a sequence) of a batch: its tasks, or none when it is reused."""

    variant: str | None
    sequence: str
    run_dir: Path
    tasks: list[RunTask] = field(default_factory=list)
    reused: bool = False
    outcome: TaskOutcome | None = None
    record: RunRecord | None = None  # its run.json once it ran (or could not start)


class Planner:
    """Turns (graph, sequence) runs into tasks: counts each run's frames (opening only its source,
    so an unusable input is found before anything runs) and splits it into chunks."""

    def __init__(
        self,
        pm: PluginManager,
        chunk_frames: int | None = None,
        warmup: int = 0,
        cache: ResultCache | None = None,
        record_extra: dict[str, Any] | None = None,
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
        self.record_extra = dict(record_extra or {})
        self.tasks: list[RunTask] = []
        #: what the command says before the runs start (a graph whose state outlives the warm-up)
        self.warnings: list[str] = []
        self._counts: dict[str, int | None] = {}

    def _count(self, graph: ResolvedGraph, input_path: Path | None, frames: slice | None) -> int | None:
        g = graph.validate(self.pm)
        key = digest(g.resolved_dict()["nodes"][g.source.id], str(input_path), str(frames))
        if key not in self._counts:
            self._counts[key] = count_frames(graph, input_path, frames, self.pm)
        return self._counts[key]

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
        run_key: str | None = None,
    ) -> Planned:
        """Plan the run of ``graph`` on a sequence into ``run_dir``."""
        cache = self.cache
        common = {
            "variant": variant,
            "sequence": sequence,
            "graph": graph,
            "input": str(input_path) if input_path is not None else None,
            "run_dir": str(run_dir),
            "cache_dir": str(cache.root.resolve()) if cache is not None else None,
            "cache_max_bytes": cache.max_bytes if cache is not None else 0,
            "record_cache": cache is not None,
            "record_extra": self.record_extra,
            "selection": selection_text(frames),
        }
        plan = Planned(variant, sequence, run_dir)
        try:
            n = self._count(graph, input_path, frames)
        except (InputError, NodeError, GraphError) as exc:  # this run cannot start: the others still run
            task = RunTask(-1, frames=frames, **common)
            error = _error_record(task, exc)
            error["before_any_frame"] = True
            plan.outcome = TaskOutcome(-1, RunResult(), error)
            return plan
        if self.chunk_frames is None:
            plan.tasks.append(RunTask(len(self.tasks), frames=frames, run_key=run_key, total=n, **common))
        else:
            n_input = self._count(graph, input_path, None)
            if n is None or n_input is None:
                raise UsageError(
                    f"--chunk-frames: the source of {graph.display} cannot tell how many frames {input_path} has"
                )
            key = None if run_key is None else digest(run_key, "chunks", self.chunk_frames, self.warmup)
            chunks = chunk_selections(n_input, frames, self.chunk_frames, self.warmup)
            note = self._carried_state_note(graph, chunks)
            for k, (sel, w, start, count) in enumerate(chunks):
                plan.tasks.append(
                    RunTask(
                        len(self.tasks) + k,
                        frames=sel,
                        run_key=key,
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


def finish_runs(plans: list[Planned], outcomes: dict[int, TaskOutcome], partial: bool = False) -> None:
    """Give every planned run its outcome and record (merging chunked runs; a run that could not
    start gets a folder with its run.json), and remove what killed tasks left. ``partial``: after an
    interruption, only the runs whose tasks all ended."""
    for plan in plans:
        if plan.reused:
            plan.record = None
            continue
        if not plan.tasks:  # could not start: its outcome was set by the planner
            assert plan.outcome is not None
            tmp = _tmp_dir(plan.run_dir)
            tmp.mkdir(parents=True)
            record = task_record(None, None, RunResult(), plan.outcome.error, {})
            write_run_files(tmp, record, {})
            place_dir(tmp, plan.run_dir)
        elif any(t.index not in outcomes for t in plan.tasks):
            if not partial:
                raise KeyError(f"no outcome for a task of {plan.tasks[0].label}")
            clean_leftovers(plan.run_dir)
            continue
        elif plan.tasks[0].chunk is not None:
            plan.outcome = merge_chunks(plan.tasks, [outcomes[t.index] for t in plan.tasks])
        else:
            plan.outcome = outcomes[plan.tasks[0].index]
        clean_leftovers(plan.run_dir)
        if not plan.outcome.placed:  # its workers kept dying: the folder (if any) is an older run's
            plan.record = task_record(None, None, plan.outcome.result, plan.outcome.error, {})
            continue
        plan.record = read_record(plan.run_dir) or task_record(
            None, None, plan.outcome.result, plan.outcome.error, {}
        )


def describe_error(error: dict[str, Any]) -> str:
    """``variant / sequence: frame F: message`` for a failed run."""
    where = (
        f"{error['variant']} / {error['sequence']}"
        if error.get("variant") is not None
        else f"{error['sequence']}"
    )
    frame = (
        f"frame {error['frame']}: "
        if error.get("frame") is not None and f"frame {error['frame']}" not in error["message"]
        else ""
    )
    return f"{where}: {frame}{error['message']}"
