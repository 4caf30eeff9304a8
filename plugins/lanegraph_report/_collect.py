"""Reading what a report shows: a ``lanegraph run`` output folder (its lanes, ``timings.json``,
``run.json``; with a dataset file, a run folder ``<sequence>/`` per sequence) or a ``lanegraph
ablate`` output folder (``runs/<variant>/<sequence>/``, ``results.csv``), the ground truth, and the
graph the run names. A run folder's lanes are the file its ``run.json`` records
(:mod:`lanegraph.records.results`)."""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lanegraph.api import (
    LANES,
    Session,
    describe,
    find_result,
    read_gt,
    read_jsonl,
    read_record,
    select_frames,
    single_sequence,
)
from lanegraph.builtin import find_graph
from lanegraph.errors import GraphError, InputError, UsageError
from lanegraph.frames import parse_frames
from lanegraph.plugins import PluginManager

#: the ground truth looked for in an input folder when none is given
GT_NAME = "lanes_gt.jsonl"


@dataclass
class RunFiles:
    """What one run (a variant on a sequence) wrote."""

    folder: Path
    records: list[dict[str, Any]]
    timings: dict[str, Any] | None = None
    failures: dict[str, str] = field(default_factory=dict)  # frame -> why it failed while running
    lanes_file: Path | None = None  # where the records come from


@dataclass
class Sequence:
    """One sequence of the report: where its frames come from and its ground truth."""

    name: str
    input: Path | None
    frames: slice | None = None
    gt: list[dict[str, Any]] | None = None
    gt_path: Path | None = None
    default_source: bool = (
        False  # no input: the source the graph (or a selecting source) chooses without one reads it
    )


@dataclass
class Collected:
    """Everything a report is made from."""

    kind: str  # "run" or "ablation"
    run_dir: Path
    variants: list[str]
    sequences: list[Sequence]
    runs: dict[tuple[int, int], RunFiles]  # (variant index, sequence index) -> its files
    graph: Any = None  # the graph (lanegraph's Graph) drawn with its times, when known
    results: list[dict[str, str]] = field(default_factory=list)  # an ablation's results.csv rows
    notes: list[str] = field(default_factory=list)


