"""Cross-validated parameter search (``lanegraph tune``): each fold chooses params on the other
sequences and is scored on the ones it left out.

**Folds** (:class:`LeaveOneGroupOut`, modelled on scikit-learn's splitter of that name): one fold
per group of sequences (a sequence's ``group`` in the dataset file, else its own name); the fold
leaves that group out, chooses on the others and scores the left-out group. A fold never scores on
a sequence it chose on (:func:`choose` sees only the training sequences' counts).

**The score** of a set of params on some sequences pools their frames (:class:`Counts`):

- detection ratio = correct frames / frames, a frame being correct when every reported lane matches
  a marking and every painted ego boundary is matched (:func:`lanegraph.api.evaluate`): a false
  lane makes a frame wrong exactly as a missed boundary does;
- ties are broken by precision first (fewer false lanes per frame), then more ego boundaries
  matched, then a smaller mean |dx|, then the earlier trial (:func:`selection_key`);
- Optuna's objective value is ``detection ratio - false lanes / (1000 * frames)``
  (:meth:`Counts.score`): the first tie-break folded in, worth less than one frame.

A run that fails counts every frame of its sequence wrong.

**Two ways to search** (``--sampler``):

- random, grid, qmc (samplers that do not look at the scores): one shared study; each trial runs
  its params on every sequence once, and each fold picks among the same trials using its training
  sequences only -- cheap and as honest;
- tpe: the proposals follow the scores, so each fold has its own study over its training
  sequences (and one more study over all sequences chooses the final params).

Either way the params chosen on all sequences are the tuned graph's, and the graph's own values
are tried first (when they lie in the space) so the table has the untuned baseline too.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from lanegraph.api import digest, evaluate, read_gt, read_predictions
from lanegraph.errors import UsageError

from .runs import (
    INDEPENDENT_SAMPLERS,
    RunRequest,
    make_pruner,
    make_sampler,
    open_study,
    run_variants,
    trial_states,
)
from .space import Space, sets_of


# --------------------------------------------------------------------------- scores
@dataclass
class Counts:
    """Frame-level counts of the lane metric over some frames (pooled by adding)."""

    frames: int = 0
    correct: int = 0
    reported: int = 0
    matched: int = 0
    ego_total: int = 0
    ego_matched: int = 0
    dx_sum: float = 0.0
    dx_n: int = 0
    failed_runs: int = 0

    def __add__(self, other: Counts) -> Counts:
        return Counts(**{k: getattr(self, k) + getattr(other, k) for k in self.__dataclass_fields__})

    @property
    def false_lanes(self) -> int:
        return self.reported - self.matched

    @property
    def detection_ratio(self) -> float:
        return self.correct / self.frames if self.frames else 0.0

    @property
    def precision(self) -> float | None:
        return self.matched / self.reported if self.reported else None

    @property
    def ego_recall(self) -> float | None:
        return self.ego_matched / self.ego_total if self.ego_total else None

    @property
    def mean_abs_dx_px(self) -> float | None:
        return self.dx_sum / self.dx_n if self.dx_n else None

    def score(self) -> float:
        """Optuna's value: detection ratio - false lanes / (1000 frames)."""
        return (self.correct - self.false_lanes / 1000.0) / self.frames if self.frames else 0.0

    def figures(self) -> dict[str, Any]:
        return {
            "frames": self.frames,
            "detection_ratio": self.detection_ratio,
            "precision": self.precision,
            "false_lanes": self.false_lanes,
            "ego_recall": self.ego_recall,
            "mean_abs_dx_px": self.mean_abs_dx_px,
            "failed_runs": self.failed_runs,
        }


def counts_of(pred: list[dict[str, Any]], gt: list[dict[str, Any]]) -> Counts:
    """The counts of one run's lanes against its ground truth (:func:`lanegraph.api.evaluate`)."""
    ev = evaluate(pred, gt)
    c = Counts()
    for r in ev["per_frame"]:
        c.frames += 1
        c.correct += int(r.correct)
        c.reported += r.reported
        c.matched += r.matched
        c.ego_total += r.ego_total
        c.ego_matched += r.ego_matched
        c.dx_sum += sum(r.dx)
        c.dx_n += len(r.dx)
    return c


