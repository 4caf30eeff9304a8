"""`lanegraph tune`: cross-validated search on synthetic sequences -- the known best param found,
folds that never score on a sequence they chose on, an interrupted study resumed, bad space files
refused before any frame, and the same search on a real Dask cluster and tracked by a real MLflow
server."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from lanegraph.cli import main

ROOT = Path(__file__).resolve().parents[2]

#: the toy graph: paper.yaml without the line follower (so verify alone decides), its paint check's
#: `min_painted_rows` set where no lane passes: only a small value finds the lanes
TOY = """name: toy
extends: {paper}
remove: [follow, verify_followed, verify_straddled, merge, near]
nodes:
  verify: {{params: {{min_painted_rows: 50000}}}}
  project: {{inputs: {{lanes: verify.lanes}}}}
"""
#: the known best (10) is neither the graph's value nor the first choice
SPACE = "params:\n  verify.min_painted_rows: {choices: [100000, 10, 50000]}\n"


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    """Three 2-frame synthetic sequences (two groups: `c` is grouped with nothing else, `a`
    and `b` are their own), the toy graph, the space and a result cache shared by the tests."""
    from lanegraph_synthetic import preset, write_sequence

    root = tmp_path_factory.mktemp("tune")
    write_sequence(preset("straight"), root / "a", 2)
    write_sequence(preset("curved"), root / "b", 2)
    write_sequence(preset("straight", seed=3), root / "c", 2)
    (root / "ds.yaml").write_text(
        "name: toy\nsequences:\n"
        "  - {name: a, input: a, gt: a/lanes_gt.jsonl}\n"
        "  - {name: b, input: b, gt: b/lanes_gt.jsonl}\n"
        "  - {name: c, input: c, gt: c/lanes_gt.jsonl, group: third}\n"
    )
    (root / "toy.yaml").write_text(TOY.format(paper=ROOT / "graphs" / "paper.yaml"))
    (root / "space.yaml").write_text(SPACE)
    return root


def _tune(toy: Path, out: Path, *extra: str, sampler: str = "grid"):
    args = ["tune", str(toy / "toy.yaml"), "--dataset", str(toy / "ds.yaml"), "--space", str(toy / "space.yaml"),
            "--out", str(out), "--sampler", sampler, "--cache-dir", str(toy / "cache"), "--quiet", *extra]  # fmt: skip
    return CliRunner().invoke(main, args)


def _rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(path.open()))


@pytest.fixture(scope="module")
def tuned(toy):
    out = toy / "out"
    with pytest.MonkeyPatch.context() as mp:  # run where the graph is, as a user does
        mp.chdir(toy)
        r = _tune(toy, out)
    assert r.exit_code == 0, r.output
    return out, r.output


def test_tune_finds_the_known_best_param_and_writes_a_graph_that_runs(tuned, toy, tmp_path, monkeypatch):
    out, output = tuned
    folds = json.loads((out / "folds.json").read_text())
    assert folds["mode"] == "shared" and folds["sampler"] == "grid"
    assert [f["left_out"] for f in folds["folds"]] == ["a", "b", "third"]
    assert all(f["params"] == {"verify.min_painted_rows": 10} for f in folds["folds"])
    assert folds["chosen_on_all"]["params"] == {"verify.min_painted_rows": 10}
    # every grid point was tried once; the graph's own value (50000) is the baseline, and finds nothing
    trials = _rows(out / "trials.csv")
    assert sorted(int(t["verify.min_painted_rows"]) for t in trials) == [10, 50000, 100000]
    assert [t["baseline"] for t in trials if t["verify.min_painted_rows"] == "50000"] == ["True"]
    table = {r["sequence"]: r for r in _rows(out / "results.csv")}
    assert list(table) == ["a", "b", "c", "all"]
    assert table["all"]["left_out_detection_ratio"] == table["all"]["tuned_on_detection_ratio"] == "1.0"
    assert table["all"]["baseline_detection_ratio"] == "0.0" and table["c"]["fold"] == "third"
    assert "| sequence | frames | left out | tuned on | baseline |" in output
    assert (out / "report" / "index.html").read_text().count("<tr") >= 8
    assert "<script" not in (out / "report" / "index.html").read_text()
    command = json.loads((out / "command.json").read_text())
    assert command["kind"] == "tune" and "tuned.yaml" in command["written"]
    # the tuned graph extends the input graph and runs as it is
    tuned_graph = yaml.safe_load((out / "tuned.yaml").read_text())
    assert tuned_graph["extends"] == "../toy.yaml"  # the input graph, found from the current folder
    assert tuned_graph["nodes"] == {"verify": {"params": {"min_painted_rows": 10}}}
    monkeypatch.chdir(toy)
    r = CliRunner().invoke(main, ["run", str(out / "tuned.yaml"), "--input", str(toy / "a"),
                                  "--out", str(tmp_path / "run"), "--quiet"])  # fmt: skip
    assert r.exit_code == 0, r.output
    lanes = [json.loads(line) for line in (tmp_path / "run" / "lanes.jsonl").read_text().splitlines()]
    assert len(lanes) == 2 and all(len(f["lanes"]) >= 2 for f in lanes)


def test_a_second_tune_into_another_folder_reuses_the_cache_and_the_folder_rule_holds(tuned, toy):
    out, _ = tuned
    # the same command again: the folder holds this tune: it runs again (the study resumed, done)
    r = _tune(toy, out)
    assert r.exit_code == 0, r.output
    assert len(_rows(out / "trials.csv")) == 3
    # another sampler is another tune: refused before anything, the folder as it was
    before = sorted(p.name for p in out.iterdir())
    r = _tune(toy, out, sampler="random")
    assert r.exit_code == 2 and "holds the results of another" in r.output
    assert sorted(p.name for p in out.iterdir()) == before
    # --overwrite removes what the grid tune wrote (its study too), not the user's file beside it
    other = toy / "out_overwrite"
    assert _tune(toy, other).exit_code == 0
    (other / "notes.txt").write_text("mine")
    r = _tune(toy, other, "--overwrite", "--trials", "2", sampler="random")
    assert r.exit_code == 0, r.output
    assert (other / "notes.txt").read_text() == "mine"
    assert "resuming" not in r.output and len(_rows(other / "trials.csv")) == 2


def test_name_names_the_tuned_graph_whose_description_remakes_it(tuned, toy, monkeypatch):
    """``--name``: the tuned graph's name; its description names the search as a command line that
    remakes it (no --out, no cache option) and the pooled left-out figure; the same search into
    another folder writes the same file, byte for byte."""
    monkeypatch.chdir(toy)
    texts = []
    for out in ("out_named", "out_named_again"):
        r = CliRunner().invoke(
            main,
            ["tune", "toy.yaml", "--dataset", "ds.yaml", "--space", "space.yaml", "--out", out,
             "--sampler", "grid", "--cache-dir", str(toy / "cache"), "--name", "toy_best", "-q"],
        )  # fmt: skip
        assert r.exit_code == 0, r.output
        texts.append((toy / out / "tuned.yaml").read_text())
    assert texts[0] == texts[1]
    doc = yaml.safe_load(texts[0])
    assert doc["name"] == "toy_best" and doc["extends"] == "../toy.yaml"
    assert doc["nodes"] == {"verify": {"params": {"min_painted_rows": 10}}}
    command = (
        "`lanegraph tune toy.yaml --dataset ds.yaml --space space.yaml --sampler grid --trials 20 --seed 0 "
        "--grid-points 5 --name toy_best`"
    )
    assert command in doc["description"]
    # the grid finds 10 on every fold: left out and tuned on all right; the toy's own 50000 finds nothing
    assert (
        "Left out (each group scored by the fold that chose on the others), pooled: 100.0 % detection"
        in (doc["description"])
    )
    assert "toy's own values: 0.0 % detection ratio" in doc["description"]
    r = CliRunner().invoke(
        main, ["run", str(toy / "out_named" / "tuned.yaml"), "--input", "a", "--out", "run_named", "-q"]
    )
    assert r.exit_code == 0, r.output
    # the default name is the graph's and _tuned
    assert yaml.safe_load((tuned[0] / "tuned.yaml").read_text())["name"] == "toy_tuned"


def test_a_folder_whose_study_was_made_with_other_graph_values_is_another_tune(toy, tmp_path):
    """The study in OUT keeps each trial's counts: a graph edited since (a value outside the space)
    would resume with counts the graph no longer gives, so the folder is another tune's (exit 2)."""
    graph = tmp_path / "g.yaml"
    graph.write_text(TOY.format(paper=ROOT / "graphs" / "paper.yaml"))
    args = ["tune", str(graph), "--dataset", str(toy / "ds.yaml"), "--space", str(toy / "space.yaml"),
            "--out", str(tmp_path / "out"), "--sampler", "grid", "--cache-dir", str(toy / "cache"), "-q"]  # fmt: skip
    assert CliRunner().invoke(main, args).exit_code == 0
    assert CliRunner().invoke(main, args).exit_code == 0  # unchanged: the same tune (resumed, done)
    graph.write_text(graph.read_text() + "  hough: {params: {min_relative: 0.3}}\n")
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2 and "holds the results of another" in r.output, r.output


