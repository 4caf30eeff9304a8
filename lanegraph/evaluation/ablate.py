"""Ablation runs: several graph variants (and param sweeps) over the same input, evaluated and
tabulated, with the work the variants share computed once (:mod:`lanegraph.run.cache`).

The input is a :class:`~lanegraph.evaluation.dataset.Dataset` (one or more sequences). Writes
``OUT/runs/<variant>/<sequence>/`` per run (what its sinks write, ``timings.json``, ``run.json``;
its lanes are found through :mod:`lanegraph.records.results`), and ``OUT/results.csv``
(one row per variant and sequence, and a pooled row per variant with ``sequence`` = ``all``),
``OUT/results.md``, ``OUT/accuracy.png`` (pooled accuracy per variant) and ``OUT/accuracy_vs_ms.png``.
A run whose resolved graph, input files and frame selection are unchanged since the last ablation
(same output folder) is not run again: its recorded results are reused.

The runs are a batch of the run service (:meth:`lanegraph.service.Session.run_tasks`: one after
another in this process, or on a Dask cluster with the same outputs byte for byte); this module
makes their rows (:func:`ablation_rows`) and the tables and plots (:func:`write_reports`).

A run that fails (a node raising under ``on_error: fail``, an input a variant cannot read) does not
end the ablation: every run is made, the failed one gets its row with its ``error`` (and no
figures), its ``run.json`` says what happened; the command exits 1 at the end. Frames that failed under ``on_error: skip`` are counted in
``failed_frames``.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import UsageError
from ..paths import write_text_atomic
from ..records.results import LANES, find_result
from .dataset import POOLED, evaluate_sequences
from .metrics import evaluate, read_predictions
from .plots import write_ablation_plots

if TYPE_CHECKING:
    from ..batches.batch import Planned


@dataclass
class Variant:
    """One run of an ablation: a graph file plus ``--set`` overrides."""

    name: str
    graph: Path
    sets: list[str] = field(default_factory=list)


def expand_sweeps(base: Path, sweeps: list[str]) -> list[Variant]:
    """``node.param=v1,v2,...`` -> one variant of ``base`` per value."""
    out = []
    for sw in sweeps:
        key, _, values = sw.partition("=")
        if not values:
            raise ValueError(f"--sweep {sw!r}: expected node.param=v1,v2,...")
        for v in values.split(","):
            out.append(Variant(f"{base.stem}[{key}={v}]", base, [f"{key}={v}"]))
    return out


def _extra_metrics(pred: list[dict], gt: list[dict]) -> dict[str, Any]:
    """CULane F1 when the extra metrics module is available."""
    try:
        from . import metrics_extra  # noqa: PLC0415
    except ImportError:
        return {}
    try:
        res = metrics_extra.culane_metrics(pred, gt)
    except Exception:  # noqa: BLE001 - a missing extra metric must not lose the ablation
        return {}
    return {"culane_f1": res.get("f1") if isinstance(res, dict) else None}


def row_of_run(
    name: str,
    sequence: str,
    timings: Mapping[str, Any],
    evaluation: Mapping[str, Any] | None,
    error: str | None,
    failed_frames: int,
) -> dict[str, Any]:
    """A results row (as ``lanegraph ablate`` tabulates them) of one run: its figures against the
    ground truth (``evaluation``) when there is one, its times per node."""
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


def ablation_rows(variants: list[Variant], plans: list[Planned], gts: dict[str, Any]) -> list[dict[str, Any]]:
    """The rows of an ablation's runs (``plans``: each variant's runs, in the variants' order),
    from their records and lanes: one per variant and sequence, then the variant's pooled row
    (``sequence`` = ``all``). A variant with a run that did not end (an interrupted ablation) has
    no rows."""
    rows: list[dict[str, Any]] = []
    by_variant: dict[str, list[Planned]] = {}
    for plan in plans:
        by_variant.setdefault(str(plan.variant), []).append(plan)
    for var in variants:
        var_plans = by_variant.get(var.name, [])
        if any(p.record is None for p in var_plans):
            continue
        var_rows: list[dict[str, Any]] = []
        evals: list[tuple[str, list, list]] = []
        for plan in var_plans:
            run_dir = plan.run_dir
            record = plan.record
            assert record is not None
            timings = record.timings or {}
            gt = gts[plan.sequence]
            lanes_file = (
                find_result(run_dir, LANES, record=record) if gt is not None and not record.error else None
            )
            ev, extra = None, {}
            if lanes_file is not None:
                pred = read_predictions(lanes_file)
                ev, extra = evaluate(pred, gt), _extra_metrics(pred, gt)
                evals.append((plan.sequence, pred, gt))
            row = row_of_run(var.name, plan.sequence, timings, ev, record.error, len(record.failures))
            row.pop("frames_not_run", None)
            row.update(
                extra, graph=str(var.graph), sets=" ".join(var.sets), before_any_frame=record.before_any_frame
            )
            row["wall_s"] = round(plan.outcome.wall_s, 2) if plan.outcome is not None else 0.0
            row["reused"] = plan.reused
            row["cache_hits"] = sum(timings.get("cache", {}).get("hits", {}).values())
            var_rows.append(row)
        rows += var_rows
        rows.append(_pooled_row(var, var_rows, evals))
    return rows


def _pooled_row(
    var: Variant, var_rows: list[dict[str, Any]], evals: list[tuple[str, list, list]]
) -> dict[str, Any]:
    """The variant's row over all sequences: metrics over every frame as one set; times are the
    sequences' medians weighted by their frame counts. No figures when a sequence's run failed (they
    would be over other frames than the other variants')."""
    row: dict[str, Any] = {
        "variant": var.name,
        "sequence": POOLED,
        "graph": str(var.graph),
        "sets": " ".join(var.sets),
    }
    failed = [r["sequence"] for r in var_rows if r.get("error")]
    row["error"] = f"failed on sequence(s) {', '.join(failed)}" if failed else None
    row["failed_frames"] = sum(int(r.get("failed_frames") or 0) for r in var_rows)
    row["before_any_frame"] = all(r.get("before_any_frame") for r in var_rows)
    if evals and not failed:
        ev = evaluate_sequences(evals)[POOLED]
        row.update(
            {k: ev[k] for k in ("frames", "detection_ratio", "precision", "ego_recall", "mean_abs_dx_px")}
        )
        pred = [{**p, "frame": f"{n}/{p.get('frame')}"} for n, ps, _ in evals for p in ps]
        gt = [{**g, "frame": f"{n}/{g.get('frame')}"} for n, _, gs in evals for g in gs]
        row.update(_extra_metrics(pred, gt))
    weights = [max(int(r.get("frames_run") or 0), 1) for r in var_rows]

    def weighted(values: list[float | None]) -> float | None:
        pairs = [(v, w) for v, w in zip(values, weights) if v is not None]
        return round(sum(v * w for v, w in pairs) / sum(w for _, w in pairs), 2) if pairs else None

    row["ms_per_frame"] = weighted([r.get("ms_per_frame") for r in var_rows])
    stages = list(dict.fromkeys(s for r in var_rows for s in r["stage_ms"]))
    row["stage_ms"] = {s: weighted([r["stage_ms"].get(s) for r in var_rows]) for s in stages}
    row["frames_run"] = sum(int(r.get("frames_run") or 0) for r in var_rows)
    row["wall_s"] = round(sum(r["wall_s"] for r in var_rows), 2)
    row["reused"] = all(r["reused"] for r in var_rows)
    row["cache_hits"] = sum(r["cache_hits"] for r in var_rows)
    return row


def distinct_folders(variants: list[Variant]) -> None:
    """Give every variant a folder of its own (``runs/<variant>/``): a variant given twice (the
    same graph file and ``--set``) is refused (:class:`UsageError`); two different variants whose
    names (or folder names) are equal get ``-2``, ``-3`` ... after the name of the later one, so
    that no run overwrites another's and no two rows are one run's."""
    seen: dict[tuple[str, tuple[str, ...]], str] = {}
    folders: set[str] = set()
    for var in variants:
        ident = (str(Path(var.graph).resolve()), tuple(var.sets))
        if ident in seen:
            sets = f" with --set {' '.join(var.sets)}" if var.sets else ""
            raise UsageError(
                f"variant {var.name!r} ({var.graph}{sets}) is given twice (first as {seen[ident]!r}): "
                "one run of it is enough"
            )
        name, k = var.name, 1
        while _safe(name).lower() in folders:  # case-insensitive file systems too
            k += 1
            name = f"{var.name}-{k}"
        var.name = name
        seen[ident] = name
        folders.add(_safe(name).lower())


def _safe(name: str) -> str:
    """A variant's folder name: one plain name (never '..' or hidden), whatever the variant is called."""
    out = "".join(ch if ch.isalnum() or ch in "-_.=[]" else "_" for ch in name)[:200]
    return out if out and not out.startswith(".") else "_" + out


def _fmt(x: Any, pct: bool = False) -> str:
    if x is None:
        return "n/a"
    if isinstance(x, float):
        return f"{100 * x:.1f} %" if pct else f"{x:.2f}"
    return str(x)


def write_reports(rows: list[dict[str, Any]], out_dir: Path) -> None:
    """``results.csv`` (every row), ``results.md`` (the pooled table, then each sequence's) and the
    two plots (pooled rows)."""
    stages = list(dict.fromkeys(s for r in rows for s in r.get("stage_ms", {})))
    _write_csv(rows, stages, out_dir / "results.csv")
    write_text_atomic(out_dir / "results.md", _results_md(rows, stages))
    write_ablation_plots([r for r in rows if r.get("sequence") == POOLED], out_dir)


def _write_csv(rows: list[dict[str, Any]], stages: list[str], path: Path) -> None:
    cols = [
        "variant",
        "sequence",
        "frames",
        "detection_ratio",
        "precision",
        "ego_recall",
        "mean_abs_dx_px",
        "culane_f1",
        "ms_per_frame",
    ]
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(
        cols + [f"ms_{s}" for s in stages] + ["wall_s", "reused", "cache_hits", "failed_frames", "error"]
    )
    for r in rows:
        w.writerow(
            [r.get(c) for c in cols]
            + [r["stage_ms"].get(s) for s in stages]
            + [r["wall_s"], r["reused"], r["cache_hits"], r.get("failed_frames", 0), r.get("error") or ""]
        )
    write_text_atomic(path, buf.getvalue())


#: what an ablation's ms/frame is (results.md, the accuracy-against-time plot): what it measured,
#: not a benchmark
TIMING_NOTE = (
    "ms/frame: the sum of the nodes' median times per frame in this ablation's own runs, as measured "
    "here (a node taken from the result cache counts with the time it took when computed; on the "
    "first run on a machine its first frames include compiling, and other jobs on the machine count): "
    "compare variants of one ablation, not machines; benchmarks/bench_pipeline.py measures speed"
)


def _results_md(rows: list[dict[str, Any]], stages: list[str]) -> str:
    pooled = [r for r in rows if r.get("sequence") == POOLED]
    sequences = list(dict.fromkeys(r["sequence"] for r in rows if r.get("sequence") != POOLED))
    head = [
        "| variant | detection ratio | precision | ego recall | mean abs dx (px) | CULane F1 | ms/frame |",
        "|---|---|---|---|---|---|---|",
    ]

    def table(sel: list[dict[str, Any]]) -> list[str]:
        return head + [
            f"| {r['variant']} | {_fmt(r.get('detection_ratio'), True)} | {_fmt(r.get('precision'), True)} | "
            f"{_fmt(r.get('ego_recall'), True)} | {_fmt(r.get('mean_abs_dx_px'))} | {_fmt(r.get('culane_f1'))} | "
            f"{_fmt(r.get('ms_per_frame'))} |"
            for r in sel
        ]

    frames: dict[str, int] = {}
    for r in rows:  # a failed run has fewer (or no) frames: the sequence's count is the largest
        frames[r["sequence"]] = max(
            frames.get(r["sequence"], 0), int(r.get("frames") or r.get("frames_run") or 0)
        )
    lines = [
        f"All sequences pooled ({', '.join(sequences)}; {frames.get(POOLED) or 0} frames):",
        "",
        *table(pooled),
    ]
    if len(sequences) > 1:
        for name in sequences:
            lines += [
                "",
                f"Sequence {name} ({frames.get(name) or 0} frames):",
                "",
                *table([r for r in rows if r.get("sequence") == name]),
            ]
    lines += [
        "",
        TIMING_NOTE,
        "",
        "Median ms per frame per stage (pooled):",
        "",
        "| variant | " + " | ".join(stages) + " |",
        "|---|" + "---|" * len(stages),
    ]
    for r in pooled:
        lines.append(f"| {r['variant']} | " + " | ".join(_fmt(r["stage_ms"].get(s)) for s in stages) + " |")
    failed = [r for r in rows if r.get("sequence") != POOLED and (r.get("error") or r.get("failed_frames"))]
    if failed:
        lines += [
            "",
            "Failed runs (no figures for a run that stopped; see its runs/<variant>/<sequence>/run.json):",
            "",
        ]
        for r in failed:
            what = (
                r.get("error")
                or f"{r['failed_frames']} frame(s) failed (on_error skip), figures over the others"
            )
            lines.append(f"- {r['variant']} / {r['sequence']}: {what}")
    return "\n".join(lines) + "\n"
