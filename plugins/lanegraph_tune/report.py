"""The report page of ``lanegraph tune``: one static HTML file (``OUT/report/index.html``), no script
and no network: the left-out against tuned-on table, each fold's choice and every trial's score
(an inline SVG), readable from ``file://`` and fit to send."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

from lanegraph.api import POOLED
from lanegraph.paths import write_text_atomic

from .search import TuneResult, pooled

_STYLE = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:70em;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:.3em .6em;text-align:left}
th{background:#f3f3f3}tr.pooled td{font-weight:bold}.bad{color:#b00}.note{color:#555}
"""


def _pct(x: Any) -> str:
    return "n/a" if x is None or x == "" else f"{100 * float(x):.1f} %"


def _scores_svg(result: TuneResult, width: int = 640, height: int = 220) -> str:
    """Each trial's pooled score (on the sequences it ran on) against its order, one colour per study."""
    trials = result.trials
    if not trials:
        return "<p class='note'>no finished trial</p>"
    studies = list(dict.fromkeys(t.study for t in trials))
    colours = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf"]
    scores = [pooled(t.counts, list(t.counts)).score() for t in trials]
    lo, hi = min(min(scores), 0.0), max(max(scores), 1.0)
    pad = 30
    pts = []
    for k, (t, s) in enumerate(zip(trials, scores)):
        x = pad + (width - 2 * pad) * (k / max(len(trials) - 1, 1))
        y = height - pad - (height - 2 * pad) * ((s - lo) / ((hi - lo) or 1))
        c = colours[studies.index(t.study) % len(colours)]
        tip = html.escape(f"{t.study}#{t.number}: score {s:.3f} {t.params}")
        pts.append(f"<circle cx='{x:.1f}' cy='{y:.1f}' r='4' fill='{c}'><title>{tip}</title></circle>")
    legend = "".join(
        f"<text x='{pad + 120 * i}' y='14' fill='{colours[i % len(colours)]}' font-size='12'>{html.escape(s)}</text>"
        for i, s in enumerate(studies)
    )
    axis = (
        f"<line x1='{pad}' y1='{height - pad}' x2='{width - pad}' y2='{height - pad}' stroke='#999'/>"
        f"<text x='2' y='{pad}' font-size='11'>{hi:.2f}</text><text x='2' y='{height - pad}' font-size='11'>{lo:.2f}</text>"
        f"<text x='{width / 2:.0f}' y='{height - 8}' font-size='11'>trials in order (score: detection ratio - false lanes / 1000 frames)</text>"
    )
    return f"<svg width='{width}' height='{height}' xmlns='http://www.w3.org/2000/svg'>{legend}{axis}{''.join(pts)}</svg>"


def write_tune_report(result: TuneResult, rows: list[dict[str, Any]], out_dir: Path, title: str) -> Path:
    """Write ``OUT/report/index.html``; returns its path."""
    e = html.escape
    head = "<tr><th>sequence</th><th>frames</th><th>left out</th><th>tuned on</th><th>baseline</th></tr>"
    body = []
    for r in rows:
        cells = []
        for what in ("left_out", "tuned_on", "baseline"):
            dr = r.get(f"{what}_detection_ratio")
            worse = (
                what == "left_out" and dr is not None and r.get("tuned_on_detection_ratio") not in (None, "")
            )
            cls = " class='bad'" if worse and float(dr) < float(r["tuned_on_detection_ratio"]) else ""
            cells.append(
                f"<td{cls}>n/a</td>"
                if dr is None
                else f"<td{cls}>{_pct(dr)} <span class='note'>(precision {_pct(r.get(f'{what}_precision'))}, "
                f"{r.get(f'{what}_false_lanes')} false)</span></td>"
            )
        pooled_row = r["sequence"] == POOLED
        name = "all (pooled)" if pooled_row else r["sequence"]
        body.append(
            f"<tr{' class=pooled' if pooled_row else ''}><td>{e(str(name))}</td><td>{r['frames']}</td>{''.join(cells)}</tr>"
        )
    folds = [
        "<tr><th>left out</th><th>trained on</th><th>trial</th><th>params</th><th>train detection ratio</th></tr>"
    ]
    for f in result.folds:
        params = "<br>".join(e(f"{k} = {v}") for k, v in f.params.items()) or "(none finished)"
        folds.append(
            f"<tr><td>{e(f.name)}</td><td>{e(', '.join(f.train))}</td><td>{e(f.study)}#{f.trial}</td>"
            f"<td>{params}</td><td>{_pct(f.train_counts.detection_ratio)}</td></tr>"
        )
    final = ""
    if result.final is not None:
        final = (
            "<ul>"
            + "".join(f"<li><code>{e(k)}: {e(str(v))}</code></li>" for k, v in result.final.params.items())
            + "</ul>"
        )
    mode = (
        "one shared study: every trial ran on every sequence, each fold chose among the trials on its training sequences"
        if result.mode == "shared"
        else "one study per fold over its training sequences, and one over all sequences"
    )
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{e(title)}</title><style>{_STYLE}</style></head>
<body><h1>{e(title)}</h1>
<p>Search: {e(mode)} ({e(result.sampler)} sampler, {len(result.trials)} finished trial(s)).
A frame is right when every reported lane matches a marking and both painted ego boundaries are found:
a false lane costs a frame as a missed boundary does. <em>Left out</em>: the sequence scored by the fold
that did not see it; <em>tuned on</em>: the params chosen on all sequences; <em>baseline</em>: the graph's own values.</p>
<h2>Detection ratio per sequence</h2><table>{head}{"".join(body)}</table>
<h2>Each fold's choice</h2><table>{"".join(folds)}</table>
<h2>Chosen on all sequences (tuned.yaml)</h2>{final}
<h2>Trials</h2>{_scores_svg(result)}
</body></html>
"""
    path = out_dir / "report" / "index.html"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, page)
    return path