@pytest.mark.parametrize("name", ["", "../paper", "two words", "-x", "a" * 101])
def test_a_bad_name_is_refused_before_anything(toy, tmp_path, name):
    r = _tune(toy, tmp_path / "out", "--name", name)
    assert r.exit_code == 2 and "--name" in r.output, r.output
    assert not (tmp_path / "out").exists()


class _FakeRuns:
    """Tuner._run replaced: the counts a param set gets on a sequence, from a table, and every call
    recorded (which params ran on which sequences)."""

    def __init__(self, best: dict[str, int], interrupt_at: int | None = None):
        self.best = best  # per sequence: the value that gets every frame right there
        self.calls: list[tuple[int, list[str]]] = []
        self.interrupt_at = interrupt_at

    def __call__(self, tuner, batch):
        from lanegraph_tune.search import Counts

        out = []
        for params, seqs in batch:
            if self.interrupt_at is not None and len(self.calls) == self.interrupt_at:
                raise KeyboardInterrupt
            v = params["verify.min_painted_rows"]
            self.calls.append((v, list(seqs)))
            out.append(
                {s: Counts(frames=4, correct=4 if v == self.best[s] else 1, ego_total=8) for s in seqs}
            )
        return out


def _tuner(toy: Path, out: Path, sampler: str, trials: int, space: str):
    from lanegraph_tune.search import Tuner, TuneSetup
    from lanegraph_tune.space import load_space

    from lanegraph.api import load_dataset
    from lanegraph.graph.files import load_graph_named

    g = load_graph_named(str(toy / "toy.yaml"))
    (toy / f"space_{sampler}.yaml").write_text(space)
    sp = load_space(toy / f"space_{sampler}.yaml", g)
    out.mkdir(parents=True, exist_ok=True)
    setup = TuneSetup(out, trials, sampler, seed=1, progress=False, echo=lambda m: None)
    return Tuner(toy / "toy.yaml", g, sp, load_dataset(toy / "ds.yaml"), setup)


