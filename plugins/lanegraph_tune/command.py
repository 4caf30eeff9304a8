"""``lanegraph tune`` on the run service (:class:`lanegraph.api.Session`): the graph and space
checked, the output folder checked and claimed as ``ablate`` does (:func:`lanegraph.api.check_folder`,
:func:`lanegraph.api.command_kept`), the search (:mod:`lanegraph_tune.search`), its tables, tuned
graph and report written, the trials tracked."""

from __future__ import annotations

import hashlib
import json
import math
import re
import shlex
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lanegraph import interrupts
from lanegraph.api import (
    TuneEntry,
    check_folder,
    command_kept,
    dataset_identity,
    result_cache,
    write_resolved_graph,
)
from lanegraph.builtin import find_graph
from lanegraph.errors import GraphError, InputError, LanegraphError, NotStarted, RunStopped, UsageError
from lanegraph.paths import write_text_atomic
from lanegraph.runlog import get_logger
from lanegraph.tracking import CommandRecord, TrackedRun, existing

from .output import TUNE_FILES, tuned_description, tuned_graph, write_tables
from .report import write_tune_report
from .runs import JOURNAL, PRUNERS, SAMPLERS, make_sampler
from .search import Counts, TrialResult, Tuner, TuneSetup, pooled
from .space import load_space

#: what a tune writes into OUT (what --overwrite may remove, with runs/ and the report)
WRITTEN = [*TUNE_FILES, JOURNAL, f"{JOURNAL}.lock", "runs", "report", "command.json", "run.log"]
#: the names a tune writes, by kind (as lanegraph.api.check_folder takes them): a name held by the user is refused
WRITES = {
    **dict.fromkeys([*TUNE_FILES, JOURNAL, f"{JOURNAL}.lock", "command.json", "run.log"], "file"),
    "runs": "tree",
    "report": "dir",
    "report/index.html": "file",
}


@dataclass
class TuneOptions:
    """The options of ``lanegraph tune`` besides graph, dataset, space and folder."""

    trials: int = 20
    sampler: str = "random"
    pruner: str = "none"
    seed: int = 0
    frames: slice | None = None
    grid_points: int = 5
    cache_dir: Path | None = None
    cache_max_gb: float = 2.0
    no_cache: bool = False
    scheduler: str | None = None
    name: str | None = None  # the tuned graph's name (--name); default: the graph's name and _tuned
    dataset_file: Path | None = None  # the dataset file as given, for the tuned graph's description


def _check_options(o: TuneOptions) -> None:
    if o.trials < 1:
        raise UsageError(f"--trials: expected an integer >= 1, got {o.trials}")
    if o.sampler not in SAMPLERS:
        raise UsageError(f"--sampler {o.sampler}: expected one of {', '.join(SAMPLERS)}")
    if o.pruner not in PRUNERS:
        raise UsageError(f"--pruner {o.pruner}: expected one of {', '.join(PRUNERS)}")
    if o.pruner != "none" and o.sampler != "tpe":
        raise UsageError(
            f"--pruner {o.pruner}: pruning stops a trial between training sequences, which only the per-fold "
            "studies of --sampler tpe do (the shared trials of random, grid and qmc run every sequence)"
        )
    if not (math.isfinite(o.cache_max_gb) and o.cache_max_gb > 0):
        raise UsageError(f"--cache-max-gb: expected a size in GiB > 0, got {o.cache_max_gb}")
    if o.grid_points < 1:
        raise UsageError(f"--grid-points: expected an integer >= 1, got {o.grid_points}")
    if o.name is not None and not GRAPH_NAME.fullmatch(o.name):
        raise UsageError(
            f"--name {o.name!r}: expected a graph name of 1-100 letters, digits, '_', '-' or '.', starting "
            "with a letter or digit"
        )


#: what --name may be: a graph's short name, one word
GRAPH_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,99}")


def search_command(
    graph: Path | str, dataset_file: Path | str | None, space: Path | str, o: TuneOptions
) -> str:
    """The ``lanegraph tune`` command line that makes the same search (without ``--out`` and the
    options that change no result: the cache, the scheduler, tracking), as its arguments were given."""
    words = ["lanegraph", "tune", str(graph)]
    if dataset_file is not None:
        words += ["--dataset", Path(dataset_file).as_posix()]
    words += ["--space", Path(space).as_posix(), "--sampler", o.sampler, "--trials", str(o.trials)]
    words += ["--seed", str(o.seed)]
    if o.sampler == "grid":
        words += ["--grid-points", str(o.grid_points)]
    if o.pruner != "none":
        words += ["--pruner", o.pruner]
    if o.frames is not None:
        words += ["--frames", _frames_text(o.frames)]
    if o.name is not None:
        words += ["--name", o.name]
    return " ".join(shlex.quote(w) for w in words)


