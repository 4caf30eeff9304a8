"""One run, whatever asks for it: a :class:`RunTask` run by :func:`execute_task`, the one place an
:class:`~lanegraph.run.executor.Executor` is built (:func:`build_executor`) and a run's record
(:func:`task_record`; a test asserts that no other module builds either).

A task is one graph on one input: ``lanegraph run`` on one input (written in place into OUT,
checkpointed), a sequence of ``run --dataset``, a variant on a sequence of ``ablate``, or a chunk
of any of them. Runners (:mod:`lanegraph.batches.runners`) only decide where it runs (``task.execute()``). What a run keeps
beside its frames subscribes to its events (:class:`Subscriber`, as Hamilton's lifecycle adapters):
the checkpoint, the debug pictures, ``run.log``; its record is kept when it ends (:func:`keep_record`).

A task not written in place writes into a temporary folder beside its run folder renamed into place
when it ends, so a task run again after its worker died never duplicates or mixes lines, and a
reader never sees half a run. The graph travels as its resolved dict, validated once where it runs.
"""

from __future__ import annotations

import errno
import os
import shutil
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import HookError, InputError, LanegraphError, UsageError
from ..graph.files import ResolvedGraph
from ..graph.model import Graph
from ..nodes import RunContext
from ..paths import relative_inside
from ..plugins import PluginManager, get_plugin_manager
from ..records.checkpointing import Checkpointer, checkpoint_for, resumed_frame_ids
from ..records.owned import seal
from ..records.provenance import versions, write_resolved_graph
from ..records.record import Provenance, RunRecord, Stopped, write_run_files
from ..records.resume import Checkpoint
from ..runlog import RunLog, get_logger
from .cache import Caching, ResultCache
from .executor import Executor
from .outcome import FrameFailure, RunResult
from .warmup import WarmUp


class Subscriber:
    """What a run's events reach (Hamilton's lifecycle adapters): ``pieces`` (the executor's
    pieces it adds, before the executor is built), ``started`` (the nodes opened, before the first
    frame), ``ended`` (the executor closed, however the run ended; before the record is built)."""

    def pieces(self, task: RunTask, g: Graph, ctx: RunContext) -> dict[str, Any]:
        return {}

    def started(self, task: RunTask, ex: Executor, folder: Path) -> None:
        pass

    def ended(self, task: RunTask, result: RunResult) -> None:
        pass


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
    provenance: Provenance | None = None  # how the run is made (its run.json says it)
    identity: dict[str, Any] | None = None  # what makes it this run (lanegraph run: its folder's claim)
    notes: tuple[str, ...] = ()  # warnings for the run's run.json (a chunked run's carried state)
    selection: str = ""  # the run's --frames text (a chunk's task too: the run's, not the chunk's)
    in_place: bool = False  # written into run_dir itself, checkpointed (lanegraph run)
    resume: bool = False  # continue the run in run_dir after its checkpoint (in place only)
    debug_dir: str | None = None  # --debug-dir (recorded in run.json)
    subscribers: tuple[Subscriber, ...] = ()  # what else its events reach (--debug-dir's pictures)
    verbose: bool = False  # run.log records the details too

    @property
    def label(self) -> str:
        where = f"{self.variant} / {self.sequence}" if self.variant is not None else self.sequence
        return where if self.chunk is None else f"{where} (chunk {self.chunk})"

    def execute(
        self, cache: ResultCache | None = None, progress: Callable[[int], None] | None = None
    ) -> TaskOutcome:
        """Run this task here: :func:`execute_task`, what a runner calls in this process or in a worker."""
        return execute_task(self, cache=cache, progress=progress)

    def failed(self, message: str) -> TaskOutcome:
        """The outcome of this task when its runner could not run it (its workers kept dying, it could
        not be sent): ``message`` says why; exit code 1, not the input's fault."""
        return TaskOutcome(self.index, error={
            "variant": self.variant, "sequence": self.sequence, "frame": None, "node": None,
            "message": message, "input": False, "before_any_frame": False, "stage": "run", "exit_code": 1,
        })  # fmt: skip


