"""``lanegraph report``: a self-contained browser report of a run or an ablation.

:func:`write_report` reads a ``lanegraph run`` output folder (its lanes, ``timings.json``,
``run.json``; with a dataset file, a run folder ``<sequence>/`` per sequence) or a ``lanegraph
ablate`` output folder (``runs/<variant>/<sequence>/``, ``results.csv``) and writes
``OUT/index.html`` with its pictures in ``OUT/assets/``:

- **Frames**: the left image of every frame with the reported lanes and the ground-truth markings,
  coloured by outcome (matched, false lane, missed ego boundary) as
  :func:`lanegraph.evaluation.metrics.match_frame` decides it; the frame list marks the frames
  ``lanegraph eval`` fails, with a "failed only" filter; ← / → and a slider step through it.
- **Nodes**: the resolved graph drawn with each node's median and p90 time, and every node's
  picture of the frames recorded with ``--debug-dir``, in graph order.
- **Metrics**: detection ratio, precision, ego recall and mean |dx| per sequence and pooled, and
  the per-node times; for an ablation its sortable results table, accuracy against time, time per
  stage, and a side-by-side view of two variants with the frames where they disagree first.

The page carries its script, style and data inline and its pictures as JPEG files beside it: it
opens from ``file://`` and fetches nothing from the network.
"""

from __future__ import annotations

from ._build import IMAGE_WIDTH, ReportSummary, write_report

__all__ = ["IMAGE_WIDTH", "ReportSummary", "write_report"]