def _frames_text(s: slice) -> str:
    parts = ["" if v is None else str(v) for v in (s.start, s.stop)]
    return ":".join(parts) + (f":{s.step}" if s.step is not None else "")


def tune(
    session: Any, graph_name: Path, dataset: Any, space_file: Path, out_dir: Path, o: TuneOptions
) -> int:
    """``lanegraph tune``; 0, or 1 when runs failed or tracking failed. Everything that can be
    checked before a frame runs (graph, space, options, folder, Optuna) is: exit 2."""
    _check_options(o)
    graph_path = find_graph(str(graph_name))
    g = session.load_graph(graph_path)
    space = load_space(space_file, g)
    make_sampler(o.sampler, o.seed)  # Optuna missing: said before anything is written
    runner = session.runner(o.scheduler)
    space_digest = hashlib.sha256(space.digest_text().encode()).hexdigest()[:16]
    identity = dataset_identity(
        "tune", [str(graph_path.resolve()), f"space {space_digest}", f"sampler {o.sampler}", f"seed {o.seed}",
                 f"graph {_graph_digest(g)}"],
        dataset, o.frames,
    )  # fmt: skip
    setup = TuneSetup(
        out_dir, o.trials, o.sampler, o.pruner, o.seed, o.frames, o.grid_points, None, runner,
        progress=session.progress, echo=session.err,
        provenance=session.provenance(None),
        on_trial=lambda t: session.tracking.log_run(_tracked_trial(t)),
    )  # fmt: skip
    try:  # reads every ground truth: a missing or malformed one is found before anything is written
        tuner = Tuner(graph_path, g, space, dataset, setup)
    except InputError as exc:
        raise NotStarted(exc) from exc
    check_folder(out_dir, identity, overwrite=session.overwrite, writes=WRITES)
    cache_folder = (o.cache_dir, "--cache-dir") if o.cache_dir is not None and not o.no_cache else (None, "")
    t0 = time.perf_counter()
    with (
        interrupts.handling(),
        session.locked(out_dir, "tune", cache_folder),
        tune_kept(session, out_dir, identity, graph_path, space_file, o),
    ):
        cache = result_cache(o.cache_dir, o.cache_max_gb, o.no_cache)
        if runner.name == "inprocess":  # the runs in this process share the cache (workers open their own)
            runner.cache = cache
        setup.cache = cache
        try:
            result = tuner.run()
        except (InputError, GraphError) as exc:
            raise NotStarted(exc) from exc
        except KeyboardInterrupt as exc:
            label, code = interrupts.label_and_code(exc)
            raise RunStopped(
                f"interrupted ({label}); the finished trials are kept in {out_dir}/{JOURNAL}: the same command "
                "resumes the search",
                exit_code=code,
            ) from None
        except OSError as exc:
            raise RunStopped(
                f"{str(exc.filename) + ': ' if exc.filename else ''}{exc.strerror or exc}", exc
            ) from None
        rows = write_tables(result, out_dir)
        write_resolved_graph(out_dir, g.resolved_dict())
        description = tuned_description(
            g,
            graph_name,
            result,
            rows,
            search_command(graph_name, o.dataset_file or dataset.file, space_file, o),
        )
        _write_tuned(g, graph_path, out_dir, result, session, o.name, description)
        write_tune_report(result, rows, out_dir, f"lanegraph tune: {g.name} on {dataset.name}")
    for fold in result.folds:
        session.tracking.log_run(_tracked_fold(fold))
    session.out((out_dir / "results.md").read_text())
    hits = f", cache {cache.hits} hits / {cache.misses} misses" if cache is not None else ", no cache"
    session.out(
        f"{len(result.trials)} trial(s), {len(result.folds)} fold(s) in {time.perf_counter() - t0:.1f} s{hits} -> "
        f"{out_dir}/results.md, results.csv, folds.json, trials.csv, tuned.yaml, report/index.html"
    )
    failed = sum(c.failed_runs for t in result.trials for c in t.counts.values())
    if failed:
        session.err(f"{failed} run(s) failed; their sequences counted every frame wrong (see {out_dir}/runs)")
    status = 1 if failed or result.final is None else 0
    session.tracking.end("failed" if status else "ok", existing(out_dir, [*TUNE_FILES, "command.json"]))
    return status if session.tracking.ok else max(status, 1)


