"""What the run service keeps beside a command's results, so that they can be trusted months later:
the output folder claimed for one run (:mod:`lanegraph.run.folder`), the resolved graph
(``graph.yaml``), the record's provenance (command line, overrides, versions, git commit), the run's
log (``run.log``, :mod:`lanegraph.runlog`) and its experiment tracking (:mod:`lanegraph.tracking`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..evaluation.metrics import evaluate, read_ground_truth, read_predictions
from ..frames import selection_text
from ..run.folder import command_identity, run_identity
from ..run.provenance import command_line, git_commit, versions
from ..run.results import LANES, find_result
from ..run.resume import graph_identity, resolved_input
from ..tracking import TrackedRun, flatten_params, tracked_row

#: the ground truth a run's input folder may hold (scored when a single run is tracked)
GT_NAME = "lanes_gt.jsonl"
#: the files of an ablation folder (besides runs/ and the report) its tracking keeps
ABLATION_FILES = ("results.csv", "results.md", "accuracy.png", "accuracy_vs_ms.png", "command.json")


def provenance(pm: Any, graph_file: str | Path | None, sets: Sequence[str] = ()) -> dict[str, Any]:
    """The fields of a record that say how it was made: ``command``, ``overrides``, ``versions``
    and ``git`` (the commit of the graph file's checkout, when it lies in one)."""
    out = {"command": command_line(), "overrides": list(sets), "versions": versions(pm)}
    if graph_file:
        out["git"] = git_commit(Path(graph_file))
    return out


def single_identity(
    resolved: dict[str, Any], input_path: Path | None, frames: slice | None
) -> dict[str, Any]:
    """The identity of ``lanegraph run`` on one input (:func:`lanegraph.run.folder.run_identity`)."""
    return run_identity(graph_identity(resolved), resolved_input(input_path), selection_text(frames))


def dataset_identity(
    kind: str, variants: Sequence[str], dataset: Any, frames: slice | None
) -> dict[str, Any]:
    """The identity of an ablation or a dataset run: its variants, its sequences' inputs, its frames."""
    inputs = {s.name: resolved_input(s.input) for s in dataset}
    return command_identity(kind, list(variants), inputs, selection_text(frames))


def tracked_run(
    g: Any, run_dir: Path, sequence: str, gt: Path | None, sets: Sequence[str], record: Any
) -> TrackedRun:
    """The tracked run of ``lanegraph run`` or of one sequence of ``run --dataset`` (its record
    written): params, figures against the ground truth ``gt`` over the frames it selected, files."""
    from ..evaluation.ablate import row_of_run  # the ablation tables load only when a run is tracked

    timings = (record.timings if record is not None else None) or {}
    ev = None
    lanes = find_result(run_dir, LANES, record=record) if record is not None and gt is not None else None
    if lanes is not None and Path(gt).is_file():
        try:
            ids = list(record.selection.ids) if record.selection is not None else []
            ev = evaluate(read_predictions(lanes), read_ground_truth(Path(gt)), frames=ids)
        except Exception:  # noqa: BLE001 - a ground truth that does not read: tracked without figures
            ev = None
    error = record.error if record is not None else "no record"
    row = row_of_run(g.name, sequence, timings, ev, error, len(record.failures) if record is not None else 0)
    results = list(record.results.values()) if record is not None else []
    tags = {"lanegraph.graph": str(g.file), "lanegraph.sets": " ".join(sets)}
    return tracked_row(row, flatten_params(g.resolved_dict()), run_dir, results, tags)


def tracked_ablation_runs(
    rows: Sequence[Mapping[str, Any]],
    graphs: Mapping[str, Any],
    run_dirs: Mapping[tuple[str, str], Path],
    records: Mapping[tuple[str, str], Any],
) -> list[TrackedRun]:
    """The tracked runs of an ablation: one per variant and sequence, and per variant pooled over
    several sequences (``sequence`` ``all``). ``graphs``: each variant's validated graph;
    ``run_dirs``: each run's folder; ``records``: each run's record (in memory)."""
    sequences = {r["sequence"] for r in rows if r.get("sequence") != "all"}
    out = []
    for row in rows:
        if row.get("sequence") == "all" and len(sequences) < 2:
            continue  # one sequence: the pooled row repeats it
        g = graphs.get(str(row.get("variant")))
        params = flatten_params(g.resolved_dict()) if g is not None else {}
        key = (str(row.get("variant")), str(row.get("sequence")))
        run_dir, rec = run_dirs.get(key), records.get(key)
        results = list(rec.results.values()) if rec is not None else []
        tags = {"lanegraph.graph": str(row.get("graph") or ""), "lanegraph.sets": str(row.get("sets") or "")}
        out.append(tracked_row(row, params, run_dir, results, tags))
    return out