@pytest.mark.parametrize("sampler", ["grid", "tpe"])
def test_a_fold_never_scores_on_a_sequence_it_chose_on(toy, tmp_path, monkeypatch, sampler):
    from lanegraph_tune.search import Tuner

    # 1 is right on a and b, 2 on c alone, 3 nowhere: the fold that leaves c out must choose 1 and
    # score 25 % on c; choosing on c too would have given 2
    fake = _FakeRuns({"a": 1, "b": 1, "c": 2})
    monkeypatch.setattr(Tuner, "_run", lambda self, batch, f=fake: f(self, batch))
    seen: list[tuple[str, list[str]]] = []
    search = Tuner._search

    def spy(self, name, seed, sequences, label):
        seen.append((name, list(sequences)))
        return search(self, name, seed, sequences, label)

    monkeypatch.setattr(Tuner, "_search", spy)
    space = "params:\n  verify.min_painted_rows: {choices: [3, 2, 1]}\n"
    result = _tuner(toy, tmp_path / sampler, sampler, 6, space).run()
    folds = {f.name: f for f in result.folds}
    assert {k: (f.train, f.test) for k, f in folds.items()} == {
        "a": (["b", "c"], ["a"]), "b": (["a", "c"], ["b"]), "third": (["a", "b"], ["c"]),
    }  # fmt: skip
    third = folds["third"]
    assert third.params == {"verify.min_painted_rows": 1}
    assert third.test_counts["c"].detection_ratio == 0.25 and third.train_counts.detection_ratio == 1.0
    assert result.final.params == {"verify.min_painted_rows": 1}
    for f in result.folds:
        assert not set(f.train) & set(f.test)
    if sampler == "tpe":  # each fold's study ran on its training sequences only
        for name, seqs in seen:
            if name.startswith("fold-"):
                left_out = folds[name.removeprefix("fold-")].test
                assert not set(seqs) & set(left_out), (name, seqs)
        # the runs on a left-out sequence are the fold's chosen params alone, once
        on_c = [v for v, seqs in fake.calls if "c" in seqs and seqs == ["c"]]
        assert on_c == [1]