@dataclass
class TaskOutcome:
    """What a task did. ``error``: why it stopped (``variant``, ``sequence``, ``frame``, ``node``,
    ``message``, ``input`` -- whether the input was at fault --, ``before_any_frame``, ``stage``:
    ``build``, ``open`` or ``run``, ``exit_code``); ``record``: the run.json it wrote (None for a
    chunk); ``outputs``: the files its sinks wrote."""

    index: int
    result: RunResult = field(default_factory=RunResult)
    error: dict[str, Any] | None = None
    wall_s: float = 0.0
    worker: str | None = None
    record: RunRecord | None = None
    outputs: list[str] = field(default_factory=list)
    unwritten: str | None = None  # why run.json could not be written (a full disk)
    complete: Checkpoint | None = None  # --resume of a run that was complete: nothing ran
    exception: BaseException | None = field(default=None, repr=False)  # in this process only

    def __getstate__(self) -> dict[str, Any]:  # an exception may not travel back from a worker
        return {**self.__dict__, "exception": None}


# --------------------------------------------------------------------------- folders
_CACHES: dict[tuple[str, int], ResultCache] = {}
_CACHES_LOCK = threading.Lock()


def shared_cache(root: str, max_bytes: int) -> ResultCache:
    """The process's :class:`ResultCache` on ``root`` (one per process, so its folder is scanned once)."""
    with _CACHES_LOCK:
        key = (str(root), int(max_bytes))
        if key not in _CACHES:
            _CACHES[key] = ResultCache(root, max_bytes)
        return _CACHES[key]


def tmp_dir(dest: Path) -> Path:
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


def chunks_dir(run_dir: Path, in_place: bool = False) -> Path:
    """Where a chunked run's chunks are kept until they are merged: inside a folder written in place
    (the user's), beside a run folder of a batch."""
    return run_dir / ".lanegraph-chunks" if in_place else run_dir.parent / f".{run_dir.name}.chunks"


# --------------------------------------------------------------------------- run events
class Checkpointing(Subscriber):
    """The checkpoint of a run written in place: the one it resumes (checked against the graph,
    input and frames before anything opens) and the one it keeps after every frame."""

    def __init__(self, folder: Path, resume: bool, pm: PluginManager):
        self.ckpt, self.path = checkpoint_for(folder, resume)
        self.resumed_ids = resumed_frame_ids(folder, self.ckpt) if self.ckpt is not None else []
        self.pm = pm

    def skip(self) -> int:
        return self.ckpt.position if self.ckpt is not None else 0

    def pieces(self, task, g, ctx):
        return {"checkpointer": Checkpointer(g, ctx, self.path, self.ckpt, port_types=self.pm.port_types)}


class Logging(Subscriber):
    """``run.log`` in the run's folder while it runs (continued by a resumed run)."""

    def __init__(self, pm: PluginManager):
        self.pm = pm
        self.log: RunLog | None = None

    def started(self, task, ex, folder):
        self.log = RunLog(folder, append=task.resume, verbose=task.verbose, pm=self.pm).__enter__()
        command = task.provenance.command if task.provenance is not None else []
        get_logger("run").info(
            "run of %s on %s into %s: %s", ex.graph.file, task.input or "the synthetic scene", task.run_dir,
            " ".join(command), extra={"file_only": True},
        )  # fmt: skip

    def ended(self, task, result):
        if self.log is not None:
            self.log.__exit__(None, None, None)
            self.log = None


class Sealing(Subscriber):
    """A run in place: what it wrote is recorded as lanegraph's once it has started (a killed run's
    files are known as lanegraph's: :func:`lanegraph.records.owned.seal`)."""

    def started(self, task, ex, folder):
        seal(folder, final=False)


