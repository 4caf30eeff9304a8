"""The report's drawings as SVG text, made offline (no Graphviz, no plotting library): the resolved
graph in layers with each node's times, a bar chart of per-node times, stacked per-stage times of
ablation variants and the accuracy-against-time scatter.

Every text that comes from a graph, an output folder or a results table is escaped here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from html import escape
from typing import Any

#: categorical colours (stages, variants)
PALETTE = (
    "#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7",
    "#9c755f", "#bab0ac", "#1f77b4", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#17becf",
)  # fmt: skip

_FONT = 'font-family="system-ui, -apple-system, Segoe UI, Helvetica, Arial, sans-serif"'


def _ms(x: float | None) -> str:
    if x is None:
        return "n/a"
    return f"{x:.1f}" if x >= 1 else f"{x:.2f}"


def _clip(text: str, n: int) -> str:
    return text if len(text) <= n else text[: n - 1] + "…"


#: box width and height of a node, gaps between boxes and layers, margin, pixels
_BW, _BH, _HGAP, _VGAP, _MARGIN = 168, 52, 22, 34, 16

Edge = tuple[str, str, str, str, bool]


def graph_svg(
    order: Sequence[str],
    types: Mapping[str, str],
    edges: Sequence[Edge],
    timings: Mapping[str, Mapping[str, Any]] | None = None,
) -> str:
    """The graph in layers, top to bottom, as SVG.

    ``order``: node ids in execution order; ``types``: node id -> type name; ``edges``:
    ``(src_node, src_port, dst_node, dst_port, previous)``, ``previous`` marking a feedback edge
    (dashed, drawn along the right); ``timings``: node id -> ``{"median_ms", "p90_ms"}`` as in
    ``timings.json``. A node's fill is darker the larger its share of the summed median times.
    """
    timings = timings or {}
    lay = _Layout(order, edges)
    W = lay.left + lay.width + 2 * _MARGIN + lay.right_pad
    H = lay.n_layers * (_BH + _VGAP) - _VGAP + 2 * _MARGIN
    medians = {nid: (timings.get(nid) or {}).get("median_ms") or 0.0 for nid in order}
    total = sum(medians.values()) or 1.0
    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" class="graph" viewBox="0 0 {W:.0f} {H:.0f}" width="{W:.0f}" height="{H:.0f}" {_FONT} font-size="11">',
        '<defs><marker id="arrow" viewBox="0 0 8 8" refX="7" refY="4" markerWidth="7" markerHeight="7" orient="auto">'
        '<path d="M0,0 L8,4 L0,8 z" fill="#667"/></marker></defs>',
        f'<g transform="translate({_MARGIN},{_MARGIN})">',
    ]
    out += [_edge_svg(lay, e) for e in edges if e[0] in lay.x and e[2] in lay.x]
    out += [
        _node_svg(lay, nid, types.get(nid, "?"), timings.get(nid) or {}, medians[nid] / total)
        for nid in order
    ]
    out.append("</g></svg>")
    return "".join(out)


class _Layout:
    """Where the nodes of a graph go: layers by the longest chain of forward edges, parents' mean
    position first within a layer (fewer crossings), each layer centred, room on the left for
    edges that skip layers and on the right for feedback edges."""

    def __init__(self, order: Sequence[str], edges: Sequence[Edge]):
        index = {nid: i for i, nid in enumerate(order)}
        parents: dict[str, list[str]] = {nid: [] for nid in order}
        for s, _, d, _, prev in edges:
            if not prev and s in parents and d in parents:
                parents[d].append(s)
        layer: dict[str, int] = {}
        for nid in order:  # execution order is topological over the forward edges
            layer[nid] = max((layer[p] + 1 for p in parents[nid] if p in layer), default=0)
        layers: list[list[str]] = [[] for _ in range(max(layer.values(), default=-1) + 1)]
        for nid in order:
            layers[layer[nid]].append(nid)
        x: dict[str, float] = {}
        for li, ids in enumerate(layers):
            if li:
                ids.sort(
                    key=lambda n: (
                        sum(x[p] for p in parents[n]) / len(parents[n]) if parents[n] else 0.0,
                        index[n],
                    )
                )
            for k, nid in enumerate(ids):
                x[nid] = k * (_BW + _HGAP)
        self.width = max((len(ids) * (_BW + _HGAP) - _HGAP for ids in layers), default=_BW)
        for ids in layers:  # centre each layer
            shift = (self.width - (len(ids) * (_BW + _HGAP) - _HGAP)) / 2
            for nid in ids:
                x[nid] += shift
        self.forward = [e for e in edges if not e[4] and e[0] in x and e[2] in x]
        # inputs enter a node's top side spread out in port order; outputs leave its bottom per port
        self.ins: dict[str, list[Edge]] = {}
        self.outs: dict[str, list[str]] = {}
        for e in self.forward:
            self.ins.setdefault(e[2], []).append(e)
            if e[1] not in self.outs.setdefault(e[0], []):
                self.outs[e[0]].append(e[1])
        # an edge that skips layers bows out to the left, past the nodes it skips
        longest = max((layer[e[2]] - layer[e[0]] for e in self.forward), default=1)
        self.left = (
            0.0
            if longest <= 1
            else max(0.0, 0.75 * (150 + 10 * longest) - _BW / 2 - min(x.values(), default=0.0))
        )
        self.x = {nid: v + self.left for nid, v in x.items()}
        self.y = {nid: layer[nid] * (_BH + _VGAP) for nid in order}
        self.layer = layer
        self.n_layers = len(layers)
        self.right_pad = 60 if any(e[4] for e in edges) else 0


def _edge_svg(lay: _Layout, e: Edge) -> str:
    """One edge: a curve from the source's output to the target's input; a feedback edge dashed,
    out of the source's right side, up along the right, into the target's right side."""
    s, sp, d, dp, prev = e
    x, y = lay.x, lay.y
    title = f"<title>{escape(s)}.{escape(sp)} → {escape(d)}.{escape(dp)}{' (previous frame)' if prev else ''}</title>"
    if prev:
        x0, y0 = x[s] + _BW, y[s] + _BH / 2
        x1, y1 = x[d] + _BW, y[d] + _BH / 2
        xr = lay.left + lay.width + lay.right_pad * 0.7
        path = f"M{x0:.1f},{y0:.1f} C{xr:.1f},{y0:.1f} {xr:.1f},{y1:.1f} {x1 + 2:.1f},{y1:.1f}"
        return f'<path d="{path}" fill="none" stroke="#a05" stroke-width="1.3" stroke-dasharray="5 3" marker-end="url(#arrow)">{title}</path>'
    ports = lay.outs[s]
    x0, y0 = x[s] + _BW * (ports.index(sp) + 1) / (len(ports) + 1), y[s] + _BH
    k, n = lay.ins[d].index(e), len(lay.ins[d])
    x1, y1 = x[d] + _BW * (k + 1) / (n + 1), y[d]
    skipped = lay.layer[d] - lay.layer[s]
    if skipped > 1:
        bow = 150 + 10 * skipped
        path = f"M{x0:.1f},{y0:.1f} C{x0 - bow:.1f},{y0 + 40:.1f} {x1 - bow:.1f},{y1 - 40:.1f} {x1:.1f},{y1 - 1:.1f}"
    else:
        my = (y0 + y1) / 2
        path = f"M{x0:.1f},{y0:.1f} C{x0:.1f},{my:.1f} {x1:.1f},{my:.1f} {x1:.1f},{y1 - 1:.1f}"
    return (
        f'<path d="{path}" fill="none" stroke="#667" stroke-width="1.2" stroke-opacity="{0.55 if skipped > 1 else 1}" '
        f'marker-end="url(#arrow)">{title}</path>'
    )


def _node_svg(lay: _Layout, nid: str, type_name: str, t: Mapping[str, Any], share: float) -> str:
    """One node's box: its id, type and median / p90 times, darker the larger its ``share``."""
    x, y = lay.x[nid], lay.y[nid]
    light = 97 - 45 * min(share / 0.5, 1.0)  # half the time or more: the darkest
    fill = f"hsl(28, 90%, {light:.0f}%)"
    med, p90 = t.get("median_ms"), t.get("p90_ms")
    times = f"{_ms(med)} / {_ms(p90)} ms" if t else "no timing"
    tip = f"{nid} ({type_name}): median {_ms(med)} ms, p90 {_ms(p90)} ms, {100 * share:.0f} % of the summed medians"
    return (
        f'<g class="node" data-node="{escape(nid)}"><title>{escape(tip)}</title>'
        f'<rect x="{x:.1f}" y="{y:.1f}" width="{_BW}" height="{_BH}" rx="6" fill="{fill}" stroke="#889"/>'
        f'<text x="{x + _BW / 2:.1f}" y="{y + 16:.1f}" text-anchor="middle" font-weight="600" font-size="12">{escape(_clip(nid, 22))}</text>'
        f'<text x="{x + _BW / 2:.1f}" y="{y + 31:.1f}" text-anchor="middle" fill="#444">{escape(_clip(type_name, 26))}</text>'
        f'<text x="{x + _BW / 2:.1f}" y="{y + 45:.1f}" text-anchor="middle" fill="#333">{escape(times)}</text></g>'
    )