def test_an_interrupted_study_resumes_with_the_same_params(toy, tmp_path, monkeypatch):
    from lanegraph_tune.search import Tuner

    space = "params:\n  verify.min_painted_rows: {low: 1, high: 40}\n"
    out = tmp_path / "study"
    first = _FakeRuns(dict.fromkeys("abc", 7), interrupt_at=3)
    monkeypatch.setattr(Tuner, "_run", lambda self, batch, f=first: f(self, batch))
    with pytest.raises(KeyboardInterrupt):
        _tuner(toy, out, "random", 6, space).run()
    assert len(first.calls) == 3 and (out / "study.journal").is_file()
    again = _FakeRuns(dict.fromkeys("abc", 7))
    monkeypatch.setattr(Tuner, "_run", lambda self, batch, f=again: f(self, batch))
    result = _tuner(toy, out, "random", 6, space).run()
    assert len(again.calls) == 3  # three trials finished before: three more
    assert len(result.trials) == 6 and sorted(t.number for t in result.trials)[:3] == [0, 1, 2]
    # an uninterrupted study with the same seed tries the same params
    fresh = _FakeRuns(dict.fromkeys("abc", 7))
    monkeypatch.setattr(Tuner, "_run", lambda self, batch, f=fresh: f(self, batch))
    _tuner(toy, tmp_path / "fresh", "random", 6, space).run()
    assert [v for v, _ in first.calls + again.calls] == [v for v, _ in fresh.calls]


