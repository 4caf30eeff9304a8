"""lanegraph_dask: runs the tasks of a batch on a Dask cluster (``--scheduler local``, ``local:N`` or
a scheduler's address; ``pip install "lanegraph[distributed]"``).

A plugin of the ``lanegraph.plugins`` entry-point group like a third party's: it adds its runner,
:class:`lanegraph_dask.runner.DaskRunner`, through the ``lanegraph_runners`` hook, and imports
lanegraph only from ``lanegraph.api`` and the core's public modules. Loading it imports neither
Dask nor the engine: the hook imports the runner when a ``--scheduler`` is given, and the runner
imports Dask (:mod:`lanegraph_dask.cluster`) only when it starts or reaches a cluster.
"""

from __future__ import annotations

import lanegraph


@lanegraph.hookimpl
def lanegraph_runners() -> list[type]:
    from .runner import DaskRunner

    return [DaskRunner]
