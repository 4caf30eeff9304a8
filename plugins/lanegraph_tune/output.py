"""What ``lanegraph tune`` writes into its folder: ``folds.json`` (each fold's choice),
``trials.csv`` (every trial's params and scores per sequence), ``results.csv`` / ``results.md``
(each sequence's left-out score beside its tuned-on one and the untuned graph's) and
``tuned.yaml`` (the params chosen on all sequences, a graph that ``extends`` the input graph)."""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path
from typing import Any

import yaml

from lanegraph.api import POOLED
from lanegraph.builtin import graphs_dir
from lanegraph.paths import write_text_atomic

from .search import Counts, TuneResult, pooled

#: the files tune writes into its folder, besides runs/, the report, command.json and run.log
TUNE_FILES = ("folds.json", "trials.csv", "results.csv", "results.md", "tuned.yaml", "graph.yaml")


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def table_rows(result: TuneResult) -> list[dict[str, Any]]:
    """One row per sequence and a pooled row: left-out (its fold's choice), tuned-on (the choice on
    all sequences) and baseline (the graph's own values, when they were tried) figures."""
    fold_of = {s: f for f in result.folds for s in f.test}
    base = next((t for t in result.trials if t.baseline and t.study in ("shared", "all")), None)
    rows = []
    sums = {"left_out": Counts(), "tuned_on": Counts(), "baseline": Counts()}
    for seq in result.sequences:
        fold = fold_of.get(seq.name)
        row: dict[str, Any] = {"sequence": seq.name, "group": result.groups[seq.name]}
        row["fold"] = fold.name if fold is not None else None
        row["fold_trial"] = fold.trial if fold is not None else None
        parts = {
            "left_out": fold.test_counts.get(seq.name) if fold is not None else None,
            "tuned_on": result.final.counts.get(seq.name) if result.final is not None else None,
            "baseline": base.counts.get(seq.name) if base is not None else None,
        }
        for what, c in parts.items():
            row.update(_figures(what, c))
            if c is not None and sums[what] is not None:
                sums[what] = sums[what] + c
            elif c is None:
                sums[what] = None  # a sequence without figures: no pooled figure
        row["frames"] = next((c.frames for c in parts.values() if c is not None), None)
        rows.append(row)
    total = {"sequence": POOLED, "group": "", "fold": "", "fold_trial": ""}
    for what, c in sums.items():
        total.update(_figures(what, c if c is not None and c.frames else None))
    total["frames"] = sum(int(r["frames"] or 0) for r in rows)
    return [*rows, total]


def _figures(what: str, c: Counts | None) -> dict[str, Any]:
    if c is None:
        return {f"{what}_{k}": None for k in ("detection_ratio", "precision", "false_lanes")}
    return {
        f"{what}_detection_ratio": round(c.detection_ratio, 6),
        f"{what}_precision": None if c.precision is None else round(c.precision, 6),
        f"{what}_false_lanes": c.false_lanes,
    }


COLUMNS = [
    "sequence", "group", "frames", "fold", "fold_trial",
    "left_out_detection_ratio", "left_out_precision", "left_out_false_lanes",
    "tuned_on_detection_ratio", "tuned_on_precision", "tuned_on_false_lanes",
    "baseline_detection_ratio", "baseline_precision", "baseline_false_lanes",
]  # fmt: skip


