"""Legible plots with many variants: labels placed apart (no label over another or over a point),
every variant in a legend; ``accuracy_vs_ms.png`` (matplotlib) and the report's SVG scatter (in a
real headless Chromium, with the fonts it draws)."""

from __future__ import annotations

import itertools
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lanegraph_report import _svg

from lanegraph.evaluation.plots import accuracy_vs_ms_figure, place_labels, text_width

#: thirteen variants, as an ablation of the paper graph gives them: all between 100 and 140 ms,
#: ten of them at a detection ratio of 100 %
CLUSTER = [
    ("paper", 131.3, 1.0),
    ("bm", 100.4, 0.981),
    ("hough2d", 131.27, 1.0),
    ("no_road_mask", 114.3, 1.0),
    ("no_temporal_mask", 115.9, 1.0),
    ("paper_literal", 109.7, 0.241),
    ("ransac", 114.8, 1.0),
    ("slt", 131.2, 1.0),
    ("own_sgm_fast", 138.9, 0.981),
    ("paper[fit.roi_width=20]", 120.1, 1.0),
    ("paper[fit.roi_width=60]", 121.3, 1.0),
    ("paper[hough.min_relative=0.1]", 119.8, 1.0),
    ("paper[hough.min_relative=0.5]", 118.2, 1.0),
]


def _overlap(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _pairs_overlapping(boxes):
    return [(i, j) for (i, a), (j, b) in itertools.combinations(enumerate(boxes), 2) if _overlap(a, b)]


def test_labels_of_a_cluster_are_placed_apart():
    anchors = [(50 + 3 * ms, 300 - 250 * acc) for _, ms, acc in CLUSTER]
    sizes = [(text_width(n, 11), 13.0) for n, _, _ in CLUSTER]
    bounds = (0.0, 0.0, 600.0, 320.0)
    boxes = place_labels(anchors, sizes, bounds, marker=5.0)
    placed = [b for b in boxes if b is not None]
    assert len(placed) >= 11  # nearly all fit; the legend names the others
    assert _pairs_overlapping(placed) == []
    for b in placed:
        assert bounds[0] <= b[0] and b[2] <= bounds[2] and bounds[1] <= b[1] and b[3] <= bounds[3]
        for x, y in anchors:  # no label over a point
            assert not _overlap(b, (x - 5, y - 5, x + 5, y + 5))
    # the naive placement (every label to the upper right of its point) overlaps: the test can fail
    naive = [(x + 3, y - 3 - h, x + 3 + w, y - 3) for (x, y), (w, h) in zip(anchors, sizes)]
    assert _pairs_overlapping(naive)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(0, 400), st.floats(0, 300), st.floats(5, 120), st.floats(5, 20)),
        min_size=1,
        max_size=25,
    )
)
def test_placed_labels_never_overlap(points):
    boxes = place_labels(
        [(x, y) for x, y, _, _ in points], [(w, h) for _, _, w, h in points], (0, 0, 400, 300)
    )
    placed = [b for b in boxes if b is not None]
    assert _pairs_overlapping(placed) == []
    for (_, _, w, h), b in zip(points, boxes):
        if b is not None:
            assert b[2] - b[0] == pytest.approx(w) and b[3] - b[1] == pytest.approx(h)
            assert 0 <= b[0] and b[2] <= 400 and 0 <= b[1] and b[3] <= 300


def test_accuracy_vs_ms_png_of_thirteen_clustered_variants_is_legible():
    import matplotlib.pyplot as plt
    from matplotlib.text import Text

    rows = [{"variant": n, "ms_per_frame": ms, "detection_ratio": acc} for n, ms, acc in CLUSTER]
    random.Random(0).shuffle(rows)
    fig = accuracy_vs_ms_figure(rows)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        ax = fig.axes[0]
        labels = [t for t in ax.texts if t.get_text() in {n for n, _, _ in CLUSTER}]
        # the text's own box (an annotation's extent includes its leader line)
        boxes = [tuple(Text.get_window_extent(t, renderer).extents) for t in labels]
        assert len(labels) >= 11, [t.get_text() for t in labels]
        assert _pairs_overlapping(boxes) == [], [
            (labels[i].get_text(), labels[j].get_text()) for i, j in _pairs_overlapping(boxes)
        ]
        frame = ax.get_window_extent(renderer).extents
        for b in boxes:
            assert frame[0] <= b[0] and b[2] <= frame[2] and frame[1] <= b[1] and b[3] <= frame[3]
        # every point drawn, and over no label
        points = [tuple(ax.transData.transform((r["ms_per_frame"], r["detection_ratio"]))) for r in rows]
        for x, y in points:
            assert not any(_overlap(b, (x - 3, y - 3, x + 3, y + 3)) for b in boxes)
        # every variant named in the legend, with a style of its own
        legend = ax.get_legend()
        assert sorted(t.get_text() for t in legend.get_texts()) == sorted(n for n, _, _ in CLUSTER)
        styles = {(tuple(c.get_facecolor()[0]), c.get_paths()[0].vertices.tobytes()) for c in ax.collections}
        assert len(styles) == len(CLUSTER)
    finally:
        plt.close(fig)


def test_report_scatter_of_thirteen_clustered_variants_in_chromium(tmp_path):
    from tests.engine.test_report import CHROMIUM_ARGS, _chromium

    try:
        from playwright import sync_api
    except ImportError as exc:
        pytest.skip(f"playwright is not installed ({exc}): pip install -e '.[browser]'")
    exe = _chromium()
    if exe is None:
        pytest.skip("no Chromium found (/usr/bin/chromium; Debian: apt-get install chromium)")
    svg = _svg.scatter_svg(CLUSTER, "median ms per frame", "detection ratio")
    page_file = tmp_path / "scatter.html"
    page_file.write_text(f"<!doctype html><html><body style='margin:0'>{svg}</body></html>")
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 800})
            page.goto(page_file.as_uri())
            boxes = page.eval_on_selector_all(
                "svg .point text.label",
                "els => els.map(e => { const r = e.getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom, e.textContent]; })",
            )
            dots = page.eval_on_selector_all(
                "svg .point > circle",
                "els => els.map(e => { const r = e.getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]; })",
            )
            legend = page.eval_on_selector_all("svg .legend-entry text", "els => els.map(e => e.textContent)")
        finally:
            browser.close()
    assert len(dots) == len(CLUSTER) and sorted(legend) == sorted(n for n, _, _ in CLUSTER)
    assert len(boxes) >= 11
    rects = [b[:4] for b in boxes]
    assert _pairs_overlapping(rects) == [], [(boxes[i][4], boxes[j][4]) for i, j in _pairs_overlapping(rects)]
    for b in rects:
        assert not any(_overlap(b, d) for d in dots), b