def _graph_digest(g: Any) -> str:
    """What the trials' counts kept in OUT's study depend on besides the space: the graph resolved
    (every param spelt out) and its node types' code. A tune into a folder whose study was made with
    other values or other code is another tune (refused, or started afresh with --overwrite), not
    resumed with counts the code no longer gives."""
    resolved = json.dumps(g.resolved_dict(), sort_keys=True, default=str)
    code = sorted({f"{n.type.name} {n.type.code_version}" for n in g.nodes.values()})
    return hashlib.sha256("\n".join([resolved, *code]).encode()).hexdigest()[:16]


def _write_tuned(
    g: Any, graph_path: Path, out_dir: Path, result: Any, session: Any, name: str | None, description: str
) -> None:
    """``tuned.yaml``, extending the input graph (a built-in one by name, else by its path from OUT),
    checked to load as ``lanegraph run`` loads it; where it does not (the input graph lies outside
    the folders ``extends`` may reach from OUT), it extends the resolved copy ``graph.yaml``."""
    path = out_dir / "tuned.yaml"
    texts = [
        tuned_graph(g, graph_path, out_dir, result, extends=extends, name=name, description=description)
        for extends in (None, "graph.yaml")
    ]
    for text in texts:
        write_text_atomic(path, text)
        try:
            session.load_graph(path)
            return
        except LanegraphError as exc:
            get_logger("run").info("tuned.yaml: %s", exc)
    session.err(f"warning: {path} does not load from here (see run.log); the params chosen are in folds.json")


def _tracked_trial(t: TrialResult) -> TrackedRun:
    c = pooled(t.counts, list(t.counts))
    return TrackedRun(
        variant=f"{t.study}#{t.number}",
        sequence=",".join(t.counts),
        params={k: str(v) for k, v in t.params.items()},
        metrics=_metrics(c) | {"score": c.score()},
        tags={"lanegraph.tune.study": t.study, "lanegraph.tune.baseline": str(t.baseline)},
    )


def _tracked_fold(fold: Any) -> TrackedRun:
    test = Counts()
    for c in fold.test_counts.values():
        test = test + c
    return TrackedRun(
        variant=f"fold {fold.name}",
        sequence=",".join(fold.test),
        params={k: str(v) for k, v in fold.params.items()},
        metrics={f"left_out.{k}": v for k, v in _metrics(test).items()}
        | {f"train.{k}": v for k, v in _metrics(fold.train_counts).items()},
        tags={
            "lanegraph.tune.train": ",".join(fold.train),
            "lanegraph.tune.trial": f"{fold.study}#{fold.trial}",
        },
        status="ok" if fold.trial is not None else "stopped",
    )


def _metrics(c: Counts) -> dict[str, float]:
    out = {
        "frames": float(c.frames),
        "detection_ratio": c.detection_ratio,
        "false_lanes": float(c.false_lanes),
    }
    for k in ("precision", "ego_recall", "mean_abs_dx_px"):
        v = getattr(c, k)
        if v is not None:
            out[k] = float(v)
    return out


def tune_kept(
    session: Any, out_dir: Path, identity: dict[str, Any], graph_path: Path, space_file: Path, o: TuneOptions
) -> Any:
    """What a tune keeps beside its results, as an ablation does
    (:func:`lanegraph.api.command_kept`): ``command.json`` with the search."""
    made = session.provenance(graph_path)
    search = TuneEntry(
        graph=str(graph_path), space=str(space_file),
        options={"trials": o.trials, "sampler": o.sampler, "pruner": o.pruner, "seed": o.seed},
    )  # fmt: skip
    tracked = CommandRecord("tune", f"tune -> {out_dir}", out_dir, list(made.command),
                            {"graph": str(graph_path), "space": str(space_file), "sampler": o.sampler,
                             "trials": str(o.trials)})  # fmt: skip
    return command_kept(
        session, out_dir, identity, WRITES, tracked,
        lambda final: session.keep_command(out_dir, "tune", made, identity, WRITTEN, search=search),
        f"tune into {out_dir}: {' '.join(made.command)}", append=True,
    )  # fmt: skip