def subscribers(task: RunTask, pm: PluginManager, cache: ResultCache | None) -> list[Subscriber]:
    """What a task's run events reach, from what the task asks for."""
    subs: list[Subscriber] = []
    if task.in_place and task.chunk is None:
        subs.append(Checkpointing(Path(task.run_dir), task.resume, pm))
    subs += [*task.subscribers, Logging(pm)]
    if task.in_place and task.chunk is None:
        subs.append(Sealing())
    return subs


# --------------------------------------------------------------------------- one task
def error_record(task: RunTask, exc: BaseException, stage: str) -> dict[str, Any]:
    """What stopped ``task``: where, why and whether its input was at fault."""
    cause = getattr(exc, "cause", None)
    if isinstance(exc, KeyboardInterrupt):
        from .. import interrupts

        label, code = interrupts.label_and_code(exc)
        message = f"interrupted ({label}); continue with --resume"
    elif isinstance(exc, HookError) and isinstance(exc.cause, UsageError):  # --debug-dir's, say: exit 2
        message, code = str(exc.cause), 2
    elif isinstance(exc, OSError) and not isinstance(exc, LanegraphError):
        message, code = f"{str(exc.filename) + ': ' if exc.filename else ''}{exc.strerror or exc}", 1
    else:
        message = str(exc) if isinstance(exc, LanegraphError) else f"{type(exc).__name__}: {exc}"
        code = exc.exit_code if isinstance(exc, LanegraphError) else 1
    return {
        "variant": task.variant,
        "sequence": task.sequence,
        "frame": getattr(exc, "frame", None),
        "node": getattr(exc, "node_id", None),
        "message": message,
        "input": isinstance(exc, InputError) or isinstance(cause, InputError),
        "before_any_frame": stage != "run",
        "stage": stage,
        "exit_code": code,
    }


def task_record(
    task: RunTask | None,
    result: RunResult,
    error: dict[str, Any] | None,
    graph_file: str | None = None,
    timings: dict[str, Any] | None = None,
    written: list[str] | None = None,
    frame_ids: list[str] | None = None,
    pm: PluginManager | None = None,
) -> RunRecord:
    """The one builder of a run's :class:`~lanegraph.records.record.RunRecord` (``task``: None for a
    run known only by its outcome)."""
    stop = Stopped(error=error["message"], node=error["node"], frame=error["frame"]) if error else None
    made = task.provenance if task is not None else None
    if made is not None and made.versions:  # at the end: the libraries the run loaded (ONNX Runtime ...)
        made = made.model_copy(update={"versions": versions(pm or get_plugin_manager())})
    debug = (
        relative_inside(Path(task.debug_dir), Path(task.run_dir))
        if task is not None and task.debug_dir
        else None
    )
    return RunRecord.of(
        result,
        graph=graph_file,
        input=task.input if task is not None else None,
        sequence=task.sequence if task is not None and not task.in_place else None,
        stopped=stop,
        timings=timings,
        before_any_frame=bool(error.get("before_any_frame")) if error is not None else False,
        frames=task.selection if task is not None else None,
        frame_ids=frame_ids,
        provenance=made,
        identity=task.identity if task is not None else None,
        debug_dir=debug,
        written=written,
    )  # fmt: skip


def keep_record(
    folder: Path,
    task: RunTask,
    result: RunResult,
    error: dict[str, Any] | None,
    graph_file: str | None,
    written: list[str],
    frame_ids: list[str] | None = None,
    pm: PluginManager | None = None,
) -> tuple[RunRecord, str | None]:
    """Write the task's ``timings.json`` and ``run.json`` into ``folder`` (and ``run_key.txt``);
    the record, and why it could not be written (None when it was)."""
    timings = result.timings_json()
    if task.record_cache:
        timings["cache"] = {"hits": result.cache_hits, "misses": result.cache_misses}
    record = task_record(task, result, error, graph_file, timings, written, frame_ids, pm)
    try:
        write_run_files(folder, record, timings)
        if task.run_key is not None and error is None:
            (folder / "run_key.txt").write_text(task.run_key)
    except OSError as exc:
        return record, f"cannot write {folder}/run.json and timings.json: {exc.strerror or exc}"
    return record, None