def node_times_svg(rows: Sequence[tuple[str, str, float | None, float | None]]) -> str:
    """Horizontal bars of per-node times: ``(node id, type, median ms, p90 ms)`` per row; the bar
    is the median, the tick the 90th percentile."""
    rows = [r for r in rows if r[2] is not None]
    if not rows:
        return '<p class="note">no node timings</p>'
    label_w, bar_w, row_h, top = 190, 420, 20, 22
    top_ms = max(max(r[3] or r[2] or 0.0, r[2] or 0.0) for r in rows) or 1.0
    W, H = label_w + bar_w + 120, top + row_h * len(rows) + 8
    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" class="chart" viewBox="0 0 {W} {H}" width="{W}" height="{H}" {_FONT} font-size="11">'
    ]
    out.append(f'<text x="{label_w}" y="13" fill="#555">median (bar) and p90 (tick), ms per frame</text>')
    for k, (nid, ntype, med, p90) in enumerate(rows):
        yy = top + k * row_h
        wmed = bar_w * (med or 0.0) / top_ms
        out.append(
            f"<g><title>{escape(nid)} ({escape(ntype)}): median {_ms(med)} ms, p90 {_ms(p90)} ms</title>"
        )
        out.append(f'<text x="{label_w - 6}" y="{yy + 13}" text-anchor="end">{escape(_clip(nid, 28))}</text>')
        out.append(
            f'<rect x="{label_w}" y="{yy + 3}" width="{max(wmed, 0.5):.1f}" height="{row_h - 7}" fill="{PALETTE[0]}"/>'
        )
        if p90 is not None:
            xp = label_w + bar_w * p90 / top_ms
            out.append(
                f'<line x1="{xp:.1f}" x2="{xp:.1f}" y1="{yy + 1}" y2="{yy + row_h - 2}" stroke="#c33" stroke-width="2"/>'
            )
        out.append(
            f'<text x="{label_w + bar_w + 6}" y="{yy + 13}" fill="#333">{_ms(med)} / {_ms(p90)}</text></g>'
        )
    out.append("</svg>")
    return "".join(out)