def test_an_interrupted_tune_on_the_command_line_resumes(toy, tmp_path, monkeypatch):
    from lanegraph_tune import search as tune_module

    calls = []
    real = tune_module.run_variants

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(tune_module, "run_variants", interrupted)
    out = tmp_path / "out"
    r = _tune(toy, out)
    assert r.exit_code == 130 and "resumes the search" in r.output
    monkeypatch.setattr(tune_module, "run_variants", real)
    r = CliRunner().invoke(
        main,
        ["tune", str(toy / "toy.yaml"), "--dataset", str(toy / "ds.yaml"), "--space", str(toy / "space.yaml"),
         "--out", str(out), "--sampler", "grid", "--cache-dir", str(toy / "cache")],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "resuming study 'shared': 1 of 3 trial(s) done" in r.output
    assert sorted(int(t["verify.min_painted_rows"]) for t in _rows(out / "trials.csv")) == [10, 50000, 100000]


# --------------------------------------------------------------------------- bad space files
GOOD = {
    "params": {
        "verify.min_paint_contrast": {"low": 0.1, "high": 0.5},
        "verify.min_painted_rows": {"low": 4, "high": 20},
        "roadmask.keep": {"choices": ["bottom", "bottom_centre"]},
        "roadmask.height_tolerance_m": {"low": 0.04, "high": 0.16, "log": True},
    }
}


def _set(path: str, value):
    def mutate(d):
        keys = path.split("/")
        for k in keys[:-1]:
            d = d[k]
        if value is _DELETE:
            del d[keys[-1]]
        else:
            d[keys[-1]] = value

    return mutate


_DELETE = object()
MUTATORS = [
    (
        _set("params/verify.min_paint_contrast/high", 20.0),
        "params.verify.min_paint_contrast: high = 20.0: out of",
    ),
    (_set("params/verify.min_painted_rows/low", 0), "params.verify.min_painted_rows: low = 0: out of"),
    (
        _set("params/verfy.min_width_m", {"low": 0.1, "high": 0.2}),
        "has no node 'verfy'; did you mean 'verify'",
    ),
    (_set("params/verify.min_widht_m", {"low": 0.1, "high": 0.2}), "has no param 'min_widht_m'"),
    (_set("params/roadmask.keep/choices", ["bottom", "middle"]), "params.roadmask.keep: choice 'middle'"),
    (_set("params/verify.min_paint_contrast/low", 0.9), "low (0.9) is above high (0.5)"),
    (_set("params/roadmask.height_tolerance_m/low", 0.0), "a log range needs low > 0"),
    (_set("params/verify.min_paint_contrast/lo", 0.2), "params.verify.min_paint_contrast.lo: Extra inputs"),
    (_set("params/verify.min_paint_contrast/low", _DELETE), "expected a range (low and high) or choices"),
    (_set("params/verify.min_paint_contrast/log", "often"), "params.verify.min_paint_contrast.log"),
    (_set("params/verify", {"low": 1, "high": 2}), "params.verify: expected node_id.param"),
    (_set("params", {}), "params: Dictionary should have at least 1 item"),
    (_set("trials", 5), "trials: Extra inputs are not permitted"),
]


@pytest.mark.parametrize(("mutate", "message"), MUTATORS, ids=[m for _, m in MUTATORS])
def test_a_bad_space_file_is_a_located_error_before_any_frame(tmp_path, mutate, message, synthetic_dataset):
    import copy

    space = copy.deepcopy(GOOD)
    mutate(space)
    (tmp_path / "space.yaml").write_text(yaml.safe_dump(space, sort_keys=False))
    args = ["tune", "paper", "--dataset", str(synthetic_dataset), "--space", str(tmp_path / "space.yaml"),
            "--out", str(tmp_path / "out")]  # fmt: skip
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2, r.output
    assert f"{tmp_path / 'space.yaml'}: " in r.output and message in r.output, r.output
    assert not (tmp_path / "out").exists()


def test_the_good_space_is_accepted_and_not_yaml_is_refused(tmp_path):
    from lanegraph_tune.space import load_space

    from lanegraph.errors import UsageError
    from lanegraph.graph.files import load_graph_named

    g = load_graph_named("paper")
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(GOOD, sort_keys=False))
    space = load_space(tmp_path / "s.yaml", g)
    assert [p.kind for p in space.params] == ["float", "int", "choice", "float"]
    assert space.params[1].grid(5) == [4, 8, 12, 16, 20] and space.params[2].grid(5) == [
        "bottom",
        "bottom_centre",
    ]
    (tmp_path / "bad.yaml").write_text("params: [unclosed\n")
    with pytest.raises(UsageError, match="bad.yaml: not valid YAML"):
        load_space(tmp_path / "bad.yaml", g)


