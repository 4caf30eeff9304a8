"""The report page: one HTML file with its style, script and data inline (the left images and node
pictures are JPEG files beside it, referenced relatively), so it opens from ``file://`` with no
server and fetches nothing from the network (a Content-Security-Policy forbids it)."""

from __future__ import annotations

import json
import re
from html import escape
from importlib import resources
from pathlib import Path
from typing import Any

from lanegraph import __version__
from lanegraph.api import POOLED

from . import _svg
from ._collect import Collected

_RATIO_COLS = ("detection_ratio", "precision", "ego_recall")


def _path(p: Any) -> str:
    """A path by its last two parts, the whole of it in a tooltip."""
    parts = Path(p).parts
    return f'<span title="{escape(str(p))}">{escape("/".join(parts[-2:]))}</span>'


def _asset(name: str) -> str:
    return resources.files("lanegraph_report").joinpath(name).read_text(encoding="utf-8")


def _pct(x: Any) -> str:
    v = _float(x)
    return "n/a" if v is None else f"{100 * v:.1f} %"


def _float(x: Any) -> float | None:
    if x is None or x == "":
        return None
    try:
        return float(x)
    except (TypeError, ValueError):
        return None


def _num(x: Any, digits: int = 2) -> str:
    v = _float(x)
    return "n/a" if v is None else f"{v:.{digits}f}"


def _cell(text: str, sort: Any = None) -> str:
    v = _float(sort)
    attr = f' data-v="{v!r}"' if v is not None else ""
    return f"<td{attr}>{escape(text)}</td>"


def _metrics_table(metrics: dict[str, Any], frames: list[dict[str, Any]], data: Collected) -> str:
    """Each variant's figures per sequence and pooled (the run's, or computed for the ablation)."""
    rows = []
    for name, per_seq in metrics.items():
        for seq, r in per_seq.items():
            label = f"{seq} (pooled)" if seq == POOLED else seq
            failed = len(r["failed_frames"])
            rows.append(
                "<tr>"
                + (_cell(name) if len(data.variants) > 1 else "")
                + _cell(label)
                + _cell(str(r["frames"]), r["frames"])
                + _cell(str(failed), failed)
                + "".join(_cell(_pct(r[c]), r[c]) for c in _RATIO_COLS)
                + _cell(_num(r["mean_abs_dx_px"]), r["mean_abs_dx_px"])
                + "</tr>"
            )
    head = (
        "<tr>"
        + ("<th>variant</th>" if len(data.variants) > 1 else "")
        + "<th>sequence</th><th>frames</th><th>failed</th><th>detection ratio</th><th>precision</th>"
        "<th>ego recall</th><th>mean |dx| (px)</th></tr>"
    )
    return f'<table class="sortable" id="metrics-table"><thead>{head}</thead><tbody>{"".join(rows)}</tbody></table>'


def _results_table(data: Collected, metrics: dict[str, Any]) -> tuple[str, list[dict[str, Any]]]:
    """An ablation's ``results.csv`` as a sortable table (accuracy computed here where the
    ablation had no ground truth); returns the HTML and the rows used."""
    rows = []
    for r in data.results:
        row = dict(r)
        mine = (metrics.get(row.get("variant", "")) or {}).get(row.get("sequence", ""))
        if mine is None and row.get("sequence") == POOLED and len(data.sequences) == 1:
            mine = (metrics.get(row.get("variant", "")) or {}).get(data.sequences[0].name)
        if _float(row.get("detection_ratio")) is None and mine is not None:
            for c in (*_RATIO_COLS, "mean_abs_dx_px", "frames"):
                row[c] = mine[c]
        rows.append(row)
    cols = [
        ("variant", "variant", None),
        ("sequence", "sequence", None),
        ("frames", "frames", "int"),
        ("detection_ratio", "detection ratio", "pct"),
        ("precision", "precision", "pct"),
        ("ego_recall", "ego recall", "pct"),
        ("mean_abs_dx_px", "mean |dx| (px)", "num"),
        ("culane_f1", "CULane F1", "num"),
        ("ms_per_frame", "ms/frame", "num"),
    ]
    head = "".join(f"<th>{escape(label)}</th>" for _, label, _ in cols)
    body = []
    for r in rows:
        cells = []
        for key, _, kind in cols:
            v = r.get(key)
            if kind == "pct":
                cells.append(_cell(_pct(v), v))
            elif kind == "num":
                cells.append(_cell(_num(v), v))
            elif kind == "int":
                cells.append(_cell("n/a" if _float(v) is None else str(int(float(v))), v))
            else:
                cells.append(_cell(str(v or "")))
        cls = ' class="pooled"' if r.get("sequence") == POOLED else ""
        body.append(f"<tr{cls}>{''.join(cells)}</tr>")
    html = (
        '<p class="note">Click a column to sort. Rows with sequence <code>all</code> pool every sequence.</p>'
        f'<table class="sortable" id="results-table"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table>'
    )
    return html, rows


