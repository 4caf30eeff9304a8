"""What ``lanegraph tune`` needs from elsewhere: its runs and its Optuna study.

- :func:`run_variants` is the **one** place tune runs graphs: a list of (graph variant, sequence)
  requests made into a batch of the run service (:meth:`lanegraph.api.Session.run_tasks`) and run by
  a runner (in this process or on Dask, ``--scheduler``), the result cache shared; it returns each
  run's folder, lanes file or error. A run whose resolved graph, input and frames are
  unchanged since an earlier tune into the same folder is reused, as ``ablate`` does.
- :func:`open_study` / :func:`make_sampler`: Optuna's study on a journal file in the output folder
  (``study.journal``), so an interrupted tune resumes. Optuna is an extra (``pip install
  "lanegraph[tune]"``), imported only here and only when a tune runs.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lanegraph.api import LANES, BatchRun, Session, describe_error, find_result
from lanegraph.errors import GraphError, UsageError
from lanegraph.paths import inside, safe_name

#: the samplers whose proposals do not depend on the scores: one shared set of trials serves every fold
INDEPENDENT_SAMPLERS = ("random", "grid", "qmc")
SAMPLERS = (*INDEPENDENT_SAMPLERS, "tpe")
PRUNERS = ("none", "median")
JOURNAL = "study.journal"


@dataclass
class RunRequest:
    """One graph variant on one sequence: the variant's folder name and its ``--set`` items."""

    variant: str
    graph: Path
    sets: list[str]
    sequence: Any  # a sequence of the dataset (lanegraph.api.load_dataset)
    frames: slice | None = None


@dataclass
class RunDone:
    """What a requested run left: its folder, its lanes file (None when it failed) and its error."""

    run_dir: Path
    lanes: Path | None = None
    error: str | None = None
    reused: bool = False
    failed_frames: int = 0
    extra: dict[str, Any] = field(default_factory=dict)


def run_variants(
    requests: Sequence[RunRequest],
    out_dir: Path,
    *,
    cache: Any,
    runner: Any,
    progress: bool,
    echo: Callable[[str], None] | None,
    provenance: Any = None,
) -> dict[tuple[str, str], RunDone]:
    """Run every request (its folder ``OUT/runs/<variant>/<sequence>/``) as one batch of the run
    service (``runner``: that of ``--scheduler``, None: in this process sharing ``cache``;
    ``provenance``: how the runs are made, in each run.json); ``{(variant, sequence): RunDone}``. A
    variant whose params the graph refuses is a failed run (its error said), not a stopped tune.
    Ctrl-C ends the finished runs' folders whole and is raised again."""
    service = Session(err=echo, progress=progress)
    runs: list[tuple[RunRequest, BatchRun]] = []
    done: dict[tuple[str, str], RunDone] = {}
    for req in requests:
        run_dir = inside(out_dir, f"runs/{req.variant}/{safe_name(req.sequence.name)}", "tune --out")
        try:
            graph = service.open_graph(req.graph, req.sets)
            graph.validate(service.pm)
        except GraphError as exc:
            done[(req.variant, req.sequence.name)] = RunDone(run_dir, error=str(exc))
            continue
        runs.append(
            (
                req,
                BatchRun(
                    req.variant, req.sequence.name, graph, req.sequence.input, req.frames, run_dir, provenance
                ),
            )
        )
    # a run whose folder holds its result for the same graph, input, frames and code is not run again
    batch = service.run_tasks([r for _, r in runs], runner, cache=cache, reuse=cache is not None)
    if batch.interrupted is not None:
        raise batch.interrupted
    for (req, _), plan in zip(runs, batch.plans):
        record = plan.record
        error = None
        if plan.outcome is not None and plan.outcome.error is not None:
            error = describe_error(plan.outcome.error)
        elif record is not None and record.error:
            error = record.error
        lanes = find_result(plan.run_dir, LANES, record=record) if error is None else None
        if error is None and lanes is None:
            error = f"{plan.run_dir}: the run wrote no lanes (the graph needs a lanes sink)"
        failed = len(record.failures) if record is not None else 0
        done[(req.variant, req.sequence.name)] = RunDone(plan.run_dir, lanes, error, plan.reused, failed)
    return done


# --------------------------------------------------------------------------- the study
def _optuna() -> Any:
    try:
        import optuna
    except ImportError:
        raise UsageError(
            'lanegraph tune needs Optuna: pip install "lanegraph[tune]" (or pip install optuna)'
        ) from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna


def make_sampler(name: str, seed: int, grid: dict[str, list[Any]] | None = None) -> Any:
    """Optuna's sampler for ``--sampler``: random, grid (``grid``: the values per param), qmc
    (scrambled Sobol) or tpe."""
    optuna = _optuna()
    if name == "random":
        return optuna.samplers.RandomSampler(seed=seed)
    if name == "grid":

        class AskTellGrid(optuna.samplers.GridSampler):
            """The grid sampler for ask-and-tell: tune asks as many trials as the grid has points,
            so the sampler need not stop the study (``Study.stop`` works only inside ``optimize``)."""

            def after_trial(self, study, trial, state, values):  # noqa: ANN001, D102
                return None

        return AskTellGrid(grid or {}, seed=seed)
    if name == "qmc":  # experimental in Optuna (its warning said in docs/tune.md, not on every run)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            return optuna.samplers.QMCSampler(
                seed=seed, scramble=True, independent_sampler=optuna.samplers.RandomSampler(seed=seed),
                warn_independent_sampling=False, warn_asynchronous_seeding=False,
            )  # fmt: skip
    if name == "tpe":
        return optuna.samplers.TPESampler(seed=seed)
    raise UsageError(f"--sampler {name}: expected one of {', '.join(SAMPLERS)}")


def make_pruner(name: str) -> Any:
    """Optuna's pruner for ``--pruner``: none, or median (a trial whose score after a training
    sequence is below the median of earlier trials' at that step stops early; per-fold studies only)."""
    optuna = _optuna()
    if name == "median":
        return optuna.pruners.MedianPruner(n_startup_trials=3, n_warmup_steps=0)
    return optuna.pruners.NopPruner()


def open_study(out_dir: Path, name: str, sampler: Any, pruner: Any, requeue: bool = True) -> Any:
    """The study ``name`` in ``OUT/study.journal`` (created, or loaded to resume), maximising the
    score. Trials a killed tune left running are failed and (``requeue``) their params queued
    again, so a resumed tune tries the same params it would have (a grid sampler needs no queue:
    it takes the grid's points no finished trial has)."""
    optuna = _optuna()
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(str(out_dir / JOURNAL)))
    study = optuna.create_study(
        storage=storage,
        sampler=sampler,
        pruner=pruner,
        study_name=name,
        direction="maximize",
        load_if_exists=True,
    )
    state = optuna.trial.TrialState
    for t in study.get_trials(deepcopy=False, states=(state.RUNNING,)):
        if requeue:
            study.enqueue_trial(dict(t.params), user_attrs={"requeued_from": t.number})
        study.tell(t.number, state=state.FAIL)
    return study


def trial_states() -> Any:
    return _optuna().trial.TrialState