def test_a_dataset_group_is_read_and_folds_leave_a_group_out(tmp_path):
    from lanegraph_tune.search import LeaveOneGroupOut

    from lanegraph.api import load_dataset

    for n in "xyz":
        (tmp_path / n).mkdir()
    (tmp_path / "d.yaml").write_text(
        "sequences:\n  - {name: x, input: x, group: g1}\n  - {name: y, input: y, group: g1}\n  - {name: z, input: z}\n"
    )
    ds = load_dataset(tmp_path / "d.yaml")
    groups = [s.group or s.name for s in ds]
    assert groups == ["g1", "g1", "z"]
    assert list(LeaveOneGroupOut().split(groups)) == [([2], [0, 1]), ([0, 1], [2])]
    from lanegraph.errors import UsageError

    with pytest.raises(UsageError, match="at least two groups"):
        list(LeaveOneGroupOut().split(["g1", "g1"]))


# --------------------------------------------------------------------------- Dask and MLflow
try:
    from .test_distributed import dask_cluster  # noqa: F401 - the fixture: a real scheduler and two workers
except pytest.skip.Exception:  # the distributed extra is missing: those tests skip
    pass


from ..plugins.test_mlflow import mlflow_server  # noqa: E402, F401 - a real `mlflow server` on 127.0.0.1


@pytest.mark.cluster
def test_tune_on_a_dask_cluster_equals_the_in_process_tune(tuned, toy, request):
    if "dask_cluster" not in globals():
        pytest.skip('the Dask tests need the distributed extra: pip install -e ".[test]"')
    address, _ = request.getfixturevalue("dask_cluster")
    out = toy / "out_dask"
    r = _tune(toy, out, "--scheduler", address, "--no-cache")
    assert r.exit_code == 0, r.output
    ref, _ = tuned
    assert (out / "results.csv").read_text() == (ref / "results.csv").read_text()
    assert (
        json.loads((out / "folds.json").read_text())["folds"]
        == json.loads((ref / "folds.json").read_text())["folds"]
    )


@pytest.mark.mlflow
def test_every_trial_and_fold_is_tracked_on_a_real_mlflow_server(toy, tmp_path, request, monkeypatch):
    mlflow = pytest.importorskip("mlflow", reason='MLflow is not installed: pip install -e ".[mlflow]"')
    uri = request.getfixturevalue("mlflow_server")
    monkeypatch.setenv("MLFLOW_EXPERIMENT_NAME", f"lanegraph-tune-{tmp_path.name}")
    r = _tune(toy, tmp_path / "out", "--track", f"mlflow:{uri}")
    assert r.exit_code == 0, r.output
    mlflow.set_tracking_uri(uri)
    runs = mlflow.search_runs(experiment_names=[f"lanegraph-tune-{tmp_path.name}"], output_format="list")
    names = sorted(r.info.run_name for r in runs)
    assert f"tune -> {tmp_path / 'out'}" in names
    assert sum(n.startswith("shared#") for n in names) == 3 and sum(n.startswith("fold ") for n in names) == 3
    fold = next(r for r in runs if r.info.run_name.startswith("fold third"))
    assert fold.data.params == {"verify.min_painted_rows": "10"}
    assert (
        fold.data.metrics["left_out.detection_ratio"] == 1.0
        and fold.data.tags["lanegraph.tune.train"] == "a,b"
    )


