"""The Dask runner: ``--scheduler`` texts understood (:func:`parse_scheduler`) and the runner that
starts or reaches the cluster, runs the tasks there and lets it go (:class:`DaskRunner`). Dask
itself is imported by :mod:`lanegraph_dask.cluster`, when a cluster is started or reached."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from lanegraph.api import BaseRunner
from lanegraph.errors import UsageError

_SCHEDULER = re.compile(r"^local(?::(?P<n>[^:]*))?$")


@dataclass(frozen=True)
class SchedulerSpec:
    """Where a batch runs: ``local`` (``workers`` processes on this machine, ``None``: one per core)
    or ``address`` (an existing Dask scheduler)."""

    text: str
    workers: int | None = None
    address: str | None = None

    @property
    def local(self) -> bool:
        return self.address is None


def parse_scheduler(text: str | None) -> SchedulerSpec | None:
    """``--scheduler``: absent -> ``None`` (in this process); ``local`` or ``local:N``; anything else
    is a scheduler address for ``distributed.Client`` (``tcp://HOST:PORT``, ``tls://...``, a
    scheduler file ``*.json``). Raises :class:`~lanegraph.errors.UsageError` saying what was
    expected."""
    if text is None:
        return None
    text = text.strip()
    if not text:
        raise UsageError(
            "--scheduler: expected local, local:N or a scheduler address such as tcp://HOST:8786, got ''"
        )
    m = _SCHEDULER.match(text)
    if m:
        n = m.group("n")
        if n is None:
            return SchedulerSpec(text)
        if not n.isdigit() or int(n) < 1:
            raise UsageError(
                f"--scheduler {text}: expected local:N with N a number of worker processes >= 1, got {n!r}"
            )
        return SchedulerSpec(text, workers=int(n))
    return SchedulerSpec(text, address=text)


class DaskRunner(BaseRunner):
    """The tasks on a Dask cluster: ``local``, ``local:N`` or an existing scheduler's address."""

    name = "dask"
    fallback = True  # takes the texts no other runner claims (an address has no fixed form)

    def __init__(self, spec: SchedulerSpec):
        self.spec = spec
        self._cluster: Any = None

    @classmethod
    def from_spec(cls, text: str) -> DaskRunner | None:
        spec = parse_scheduler(text)
        if spec is None:
            return None
        from .cluster import check_spec

        check_spec(spec)  # local:N beyond the CPUs, an unknown scheme: refused before anything runs
        return cls(spec)

    def init(self, echo):  # noqa: D102 - BaseRunner.init
        from .cluster import connect

        self._cluster = connect(self.spec, echo)

    def execute(self, tasks, bar, outcomes):  # noqa: D102 - BaseRunner.execute
        from .cluster import submit_all

        submit_all(self._cluster.client, tasks, bar, outcomes)

    def finalize(self):  # noqa: D102 - BaseRunner.finalize
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None