def failed_counts(gt: list[dict[str, Any]]) -> Counts:
    """A failed run: every frame of its sequence wrong."""
    ego = sum(sum(1 for s in ("left", "right") if (g.get("ego") or {}).get(s) is not None) for g in gt)
    return Counts(frames=len(gt), ego_total=ego, failed_runs=1)


def pooled(counts: dict[str, Counts], sequences: Sequence[str]) -> Counts:
    out = Counts()
    for s in sequences:
        out = out + counts[s]
    return out


def selection_key(c: Counts, number: int) -> tuple:
    """Smaller is better: detection ratio, then false lanes per frame (precision first), then ego
    boundaries matched, then mean |dx|, then the trial's number."""
    frames = max(c.frames, 1)
    dx = c.mean_abs_dx_px
    return (
        -c.correct / frames,
        c.false_lanes / frames,
        -c.ego_matched / frames,
        dx if dx is not None else 1e9,
        number,
    )


# --------------------------------------------------------------------------- folds
class LeaveOneGroupOut:
    """Folds that each leave one group out (scikit-learn's ``LeaveOneGroupOut``): ``split(groups)``
    yields ``(train indices, test indices)`` per distinct group, in order of first appearance."""

    def get_n_splits(self, groups: Sequence[str]) -> int:
        return len(dict.fromkeys(groups))

    def split(self, groups: Sequence[str]):
        names = list(dict.fromkeys(groups))
        if len(names) < 2:
            raise UsageError(
                f"tune needs at least two groups of sequences to leave one out, got {len(names)} ({', '.join(names)})"
            )
        for name in names:
            test = [i for i, g in enumerate(groups) if g == name]
            train = [i for i, g in enumerate(groups) if g != name]
            yield train, test


@dataclass
class TrialResult:
    """A finished trial: its number, study, params and counts per sequence it ran on."""

    study: str
    number: int
    params: dict[str, Any]
    counts: dict[str, Counts]
    baseline: bool = False
    state: str = "COMPLETE"


@dataclass
class Fold:
    """A fold: the group it leaves out, its training and test sequences, the trial it chose (on its
    training sequences only) and that trial's counts on each."""

    name: str
    train: list[str]
    test: list[str]
    study: str
    trial: int | None = None
    params: dict[str, Any] = field(default_factory=dict)
    train_counts: Counts = field(default_factory=Counts)
    test_counts: dict[str, Counts] = field(default_factory=dict)


def choose(trials: Sequence[TrialResult], sequences: Sequence[str]) -> TrialResult | None:
    """The best trial over ``sequences`` (:func:`selection_key`), from those that ran on all of them."""
    usable = [t for t in trials if t.state == "COMPLETE" and all(s in t.counts for s in sequences)]
    if not usable:
        return None
    return min(usable, key=lambda t: selection_key(pooled(t.counts, sequences), t.number))


# --------------------------------------------------------------------------- the search
@dataclass
class TuneResult:
    mode: str  # "shared" or "per-fold"
    sampler: str
    trials: list[TrialResult]
    folds: list[Fold]
    final: TrialResult | None
    sequences: list[Any]  # the dataset's sequences (lanegraph.api.load_dataset)
    groups: dict[str, str]


@dataclass
class TuneSetup:
    """What a tune needs besides the graph and space."""

    out_dir: Path
    trials: int
    sampler: str = "random"
    pruner: str = "none"
    seed: int = 0
    frames: slice | None = None
    grid_points: int = 5
    cache: Any = None  # the result cache shared by the runs (None: none)
    runner: Any = None  # the runner of --scheduler (None: in this process)
    progress: bool = True
    echo: Callable[[str], None] = print
    provenance: Any = None  # how the runs are made (lanegraph.api.Session.provenance), in each run.json
    on_trial: Callable[[TrialResult], None] | None = None


