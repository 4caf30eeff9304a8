"""lanegraph_report: a self-contained browser report of a run or an ablation (``lanegraph report``,
``run --report``, ``ablate --report``), and ``lanegraph eval``.

A plugin like any third party's: it writes reports through the ``lanegraph_write_report`` hook
(what the run service's ``Session.report`` calls) and adds the commands ``lanegraph report``
(:mod:`lanegraph_report.cli`) and ``lanegraph eval`` (:mod:`lanegraph_report.evaluate`), entry
points of ``lanegraph.commands``. It imports its modules, and OpenCV, only when a report is
written: loading the plugin costs nothing.

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

from typing import Any

from lanegraph import hookimpl

__all__ = ["IMAGE_WIDTH", "ReportSummary", "write_report"]


def __getattr__(name: str) -> Any:
    """:func:`write_report`, :class:`ReportSummary` and :data:`IMAGE_WIDTH`, imported when first
    asked for (``from lanegraph_report import write_report``)."""
    if name in __all__:
        from . import _build

        return getattr(_build, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@hookimpl
def lanegraph_write_report(
    run_dir, out_dir, dataset, gt, input_path, frames, sets, debug_dir, graph, pm, progress
):
    """The report of ``run_dir`` (:func:`write_report`), for ``Session.report``."""
    from ._build import write_report

    return write_report(
        run_dir, out_dir, gt=gt, dataset=dataset, input_path=input_path, frames=frames, sets=sets,
        debug_dir=debug_dir, graph=graph, pm=pm, progress=progress,
    )  # fmt: skip
