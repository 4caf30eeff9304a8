"""The figures of an ablation (``accuracy.png``, ``accuracy_vs_ms.png``) and the placement of point
labels that keeps them legible with many variants (also used by the report's SVG scatter).

Variants of one graph tend to cluster: ten of the tutorial's thirteen take 100-140 ms per frame at
a detection ratio of 100 %. Every point gets its own colour and marker and a legend entry, and its
label is put where it overlaps no other label and no point (:func:`place_labels`), joined to its
point by a thin line when it had to move away; a label with no free place within reach is left out,
the legend still names the point.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..paths import write_bytes_atomic

#: a label's box: (x0, y0, x1, y1), x0 <= x1 and y0 <= y1, in pixels
Box = tuple[float, float, float, float]

#: directions tried around a point, in order of preference (radians; 0 = to the right)
_ANGLES = [math.radians(a) for a in (20, 160, -20, -160, 90, -90, 50, 130, -50, -130, 0, 180)]


#: advance widths in em of DejaVu Sans, the widest of the common sans-serif fonts (Helvetica, Arial,
#: Segoe UI are narrower): a width estimated from them holds the text drawn in any of these
_EM = {
    **dict.fromkeys("abdghnopqu", 0.635), "c": 0.55, "e": 0.615, "f": 0.352, "i": 0.278, "j": 0.278,
    "k": 0.579, "l": 0.278, "m": 0.974, "r": 0.411, "s": 0.521, "t": 0.392, "v": 0.592, "w": 0.818,
    "x": 0.592, "y": 0.592, "z": 0.525, **dict.fromkeys("0123456789", 0.636), " ": 0.318, ".": 0.318,
    ",": 0.318, "_": 0.5, "-": 0.361, "=": 0.838, "+": 0.838, "[": 0.39, "]": 0.39, "(": 0.39,
    ")": 0.39, ":": 0.337, "/": 0.337, "%": 0.95, "I": 0.295, "J": 0.295, "M": 0.863, "W": 0.989,
}  # fmt: skip


def text_width(text: str, font_size: float) -> float:
    """An upper estimate of the width of ``text`` in pixels at ``font_size`` pixels, in a
    sans-serif font (for labels drawn where the text cannot be measured, as in SVG)."""
    em = sum(_EM.get(ch, 0.76 if ch.isupper() else (0.65 if ch.isascii() else 1.0)) for ch in text)
    return 1.04 * em * font_size


def _overlaps(a: Box, b: Box, gap: float = 0.0) -> bool:
    return a[0] < b[2] + gap and b[0] < a[2] + gap and a[1] < b[3] + gap and b[1] < a[3] + gap


def place_labels(
    anchors: Sequence[tuple[float, float]],
    sizes: Sequence[tuple[float, float]],
    bounds: Box,
    marker: float = 5.0,
    gap: float = 2.0,
    step: float = 9.0,
    rings: int = 12,
) -> list[Box | None]:
    """Boxes for the labels of points that overlap neither each other nor any point's marker.

    Parameters
    ----------
    anchors
        The points, ``(x, y)`` in pixels (either direction of ``y``).
    sizes
        Each label's ``(width, height)`` in pixels.
    bounds
        ``(x0, y0, x1, y1)``: the area every label box must stay inside.
    marker
        Half the side of the square kept free around each point, pixels.
    gap
        Least distance between two labels, pixels.
    step, rings
        Labels are tried on rings around their point, ``marker + gap + k * step`` pixels away for
        ``k < rings``, in several directions each.

    Returns
    -------
    list
        Per label, its box ``(x0, y0, x1, y1)``, or None where no free place was found (the caller
        leaves that label out; a legend names the point). Greedy, in the order given.
    """
    markers = [(x - marker, y - marker, x + marker, y + marker) for x, y in anchors]
    placed: list[Box] = []
    out: list[Box | None] = []
    for (ax, ay), (w, h) in zip(anchors, sizes):
        found = None
        for ring in range(rings):
            r = marker + gap + ring * step
            for t in _ANGLES:
                c, s = math.cos(t), math.sin(t)
                px, py = ax + r * c, ay + r * s
                x0 = px if c > 0.3 else (px - w if c < -0.3 else px - w / 2)
                y0 = py if s > 0.3 else (py - h if s < -0.3 else py - h / 2)
                box = (x0, y0, x0 + w, y0 + h)
                if box[0] < bounds[0] or box[1] < bounds[1] or box[2] > bounds[2] or box[3] > bounds[3]:
                    continue
                if any(_overlaps(box, m) for m in markers) or any(_overlaps(box, p, gap) for p in placed):
                    continue
                found = box
                break
            if found is not None:
                break
        out.append(found)
        if found is not None:
            placed.append(found)
    return out


def nearest_on_box(box: Box, x: float, y: float) -> tuple[float, float]:
    """The point of ``box`` nearest to ``(x, y)`` (where a leader line from the point ends)."""
    return min(max(x, box[0]), box[2]), min(max(y, box[1]), box[3])


# --------------------------------------------------------------------------- matplotlib figures
_MARKERS = "osD^vP*Xh<>p"
_DPI = 110


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _style(i: int) -> tuple[Any, str]:
    """A colour and a marker of their own for point ``i`` (tab10 colours x markers)."""
    plt = _pyplot()
    colours = plt.get_cmap("tab10").colors
    return colours[i % len(colours)], _MARKERS[(i // len(colours) + i) % len(_MARKERS)]


def accuracy_figure(rows: Sequence[dict[str, Any]]) -> Any:
    """Bars of detection ratio and precision per variant (the pooled rows)."""
    plt = _pyplot()
    names = [r["variant"] for r in rows]
    acc = [r.get("detection_ratio") or 0.0 for r in rows]
    prec = [r.get("precision") or 0.0 for r in rows]
    fig, ax = plt.subplots(figsize=(max(6, 0.8 * len(rows) + 2), 4), dpi=_DPI)
    xs = range(len(rows))
    ax.bar([x - 0.2 for x in xs], acc, width=0.4, label="detection ratio")
    ax.bar([x + 0.2 for x in xs], prec, width=0.4, label="precision")
    ax.set_xticks(list(xs), names, rotation=35, ha="right")
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("fraction")
    ax.set_title("accuracy per variant")
    ax.legend(loc="lower right")
    fig.tight_layout()
    return fig


def accuracy_vs_ms_figure(rows: Sequence[dict[str, Any]]) -> Any:
    """Detection ratio against median ms per frame, one point per variant: each its own colour and
    marker, named in a legend beside the axes and by a label placed apart from the others."""
    plt = _pyplot()
    pts = [
        (r["variant"], float(r["ms_per_frame"]), float(r.get("detection_ratio") or 0.0))
        for r in rows
        if r.get("ms_per_frame") is not None
    ]
    fig, ax = plt.subplots(figsize=(8.5, 5), dpi=_DPI)
    for i, (name, ms, acc) in enumerate(pts):
        colour, marker = _style(i)
        ax.scatter(
            [ms], [acc], color=colour, marker=marker, s=36, edgecolors="#333", linewidths=0.5, label=name
        )
    ax.set_xlabel("median ms per frame (all nodes, as measured in this ablation's runs; see results.md)")
    ax.set_ylabel("detection ratio")
    ax.set_ylim(-0.02, 1.08)
    if pts:
        lo, hi = min(p[1] for p in pts), max(p[1] for p in pts)
        pad = max(0.15 * (hi - lo), 0.08 * hi, 1.0)
        ax.set_xlim(max(0.0, lo - pad), hi + pad)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False, borderaxespad=0)
    ax.set_title("accuracy against time")
    fig.tight_layout()
    if pts:
        _label_points(fig, ax, pts)
    return fig


def _label_points(fig: Any, ax: Any, pts: list[tuple[str, float, float]]) -> None:
    """Direct labels placed apart (display pixels, measured with the figure's renderer)."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    sizes = []
    for name, _, _ in pts:
        t = ax.text(0, 0, name, fontsize=7, ha="left", va="bottom")
        bb = t.get_window_extent(renderer)
        sizes.append((bb.width, bb.height))
        t.remove()
    anchors = [tuple(ax.transData.transform((ms, acc))) for _, ms, acc in pts]
    frame = ax.get_window_extent(renderer)
    pixel = fig.dpi / 72.0  # display pixels per point
    boxes = place_labels(
        anchors,
        sizes,
        (frame.x0 + 2, frame.y0 + 2, frame.x1 - 2, frame.y1 - 2),
        marker=4 * pixel,
        gap=1.5 * pixel,
        step=6 * pixel,
    )
    for (name, ms, acc), (axp, ayp), box in zip(pts, anchors, boxes):
        if box is None:
            continue
        far = math.dist((axp, ayp), nearest_on_box(box, axp, ayp)) > 8 * pixel
        ax.annotate(
            name,
            (ms, acc),
            xytext=((box[0] - axp) / pixel, (box[1] - ayp) / pixel),
            textcoords="offset points",
            ha="left",
            va="bottom",
            fontsize=7,
            annotation_clip=False,
            arrowprops={"arrowstyle": "-", "color": "#888", "lw": 0.6, "shrinkA": 0, "shrinkB": 3}
            if far
            else None,
        )


def save_png(fig: Any, path: Path) -> None:
    """``fig`` as a PNG at ``path`` (atomically; the umask's mode), then closed."""
    buf = io.BytesIO()
    fig.savefig(buf, dpi=_DPI, format="png")
    _pyplot().close(fig)
    write_bytes_atomic(path, buf.getvalue())


def write_ablation_plots(rows: Sequence[dict[str, Any]], out_dir: Path) -> None:
    """``accuracy.png`` and ``accuracy_vs_ms.png`` of an ablation's pooled rows into ``out_dir``."""
    save_png(accuracy_figure(rows), out_dir / "accuracy.png")
    save_png(accuracy_vs_ms_figure(rows), out_dir / "accuracy_vs_ms.png")