class Tuner:
    """Runs the search of :mod:`lanegraph_tune.search` (see the module's doc)."""

    def __init__(self, graph_path: Path, graph: Any, space: Space, dataset: Any, setup: TuneSetup):
        self.graph_path = Path(graph_path)
        self.graph = graph
        self.space = space
        self.setup = setup
        self.sequences = list(dataset)
        self.groups = {s.name: (s.group or s.name) for s in self.sequences}
        self.gts = {}
        for s in self.sequences:
            if s.gt is None:
                raise UsageError(f"sequence {s.name!r}: tune scores every sequence: give it a gt file")
            sel = s.frames if s.frames is not None else setup.frames
            self.gts[s.name] = read_gt(s, sel)
        self.splits = list(LeaveOneGroupOut().split([self.groups[s.name] for s in self.sequences]))
        self.independent = setup.sampler in INDEPENDENT_SAMPLERS
        grid = {p.key: p.grid(setup.grid_points) for p in space.params}
        self.grid_size = 1
        for v in grid.values():
            self.grid_size *= len(v)
        self.grid = grid
        self._baseline = self.baseline()

    # -- pieces
    def baseline(self) -> dict[str, Any] | None:
        """The graph's own values of the searched params, when every one lies in the space."""
        out = {}
        for p in self.space.params:
            node_id, _, name = p.key.partition(".")
            v = getattr(self.graph.nodes[node_id].params, name)
            if p.kind == "choice":
                if v not in p.choices:
                    return None
            elif self.setup.sampler == "grid":
                if v not in self.grid[p.key]:
                    return None
            elif not (isinstance(v, (int, float)) and p.low <= v <= p.high):
                return None
            out[p.key] = v
        return out

    def _variant(self, params: dict[str, Any]) -> str:
        return "p-" + digest(sets_of(params))[:12]

    def _run(self, batch: list[tuple[dict[str, Any], list[str]]]) -> list[dict[str, Counts]]:
        """Run each params set on its sequences (one batch); the counts per sequence."""
        specs = {s.name: s for s in self.sequences}
        requests, asked = [], set()
        for params, seqs in batch:
            for name in seqs:
                s = specs[name]
                if (self._variant(params), name) in asked:  # the same params twice in a batch: one run
                    continue
                asked.add((self._variant(params), name))
                requests.append(
                    RunRequest(self._variant(params), self.graph_path, sets_of(params), s,
                               s.frames if s.frames is not None else self.setup.frames)
                )  # fmt: skip
        st = self.setup
        done = run_variants(
            requests, st.out_dir, cache=st.cache, runner=st.runner, progress=st.progress, echo=st.echo,
            provenance=st.provenance,
        )  # fmt: skip
        out = []
        for params, seqs in batch:
            counts = {}
            for name in seqs:
                d = done[(self._variant(params), name)]
                if d.error is not None or d.lanes is None:
                    st.echo(f"warning: tune: params {json.dumps(params)} on {name}: {d.error}")
                    counts[name] = failed_counts(self.gts[name])
                else:
                    counts[name] = counts_of(read_predictions(d.lanes), self.gts[name])
            out.append(counts)
        return out

    def _ask(self, study: Any) -> tuple[Any, dict[str, Any]]:
        if self.setup.sampler == "random":  # seeded per trial: a resumed study draws what it would have
            states = trial_states()
            k = len(study.get_trials(deepcopy=False, states=(states.COMPLETE, states.RUNNING, states.PRUNED)))
            study.sampler = make_sampler("random", self.setup.seed * 1_000_003 + k)
        trial = study.ask()
        return trial, {p.key: p.suggest(trial) for p in self.space.params}

    def _tell(
        self, study: Any, trial: Any, params: dict[str, Any], counts: dict[str, Counts], name: str
    ) -> TrialResult:
        trial.set_user_attr("counts", {k: asdict(v) for k, v in counts.items()})
        seqs = list(counts)
        study.tell(trial, pooled(counts, seqs).score())
        result = TrialResult(name, trial.number, params, counts, params == self._baseline)
        if self.setup.on_trial is not None:
            self.setup.on_trial(result)
        return result

    def _study(self, name: str, seed: int) -> Any:
        st = self.setup
        study = open_study(
            st.out_dir,
            name,
            make_sampler(st.sampler, seed, self.grid),
            make_pruner(st.pruner),
            requeue=st.sampler != "grid",
        )
        if not study.trials and self._baseline is not None and st.sampler != "grid":
            study.enqueue_trial(self._baseline)  # the graph's own values first (a grid tries them when on it)
        return study

    def _finished(self, study: Any, name: str) -> list[TrialResult]:
        states = trial_states()
        out = []
        for t in study.get_trials(deepcopy=False, states=(states.COMPLETE,)):
            counts = {k: Counts(**v) for k, v in (t.user_attrs.get("counts") or {}).items()}
            out.append(TrialResult(name, t.number, dict(t.params), counts, dict(t.params) == self._baseline))
        return out

    def _search(self, name: str, seed: int, sequences: list[str], label: str) -> list[TrialResult]:
        """``trials`` trials of study ``name`` on ``sequences`` (resumed where one stopped)."""
        st = self.setup
        study = self._study(name, seed)
        results = self._finished(study, name)
        n = min(st.trials, self.grid_size) if st.sampler == "grid" else st.trials
        if results:
            st.echo(f"tune: {label}: resuming study {name!r}: {len(results)} of {n} trial(s) done")
        batch = 1
        if self.independent and st.runner is not None and getattr(st.runner, "name", "") != "inprocess":
            batch = max(1, n - len(results))  # a cluster runs the independent trials side by side
        while len(results) < n:
            k = min(batch, n - len(results))
            asked = [self._ask(study) for _ in range(k)]
            first = len(results) + 1
            span = f"{first}/{n}" if k == 1 else f"{first}-{first + k - 1}/{n}"
            st.echo(f"tune: {label}: trial {span}: {len(sequences)} sequence(s) ({', '.join(sequences)})")
            if st.pruner != "none" and not self.independent:
                results += self._pruned_trial(study, name, asked[0], sequences)
                continue
            all_counts = self._run([(params, sequences) for _, params in asked])
            for (trial, params), counts in zip(asked, all_counts):
                results.append(self._tell(study, trial, params, counts, name))
        return results

    def _pruned_trial(self, study: Any, name: str, asked: tuple, sequences: list[str]) -> list[TrialResult]:
        """One trial run a sequence at a time, its pooled score reported after each (pruning)."""
        trial, params = asked
        counts: dict[str, Counts] = {}
        for step, seq in enumerate(sequences):
            counts.update(self._run([(params, [seq])])[0])
            trial.report(pooled(counts, list(counts)).score(), step)
            if trial.should_prune() and step < len(sequences) - 1:
                study.tell(trial, state=trial_states().PRUNED)
                self.setup.echo(f"tune: trial {trial.number} pruned after {seq}")
                return []
        return [self._tell(study, trial, params, counts, name)]

    # -- the whole search
    def run(self) -> TuneResult:
        names = [s.name for s in self.sequences]
        folds = []
        trials: list[TrialResult] = []
        seed = self.setup.seed
        if self.independent:
            trials = self._search("shared", seed, names, f"shared trials ({self.setup.sampler})")
            for train_i, test_i in self.splits:
                folds.append(self._fold(train_i, test_i, "shared", trials))
            final = choose(trials, names)
        else:
            for k, (train_i, test_i) in enumerate(self.splits):
                fold_name = self.groups[self.sequences[test_i[0]].name]
                train = [names[i] for i in train_i]
                found = self._search(
                    f"fold-{fold_name}",
                    seed + k + 1,
                    train,
                    f"fold {k + 1}/{len(self.splits)} (leaves out {fold_name})",
                )
                trials += found
                fold = self._fold(train_i, test_i, f"fold-{fold_name}", found)
                if fold.trial is not None:  # the chosen params on the left-out sequences: runs of their own
                    self.setup.echo(
                        f"tune: fold {k + 1}/{len(self.splits)}: its choice ({fold.study}#{fold.trial}) on the "
                        f"left-out {', '.join(fold.test)}"
                    )
                    fold.test_counts = self._run([(fold.params, fold.test)])[0]
                folds.append(fold)
            found = self._search("all", seed, names, "all sequences")
            trials += found
            final = choose(found, names)
        return TuneResult(
            "shared" if self.independent else "per-fold", self.setup.sampler, trials, folds, final,
            self.sequences, self.groups,
        )  # fmt: skip

    def _fold(self, train_i: list[int], test_i: list[int], study: str, trials: list[TrialResult]) -> Fold:
        names = [s.name for s in self.sequences]
        train, test = [names[i] for i in train_i], [names[i] for i in test_i]
        assert not set(train) & set(test), "a fold's training and test sequences overlap"
        fold = Fold(self.groups[test[0]], train, test, study)
        best = choose(trials, train)  # chosen on the training sequences alone
        if best is not None:
            fold.trial, fold.params = best.number, dict(best.params)
            fold.train_counts = pooled(best.counts, train)
            fold.test_counts = {s: best.counts[s] for s in test if s in best.counts}
        return fold