def build_executor(g: Graph, ctx: RunContext, pm: PluginManager, **pieces: Any) -> Executor:
    """The one place an :class:`~lanegraph.run.executor.Executor` is made (its pieces: checkpoint,
    cache, warm-up, prefetch)."""
    return Executor(g, ctx, pm, **pieces)


def run_graph(
    graph: Graph, context: RunContext | None = None, pm: PluginManager | None = None, **pieces: Any
) -> RunResult:
    """Run a validated graph once, outside any task (the conformance check of :mod:`lanegraph.testing`)."""
    return build_executor(graph, context or RunContext(), pm or get_plugin_manager(), **pieces).run()


def execute_task(
    task: RunTask,
    cache: ResultCache | None = None,
    progress: Callable[[int], None] | None = None,
    pm: PluginManager | None = None,
) -> TaskOutcome:
    """Run ``task`` (in this process) and keep its folder; never raises for a failure of the run --
    the outcome says where it stopped -- but an interruption (Ctrl-C, SIGTERM, SIGHUP) is raised
    again once the record of what was done is written. ``progress(n)`` is called with the number
    of frames done after each frame. ``cache``: the cache to use (default: the task's ``cache_dir``)."""
    t0 = time.perf_counter()
    pm = pm or get_plugin_manager()
    run_dir = Path(task.run_dir)
    if task.chunk is not None:
        chunks = chunks_dir(run_dir, task.in_place)
        chunks.mkdir(parents=True, exist_ok=True)
        dest: Path | None = chunks / f"{task.chunk:06d}"
        folder = tmp_dir(dest)
    elif task.in_place:
        dest, folder = None, run_dir
    else:
        dest, folder = run_dir, tmp_dir(run_dir)
    folder.mkdir(parents=True, exist_ok=task.in_place and task.chunk is None)
    if cache is None and task.cache_dir:
        cache = shared_cache(task.cache_dir, task.cache_max_bytes)
    ex: Executor | None = None
    out = TaskOutcome(task.index)
    graph_file, stage, done = task.graph.display, "build", 0
    subs: list[Subscriber] = []
    ckpt: Checkpointing | None = None

    log = get_logger("run")

    def on_frame(index: int, frame: str | None) -> None:
        nonlocal done
        done += 1
        log.debug("frame %s (#%d) done", frame, index)  # -v: on the terminal and in run.log
        if progress is not None:
            progress(done)

    interrupted: BaseException | None = None
    try:
        g = task.graph.validate(pm)
        graph_file = g.file
        subs = subscribers(task, pm, cache)
        ckpt = next((s for s in subs if isinstance(s, Checkpointing)), None)
        ctx = RunContext(
            input_path=Path(task.input) if task.input else None, out_dir=folder, frames=task.frames,
            graph_file=g.file, extra={"resume": ckpt is not None and ckpt.ckpt is not None},
            skip=ckpt.skip() if ckpt is not None else 0,
        )  # fmt: skip
        pieces: dict[str, Any] = {"caching": cache and Caching(cache), "warming": WarmUp(task.warmup)}
        for s in subs:
            pieces.update(s.pieces(task, g, ctx))
        ex = build_executor(g, ctx, pm, **pieces)
        stage = "open"
        with ex:  # the nodes opened are closed, however the run ends
            if ckpt is not None and ckpt.ckpt is not None and ckpt.ckpt.complete:
                out.complete = ckpt.ckpt  # its input and outputs are still the checkpoint's: nothing runs
                return out
            if task.chunk is None:  # the resolved graph beside the run's results (a chunk's: the run's)
                write_resolved_graph(folder, g.resolved_dict())
            for s in subs:
                s.started(task, ex, folder)
            stage = "run"
            out.result = ex.run(on_frame=on_frame)
    except KeyboardInterrupt as exc:  # recorded (a run in place continues with --resume), then raised again
        interrupted = exc
        out.error = error_record(task, exc, stage)
    except Exception as exc:  # noqa: BLE001 - reported with variant, sequence and frame; the others go on
        out.error = error_record(task, exc, stage)
        out.exception = exc
    finally:
        for s in reversed(subs):
            try:
                s.ended(task, (ex.result if ex is not None else None) or out.result)
            except Exception:  # noqa: BLE001 - a subscriber's end must not hide the run's own
                pass
    if out.error is not None:
        out.result = (ex.result if ex is not None else None) or RunResult()
    result = out.result
    shift = task.offset - task.warmup  # executor indices count from the first warm-up frame
    if shift:
        result.failures = [
            FrameFailure(f.frame, f.index + shift, f.node_id, f.node_type, f.error) for f in result.failures
        ]
    outputs = ex.outputs() if ex is not None and ex.instances else []
    out.outputs = [str(p) for p in outputs]
    started = ex is not None and ex.result is not None
    if task.chunk is None and (started or not task.in_place):  # the user's folder: only a run that started
        written = sorted({w for p in outputs if (w := relative_inside(Path(p), folder)) is not None})
        ids = [*ckpt.resumed_ids, *result.frame_ids] if ckpt is not None and ckpt.resumed_ids else None
        out.record, out.unwritten = keep_record(folder, task, result, out.error, graph_file, written, ids, pm)
    if dest is not None and interrupted is not None:
        shutil.rmtree(folder, ignore_errors=True)  # a run folder of a batch holds a whole run or none
    elif dest is not None:
        place_dir(folder, dest)
    out.wall_s = round(time.perf_counter() - t0, 3)
    if interrupted is not None:
        raise interrupted
    return out


