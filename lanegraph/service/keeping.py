"""What the run service keeps beside a command's results, so that they can be trusted months later:
the output folder claimed for one run (:mod:`lanegraph.run.folder`), the resolved graph
(``graph.yaml``), the record's provenance (command line, overrides, versions, git commit), the run's
log (``run.log``, :mod:`lanegraph.runlog`) and its experiment tracking (:mod:`lanegraph.tracking`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import UsageError
from ..evaluation.metrics import evaluate, read_ground_truth, read_predictions
from ..frames import selection_text
from ..paths import output_fields, safe_name
from ..run.folder import ABLATION_NAMES, COMMAND_NAMES, RUN_NAMES, command_identity, run_identity
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


def run_writes(
    g: Any, out_dir: Path, debug_dir: Path | None = None, make_report: bool = False
) -> dict[str, str]:
    """What ``lanegraph run`` writes in ``out_dir`` (for :func:`lanegraph.run.owned.taken`): its own
    files and its sinks' (``file``; a sink's folder ``tree``), the ``--debug-dir`` folder inside it
    (``dir``: its pictures go beside what is there) and the report. ``--debug-dir`` that is
    ``--out`` itself is refused (its pictures' folders would be named by frames among the user's)."""
    writes = dict.fromkeys(RUN_NAMES, "file")
    for n in g.nodes.values():
        params = getattr(n, "params", None)
        if params is None:
            continue
        for field, kind in output_fields(type(params)).items():
            value = getattr(params, field, None)
            if isinstance(value, str):
                writes[value] = "tree" if kind == "dir" else "file"
    rel = relative_inside(debug_dir, out_dir)
    if rel == ".":
        raise UsageError(
            f"--debug-dir {debug_dir}: is --out itself; give a folder inside it (--debug-dir {Path(out_dir) / 'debug'}) or elsewhere"
        )
    if rel is not None:
        writes[rel] = "dir"
    if make_report:
        writes.update(REPORT_WRITES)
    return writes


#: what ``--report`` writes in OUT: its page and pictures (a page or pictures of the user's refused)
REPORT_WRITES = {"report": "dir", "report/index.html": "file", "report/assets": "tree"}


def dataset_writes(dataset: Any) -> dict[str, str]:
    """What ``lanegraph run --dataset`` writes in OUT: its record and log, a run folder per sequence."""
    return {**dict.fromkeys(COMMAND_NAMES, "file"), **{s.name: "tree" for s in dataset}}


def ablation_writes(variant_folders: Sequence[str], dataset: Any, make_report: bool) -> dict[str, str]:
    """What ``lanegraph ablate`` writes in OUT: its record, log, tables and plots, ``runs/`` and a
    run folder per variant (``variant_folders``: their folder names) and sequence."""
    writes = {**dict.fromkeys([*COMMAND_NAMES, *ABLATION_NAMES], "file"), "runs": "dir"}
    for v in variant_folders:
        for s in dataset:
            writes[f"runs/{v}/{safe_name(s.name)}"] = "tree"
    if make_report:
        writes.update(REPORT_WRITES)
    return writes


def write_command_record(out_dir: Path, fields: Mapping[str, Any]) -> None:
    """``OUT/command.json``: the record of an ablation or a dataset run as a whole (its identity,
    command line, versions, what it wrote), beside the runs' own ``run.json``."""
    from ..paths import write_text_atomic

    write_text_atomic(Path(out_dir) / "command.json", json.dumps(dict(fields), indent=2, default=str) + "\n")


def relative_inside(path: Path | None, folder: Path) -> str | None:
    """``path`` relative to ``folder`` when it lies inside it (what ``--overwrite`` may remove)."""
    if path is None:
        return None
    try:
        return str(Path(path).resolve().relative_to(Path(folder).resolve()))
    except (ValueError, OSError):
        return None


def row_of_run(
    name: str,
    sequence: str,
    timings: Mapping[str, Any],
    evaluation: Mapping[str, Any] | None,
    error: str | None,
    failed_frames: int,
) -> dict[str, Any]:
    """A results row (as ``lanegraph ablate`` tabulates them) of one run: its figures against the
    ground truth when there is one, its times per node."""
    nodes = timings.get("nodes") or {}
    row: dict[str, Any] = {
        "variant": name,
        "sequence": sequence,
        "error": error,
        "failed_frames": failed_frames,
        "frames_run": timings.get("frames", 0),
        "ms_per_frame": round(sum(v.get("median_ms") or 0.0 for v in nodes.values()), 2) if nodes else None,
        "stage_ms": {nid: v.get("median_ms") for nid, v in nodes.items()},
    }
    if evaluation is not None:
        row.update(
            {
                k: evaluation.get(k)
                for k in (
                    "frames",
                    "frames_not_run",
                    "detection_ratio",
                    "precision",
                    "ego_recall",
                    "mean_abs_dx_px",
                )
            }
        )
    return row