def _ablation_charts(rows: list[dict[str, Any]], data: Collected) -> str:
    pooled = [r for r in rows if r.get("sequence") == POOLED] or rows
    scatter = _svg.scatter_svg(
        [
            (r.get("variant", ""), _float(r.get("ms_per_frame")), _float(r.get("detection_ratio")))
            for r in pooled
        ],
        "median ms per frame (all nodes)",
        "detection ratio",
    )
    stages = [
        c[3:]
        for c in (data.results[0].keys() if data.results else [])
        if c.startswith("ms_") and c != "ms_per_frame"
    ]
    ms = {r.get("variant", ""): {s: _float(r.get(f"ms_{s}")) for s in stages} for r in pooled}
    bars = _svg.stage_times_svg([r.get("variant", "") for r in pooled], stages, ms)
    return (
        '<h2>Accuracy against time</h2><div class="figure" id="accuracy-vs-time">' + scatter + "</div>"
        '<h2>Median time per stage</h2><div class="figure" id="stage-times">' + bars + "</div>"
    )


def _node_times(data: Collected) -> str:
    """The run's per-node median and p90 times (its first sequence's when it has several)."""
    rf = data.runs.get((0, 0))
    nodes = ((rf.timings or {}).get("nodes") or {}) if rf is not None else {}
    if not nodes:
        return '<p class="note">no timings.json</p>'
    order = list(data.graph.order) if data.graph is not None else []
    ids = [n for n in order if n in nodes] + [n for n in nodes if n not in order]
    rows = [
        (n, str(nodes[n].get("type", "?")), _float(nodes[n].get("median_ms")), _float(nodes[n].get("p90_ms")))
        for n in ids
    ]
    title = "Per-node time" + (f" ({data.sequences[0].name})" if len(data.sequences) > 1 else "")
    return f'<h2>{escape(title)}</h2><div class="figure" id="node-times">{_svg.node_times_svg(rows)}</div>'


def _graph(data: Collected) -> str:
    g = data.graph
    if g is None:
        if data.kind == "ablation":
            return '<p class="note">An ablation folder does not record its variants\' graphs: see Metrics for the time per stage.</p>'
        return '<p class="note">The graph was not found (see the notes at the bottom): no drawing.</p>'
    rf = data.runs.get((0, 0))
    timings = ((rf.timings or {}).get("nodes") or {}) if rf is not None else {}
    edges = [(e.src_node, e.src_port, e.dst_node, e.dst_port, e.previous) for e in g.edges]
    # the type that ran (timings.json: a selecting source replaced) before the graph file's
    types = {nid: str((timings.get(nid) or {}).get("type") or n.type.name) for nid, n in g.nodes.items()}
    svg = _svg.graph_svg(list(g.order), types, edges, timings)
    whose = (
        f" (variant {data.variants[0]}, times on {data.sequences[0].name})" if data.kind == "ablation" else ""
    )
    return (
        f"<h2>Graph <code>{escape(g.name)}</code>{escape(whose)}</h2>"
        '<p class="note">Execution order top to bottom; each node: id, type, median / p90 ms per frame (darker: a larger '
        "share of the time); dashed: the previous frame's values (feedback edges).</p>"
        f'<div class="figure" id="graph">{svg}</div>'
    )


def render(data: Collected, frames: list[dict[str, Any]], metrics: dict[str, Any]) -> str:
    """The report page as HTML text."""

    seqs = ", ".join(s.name for s in data.sequences)
    if data.kind == "run":
        title = f"lanegraph report: {data.variants[0]} on {seqs}"
    else:
        title = f"lanegraph report: ablation of {len(data.variants)} variants on {seqs}"
    gts = [s.gt_path for s in data.sequences if s.gt_path is not None]
    sub = " · ".join(
        [
            f"{len(frames)} frame(s)",
            f"{len(data.sequences)} sequence(s)",
            "ground truth " + ", ".join(_path(p) for p in gts) if gts else "no ground truth",
            "folder " + _path(data.run_dir),
        ]
    )
    metrics_html = []
    if data.kind == "ablation":
        table, rows = _results_table(data, metrics)
        metrics_html += ["<h2>Results</h2>", table, _ablation_charts(rows, data)]
    else:
        if metrics:
            metrics_html += ["<h2>Lane metric</h2>", _metrics_table(metrics, frames, data)]
        else:
            metrics_html.append(
                '<p class="note">No ground truth: give --gt GT or --dataset FILE for the lane metric.</p>'
            )
        metrics_html.append(_node_times(data))
    notes = "".join(f"<li>{escape(n)}</li>" for n in data.notes)
    payload = {
        "kind": data.kind,
        "variants": data.variants,
        "sequences": [{"name": s.name, "gt": s.gt is not None} for s in data.sequences],
        "frames": frames,
    }
    values = {
        "TITLE": escape(title),
        "SUBTITLE": sub,
        "GRAPH": _graph(data),
        "METRICS": "".join(metrics_html),
        "NOTES": f"<h2>Notes</h2><ul>{notes}</ul>" if notes else "",
        "VERSION": escape(__version__),
        "CSS": _asset("report.css"),
        "DATA": dumps_for_html(payload),
        "JS": _asset("report.js"),
    }
    # one pass: text put in is never searched for placeholders again
    return re.sub(r"@@([A-Z]+)@@", lambda m: values[m.group(1)], _asset("page.html"))


def dumps_for_html(obj: Any) -> str:
    """JSON that is safe inside a ``<script>`` element (no ``<``, ``>`` or ``&`` left as such)."""
    text = json.dumps(obj, separators=(",", ":"), allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")
