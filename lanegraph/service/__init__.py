"""The run service: the one path by which the commands run graphs (:class:`Session`); a batch of
runs from any command: :meth:`Session.run_tasks` with :class:`lanegraph.batches.batch.BatchRun`."""

from .session import Session

__all__ = ["Session"]