def stage_times_svg(
    variants: Sequence[str], stages: Sequence[str], ms: Mapping[str, Mapping[str, float | None]]
) -> str:
    """One stacked bar per variant: its stages' median ms per frame (``ms[variant][stage]``)."""
    if not variants or not stages:
        return '<p class="note">no stage timings</p>'
    label_w, bar_w, row_h, top = 200, 460, 22, 8
    totals = {v: sum((ms.get(v) or {}).get(s) or 0.0 for s in stages) for v in variants}
    top_ms = max(totals.values()) or 1.0
    legend_rows = (len(stages) + 5) // 6
    H = top + row_h * len(variants) + 14 + 18 * legend_rows
    W = label_w + bar_w + 90
    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" class="chart" viewBox="0 0 {W} {H}" width="{W}" height="{H}" {_FONT} font-size="11">'
    ]
    for k, v in enumerate(variants):
        yy = top + k * row_h
        out.append(f'<text x="{label_w - 6}" y="{yy + 14}" text-anchor="end">{escape(_clip(v, 30))}</text>')
        x0 = float(label_w)
        for si, s in enumerate(stages):
            val = (ms.get(v) or {}).get(s) or 0.0
            w = bar_w * val / top_ms
            if w <= 0:
                continue
            out.append(
                f'<rect x="{x0:.1f}" y="{yy + 3}" width="{w:.1f}" height="{row_h - 7}" fill="{PALETTE[si % len(PALETTE)]}">'
                f"<title>{escape(v)}: {escape(s)} {_ms(val)} ms</title></rect>"
            )
            x0 += w
        out.append(f'<text x="{x0 + 5:.1f}" y="{yy + 14}" fill="#333">{_ms(totals[v])} ms</text>')
    ly = top + row_h * len(variants) + 12
    for si, s in enumerate(stages):
        lx = label_w + (si % 6) * 78
        yy = ly + (si // 6) * 18
        out.append(f'<rect x="{lx}" y="{yy}" width="10" height="10" fill="{PALETTE[si % len(PALETTE)]}"/>')
        out.append(f'<text x="{lx + 14}" y="{yy + 9}">{escape(_clip(s, 11))}</text>')
    out.append("</svg>")
    return "".join(out)


#: the height of a label's box at font size 11, pixels (ascent and descent)
_TEXT_H = 13.0


def scatter_svg(points: Sequence[tuple[str, float | None, float | None]], x_label: str, y_label: str) -> str:
    """Accuracy against time: ``(label, x, y)`` per point, ``y`` a fraction in [0, 1].

    Each point has its own colour, a legend entry beside the plot, and a label placed where it
    overlaps no other label and no point (:func:`lanegraph.evaluation.plots.place_labels`; joined to its point
    by a thin line when moved away, left out when there is no room: the legend names the point)."""
    from lanegraph.api import nearest_on_box, place_labels, text_width

    pts = [(n, float(xv), float(yv)) for n, xv, yv in points if xv is not None and yv is not None]
    if not pts:
        return '<p class="note">no variant has both a time and an accuracy</p>'
    legend_w = 34 + max(text_width(_clip(n, 32), 11) for n, _, _ in pts)
    ml, mt, mb, pw = 56, 14, 44, 470
    ph = max(322, 16 * len(pts) - 8)
    W, H = ml + pw + 16 + legend_w, mt + ph + mb
    lo, hi = min(p[1] for p in pts), max(p[1] for p in pts)
    pad = max(0.15 * (hi - lo), 0.08 * hi, 1.0)
    step = _nice_step((hi + pad - (0.0 if lo < 0.4 * hi else lo - pad)) / 5)
    x_lo = 0.0 if lo < 0.4 * hi else step * math.floor((lo - pad) / step)
    x_hi = hi + pad

    def px(xv: float) -> float:
        return ml + pw * (xv - x_lo) / (x_hi - x_lo)

    def py(yv: float) -> float:
        return mt + ph - ph * max(0.0, min(yv, 1.0))

    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" class="chart scatter" viewBox="0 0 {W:.0f} {H}" width="{W:.0f}" height="{H}" {_FONT} font-size="11">'
    ]
    out.append(f'<rect x="{ml}" y="{mt}" width="{pw}" height="{ph}" fill="#fafafa" stroke="#bbb"/>')
    for k in range(6):  # y ticks: 0, 20 ... 100 %
        yy = mt + ph - ph * k / 5
        out.append(f'<line x1="{ml}" x2="{ml + pw}" y1="{yy:.1f}" y2="{yy:.1f}" stroke="#e4e4e4"/>')
        out.append(f'<text x="{ml - 6}" y="{yy + 4:.1f}" text-anchor="end">{20 * k} %</text>')
    k = math.ceil(x_lo / step)
    while k * step <= x_hi:
        xx = px(k * step)
        out.append(f'<line x1="{xx:.1f}" x2="{xx:.1f}" y1="{mt}" y2="{mt + ph}" stroke="#eee"/>')
        out.append(f'<text x="{xx:.1f}" y="{mt + ph + 15}" text-anchor="middle">{k * step:g}</text>')
        k += 1
    out.append(
        f'<text x="{ml + pw / 2}" y="{H - 8}" text-anchor="middle" fill="#444">{escape(x_label)}</text>'
    )
    out.append(
        f'<text transform="translate(14,{mt + ph / 2}) rotate(-90)" text-anchor="middle" fill="#444">{escape(y_label)}</text>'
    )
    anchors = [(px(xv), py(yv)) for _, xv, yv in pts]
    labels = [_clip(name, 32) for name, _, _ in pts]
    boxes = place_labels(
        anchors,
        [(text_width(t, 11), _TEXT_H) for t in labels],
        (ml + 2, mt + 2, ml + pw - 2, mt + ph - 2),
        6.0,
    )
    for i, ((name, xv, yv), (xx, yy), label, box) in enumerate(zip(pts, anchors, labels, boxes)):
        colour = PALETTE[i % len(PALETTE)]
        text = ""
        if box is not None:
            lx, ly = nearest_on_box(box, xx, yy)
            if math.dist((xx, yy), (lx, ly)) > 10:
                text += f'<line class="leader" x1="{xx:.1f}" y1="{yy:.1f}" x2="{lx:.1f}" y2="{ly:.1f}" stroke="#999" stroke-width="0.7"/>'
            text += f'<text class="label" x="{box[0]:.1f}" y="{box[3] - 3:.1f}">{escape(label)}</text>'
        ly0 = mt + 4 + 16 * i
        out.append(
            f'<g class="point"><title>{escape(name)}: {yv * 100:.1f} %, {_ms(xv)} ms</title>{text}'
            f'<circle cx="{xx:.1f}" cy="{yy:.1f}" r="5" fill="{colour}" stroke="#333" stroke-width="0.6"/>'
            f'<g class="legend-entry"><circle cx="{ml + pw + 24}" cy="{ly0 + 6}" r="5" fill="{colour}" stroke="#333" stroke-width="0.6"/>'
            f'<text x="{ml + pw + 34}" y="{ly0 + 10}">{escape(label)}</text></g></g>'
        )
    out.append("</svg>")
    return "".join(out)


def _nice_step(raw: float) -> float:
    """1, 2 or 5 times a power of ten, at least ``raw``."""
    import math

    if raw <= 0:
        return 1.0
    p = 10 ** math.floor(math.log10(raw))
    for m in (1, 2, 5, 10):
        if m * p >= raw:
            return m * p
    return 10 * p