def results_md(result: TuneResult, rows: list[dict[str, Any]]) -> str:
    """The table a tune prints: left-out beside tuned-on (and baseline) per sequence, pooled last,
    then each fold's choice."""
    how = (
        f"one shared study ({result.sampler} sampler): every trial ran on every sequence; each fold chose "
        "among them on its training sequences only"
        if result.mode == "shared"
        else f"one study per fold ({result.sampler} sampler) over its training sequences, and one over all"
    )
    lines = [
        f"Search: {how}.",
        "",
        "Detection ratio (precision, false lanes) per sequence: left out = scored by the fold that did not "
        "see it; tuned on = the params chosen on all sequences, this one included; baseline = the graph's "
        "own values.",
        "",
        "| sequence | frames | left out | tuned on | baseline |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        cells = []
        for what in ("left_out", "tuned_on", "baseline"):
            dr = r.get(f"{what}_detection_ratio")
            cells.append(
                "n/a"
                if dr is None
                else f"{_pct(dr)} ({_pct(r.get(f'{what}_precision'))}, {r.get(f'{what}_false_lanes')})"
            )
        name = "**all (pooled)**" if r["sequence"] == POOLED else r["sequence"]
        lines.append(f"| {name} | {r['frames']} | " + " | ".join(cells) + " |")
    lines += ["", "Each fold's choice (made on its training sequences):", ""]
    lines += [
        "| fold (left out) | trained on | trial | params | train detection ratio |",
        "|---|---|---|---|---|",
    ]
    for f in result.folds:
        params = ", ".join(f"{k}={_value(v)}" for k, v in f.params.items()) or "(none finished)"
        lines.append(
            f"| {f.name} | {', '.join(f.train)} | {f.study}#{f.trial} | {params} | {_pct(f.train_counts.detection_ratio)} |"
        )
    if result.final is not None:
        params = ", ".join(f"{k}={_value(v)}" for k, v in result.final.params.items())
        lines += ["", f"Chosen on all sequences ({result.final.study}#{result.final.number}): {params}"]
    return "\n".join(lines) + "\n"


def _value(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else json.dumps(v) if not isinstance(v, str) else v


def write_tables(result: TuneResult, out_dir: Path) -> list[dict[str, Any]]:
    """``results.csv``, ``results.md``, ``trials.csv`` and ``folds.json``; returns the table rows."""
    rows = table_rows(result)
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow(["" if r.get(c) is None else r.get(c) for c in COLUMNS])
    write_text_atomic(out_dir / "results.csv", buf.getvalue())
    write_text_atomic(out_dir / "results.md", results_md(result, rows))
    names = [s.name for s in result.sequences]
    keys = list(dict.fromkeys(k for t in result.trials for k in t.params))
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(["study", "trial", "baseline", *keys, "score", *[f"detection_ratio_{n}" for n in names],
                *[f"false_lanes_{n}" for n in names]])  # fmt: skip
    for t in result.trials:
        ran = [n for n in names if n in t.counts]
        w.writerow(
            [
                t.study,
                t.number,
                t.baseline,
                *[t.params.get(k) for k in keys],
                round(pooled(t.counts, ran).score(), 6),
            ]
            + [round(t.counts[n].detection_ratio, 6) if n in t.counts else "" for n in names]
            + [t.counts[n].false_lanes if n in t.counts else "" for n in names]
        )
    write_text_atomic(out_dir / "trials.csv", buf.getvalue())
    folds = {
        "mode": result.mode,
        "sampler": result.sampler,
        "folds": [
            {
                "left_out": f.name,
                "train": f.train,
                "test": f.test,
                "study": f.study,
                "trial": f.trial,
                "params": f.params,
                "train_figures": f.train_counts.figures(),
                "test_figures": {s: c.figures() for s, c in f.test_counts.items()},
            }  # fmt: skip
            for f in result.folds
        ],
        "chosen_on_all": None
        if result.final is None
        else {
            "study": result.final.study,
            "trial": result.final.number,
            "params": result.final.params,
            "figures": pooled(result.final.counts, names).figures(),
        },  # fmt: skip
    }
    write_text_atomic(out_dir / "folds.json", json.dumps(folds, indent=2, default=str) + "\n")
    return rows


def extends_path(graph_file: Path, out_dir: Path) -> str:
    """How ``OUT/tuned.yaml`` names the input graph: by its name among lanegraph's graphs
    (``paper.yaml``, found from any folder) when it is one of them, else by its path relative to
    ``OUT`` (``extends`` reaches the graph's own folder, the current one and lanegraph's graphs:
    the command checks that it loads, else it extends ``graph.yaml``, the input graph resolved)."""
    graph_file = Path(graph_file).resolve()
    try:
        return graph_file.relative_to(graphs_dir().resolve()).as_posix()
    except ValueError:
        return Path(os.path.relpath(graph_file, Path(out_dir).resolve())).as_posix()


def tuned_description(
    graph: Any, graph_file: Path, result: TuneResult, rows: list[dict[str, Any]], command: str
) -> str:
    """The description of ``tuned.yaml``: which graph, the search (``command``: the ``lanegraph
    tune`` command line that remakes it, without ``--out``) and the pooled left-out, tuned-on and
    baseline figures of ``rows`` (:func:`table_rows`). Nothing in it depends on the machine, the
    output folder or the time: the same search writes the same file."""
    total = next((r for r in rows if r["sequence"] == POOLED), {})

    def figure(what: str) -> str:
        dr = total.get(f"{what}_detection_ratio")
        if dr is None:
            return "n/a"
        return (
            f"{_pct(dr)} detection ratio (precision {_pct(total.get(f'{what}_precision'))}, "
            f"{total.get(f'{what}_false_lanes')} false lanes)"
        )

    frames = total.get("frames") or 0
    groups = len(dict.fromkeys(result.groups.values()))
    return (
        f"{graph.name} ({Path(graph_file).as_posix()}) with the params lanegraph tune chose on all "
        f"{len(result.sequences)} sequences of the dataset ({frames} frames, {groups} groups): `{command}`. "
        f"Left out (each group scored by the fold that chose on the others), pooled: {figure('left_out')}; "
        f"tuned on (the params chosen on all sequences, scored on them): {figure('tuned_on')}; "
        f"{graph.name}'s own values: {figure('baseline')}. Per sequence: the tune's results.md."
    )


def tuned_graph(
    graph: Any,
    graph_file: Path,
    out_dir: Path,
    result: TuneResult,
    extends: str | None = None,
    name: str | None = None,
    description: str | None = None,
) -> str:
    """The text of ``tuned.yaml``: ``extends`` the input graph, with the params chosen on all
    sequences; named ``name`` (default: the graph's name and ``_tuned``)."""
    nodes: dict[str, dict[str, Any]] = {}
    for key, value in (result.final.params if result.final is not None else {}).items():
        node_id, _, param = key.partition(".")
        nodes.setdefault(node_id, {"params": {}})["params"][param] = value
    doc = {
        "name": name or f"{graph.name}_tuned",
        "description": description
        or (
            f"{graph.name} ({graph_file}) with the params lanegraph tune chose on all sequences of the dataset "
            f"({result.sampler} sampler); their left-out figures are in results.md beside this file"
        ),
        "extends": extends or extends_path(graph_file, out_dir),
        "nodes": nodes,
    }
    return dump_graph(doc)


class _GraphDumper(yaml.SafeDumper):
    """YAML as a graph file is written by hand: a long text folded (``>``) rather than quoted."""


def _text(dumper: yaml.SafeDumper, value: str) -> yaml.Node:
    folded = len(value) > 80 and "\n" not in value and value == value.strip()
    return dumper.represent_scalar("tag:yaml.org,2002:str", value, style=">" if folded else None)


_GraphDumper.add_representer(str, _text)


def dump_graph(doc: dict[str, Any]) -> str:
    """A graph file's text (keys in the given order; long texts folded), read back by
    ``yaml.safe_load`` as the same ``doc``."""
    return yaml.dump(doc, Dumper=_GraphDumper, sort_keys=False, width=100, allow_unicode=True)