def merge_chunks(tasks: list[RunTask], outcomes: list[TaskOutcome]) -> TaskOutcome:
    """Put a chunked run's folder together: every file of the chunk folders, in chunk order (a file
    several chunks wrote, such as the lanes, is their concatenation), ``timings.json`` and
    ``run.json`` over all chunks."""
    first = tasks[0]
    run_dir = Path(first.run_dir)
    src = chunks_dir(run_dir, first.in_place)
    folder = run_dir if first.in_place else tmp_dir(run_dir)
    folder.mkdir(parents=True, exist_ok=first.in_place)
    merged = RunResult(notes=list(first.notes))
    error = None
    written: set[str] = set()
    for task, out in sorted(zip(tasks, outcomes), key=lambda p: p[0].chunk or 0):
        chunk = src / f"{task.chunk:06d}"
        for f in sorted(p for p in chunk.rglob("*") if p.is_file()) if chunk.is_dir() else []:
            dest = folder / f.relative_to(chunk)
            dest.parent.mkdir(parents=True, exist_ok=True)
            mode = "wb" if str(f.relative_to(chunk)) not in written and first.in_place else "ab"
            written.add(str(f.relative_to(chunk)))
            with f.open("rb") as fin, dest.open(mode) as fout:
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
    names = sorted(written - {"run.log"})
    write_resolved_graph(folder, first.graph.validate().resolved_dict())  # the run's, beside its results
    record, unwritten = keep_record(folder, first, merged, error, first.graph.display, names)
    if not first.in_place:
        place_dir(folder, run_dir)
    shutil.rmtree(src, ignore_errors=True)
    wall = round(sum(o.wall_s for o in outcomes), 3)
    return TaskOutcome(first.index, merged, error, wall, record=record, unwritten=unwritten,
                       outputs=[str(run_dir / n) for n in names])  # fmt: skip


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
