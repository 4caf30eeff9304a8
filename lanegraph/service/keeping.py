"""What the run service keeps beside a command's results, so that they can be trusted months later:
the output folder claimed for one run (:mod:`lanegraph.records.folder`), the resolved graph
(``graph.yaml``), the record's provenance (command line, overrides, versions, git commit), the run's
log (``run.log``, :mod:`lanegraph.runlog`) and its experiment tracking (:mod:`lanegraph.tracking`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from ..errors import UsageError
from ..evaluation.metrics import evaluate, read_ground_truth, read_predictions
from ..frames import selection_text
from ..paths import output_fields, relative_inside, safe_name
from ..records.folder import ABLATION_NAMES, COMMAND_NAMES, RUN_NAMES, claim, command_identity, run_identity
from ..records.owned import seal
from ..records.results import LANES, find_result
from ..records.resume import graph_identity, resolved_input
from ..runlog import RunLog, get_logger
from ..tracking import CommandRecord, TrackedRun, flatten_params, tracked_row

#: the ground truth a run's input folder may hold (scored when a single run is tracked)
GT_NAME = "lanes_gt.jsonl"
#: the files of an ablation folder (besides runs/ and the report) its tracking keeps
ABLATION_FILES = ("results.csv", "results.md", "accuracy.png", "accuracy_vs_ms.png", "command.json")


def single_identity(
    resolved: dict[str, Any], input_path: Path | None, frames: slice | None
) -> dict[str, Any]:
    """The identity of ``lanegraph run`` on one input (:func:`lanegraph.records.folder.run_identity`)."""
    return run_identity(graph_identity(resolved), resolved_input(input_path), selection_text(frames))


def dataset_identity(
    kind: str, variants: Sequence[str], dataset: Any, frames: slice | None
) -> dict[str, Any]:
    """The identity of an ablation or a dataset run: its variants, its sequences' inputs, its frames."""
    inputs = {s.name: resolved_input(s.input) for s in dataset}
    return command_identity(kind, list(variants), inputs, selection_text(frames))


@contextmanager
def command_kept(
    session: Any,
    out_dir: Path,
    identity: dict[str, Any],
    writes: Mapping[str, str],
    tracked: CommandRecord,
    keep: Callable[[bool], None],
    said: str | None = None,
    append: bool = False,
) -> Iterator[None]:
    """What a batch command (``run --dataset``, ``ablate``, ``tune``) keeps beside its results once
    OUT is locked: the folder claimed (``--overwrite`` clears lanegraph's files only), the tracker's
    command run (started first: one that cannot start leaves no record to block a retry; ended
    ``interrupted`` if the block raises), ``command.json`` (``keep(final)``, before and after the
    block) and ``run.log`` (opening with the line ``said``); the folder sealed as lanegraph's."""
    claim(out_dir, identity, overwrite=session.overwrite, writes=writes)
    session.tracking.start(tracked)
    out_dir.mkdir(parents=True, exist_ok=True)
    keep(False)
    seal(out_dir, final=False)  # a killed command's files are known as lanegraph's
    try:
        with RunLog(out_dir, verbose=session.verbose > 0, append=append):
            if said is not None:
                get_logger("run").info(said, extra={"file_only": True})
            yield
    except BaseException:
        session.tracking.end("interrupted")
        seal(out_dir)
        raise
    keep(True)
    seal(out_dir)


def result_cache(cache_dir: Path | None, cache_max_gb: float, no_cache: bool) -> Any:
    """The result cache of ``--cache-dir`` and ``--cache-max-gb`` (None with ``--no-cache``)."""
    from ..run.cache import ResultCache

    try:
        return None if no_cache else ResultCache(cache_dir, int(cache_max_gb * 1024**3))
    except OSError as exc:
        raise UsageError(f"--cache-dir: cannot use the result cache: {exc.strerror or exc}") from None


def run_writes(
    g: Any, out_dir: Path, debug_dir: Path | None = None, make_report: bool = False
) -> dict[str, str]:
    """What ``lanegraph run`` writes in ``out_dir`` (for :func:`lanegraph.records.owned.taken`): its own
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


def debug_frames_option(text: str | None) -> tuple[str, ...] | None:
    """``--debug-frames``: frame ids or indices, comma-separated (None: every frame)."""
    if text is None:
        return None
    chosen = tuple(dict.fromkeys(item.strip() for item in text.split(",") if item.strip()))
    if not chosen:
        raise UsageError(f"--debug-frames {text!r}: expected frame ids or indices, comma-separated")
    return chosen
