"""Executing one task: the executor and the pieces around it (result cache, prefetch, warm-up, the
next frame's ``ahead`` nodes), choosing the source, and :mod:`lanegraph.run.task`, the one place an
executor and a run's record are built. What a run keeps is :mod:`lanegraph.records`; many tasks at
once, and the runners, are :mod:`lanegraph.batches`."""