def test_tpe_with_the_median_pruner_stops_bad_trials_between_training_sequences(toy, tmp_path, monkeypatch):
    import optuna
    from lanegraph_tune.search import Tuner

    fake = _FakeRuns({"a": 5, "b": 5, "c": 5})
    monkeypatch.setattr(Tuner, "_run", lambda self, batch, f=fake: f(self, batch))
    tuner = _tuner(
        toy, tmp_path / "pruned", "tpe", 8, "params:\n  verify.min_painted_rows: {low: 1, high: 9}\n"
    )
    tuner.setup.pruner = "median"
    result = tuner.run()
    assert all(
        len(seqs) == 1 for _, seqs in fake.calls
    )  # a sequence at a time, the score reported after each
    storage = optuna.storages.JournalStorage(
        optuna.storages.journal.JournalFileBackend(str(tmp_path / "pruned" / "study.journal"))
    )
    pruned = sum(
        t.state == optuna.trial.TrialState.PRUNED
        for s in optuna.get_all_study_summaries(storage)
        for t in optuna.load_study(study_name=s.study_name, storage=storage).trials
    )
    assert pruned >= 1
    # the final choice: the best finished trial of the study over all sequences (pruned ones left out)
    from lanegraph_tune.search import pooled

    ratios = [pooled(t.counts, ["a", "b", "c"]).detection_ratio for t in result.trials if t.study == "all"]
    assert result.final.study == "all" and pooled(
        result.final.counts, ["a", "b", "c"]
    ).detection_ratio == max(ratios)


@pytest.mark.parametrize(
    ("sequences", "message"),
    [
        ("  - {name: a, input: a, gt: a/lanes_gt.jsonl}\n", "at least two groups"),
        ("  - {name: a, input: a, gt: a/lanes_gt.jsonl}\n  - {name: b, input: b}\n", "sequence 'b': tune scores"),
        ("  - {name: a, input: a, gt: a/lanes_gt.jsonl, group: g}\n  - {name: b, input: b, gt: b/lanes_gt.jsonl, group: g}\n",
         "at least two groups"),
    ],
)  # fmt: skip
def test_a_dataset_tune_cannot_fold_is_refused_before_anything(toy, tmp_path, sequences, message):
    (toy / "bad_ds.yaml").write_text("sequences:\n" + sequences)
    args = ["tune", str(toy / "toy.yaml"), "--dataset", str(toy / "bad_ds.yaml"), "--space", str(toy / "space.yaml"),
            "--out", str(tmp_path / "out")]  # fmt: skip
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2 and message in r.output, r.output
    assert not (tmp_path / "out").exists()


def test_the_qmc_sampler_spreads_distinct_trials_over_a_range(toy, tmp_path, monkeypatch):
    from lanegraph_tune.search import Tuner

    fake = _FakeRuns(dict.fromkeys("abc", 7))
    monkeypatch.setattr(Tuner, "_run", lambda self, batch, f=fake: f(self, batch))
    space = "params:\n  verify.min_paint_contrast: {low: 0.1, high: 0.6}\n  verify.min_painted_rows: {low: 1, high: 40}\n"
    (toy / "space_q.yaml").write_text(space)
    result = _tuner(toy, tmp_path / "qmc", "qmc", 8, space).run()
    assert len(result.trials) == 8 and len(fake.calls) == 8
    points = {tuple(sorted(t.params.items())) for t in result.trials}
    assert len(points) == 8
    assert all(0.1 <= t.params["verify.min_paint_contrast"] <= 0.6 for t in result.trials)


_LISTED = """
import sys
from lanegraph.cli import command_entry_points, main
print(command_entry_points()["tune"].value)
try:
    main(["--help"])
except SystemExit:
    pass
print("LOADED", sorted(m for m in sys.modules if m.split(".")[0] in ("optuna", "lanegraph_tune")))
"""


def test_the_command_comes_from_its_plugin_and_optuna_loads_only_when_a_tune_runs():
    """``lanegraph tune`` is the plugin package lanegraph_tune's, through the ``lanegraph.commands``
    entry point; ``lanegraph --help`` loads its command module only: neither Optuna nor the search."""
    p = subprocess.run([sys.executable, "-c", _LISTED], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[0] == "lanegraph_tune.cli:tune"
    assert any(line.split()[:1] == ["tune"] for line in lines)  # listed with its help
    assert lines[-1] == "LOADED ['lanegraph_tune', 'lanegraph_tune.cli']"
