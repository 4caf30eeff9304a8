"""Ablation runs: several graph variants (and param sweeps) over the same input, evaluated and
tabulated, with the work the variants share computed once (:mod:`lanegraph.cache`).

The input is a :class:`~lanegraph.dataset.Dataset` (one or more sequences). Writes
``OUT/runs/<variant>/<sequence>/lanes.jsonl`` and ``timings.json`` per run, and ``OUT/results.csv``
(one row per variant and sequence, and a pooled row per variant with ``sequence`` = ``all``),
``OUT/results.md``, ``OUT/accuracy.png`` (pooled accuracy per variant) and ``OUT/accuracy_vs_ms.png``.
A run whose resolved graph, input files and frame selection are unchanged since the last ablation
(same output folder) is not run again: its recorded results are reused.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .batch import (
    Planned,
    Planner,
    ResolvedGraph,
    SchedulerSpec,
    clean_leftovers,
    describe_error,
    finish_runs,
    run_tasks,
)
from .cache import ResultCache, digest
from .dataset import POOLED, Dataset, evaluate_sequences, read_gt
from .metrics import evaluate, read_jsonl
from .plugins import get_plugin_manager


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


def _input_identity(input_path: Path | None) -> str:
    if input_path is None:
        return "synthetic"
    files = sorted(p for p in Path(input_path).rglob("*") if p.is_file())
    return digest([(str(p), p.stat().st_size, p.stat().st_mtime_ns) for p in files])


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


def run_ablation(
    variants: list[Variant],
    dataset: Dataset,
    out_dir: Path,
    frames: slice | None = None,
    cache: ResultCache | None = None,
    progress: bool = True,
    scheduler: SchedulerSpec | None = None,
    chunk_frames: int | None = None,
    warmup: int = 0,
    echo: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """Run every variant on every sequence of ``dataset``, evaluate and tabulate; returns the rows
    (one per variant and sequence, then the variant's pooled row, ``sequence`` = ``all``).

    Outputs: ``OUT/runs/<variant>/<sequence>/lanes.jsonl``, ``timings.json`` and ``run.json``,
    ``OUT/results.csv``, ``OUT/results.md`` and the plots. ``frames`` (``--frames``) applies to
    sequences that do not choose their own. The runs are the tasks of :mod:`lanegraph.batch`: in
    this process one after another, or on a Dask cluster with ``scheduler``, with the same outputs;
    ``chunk_frames`` / ``warmup`` split sequences into chunks. A run that fails gets its row with
    the error (``error``: variant, sequence, frame and message) and the others go on.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    pm = get_plugin_manager()
    seq_frames = {s.name: s.frames if s.frames is not None else frames for s in dataset}
    gts = {s.name: read_gt(s, seq_frames[s.name]) for s in dataset}  # a malformed one is found before any run
    idents = {s.name: _input_identity(s.input) for s in dataset}
    planner = Planner(pm, chunk_frames, warmup, cache)
    plans: list[tuple[Variant, list[Planned]]] = []
    for var in variants:
        graph = ResolvedGraph.load(var.graph, var.sets)
        g = graph.validate(pm)
        var_plans = []
        for seq in dataset:
            sel = seq_frames[seq.name]
            run_dir = out_dir / "runs" / _safe(var.name) / seq.name
            run_key = digest(g.resolved_dict(), idents[seq.name], str(sel))
            if chunk_frames is not None:
                run_key = digest(run_key, "chunks", chunk_frames, warmup)
            stamp = run_dir / "run_key.txt"
            if cache is not None and stamp.is_file() and stamp.read_text() == run_key and (run_dir / "timings.json").is_file():
                var_plans.append(Planned(var.name, seq.name, run_dir, reused=True))
                continue
            var_plans.append(planner.add(var.name, seq.name, graph, seq.input, sel, run_dir, run_key))
        plans.append((var, var_plans))
    for _, var_plans in plans:
        for plan in var_plans:
            if not plan.reused:
                clean_leftovers(plan.run_dir)
    outcomes = run_tasks(planner.tasks, scheduler, cache, progress, echo)
    finish_runs([p for _, ps in plans for p in ps], outcomes)
    if cache is not None and scheduler is not None:  # the workers' counts, for the summary line
        for out in outcomes.values():
            cache.hits += sum(out.result.cache_hits.values())
            cache.misses += sum(out.result.cache_misses.values())
    rows: list[dict[str, Any]] = []
    for var, var_plans in plans:
        var_rows: list[dict[str, Any]] = []
        evals: list[tuple[str, list, list]] = []
        for plan in var_plans:
            run_dir = plan.run_dir
            out = plan.outcome
            row: dict[str, Any] = {"variant": var.name, "sequence": plan.sequence, "graph": str(var.graph), "sets": " ".join(var.sets)}
            error = out.error if out is not None else None
            timings = json.loads((run_dir / "timings.json").read_text()) if (run_dir / "timings.json").is_file() else {}
            lanes_file = run_dir / "lanes.jsonl"
            gt = gts[plan.sequence]
            if error is None and gt is not None and lanes_file.is_file():
                pred = read_jsonl(lanes_file)
                ev = evaluate(pred, gt)
                row.update({k: ev[k] for k in ("frames", "detection_ratio", "precision", "ego_recall", "mean_abs_dx_px")})
                row.update(_extra_metrics(pred, gt))
                evals.append((plan.sequence, pred, gt))
            nodes = timings.get("nodes", {})
            # the sum of the stages' median compute times (a cached stage counts with the time it took)
            row["ms_per_frame"] = round(sum(v["median_ms"] or 0.0 for v in nodes.values()), 2) if nodes else None
            row["stage_ms"] = {nid: v["median_ms"] for nid, v in nodes.items()}
            row["frames_run"] = timings.get("frames", 0)
            row["wall_s"] = round(out.wall_s, 2) if out is not None else 0.0
            row["reused"] = plan.reused
            row["cache_hits"] = sum(timings.get("cache", {}).get("hits", {}).values())
            row["error"] = describe_error(error) if error is not None else None
            var_rows.append(row)
        rows += var_rows
        rows.append(_pooled_row(var, var_rows, evals))
    write_reports(rows, out_dir)
    return rows


def _pooled_row(var: Variant, var_rows: list[dict[str, Any]], evals: list[tuple[str, list, list]]) -> dict[str, Any]:
    """The variant's row over all sequences: metrics over every frame as one set; times are the
    sequences' medians weighted by their frame counts."""
    row: dict[str, Any] = {"variant": var.name, "sequence": POOLED, "graph": str(var.graph), "sets": " ".join(var.sets)}
    failed = [r["sequence"] for r in var_rows if r.get("error")]
    row["error"] = f"{len(failed)} of {len(var_rows)} run(s) failed: {', '.join(failed)}" if failed else None
    if evals and not failed:  # figures pooled over fewer sequences would not compare with the others'
        ev = evaluate_sequences(evals)[POOLED]
        row.update({k: ev[k] for k in ("frames", "detection_ratio", "precision", "ego_recall", "mean_abs_dx_px")})
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


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_.=[]" else "_" for ch in name)


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
    cols = ["variant", "sequence", "frames", "detection_ratio", "precision", "ego_recall", "mean_abs_dx_px", "culane_f1", "ms_per_frame"]
    with (out_dir / "results.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols + [f"ms_{s}" for s in stages] + ["wall_s", "reused", "cache_hits", "error"])
        for r in rows:
            w.writerow([r.get(c) for c in cols] + [r["stage_ms"].get(s) for s in stages] + [r["wall_s"], r["reused"], r["cache_hits"], r.get("error")])
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

    frames = {r["sequence"]: r.get("frames") or r.get("frames_run") for r in rows}
    lines = [f"All sequences pooled ({', '.join(sequences)}; {frames.get(POOLED) or 0} frames):", "", *table(pooled)]
    if len(sequences) > 1:
        for name in sequences:
            lines += ["", f"Sequence {name} ({frames.get(name) or 0} frames):", "", *table([r for r in rows if r.get("sequence") == name])]
    lines += ["", "Median ms per frame per stage (pooled):", "", "| variant | " + " | ".join(stages) + " |", "|---|" + "---|" * len(stages)]
    for r in pooled:
        lines.append(f"| {r['variant']} | " + " | ".join(_fmt(r["stage_ms"].get(s)) for s in stages) + " |")
    errors = [r for r in rows if r.get("error") and r.get("sequence") != POOLED]
    if errors:
        lines += ["", f"Failed runs ({len(errors)}; no figures for them or their variant's pooled row):", ""]
        lines += [f"- {r['error']}" for r in errors]
    (out_dir / "results.md").write_text("\n".join(lines) + "\n")
    _plots(pooled, out_dir)


def _plots(rows: list[dict[str, Any]], out_dir: Path) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover - matplotlib is a dependency
        return
    names = [r["variant"] for r in rows]
    acc = [r.get("detection_ratio") or 0.0 for r in rows]
    prec = [r.get("precision") or 0.0 for r in rows]
    fig, ax = plt.subplots(figsize=(max(6, 0.8 * len(rows) + 2), 4))
    xs = range(len(rows))
    ax.bar([x - 0.2 for x in xs], acc, width=0.4, label="detection ratio")
    ax.bar([x + 0.2 for x in xs], prec, width=0.4, label="precision")
    ax.set_xticks(list(xs), names, rotation=35, ha="right")
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("fraction")
    ax.set_title("accuracy per variant")
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(out_dir / "accuracy.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for r, a in zip(rows, acc):
        ms = r.get("ms_per_frame")
        if ms is None:
            continue
        ax.scatter(ms, a)
        ax.annotate(r["variant"], (ms, a), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xlabel("median ms per frame (all nodes)")
    ax.set_ylabel("detection ratio")
    ax.set_ylim(-0.02, 1.05)
    ax.set_title("accuracy against time")
    fig.tight_layout()
    fig.savefig(out_dir / "accuracy_vs_ms.png", dpi=110)
    plt.close(fig)
