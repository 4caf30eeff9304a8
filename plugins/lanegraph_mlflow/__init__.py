"""MLflow tracking for ``lanegraph run`` and ``lanegraph ablate`` (``--track mlflow[:URI]``).

A plugin like any third party's: it provides the tracker ``mlflow`` through the
``lanegraph_trackers`` hook and imports MLflow only when tracking is asked for
(``pip install "lanegraph[mlflow]"``). See docs/tracking.md.
"""

from __future__ import annotations

from lanegraph import hookimpl

from ._tracker import MlflowTracker

__all__ = ["MlflowTracker"]


@hookimpl
def lanegraph_trackers():
    return [MlflowTracker]