def _read_json(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", path=str(path)) from None
    if not isinstance(data, dict):
        raise InputError("expected a JSON object", path=str(path))
    return data


def read_run(folder: Path, lanes: Path) -> RunFiles:
    """A run's lanes (the file ``lanes``, required), ``timings.json`` and ``run.json`` (optional)."""
    records = read_jsonl(lanes)
    failures: dict[str, str] = {}
    run = read_record(folder, strict=True, empty=True)
    for f in run.failures:
        if f.get("frame") is not None:
            failures[str(f["frame"])] = f"node '{f.get('node')}' ({f.get('type')}): {f.get('error')}"
    stopped = run.stopped
    if stopped is not None and stopped.frame is not None:
        failures.setdefault(str(stopped.frame), f"the run stopped here: {stopped.error}")
    return RunFiles(folder, records, _read_json(folder / "timings.json"), failures, lanes)


def _gt_records(path: Path | None, frames: slice | None) -> list[dict[str, Any]] | None:
    if path is None:
        return None
    gt = read_jsonl(path)
    return gt[frames] if frames is not None else gt


def _from_dataset(ds: Any, frames: slice | None) -> list[Sequence]:
    out = []
    for s in ds:
        sel = s.frames if s.frames is not None else frames
        out.append(Sequence(s.name, s.input, sel, read_gt(s, sel), s.gt, default_source=s.input is None))
    return out


def _auto_gt(input_path: Path | None) -> Path | None:
    """``<input>/lanes_gt.jsonl`` when the input folder has one (KITTI data and written synthetic
    sequences keep their ground truth there)."""
    if input_path is not None and (Path(input_path) / GT_NAME).is_file():
        return Path(input_path) / GT_NAME
    return None


def _resolve_recorded(path_text: str | None, run_dir: Path) -> Path | None:
    """A path run.json recorded (relative to where the run was started): as given, else relative
    to the run folder's parent folders; None when it names nothing that exists."""
    if not path_text:
        return None
    p = Path(path_text)
    if p.exists():
        return p
    if not p.is_absolute():
        for base in [run_dir.resolve(), *run_dir.resolve().parents]:
            if (base / p).exists():
                return base / p
    return None


def load_recorded_graph(
    run_json: Any, run_dir: Path, sets: list[str], pm: PluginManager, notes: list[str]
) -> Any:
    """The graph run.json names, with ``sets`` applied; None (and a note) when it cannot be loaded."""
    text = run_json.graph
    if not text:
        return None
    try:
        path = _resolve_recorded(str(text), run_dir) or find_graph(Path(str(text)).stem)
    except GraphError:
        path = Path(str(text))
    if not path.is_file():
        notes.append(f"the graph {text} that run.json names was not found: no graph drawing")
        return None
    try:
        return Session.open_graph(path, sets).validate(pm)  # `extends` only into the allowed folders
    except GraphError as exc:
        notes.append(f"the graph {path} that run.json names does not load: {exc}")
        return None


def collect(
    run_dir: Path,
    *,
    gt: Path | None,
    dataset: Any,
    input_path: Path | None,
    frames: slice | None,
    sets: list[str],
    graph: Any,
    pm: PluginManager,
) -> Collected:
    """Read ``run_dir`` (a run or an ablation output folder) and the ground truth.

    Raises
    ------
    UsageError
        ``run_dir`` is neither kind of folder, or the options do not fit it.
    InputError
        a file in it (or the ground truth) is malformed.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise UsageError(
            f"{run_dir}: no such folder (expected the output folder of `lanegraph run` or `lanegraph ablate`)"
        )
    if dataset is not None and (gt is not None or input_path is not None):
        raise UsageError(
            "--dataset names every sequence's input and ground truth: give it instead of --gt/--input, not with them"
        )
    if (run_dir / "runs").is_dir() and (run_dir / "results.csv").is_file():
        return _collect_ablation(run_dir, gt, dataset, input_path, frames, graph, pm)
    return _collect_run(run_dir, gt, dataset, input_path, frames, sets, graph, pm)


def _collect_run(run_dir, gt, dataset, input_path, frames, sets, graph, pm) -> Collected:
    notes: list[str] = []
    run_json = read_record(run_dir, strict=True, empty=True)
    if graph is None:
        graph = load_recorded_graph(run_json, run_dir, sets, pm, notes)
    variant = graph.name if graph is not None else Path(str(run_json.graph or "run")).stem
    if dataset is not None:  # `run --dataset`: a run folder RUN_DIR/<sequence>/ per sequence
        seqs, runs = [], {}
        for s in _from_dataset(dataset, frames):
            folder = run_dir / s.name
            lanes = find_result(folder, LANES, pm) if folder.is_dir() else None
            rec = read_record(folder) if lanes is not None and frames is None else None
            if rec is not None and rec.selection is not None:  # the frames the run selected
                s.frames = parse_frames(rec.selection.frames or None)
                s.gt = _recorded_frames(read_gt_file(s.gt_path), rec.selection.ids, notes, s.name)
            if lanes is not None:
                runs[(0, len(seqs))] = read_run(folder, lanes)
                seqs.append(s)
            else:
                notes.append(f"sequence {s.name}: no lanes file ({describe(folder, LANES, pm)}): left out")
        if not seqs:
            raise UsageError(
                f"{run_dir}: no run folder <sequence>/ with lanes for any sequence of {dataset.file or dataset.name}"
            )
        return Collected("run", run_dir, [variant], seqs, runs, graph, notes=notes)
    lanes = find_result(run_dir, LANES, pm)
    if lanes is None:
        raise UsageError(
            f"{run_dir}: not a run folder (no lanes file: {describe(run_dir, LANES, pm)}) nor an ablation folder (no runs/ and "
            "results.csv); for a `run --dataset` folder give --dataset FILE"
        )
    if input_path is None and run_json.input:
        input_path = _resolve_recorded(str(run_json.input), run_dir)
        if input_path is None:
            notes.append(
                f"the input {run_json.input} that run.json names was not found (give --input): no left images"
            )
    if input_path is not None and not Path(input_path).exists():
        raise UsageError(f"--input {input_path}: no such file or folder")
    if gt is None:
        gt = _auto_gt(input_path)
        if gt is not None:
            notes.append(f"ground truth: {gt} (found in the input folder)")
        elif input_path is None and not run_json.input and (run_dir / GT_NAME).is_file():
            gt = run_dir / GT_NAME  # the synthetic scene's exact answer, written by its source
            notes.append(f"ground truth: {gt} (the synthetic scene's, written by the run)")
    name = single_sequence(input_path).name
    gt_records = _gt_records(gt, frames)
    if frames is None and run_json.selection is not None:  # the frames the run selected, and only those
        frames = parse_frames(run_json.selection.frames or None)
        gt_records = _recorded_frames(gt_records, run_json.selection.ids, notes)
    seq = Sequence(
        name,
        input_path,
        frames,
        gt_records,
        gt,
        default_source=input_path is None and not run_json.input,
    )
    return Collected("run", run_dir, [variant], [seq], {(0, 0): read_run(run_dir, lanes)}, graph, notes=notes)


def _recorded_frames(
    gt: list[dict[str, Any]] | None, ids: list[str], notes: list[str], sequence: str | None = None
) -> list[dict[str, Any]] | None:
    """The ground truth of the frames a run selected (its record's ids); a note says how many of
    the ground truth's frames the run did not run (they are not shown as failed)."""
    if gt is None:
        return None
    kept, not_run = select_frames(gt, ids)
    if not_run:
        where = f"sequence {sequence}: " if sequence else ""
        notes.append(
            f"{where}{not_run} frame(s) of the ground truth not run (the run selected {len(kept)}): not scored"
        )
    return kept


def read_gt_file(path: Path | None) -> list[dict[str, Any]] | None:
    return read_jsonl(path) if path is not None else None


def _safe_folder(name: str) -> str:
    """The folder `lanegraph ablate` names a variant's runs after (``runs/<variant>/``)."""
    return "".join(ch if ch.isalnum() or ch in "-_.=[]" else "_" for ch in name)


def _collect_ablation(run_dir, gt, dataset, input_path, frames, graph, pm) -> Collected:
    notes: list[str] = []
    with (run_dir / "results.csv").open(newline="", encoding="utf-8") as fh:
        results = list(csv.DictReader(fh))
    folders = {p.name: p for p in sorted((run_dir / "runs").iterdir()) if p.is_dir()}
    variants: list[str] = []
    vfolders: list[Path] = []
    for row in results:  # results.csv order, then folders it does not list
        name = row.get("variant") or ""
        f = folders.pop(_safe_folder(name), None)
        if f is not None:
            variants.append(name)
            vfolders.append(f)
    for name, f in folders.items():
        variants.append(name)
        vfolders.append(f)
    if not variants:
        raise UsageError(f"{run_dir}: an ablation folder without runs (runs/ is empty)")
    lanes = {
        (f, p.name): path
        for f in vfolders
        for p in sorted(f.iterdir())
        if p.is_dir() and (path := find_result(p, LANES, pm))
    }
    seq_names = list(dict.fromkeys(name for _, name in lanes))
    if dataset is not None:
        seqs = [s for s in _from_dataset(dataset, frames) if s.name in seq_names]
        if not seqs:
            raise UsageError(
                f"{run_dir}: no run of any sequence of {dataset.file or dataset.name} (runs/<variant>/<sequence>/)"
            )
    elif input_path is not None or gt is not None:
        if input_path is not None and not Path(input_path).exists():
            raise UsageError(f"--input {input_path}: no such file or folder")
        name = single_sequence(input_path).name if input_path is not None else None
        if name not in seq_names:
            if len(seq_names) != 1:
                raise UsageError(
                    f"{run_dir}: runs of sequences {seq_names}: with --input/--gt the folder must hold one sequence"
                    + (f" named {name!r}" if name else "")
                    + "; give --dataset FILE for several"
                )
            name = seq_names[0]
        gt = gt or _auto_gt(input_path)
        default = input_path is None and name == single_sequence(None).name
        seqs = [Sequence(name, input_path, frames, _gt_records(gt, frames), gt, default_source=default)]
    else:
        seqs = []
        for name in seq_names:  # without an input only the built-in scene's frames can be read
            default = name == single_sequence(None).name
            seqs.append(Sequence(name, None, frames, None, None, default_source=default))
            if not default:
                notes.append(
                    f"sequence {name}: no input given (--input or --dataset): no left images, no ground truth"
                )
    runs = {}
    for vi, f in enumerate(vfolders):
        for si, s in enumerate(seqs):
            if (f, s.name) in lanes:
                runs[(vi, si)] = read_run(f / s.name, lanes[(f, s.name)])
    return Collected("ablation", run_dir, variants, seqs, runs, graph, results, notes)