def evaluate_run(out_dir: Path, input_path: Path | None, frame_ids: Sequence[str]) -> dict[str, Any] | None:
    """The run's figures against the ground truth of its input folder (``lanes_gt.jsonl``), over the
    frames it selected; None without one (or without lanes)."""
    if input_path is None or not (Path(input_path) / GT_NAME).is_file():
        return None
    lanes = find_result(out_dir, LANES)
    if lanes is None:
        return None
    return evaluate(
        read_predictions(lanes), read_ground_truth(Path(input_path) / GT_NAME), frames=list(frame_ids)
    )


def tracked_single_run(
    g: Any,
    out_dir: Path,
    input_path: Path | None,
    sets: Sequence[str],
    record: Any,
    timings: Mapping[str, Any],
) -> TrackedRun:
    """The tracked run of ``lanegraph run`` (its record written): params, figures, files."""
    ids = list(record.selection.ids) if record.selection is not None else []
    try:
        ev = evaluate_run(out_dir, input_path, ids)
    except Exception:  # noqa: BLE001 - a ground truth that does not read: tracked without figures
        ev = None
    sequence = Path(input_path).name if input_path is not None else "synthetic"
    row = row_of_run(g.name, sequence, timings, ev, record.error, len(record.failures))
    return tracked_row(
        row,
        flatten_params(g.resolved_dict()),
        out_dir,
        list(record.results.values()),
        tags={"lanegraph.graph": str(g.file), "lanegraph.sets": " ".join(sets)},
    )


def tracked_ablation_runs(
    rows: Sequence[Mapping[str, Any]], graphs: Mapping[str, Any], run_dirs: Mapping[tuple[str, str], Path]
) -> list[TrackedRun]:
    """The tracked runs of an ablation: one per variant and sequence, and per variant pooled over
    several sequences (``sequence`` ``all``). ``graphs``: each variant's validated graph;
    ``run_dirs``: each run's folder."""
    sequences = {r["sequence"] for r in rows if r.get("sequence") != "all"}
    out = []
    for row in rows:
        if row.get("sequence") == "all" and len(sequences) < 2:
            continue  # one sequence: the pooled row repeats it
        g = graphs.get(str(row.get("variant")))
        params = flatten_params(g.resolved_dict()) if g is not None else {}
        run_dir = run_dirs.get((str(row.get("variant")), str(row.get("sequence"))))
        results = []
        if run_dir is not None:
            from ..run.record import read_record

            rec = read_record(run_dir)
            results = list(rec.results.values()) if rec is not None else []
        tags = {"lanegraph.graph": str(row.get("graph") or ""), "lanegraph.sets": str(row.get("sets") or "")}
        out.append(tracked_row(row, params, run_dir, results, tags))
    return out


def tracked_dataset_run(g: Any, run_dir: Path, seq: Any, sets: Sequence[str]) -> TrackedRun:
    """The tracked run of one sequence of ``lanegraph run --dataset`` (its folder written)."""
    from ..run.record import read_record

    record = read_record(run_dir)
    timings = (record.timings if record is not None else None) or {}
    ev = None
    if record is not None and seq.gt is not None and record.selection is not None:
        lanes = find_result(run_dir, LANES)
        if lanes is not None:
            try:
                ev = evaluate(
                    read_predictions(lanes), read_ground_truth(seq.gt), frames=list(record.selection.ids)
                )
            except Exception:  # noqa: BLE001 - a ground truth that does not read: tracked without figures
                ev = None
    error = record.error if record is not None else "no record"
    failures = len(record.failures) if record is not None else 0
    row = row_of_run(g.name, seq.name, timings, ev, error, failures)
    results = list(record.results.values()) if record is not None else []
    tags = {"lanegraph.graph": str(g.file), "lanegraph.sets": " ".join(sets)}
    return tracked_row(row, flatten_params(g.resolved_dict()), run_dir, results, tags)
