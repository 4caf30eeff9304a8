"""The ablation path of the run service (:meth:`lanegraph.service.Session.ablate`)."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

from .. import interrupts
from ..batches.batch import BatchRun
from ..batches.runners import InProcessRunner, Runner
from ..errors import InputError, LanegraphError, NotStarted, RunStopped, UsageError
from ..evaluation.ablate import Variant, _safe, ablation_rows, distinct_folders, expand_sweeps, write_reports
from ..evaluation.dataset import read_gt
from ..graph.files import resolve_graph_path
from ..paths import inside, safe_name
from ..records.folder import check as check_folder
from ..records.owned import seal as seal_folder
from ..records.provenance import git_commit, versions
from ..tracking import CommandRecord as TrackedCommand
from ..tracking import existing
from .keeping import (
    ABLATION_FILES,
    ablation_writes,
    command_kept,
    dataset_identity,
    debug_frames_option,
    result_cache,
    tracked_ablation_runs,
)


def ablation_variants(base: Path, variants: tuple[Path, ...], sweeps: tuple[str, ...]) -> list[Variant]:
    """BASE, each VARIANT (named by its file; by folder/file where two files share a name) and a
    variant of BASE per ``--sweep`` value."""
    paths = [resolve_graph_path(str(p)) for p in (base, *variants)]
    runs = [Variant(p.stem, p) for p in paths]
    names = [r.name for r in runs]
    for r in runs:  # disambiguate equal file names
        if names.count(r.name) > 1:
            r.name = f"{r.graph.parent.name}/{r.name}"
    try:
        runs += expand_sweeps(paths[0], list(sweeps))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return runs


def ablate(
    session: Any,
    variants: list[Variant],
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
    resume: bool = False,
    debug_dir: Path | None = None,
    debug_frames: str | None = None,
) -> int:
    """See :meth:`lanegraph.service.Session.ablate`. ``runner`` (default: the one of ``scheduler``)
    executes the runs; ``resume``: the runs an earlier ablation finished in OUT are reused even with
    ``no_cache``; ``debug_frames``: ``--debug-frames`` as given."""
    chosen = debug_frames_option(debug_frames)
    if make_report:
        session.check_reports()
    runner = runner if runner is not None else session.runner(scheduler)
    opened = [(r, session.open_graph(r.graph, tuple(r.sets))) for r in variants]
    for _, graph in opened:
        graph.validate(session.pm)  # every variant checked before anything runs
    if not (math.isfinite(cache_max_gb) and cache_max_gb > 0):
        raise UsageError(f"--cache-max-gb: expected a size in GiB > 0, got {cache_max_gb}")
    identity = dataset_identity("ablation", [r.name for r in variants], dataset, frames)
    # another ablation's results are refused before anything is written (the folder left as it was)
    distinct_folders(variants)  # a variant given twice refused; equal folder names told apart
    writes = ablation_writes([_safe(r.name) for r in variants], dataset, make_report)
    check_folder(
        out_dir, identity, overwrite=session.overwrite, writes=writes
    )  # a variant given twice refused; equal folder names told apart
    resolved = {r.name: graph for r, graph in opened}
    graphs = {name: graph.validate(session.pm) for name, graph in resolved.items()}
    seq_frames = {s.name: s.frames if s.frames is not None else frames for s in dataset}
    try:  # a malformed ground truth is found before any run: exit 2, like an unusable input
        gts = {s.name: read_gt(s, seq_frames[s.name]) for s in dataset}
    except InputError as exc:
        raise NotStarted(exc) from exc
    t0 = time.perf_counter()
    cache_folder = (cache_dir, "--cache-dir") if cache_dir is not None and not no_cache else (None, "")
    with (
        interrupts.handling(),
        session.locked(out_dir, "ablate", cache_folder, (debug_dir, "--debug-dir")),
        ablation_kept(session, out_dir, identity, variants, writes),
    ):
        cache = result_cache(cache_dir, cache_max_gb, no_cache)
        if isinstance(runner, InProcessRunner):
            runner.cache = cache
        made = session.provenance(None, [])
        runs = [
            BatchRun(
                var.name, seq.name, resolved[var.name], seq.input, seq_frames[seq.name],
                inside(out_dir, f"runs/{_safe(var.name)}/{safe_name(seq.name)}", "ablate --out"),
                made.model_copy(update={"overrides": list(var.sets), "git": git_commit(Path(var.graph))}),
                debug_dir / _safe(var.name) / safe_name(seq.name) if debug_dir is not None else None,
            )
            for var in variants
            for seq in dataset
        ]  # fmt: skip
        try:
            batch = session.run_tasks(runs, runner, cache=cache, chunk_frames=chunk_frames, warmup=warmup,
                                      reuse=cache is not None or resume, debug_frames=chosen)  # fmt: skip
        except (InputError, UsageError) as exc:  # unusable before any run: like `run`, exit 2
            raise NotStarted(exc) from exc
        except OSError as exc:
            raise RunStopped(
                f"{str(exc.filename) + ': ' if exc.filename else ''}{exc.strerror or exc}", exc
            ) from None
        rows = ablation_rows(variants, batch.plans, gts)
        if rows or batch.interrupted is None:
            write_reports(rows, out_dir)  # after Ctrl-C, the variants whose runs all ended
        if batch.interrupted is not None:
            raise session.stopped(
                batch.interrupted, f"the finished runs are in {out_dir}/runs and results.md"
            )
    if cache is not None and not isinstance(runner, InProcessRunner):  # the workers' counts, for the summary
        for plan in batch.plans:
            if plan.outcome is not None:
                cache.hits += sum(plan.outcome.result.cache_hits.values())
                cache.misses += sum(plan.outcome.result.cache_misses.values())
    status = _end(session, rows, out_dir, cache, time.perf_counter() - t0)
    runs_of = {(p.variant, p.sequence): p for p in batch.plans}
    tracked = tracked_ablation_runs(
        rows, graphs, {k: p.run_dir for k, p in runs_of.items()}, {k: p.record for k, p in runs_of.items()}
    )
    for run in tracked:
        session.tracking.log_run(run)
    if status:
        session.tracking.end("failed", existing(out_dir, ABLATION_FILES))
        return status
    if make_report:
        try:  # the base variant's source reads the left images; its graph is drawn
            session.report(out_dir, dataset=dataset, frames=frames, graph=graphs[variants[0].name])
        except LanegraphError as exc:  # the ablation's own outputs are written: they stay
            session.tracking.end("failed", existing(out_dir, ABLATION_FILES))
            raise RunStopped(str(exc), exc) from exc
        finally:
            seal_folder(out_dir)
    status = _failures(session, rows)
    session.tracking.end("failed" if status else "ok", existing(out_dir, ABLATION_FILES))
    return status if session.tracking.ok else max(status, 1)


def ablation_kept(
    session: Any, out_dir: Path, identity: dict[str, Any], variants: list[Variant], writes: dict[str, str]
) -> Any:
    """What an ablation keeps beside its results (:func:`lanegraph.service.keeping.command_kept`),
    ``command.json`` naming its variants (at the end with the libraries the runs loaded)."""
    made = session.provenance(variants[0].graph, [])
    written = ["results.csv", "results.md", "accuracy.png", "accuracy_vs_ms.png", "runs"]

    def keep(final: bool) -> None:
        m = made.model_copy(update={"versions": versions(session.pm)}) if final else made
        session.keep_command(out_dir, "ablation", m, identity, written, variants)

    tracked = TrackedCommand("ablate", f"ablate -> {out_dir}", out_dir, list(made.command),
                             {"variants": " ".join(r.name for r in variants), "frames": identity["frames"] or "all"})  # fmt: skip
    return command_kept(
        session,
        out_dir,
        identity,
        writes,
        tracked,
        keep,
        f"ablation into {out_dir}: {' '.join(made.command)}",
    )


def _end(session: Any, rows: list[dict[str, Any]], out_dir: Path, cache: Any, seconds: float) -> int:
    """Say the results table and where it went; 2 when no run could start at all."""
    runs_rows = [r for r in rows if r.get("sequence") != "all"]
    failed = [r for r in runs_rows if r.get("error")]
    if failed and all(r.get("before_any_frame") for r in failed) and len(failed) == len(runs_rows):
        for r in failed:  # nothing ran at all: the input is unusable (exit 2, as `run` says)
            session.err(f"error: {r['variant']} / {r['sequence']}: {r['error']}")
        return 2
    session.out((out_dir / "results.md").read_text())
    hits = f", cache {cache.hits} hits / {cache.misses} misses" if cache is not None else ", no cache"
    session.out(
        f"{len(rows)} row(s) in {seconds:.1f} s{hits} -> {out_dir}/results.md, results.csv, accuracy.png, accuracy_vs_ms.png"
    )
    return 0


def _failures(session: Any, rows: list[dict[str, Any]]) -> int:
    """The runs that failed and the frames that failed in the others: 1 when there are any."""
    runs_rows = [r for r in rows if r.get("sequence") != "all"]
    failed = [r for r in runs_rows if r.get("error")]
    if failed or any(r.get("failed_frames") for r in runs_rows):
        for r in failed:
            session.err(f"error: run {r['variant']} / {r['sequence']} failed: {r['error']}")
        n_frames = sum(int(r.get("failed_frames") or 0) for r in runs_rows if not r.get("error"))
        if n_frames:
            session.err(f"{n_frames} frame(s) failed in runs that went on (on_error skip); see results.md")
        return 1
    return 0


__all__ = ["ablate", "ablation_variants"]
