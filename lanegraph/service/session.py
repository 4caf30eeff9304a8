"""The run service: the one path by which a command runs graphs.

A :class:`Session` (in the manner of Kedro's ``KedroSession.run(runner=...)``) loads a graph
(:func:`lanegraph.graph.files.open_graph`), locks the output folder, opens the nodes, runs the
frames, checkpoints and writes the record (:mod:`lanegraph.run.record`, its one writer).
``lanegraph run``, ``run --dataset``, ``ablate`` and ``report`` call it; what executes a batch's
units of work is a runner object (:mod:`lanegraph.run.runners`), chosen by ``--scheduler``.

It says what it does through ``out`` (results: stdout) and ``err`` (progress, warnings, errors:
stderr). Failures are raised once, as typed errors (:class:`~lanegraph.errors.LanegraphError` and
its kinds, :class:`~lanegraph.errors.NotStarted`, :class:`~lanegraph.errors.RunStopped`), each with
its exit code; what ran returns its status (0, or 1 when frames or runs failed). The command line
maps errors to exit codes in one place (:mod:`lanegraph.cli._errors`).

Extension points kept here for every command alike: :attr:`Session.record_extra` (fields every
``run.json`` of the session gets: the command line, overrides, versions), :meth:`Session.locked`
(the output folder's lock), and the interruption of a run by Ctrl-C, SIGTERM or SIGHUP
(:class:`~lanegraph.errors.RunStopped` with exit code 130, 143 or 129 after the record of what was
done is written; :mod:`lanegraph.interrupts`).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .. import interrupts
from ..errors import HookError, InputError, LanegraphError, NotStarted, RunStopped, UsageError
from ..frames import selection_text
from ..graph.files import ResolvedGraph, load_graph_named, open_graph
from ..graph.model import Graph
from ..nodes import RunContext
from ..paths import OutputLock, prepare_dir
from ..plugins import PluginManager, get_plugin_manager
from ..run.checkpointing import Checkpointer
from ..run.executor import Executor, RunResult
from ..run.folder import check as check_folder
from ..run.folder import claim as claim_folder
from ..run.folder import seal as seal_folder
from ..run.provenance import command_line, versions, write_resolved_graph
from ..run.record import RunRecord, read_record, stopped_by, write_run_files
from ..runlog import RunLog, get_logger, progress_bar
from ..tracking import CommandRecord, Tracking
from .keeping import (
    dataset_identity,
    dataset_writes,
    provenance,
    relative_inside,
    run_writes,
    single_identity,
    tracked_dataset_run,
    tracked_single_run,
    write_command_record,
)
from .single import checkpoint_for, resumed_frame_ids

if TYPE_CHECKING:  # the batch modules load only for a batch: `lanegraph run` on one input keeps its start-up
    from ..run.runners import Runner


def _stdout(msg: str) -> None:
    print(msg, flush=True)


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


class Session:
    """Runs graphs for one command: ``session.run(graph, ...)``, ``session.run_dataset(...)``,
    ``session.ablate(...)``, ``session.report(...)``."""

    def __init__(
        self,
        pm: PluginManager | None = None,
        *,
        out: Callable[[str], None] | None = None,
        err: Callable[[str], None] | None = None,
        progress: bool = True,
        record_extra: dict[str, Any] | None = None,
        overwrite: bool = False,
        tracking: Tracking | None = None,
        verbose: int = 0,
    ):
        self.pm = pm or get_plugin_manager()
        self.out = out or _stdout
        self.err = err or _stderr
        self.progress = progress
        #: fields every run.json this session writes gets besides the run's own
        self.record_extra: dict[str, Any] = dict(record_extra or {})
        #: ``--overwrite``: a folder holding another run's results is cleared of lanegraph's files
        self.overwrite = overwrite
        #: ``--track``: the experiment tracker the runs are sent to (none: nothing is tracked)
        self.tracking = tracking if tracking is not None else Tracking(None)
        #: ``-v``: run.log records the details too
        self.verbose = verbose
        self._run_extra: dict[str, Any] = {}
        self._resumed_ids: list[str] = []
        self._frames: slice | None = None
        self._ex: Executor | None = None
        #: what a run does once its input is open (before that, nothing is written into OUT)
        self._on_open: Callable[[], None] | None = None
        self._stack = ExitStack()

    # -- graphs, folders, runners ------------------------------------------------
    def warn_plugins(self) -> None:
        """Each plugin that could not be loaded, as a warning line (every command says so, once)."""
        for e in self.pm.plugin_errors:
            self.err(f"warning: {e}")

    @staticmethod
    def open_graph(name: str | Path, sets: tuple[str, ...] | list[str] = ()) -> ResolvedGraph:
        """The graph ``name`` with ``sets`` applied (not yet validated)."""
        return open_graph(name, sets)

    def load_graph(self, name: str | Path, sets: tuple[str, ...] | list[str] = ()) -> Graph:
        """The graph ``name`` with ``sets`` applied, validated against the installed plugins."""
        return load_graph_named(name, sets, self.pm)

    def runner(self, scheduler: str | None, cache: Any = None) -> Runner:
        """The runner of ``--scheduler`` (:func:`lanegraph.run.runners.select_runner`)."""
        from ..run.runners import select_runner

        return select_runner(scheduler, self.pm, cache)

    @contextmanager
    def locked(self, out_dir: Path, command: str, *also: tuple[Path | None, str]) -> Iterator[OutputLock]:
        """``out_dir`` (and the other folders ``also``: ``(folder, option)``) checked and created,
        and ``out_dir`` locked while the block runs (one run at a time writes a folder)."""
        prepare_dir(out_dir, "--out")
        for folder, option in also:
            if folder is not None:
                prepare_dir(folder, option)
        lock = OutputLock(out_dir, command).acquire()
        try:
            yield lock
        finally:
            lock.release()

    # -- lanegraph run ---------------------------------------------------------------
    def run(
        self,
        graph: ResolvedGraph,
        *,
        input_path: Path | None,
        out_dir: Path,
        frames: slice | None = None,
        resume: bool = False,
        debug_dir: Path | None = None,
        debug_frames: str | None = None,
        make_report: bool = False,
    ) -> int:
        """``lanegraph run``: the graph on one input into ``out_dir``; 0, or 1 when frames failed.
        Raises :class:`NotStarted` for an input, checkpoint or folder unusable before any frame,
        :class:`RunStopped` when the run stopped (its record written), a :class:`GraphError`."""
        g = graph.validate(self.pm)
        if input_path is not None and not input_path.exists():
            raise UsageError(f"--input {input_path}: no such file or folder")
        chosen = None
        if debug_frames is not None:
            chosen = {item.strip() for item in debug_frames.split(",") if item.strip()}
            if not chosen:
                raise UsageError(
                    f"--debug-frames {debug_frames!r}: expected frame ids or indices, comma-separated"
                )
        resolved = g.resolved_dict()
        identity = single_identity(resolved, input_path, frames)
        # another run's results are refused before anything is written (the folder left as it was)
        writes = run_writes(g, out_dir, debug_dir, make_report)
        check_folder(
            out_dir, identity, resume=resume, overwrite=self.overwrite, resolved=resolved, writes=writes
        )
        sets = list(getattr(graph, "sets", ()) or ())
        self._run_extra = {
            **provenance(self.pm, g.file, sets),
            "identity": identity,
            "debug_dir": relative_inside(debug_dir, out_dir),
        }
        tracked = "interrupted"

        def opened() -> None:  # the input and nodes opened: the run will start; nothing written before
            try:
                self.tracking.start(
                    CommandRecord("run", f"run {g.name} -> {out_dir}", out_dir, command_line(),
                                  {"graph": str(g.file), "input": str(input_path or "synthetic"),
                                   "frames": selection_text(frames) or "all"})
                )  # fmt: skip
            except UsageError as exc:  # a tracker that cannot start: exit 2 before any frame
                raise NotStarted(exc) from exc
            write_resolved_graph(out_dir, resolved)
            self._stack.enter_context(RunLog(out_dir, append=resume, verbose=self.verbose > 0, pm=self.pm))
            get_logger("run").info(
                "run of %s on %s into %s: %s", g.file, input_path or "the synthetic scene", out_dir,
                " ".join(command_line()), extra={"file_only": True},
            )  # fmt: skip
            seal_folder(out_dir, final=False)  # a killed run's files are known as lanegraph's

        self._on_open = opened
        # Ctrl-C, SIGTERM and SIGHUP stop the run alike: its record says so, --resume continues
        with interrupts.handling(), self.locked(out_dir, "run", (debug_dir, "--debug-dir")), self._stack:
            claim_folder(
                out_dir, identity, resume=resume, overwrite=self.overwrite, resolved=resolved, writes=writes
            )
            self._stack.callback(seal_folder, out_dir)  # what it wrote, once run.log is closed
            try:
                status = self._run_locked(g, input_path, out_dir, frames, resume, debug_dir, chosen)
                tracked = "ok" if status == 0 else "failed"
            finally:
                if tracked == "interrupted":
                    self.tracking.end("interrupted")
        if make_report and status is not None:
            dbg = (
                debug_dir if debug_dir is not None and debug_dir.is_dir() else None
            )  # none if no frame was chosen
            try:
                self.report(out_dir, graph=g, input_path=input_path, frames=frames, debug_dir=dbg)
            except LanegraphError as exc:  # the run's own outputs are written: they stay
                self.tracking.end("failed")
                raise RunStopped(f"report: {exc}", exc) from exc
            finally:
                seal_folder(out_dir)
        self._track_single(g, out_dir, input_path, sets, tracked)
        status = 1 if status is None else status
        return status if self.tracking.ok else max(status, 1)

    def _track_single(
        self, g: Graph, out_dir: Path, input_path: Path | None, sets: list[str], status: str
    ) -> None:
        """Send the run (its record written) to the tracker, with its report."""
        if not self.tracking.started:
            return
        record = read_record(out_dir)
        if record is not None:
            timings = record.timings or {}
            self.tracking.log_run(tracked_single_run(g, out_dir, input_path, sets, record, timings))
        self.tracking.end(status, [])

    def _run_locked(
        self,
        g: Graph,
        input_path: Path | None,
        out_dir: Path,
        selection: slice | None,
        resume: bool,
        debug_dir: Path | None,
        debug_frames: set[str] | None,
    ) -> int | None:
        """The run once OUT is locked: its status, or None when its record could not be written."""
        ckpt, checkpoint = checkpoint_for(out_dir, resume)
        self._resumed_ids = resumed_frame_ids(out_dir, ckpt) if ckpt is not None else []
        ctx = RunContext(
            input_path=input_path,
            out_dir=out_dir,
            frames=selection,
            graph_file=g.file,
            extra={"resume": ckpt is not None},
            skip=ckpt.position if ckpt is not None else 0,
        )
        try:
            # the checkpoint piece: checked against the graph, input and frames before anything opens
            keeper = Checkpointer(g, ctx, checkpoint, ckpt, port_types=self.pm.port_types)
            ex = Executor(g, ctx, self.pm, checkpointer=keeper)
        except LanegraphError as exc:
            raise NotStarted(exc) from exc
        self._ex, self._frames = ex, selection
        if ckpt is not None:
            if ckpt.complete:
                return self._nothing_to_resume(ex, ckpt, out_dir)
            self.err(
                f"resuming after frame {ckpt.last_frame} ({ckpt.position} frame(s) of the selection already done)"
            )
        recorder = None
        if debug_dir is not None:
            from ..presentation.debug import DebugRecorder

            recorder = DebugRecorder(debug_dir, debug_frames, self.pm)
            self.pm.register(recorder)
        try:
            result = self._execute(ex, g, out_dir, input_path)
        finally:
            if recorder is not None:
                self.pm.unregister(recorder)
        return self._say_run(ex, result, g, out_dir, input_path, recorder, debug_frames)

    def _nothing_to_resume(self, ex: Executor, ckpt: Any, out_dir: Path) -> int:
        """``--resume`` of a complete run: its input and outputs are checked, nothing runs."""
        try:  # the input and the outputs must still be those of the checkpoint
            with ex:
                pass
        except LanegraphError as exc:
            raise NotStarted(exc) from exc
        self.err(
            f"nothing to resume: the run in {out_dir} is complete ({ckpt.frames_ok} frame(s) done, "
            f"{len(ckpt.failures)} failed); its outputs are left as they are"
        )
        return 1 if ckpt.failures else 0

    def _execute(self, ex: Executor, g: Graph, out_dir: Path, input_path: Path | None) -> RunResult:
        """Open and run the executor with a progress bar; when it stops, its partial record is
        written (``run.json`` says what it did and why it stopped) and :class:`RunStopped` raised."""
        bar = None
        try:
            try:
                ex.open()
            except (InputError, UsageError) as exc:  # unusable input found before any frame ran
                raise NotStarted(exc) from exc
            if self._on_open is not None:
                self._on_open()
            bar = progress_bar(len(ex) or None, g.name, enabled=self.progress)

            log = get_logger("run")

            def tick(index: int, frame: str | None) -> None:
                bar.update(1)
                bar.set_postfix_str(str(frame))
                log.debug("frame %s (#%d) done", frame, index)  # -v: on the terminal and in run.log

            return ex.run(on_frame=tick)
        except NotStarted:
            raise
        except (LanegraphError, KeyboardInterrupt, OSError) as exc:
            if bar is not None:
                bar.close()
            if isinstance(exc, KeyboardInterrupt):  # Ctrl-C, SIGTERM, SIGHUP (lanegraph.interrupts)
                label, code = interrupts.label_and_code(exc)
                err: LanegraphError = LanegraphError(f"interrupted ({label}); continue with --resume")
            elif isinstance(exc, OSError):
                err = LanegraphError(
                    f"{str(exc.filename) + ': ' if exc.filename else ''}{exc.strerror or exc}"
                )
                code = 1
            elif isinstance(exc, HookError) and isinstance(exc.cause, UsageError):
                err, code = exc.cause, 2  # a usage error (--debug-dir) found by a hook: exit 2, its words
            else:
                err, code = exc, exc.exit_code
            if ex.result is not None:  # the run started: record what it did and why it stopped
                self._write_record(out_dir, g, input_path, ex.result, stopped=err)
            raise RunStopped(str(err), exc, code) from None
        finally:
            ex.close()
            if bar is not None:
                bar.close()

    def _write_record(
        self,
        out_dir: Path,
        g: Graph,
        input_path: Path | None,
        result: RunResult,
        stopped: BaseException | None = None,
    ) -> bool:
        """``timings.json`` and ``run.json``; False (and the reason on stderr) when they cannot be
        written (a full disk)."""
        extra = {**self.record_extra, **self._run_extra}
        if "versions" in extra:  # at the end: the libraries the run loaded (ONNX Runtime ...)
            extra["versions"] = versions(self.pm)
        record = RunRecord.of(
            result,
            graph=g.file,
            input=str(input_path) if input_path else None,
            stopped=stopped_by(stopped) if stopped is not None else None,
            frames=selection_text(self._frames),
            **extra,
        )
        if record.selection is not None and self._resumed_ids:
            record.selection.ids = [*self._resumed_ids, *record.selection.ids]
        outputs = self._ex.outputs() if self._ex is not None else []
        record.written = sorted({relative_inside(Path(p), out_dir) for p in outputs} - {None})
        try:
            write_run_files(out_dir, record, result.timings_json())
        except OSError as exc:
            self.err(f"error: cannot write {out_dir}/run.json and timings.json: {exc.strerror or exc}")
            return False
        return True

    def _say_run(
        self,
        ex: Executor,
        result: RunResult,
        g: Graph,
        out_dir: Path,
        input_path: Path | None,
        recorder: Any,
        debug_frames: set[str] | None,
    ) -> int | None:
        """Write the run's record and say what it did: 0, 1 (frames failed) or None (its record
        could not be written)."""
        status = 0
        if recorder is not None and debug_frames is not None:
            missed = sorted(f for f in debug_frames if f not in recorder.matched)
            if missed:  # said at the end and in run.json's warnings
                result.notes.append(
                    f"--debug-frames {', '.join(missed)} matched no frame of the run; nothing recorded for them"
                )
        written = self._write_record(out_dir, g, input_path, result)
        if result.failures:
            self.err(f"{len(result.failures)} frame(s) failed:")
            for f in result.failures:
                self.err(f"  frame {f.frame} (#{f.index}): node '{f.node_id}' ({f.node_type}): {f.error}")
            status = 1
        for w in result.warnings():
            self.err(f"warning: {w}")
        if not written:
            return None
        outputs = [str(p) for p in ex.outputs()]
        total = result.timings_json().get("total", {})
        self.out(
            f"{result.frames} frame(s) processed -> {', '.join([*outputs, str(out_dir / 'timings.json')])}"
            + (f" (median {total['median_ms']:.1f} ms/frame)" if total else "")
        )
        return status

    # -- lanegraph run --dataset -----------------------------------------------------
    def run_dataset(
        self,
        graph: ResolvedGraph,
        dataset: Any,
        out_dir: Path,
        *,
        frames: slice | None = None,
        runner: Runner | None = None,
        chunk_frames: int | None = None,
        warmup: int = 0,
    ) -> int:
        """``lanegraph run GRAPH --dataset FILE``: the graph on every sequence, into
        ``OUT/<sequence>/``; 0, 1 when a frame failed or a sequence stopped, 2 when no sequence
        could start. Errors found before anything runs are raised (exit 2)."""
        from ..run.batch import describe_error
        from ..run.runners import InProcessRunner

        runner = runner if runner is not None else InProcessRunner()
        g = graph.validate(self.pm)  # a GraphError before anything runs
        identity = dataset_identity("dataset", [g.name], dataset, frames)
        writes = dataset_writes(dataset)
        check_folder(out_dir, identity, overwrite=self.overwrite, writes=writes)
        sets = list(graph.sets)
        self.record_extra = {**self.record_extra, **provenance(self.pm, g.file, sets)}
        try:
            with interrupts.handling(), self.locked(out_dir, "run"), self._stack:
                claim_folder(out_dir, identity, overwrite=self.overwrite, writes=writes)
                self._stack.callback(seal_folder, out_dir)
                fields = {"kind": "dataset", **self.record_extra, "identity": identity,
                          "written": [s.name for s in dataset]}  # fmt: skip
                self.tracking.start(
                    CommandRecord("run", f"run {g.name} --dataset -> {out_dir}", out_dir, list(fields["command"]),
                                  {"graph": str(g.file), "frames": identity["frames"] or "all"})
                )  # fmt: skip
                write_command_record(out_dir, fields)
                seal_folder(out_dir, final=False)
                try:
                    with RunLog(out_dir, verbose=self.verbose > 0):
                        summary = self._run_dataset(
                            graph, dataset, out_dir, frames, runner, chunk_frames, warmup
                        )
                except BaseException:
                    self.tracking.end("interrupted")
                    raise
        except LanegraphError as exc:  # a usage error, an unusable input found before any frame ran
            if exc.exit_code == 2:
                raise
            raise NotStarted(exc) from exc
        status = 0
        for s in summary:
            files = [str(out_dir / s["sequence"] / f) for f in s.get("results", {}).values()]
            line = f"{s['sequence']}: {s['frames']} frame(s) -> {', '.join(files) or out_dir / s['sequence']}"
            if s["error"] is not None and s["error"].get("before_any_frame"):
                line = f"{s['sequence']}: not run (see {out_dir / s['sequence']}/run.json)"
            if s["failures"]:
                line += f", {len(s['failures'])} frame(s) failed"
                status = 1
            self.out(line)
            for f in s["failures"]:
                self.err(f"  frame {f.frame} (#{f.index}): node '{f.node_id}' ({f.node_type}): {f.error}")
            if s["error"] is not None:
                self.err(f"error: {describe_error(s['error'])}")
                status = 1
        if summary and all(s["error"] is not None and s["error"].get("before_any_frame") for s in summary):
            status = 2  # nothing ran at all: the inputs are unusable
        if self.tracking.started:
            for seq in dataset:
                self.tracking.log_run(tracked_dataset_run(g, out_dir / seq.name, seq, sets))
            self.tracking.end("failed" if status else "ok", [])
        return status if self.tracking.ok else max(status, 1)

    def _run_dataset(
        self, graph, dataset, out_dir, frames, runner, chunk_frames, warmup
    ) -> list[dict[str, Any]]:
        """One summary per sequence: ``sequence``, ``frames``, ``failures`` (failed frames),
        ``error`` (what stopped the run, or ``None``), ``results`` (the sinks' result files)."""
        from ..run.batch import Planner, clean_leftovers, finish_runs

        graph.validate(self.pm)  # a GraphError before anything runs
        planner = Planner(self.pm, chunk_frames, warmup, record_extra=self.record_extra)
        plans = []
        for seq in dataset:
            sel = seq.frames if seq.frames is not None else frames
            run_dir = out_dir / seq.name
            if run_dir.exists() and not run_dir.is_dir():
                raise UsageError(f"{run_dir}: expected a folder for sequence {seq.name!r}, found a file")
            plans.append(planner.add(None, seq.name, graph, seq.input, sel, run_dir))
        out_dir.mkdir(parents=True, exist_ok=True)
        for plan in plans:
            clean_leftovers(plan.run_dir)
        for w in planner.warnings:  # said before anything runs (and in each run.json)
            self.err(f"warning: {w}")
        outcomes = runner.run(planner.tasks, progress=self.progress, echo=self.err)
        finish_runs(plans, outcomes)
        summary = []
        for plan in plans:
            out = plan.outcome
            assert out is not None
            results = out.result.results if out.error is None or not out.error.get("before_any_frame") else {}
            summary.append(
                {
                    "sequence": plan.sequence,
                    "frames": out.result.frames,
                    "failures": out.result.failures,
                    "error": out.error,
                    "wall_s": out.wall_s,
                    "results": results,
                }
            )
        return summary

    # -- lanegraph ablate ------------------------------------------------------------
    def ablate(
        self,
        variants: list[Any],
        dataset: Any,
        out_dir: Path,
        *,
        frames: slice | None = None,
        cache_dir: Path | None = None,
        cache_max_gb: float = 2.0,
        no_cache: bool = False,
        scheduler: str | None = None,
        runner: Runner | None = None,
        chunk_frames: int | None = None,
        warmup: int = 0,
        make_report: bool = False,
    ) -> int:
        """``lanegraph ablate``: every variant on every sequence, evaluated and tabulated; 0, 1 when
        runs or frames failed, 2 when no run could start. ``runner`` (default: the one of
        ``scheduler``) executes the runs."""
        from .ablation import ablate

        return ablate(self, variants, dataset, out_dir, frames=frames, cache_dir=cache_dir,
                      cache_max_gb=cache_max_gb, no_cache=no_cache, scheduler=scheduler, runner=runner,
                      chunk_frames=chunk_frames, warmup=warmup, make_report=make_report)  # fmt: skip

    # -- lanegraph report -------------------------------------------------------------
    def report(
        self,
        run_dir: Path,
        *,
        dataset: Any = None,
        dataset_path: Path | None = None,
        gt_path: Path | None = None,
        **kwargs: Any,
    ) -> Any:
        """Write the report of a run or ablation folder (:func:`lanegraph.presentation.report.write_report`)
        and say its summary line; returns the :class:`~lanegraph.presentation.report.ReportSummary`."""
        from ..evaluation.dataset import load_dataset
        from ..presentation.report import write_report

        if dataset_path is not None:
            dataset = load_dataset(dataset_path)
        if gt_path is not None and not gt_path.is_file():
            raise UsageError(f"--gt {gt_path}: no such file")
        summary = write_report(
            run_dir, dataset=dataset, gt=gt_path, progress=self.progress, pm=self.pm, **kwargs
        )
        self.out(summary.line())
        return summary
