"""lanegraph_tune: ``lanegraph tune``, searching a graph's params with Optuna; the ``tune`` extra.
(Being moved here from ``lanegraph.evaluation.tune*`` and ``lanegraph.service.tuning``.)"""
