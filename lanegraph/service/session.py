"""The run service: the one path by which a command runs graphs.

A :class:`Session` (Kedro's ``KedroSession.run(runner=...)``) loads a graph, checks and locks the
output folder, and runs every command alike: **plan** (each run a task,
:class:`~lanegraph.batches.batch.Planner`) -> **runner** (:mod:`lanegraph.batches.runners`, ``--scheduler``)
-> **finish** (what the command says and keeps). ``lanegraph run`` on one input is one run written
in place into OUT (checkpointed: ``--resume``); ``run --dataset`` and ``ablate`` are batches of runs
into folders of their own (:meth:`Session.run_tasks`, the public batch entry point). An option a
command cannot honour is refused in one place (:data:`REFUSED`).

It says what it does through ``out`` (stdout) and ``err`` (stderr). Failures are raised once, as
typed errors (:class:`~lanegraph.errors.NotStarted`, :class:`~lanegraph.errors.RunStopped`, ...),
each with its exit code (mapped in :mod:`lanegraph.cli._errors`); what ran returns its status.
Ctrl-C, SIGTERM or SIGHUP keep what ended (a run in place: its record and checkpoint) and raise
:class:`~lanegraph.errors.RunStopped` with exit code 130, 143 or 129.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from .. import interrupts
from ..errors import HookError, InputError, LanegraphError, NotStarted, RunStopped, UsageError
from ..frames import selection_text
from ..graph.files import ResolvedGraph, load_graph_named, open_graph
from ..graph.model import Graph
from ..paths import OutputLock, prepare_dir
from ..plugins import PluginManager, call_hook, get_plugin_manager
from ..records.folder import check as check_folder
from ..records.folder import claim as claim_folder
from ..records.owned import seal as seal_folder
from ..records.provenance import command_line, git_commit, versions
from ..records.record import CommandRecord, Provenance, VariantEntry, write_command_record
from ..runlog import RunLog
from ..tracking import CommandRecord as TrackedCommand
from ..tracking import Tracking
from .keeping import GT_NAME, debug_frames_option, run_writes, single_identity, tracked_run

if TYPE_CHECKING:  # the batch modules load only for a run: `lanegraph run --help` keeps its start-up
    from ..batches.batch import Batch, BatchRun, Planned
    from ..batches.runners import Runner


def _stdout(msg: str) -> None:
    print(msg, flush=True)


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


#: why an option cannot be given to a command (option, command) -> reason: the one place it is said
REFUSED = {
    ("--resume", "chunks"): "--resume continues a run after its checkpoint; a run in chunks (--chunk-frames) "
    "keeps none: give one or the other",
    (
        "--input",
        "dataset",
    ): "--input is for a run on one input; --dataset names the inputs (give one or the other)",
    (
        "--calib",
        "dataset",
    ): "--calib is for a run on one input; --dataset names the inputs (give one or the other)",
    ("--report", "dataset"): "--report is for a run on one input or an ablation; report on a dataset run's "
    "sequences with `lanegraph report OUT --dataset FILE`",
}


def refuse(option: str, where: str) -> None:
    """Raise the :class:`UsageError` that says why ``option`` cannot go with ``where``."""
    raise UsageError(REFUSED[(option, where)])


class Session:
    """Runs graphs for one command: ``session.run(graph, ...)``, ``session.run_dataset(...)``,
    ``session.ablate(...)``, ``session.report(...)``, and any batch: ``session.run_tasks(...)``."""

    def __init__(
        self,
        pm: PluginManager | None = None,
        *,
        out: Callable[[str], None] | None = None,
        err: Callable[[str], None] | None = None,
        progress: bool = True,
        overwrite: bool = False,
        tracking: Tracking | None = None,
        verbose: int = 0,
    ):
        self.pm = pm or get_plugin_manager()
        self.out = out or _stdout
        self.err = err or _stderr
        self.progress = progress
        #: ``--overwrite``: a folder holding another run's results is cleared of lanegraph's files
        self.overwrite = overwrite
        #: ``--track``: the experiment tracker the runs are sent to (none: nothing is tracked)
        self.tracking = tracking if tracking is not None else Tracking(None)
        #: ``-v``: run.log records the details too
        self.verbose = verbose

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
        """The runner of ``--scheduler`` (:func:`lanegraph.batches.runners.select_runner`)."""
        from ..batches.runners import select_runner

        return select_runner(scheduler, self.pm, cache)

    def provenance(self, graph_file: str | Path | None, sets: Sequence[str] = ()) -> Provenance:
        """How the runs of this command are made: the command line, the ``--set`` overrides, the
        versions and the commit of the graph file's checkout (when it lies in one)."""
        git = git_commit(Path(graph_file)) if graph_file else None
        return Provenance(command=command_line(), overrides=list(sets), versions=versions(self.pm), git=git)

    def keep_command(
        self,
        out_dir: Path,
        kind: Literal["dataset", "ablation", "tune"],
        made: Provenance,
        identity: dict[str, Any],
        written: list[str],
        variants: list[Any] | None = None,
        search: Any = None,
    ) -> None:
        """``OUT/command.json`` of a batch command: the one place its record is built."""
        entries = None
        if variants is not None:
            entries = [VariantEntry(name=v.name, graph=str(v.graph), sets=list(v.sets)) for v in variants]
        write_command_record(out_dir, CommandRecord.of(kind, made, identity, written, entries, search))

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

    def stopped(self, exc: BaseException, where: str) -> RunStopped:
        """The :class:`RunStopped` of an interruption (Ctrl-C, SIGTERM, SIGHUP); ``where``: what was kept."""
        label, code = interrupts.label_and_code(exc)
        return RunStopped(f"interrupted ({label}); {where}", exit_code=code)

    # -- every batch -------------------------------------------------------------------
    def run_tasks(
        self,
        runs: Sequence[BatchRun],
        runner: Runner | None = None,
        *,
        cache: Any = None,
        chunk_frames: int | None = None,
        warmup: int = 0,
        reuse: bool = False,
        debug_frames: tuple[str, ...] | None = None,
    ) -> Batch:
        """Run ``runs`` (each a graph on a sequence into a folder of its own) on ``runner`` (default:
        in this process, sharing ``cache``): planned (frames counted, chunks of ``chunk_frames`` after
        ``warmup`` frames; with ``reuse`` a run whose folder holds its result already is not run
        again), run, finished. Returns the :class:`~lanegraph.batches.batch.Batch`: every run's plan
        with its ``outcome`` and ``record`` (in memory: nothing is read back), and ``interrupted``
        when Ctrl-C stopped it (the runs that ended are kept). A run's failure is in its outcome;
        what is wrong before anything runs is raised (:class:`UsageError`, ...)."""
        from ..batches.batch import Planner, run_planned
        from ..batches.runners import InProcessRunner

        runner = runner if runner is not None else InProcessRunner(cache)
        planner = Planner(self.pm, chunk_frames, warmup, cache, reuse=reuse, verbose=self.verbose > 0)
        plans = []
        for r in runs:
            if r.run_dir.exists() and not r.run_dir.is_dir():
                raise UsageError(f"{r.run_dir}: expected a folder for sequence {r.sequence!r}, found a file")
            plans.append(
                planner.add(r.variant, r.sequence, r.graph, r.input, r.frames, r.run_dir, provenance=r.provenance,
                            debug_dir=r.debug_dir, subscribers=_debug_pictures(r.debug_dir, debug_frames))
            )  # fmt: skip
        for w in planner.warnings:  # said before anything runs (and in each run.json)
            self.err(f"warning: {w}")
        return run_planned(plans, planner.tasks, runner, progress=self.progress, echo=self.err)

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
        runner: Runner | None = None,
        chunk_frames: int | None = None,
        warmup: int = 0,
    ) -> int:
        """``lanegraph run``: the graph on one input into ``out_dir``; 0, or 1 when frames failed.
        Raises :class:`NotStarted` for an input, checkpoint or folder unusable before any frame,
        :class:`RunStopped` when the run stopped (its record written), a :class:`GraphError`."""
        from ..batches.batch import Planner, run_planned
        from ..batches.runners import InProcessRunner
        from ..records.checkpointing import checkpoint_for

        g = graph.validate(self.pm)
        if input_path is not None and not input_path.exists():
            raise UsageError(f"--input {input_path}: no such file or folder")
        if resume and chunk_frames is not None:
            refuse("--resume", "chunks")
        if make_report:
            self.check_reports()
        chosen = debug_frames_option(debug_frames)
        runner = runner if runner is not None else InProcessRunner()
        resolved = g.resolved_dict()
        identity = single_identity(resolved, input_path, frames)
        # another run's results are refused before anything is written (the folder left as it was)
        writes = run_writes(g, out_dir, debug_dir, make_report)
        check_folder(
            out_dir, identity, resume=resume, overwrite=self.overwrite, resolved=resolved, writes=writes
        )
        sets = list(graph.sets)
        planner = Planner(self.pm, chunk_frames, warmup, verbose=self.verbose > 0)
        # Ctrl-C, SIGTERM and SIGHUP stop the run alike: its record says so, --resume continues
        with interrupts.handling(), self.locked(out_dir, "run", (debug_dir, "--debug-dir")):
            claim_folder(
                out_dir, identity, resume=resume, overwrite=self.overwrite, resolved=resolved, writes=writes
            )
            try:
                ckpt = checkpoint_for(out_dir, resume)[0]  # without --resume: an old one removed
                plan = planner.add(
                    None, g.name, graph, input_path, frames, out_dir, provenance=self.provenance(g.file, sets),
                    in_place=True, resume=resume, identity=identity, debug_dir=debug_dir,
                    subscribers=_debug_pictures(debug_dir, chosen),
                )  # fmt: skip
            except LanegraphError as exc:  # an unusable checkpoint or input: nothing was written
                raise NotStarted(exc) from exc
            if plan.outcome is not None:  # the input cannot be opened
                raise NotStarted(plan.outcome.exception or LanegraphError(plan.outcome.error["message"]))
            if ckpt is not None and not ckpt.complete:
                self.err(
                    f"resuming after frame {ckpt.last_frame} ({ckpt.position} frame(s) of the selection already done)"
                )
            self._track_start(TrackedCommand("run", f"run {g.name} -> {out_dir}", out_dir, command_line(),
                                             {"graph": str(g.file), "input": str(input_path or "synthetic"),
                                              "frames": selection_text(frames) or "all"}))  # fmt: skip
            try:
                batch = run_planned([plan], planner.tasks, runner, progress=self.progress, echo=self.err)
                if batch.interrupted is not None:
                    self.tracking.end("interrupted")
                    raise self.stopped(batch.interrupted, "continue with --resume")
                out = plan.outcome
                said = (
                    out is not None
                    and out.complete is None
                    and (out.error is None or not out.error["before_any_frame"])
                )
                with RunLog(out_dir, append=True, verbose=self.verbose > 0) if said else nullcontext():
                    status = self._say_run(plan, out_dir)  # said into run.log too
            finally:
                seal_folder(out_dir)  # what it wrote, once run.log is closed
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
        if self.tracking.started:
            if plan.record is not None:
                gt = input_path / GT_NAME if input_path is not None else None
                name = input_path.name if input_path is not None else "synthetic"
                self.tracking.log_run(tracked_run(g, out_dir, name, gt, sets, plan.record))
            self.tracking.end("ok" if status == 0 else "failed", [])
        status = 1 if status is None else status
        return status if self.tracking.ok else max(status, 1)

    def _track_start(self, command: TrackedCommand) -> None:
        try:
            self.tracking.start(command)
        except UsageError as exc:  # a tracker that cannot start: exit 2 before any frame
            raise NotStarted(exc) from exc

    def _say_run(self, plan: Planned, out_dir: Path) -> int | None:
        """What the run on one input did: 0, 1 (frames failed) or None (its record could not be
        written); raises :class:`NotStarted` or :class:`RunStopped` when it did not end."""
        out = plan.outcome
        assert out is not None
        if out.complete is not None:  # --resume of a complete run: its input and outputs checked, nothing ran
            ck = out.complete
            self.err(
                f"nothing to resume: the run in {out_dir} is complete ({ck.frames_ok} frame(s) done, "
                f"{len(ck.failures)} failed); its outputs are left as they are"
            )
            return 1 if ck.failures else 0
        if out.unwritten is not None:
            self.err(f"error: {out.unwritten}")
        if out.error is not None:
            exc, error = out.exception, out.error
            if error["stage"] == "build" or (
                error["stage"] == "open" and (exc is None or isinstance(exc, (InputError, UsageError)))
            ):
                self.tracking.end("interrupted")
                raise NotStarted(exc if isinstance(exc, LanegraphError) else LanegraphError(error["message"]))
            self.tracking.end("interrupted")
            raise RunStopped(error["message"], exc, error["exit_code"]) from None
        result = out.result
        status = 0
        if result.failures:
            self.err(f"{len(result.failures)} frame(s) failed:")
            for f in result.failures:
                self.err(f"  frame {f.frame} (#{f.index}): node '{f.node_id}' ({f.node_type}): {f.error}")
            status = 1
        for w in result.warnings():
            self.err(f"warning: {w}")
        if out.unwritten is not None:
            return None
        total = result.timings_json().get("total", {})
        self.out(
            f"{result.frames} frame(s) processed -> {', '.join([*out.outputs, str(out_dir / 'timings.json')])}"
            + (f" (median {total['median_ms']:.1f} ms/frame)" if total else "")
        )
        return status

    # -- lanegraph run --dataset -----------------------------------------------------
    def run_dataset(self, graph: ResolvedGraph, dataset: Any, out_dir: Path, **options: Any) -> int:
        """``lanegraph run GRAPH --dataset FILE``: the graph on every sequence, into
        ``OUT/<sequence>/``; 0, 1 when a frame failed or a sequence stopped, 2 when no sequence
        could start. Errors found before anything runs are raised (exit 2). ``options``: those of
        :func:`lanegraph.service.batches.run_dataset` (``frames``, ``runner``, ``resume``, ...)."""
        from .batches import run_dataset

        return run_dataset(self, graph, dataset, out_dir, **options)

    # -- lanegraph ablate ------------------------------------------------------------
    def ablate(self, variants: list[Any], dataset: Any, out_dir: Path, **options: Any) -> int:
        """``lanegraph ablate``: every variant on every sequence, evaluated and tabulated; 0, 1 when
        runs or frames failed, 2 when no run could start. ``options``: those of
        :func:`lanegraph.service.ablation.ablate` (``frames``, the cache's, ``runner``, ...)."""
        from .ablation import ablate

        return ablate(self, variants, dataset, out_dir, **options)

    # -- lanegraph report -------------------------------------------------------------
    def report(
        self,
        run_dir: Path,
        *,
        dataset: Any = None,
        dataset_path: Path | None = None,
        gt_path: Path | None = None,
        out_dir: Path | None = None,
        input_path: Path | None = None,
        frames: slice | None = None,
        sets: Sequence[str] = (),
        debug_dir: Path | None = None,
        graph: Graph | None = None,
    ) -> Any:
        """Write the report of a run or ablation folder and say its summary line; returns the
        summary (``index``: the page; ``line()``). The plugin that writes reports does it (the
        ``lanegraph_write_report`` hook; the built-in plugin ``lanegraph_report``): without one, a
        :class:`UsageError`. What it raises reaches the caller as it is."""
        from ..evaluation.dataset import load_dataset

        self.check_reports()
        if dataset_path is not None:
            dataset = load_dataset(dataset_path)
        if gt_path is not None and not gt_path.is_file():
            raise UsageError(f"--gt {gt_path}: no such file")
        try:
            summary = call_hook(
                self.pm, "lanegraph_write_report", run_dir=Path(run_dir), out_dir=out_dir, dataset=dataset,
                gt=gt_path, input_path=input_path, frames=frames, sets=tuple(sets), debug_dir=debug_dir,
                graph=graph, pm=self.pm, progress=self.progress,
            )  # fmt: skip
        except HookError as exc:  # the report's own errors (a folder that does not fit ...) as they are
            if isinstance(exc.cause, (LanegraphError, OSError)):
                raise exc.cause from None
            raise
        if summary is None:
            raise UsageError(f"{run_dir}: {_NO_REPORTS} (those installed declined this folder)")
        self.out(summary.line())
        return summary

    def check_reports(self) -> None:
        """Raise the :class:`UsageError` that says no installed plugin writes reports, where none
        does (``run --report`` and ``ablate --report`` ask before anything runs)."""
        if self.pm.hook.lanegraph_write_report.get_hookimpls():
            return
        broken = "; ".join(str(e) for e in self.pm.plugin_errors)  # the one that would, perhaps
        raise UsageError(f"{_NO_REPORTS}" + (f"; of the plugins installed, {broken}" if broken else ""))


_NO_REPORTS = (
    "no installed plugin writes reports (the lanegraph_write_report hook; lanegraph's own is the plugin "
    "lanegraph_report)"
)


def _debug_pictures(folder: Path | None, frames: tuple[str, ...] | None) -> tuple[Any, ...]:
    """What ``--debug-dir`` adds to a run's events (:class:`lanegraph.presentation.debug.DebugPictures`)."""
    if folder is None:
        return ()
    from ..presentation.debug import DebugPictures

    return (DebugPictures(folder, frames),)


__all__ = ["Session", "refuse"]
