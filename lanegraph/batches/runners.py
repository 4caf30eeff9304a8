"""Runners: where the tasks of a run or a batch (:class:`~lanegraph.run.task.RunTask`) are executed.

A runner only schedules tasks: it runs each with ``task.execute()``
(:func:`lanegraph.run.task.execute_task`), wherever that is, so the outputs are the same byte for
byte on every runner. Its single entry point is ``run(tasks, progress=..., echo=..., done=...)``
(Kedro's ``AbstractRunner.run``), returning the :class:`~lanegraph.run.task.TaskOutcome` of every
task (:class:`Runner`); :class:`BaseRunner` gives it the life cycle of Hamilton's
``TaskExecutor``: ``init`` (start or reach what runs the tasks), ``execute`` (the tasks),
``finalize`` (let it go, however the run ended). Every run goes through a runner: ``lanegraph
run`` on one input too.

Runners are an open set: a plugin adds one through the ``lanegraph_runners`` hook, returning
runner *types* -- classes with a ``name`` and a ``from_spec(text)`` class method that returns a
runner for a ``--scheduler`` text it understands (``None`` otherwise); a type with ``fallback =
True`` is asked last (it takes the texts no other runner claims). lanegraph's own,
:class:`InProcessRunner` (``inprocess``; no ``--scheduler``: the tasks one after another in this
process), is registered through the same hook by :data:`BUILTIN_RUNNERS`; the Dask runner
(``local``, ``local:N``, a scheduler address) is a plugin of the ``lanegraph.plugins`` entry-point
group, registered like a third party's.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from ..errors import UsageError
from ..hookspecs import hookimpl
from ..plugins import call_hook
from ..run.task import RunTask, TaskOutcome
from .batch import Progress


@runtime_checkable
class Runner(Protocol):
    """What the run service asks of a runner."""

    name: str

    def run(
        self,
        tasks: list[RunTask],
        progress: bool = True,
        echo: Callable[[str], None] | None = None,
        done: dict[int, TaskOutcome] | None = None,
    ) -> dict[int, TaskOutcome]:
        """Run ``tasks``; the outcome of every task, by its index. ``done``: filled as the tasks
        end (what finished when the batch is interrupted). A task's failure is in its outcome,
        never raised."""
        ...


class BaseRunner:
    """A runner's life cycle around its one entry point, :meth:`run`: :meth:`init`, then
    :meth:`execute` with one progress bar over the tasks, then :meth:`finalize` however it ended."""

    name = "base"

    def init(self, echo: Callable[[str], None]) -> None:
        """Start or reach what runs the tasks (a cluster); before the first task."""

    def execute(self, tasks: list[RunTask], bar: Progress, outcomes: dict[int, TaskOutcome]) -> None:
        """Run ``tasks``, putting each outcome into ``outcomes`` as it ends."""
        raise NotImplementedError

    def finalize(self) -> None:
        """Let go of what :meth:`init` started; after the last task, however the tasks ended."""

    def run(self, tasks, progress=True, echo=None, done=None):  # noqa: D102 - Runner.run
        outcomes = done if done is not None else {}
        if not tasks:
            return outcomes
        self.init(echo or (lambda msg: print(msg, file=sys.stderr)))
        try:
            bar = Progress(tasks, progress, tasks[0].label if len(tasks) == 1 else "frames")
            try:
                self.execute(tasks, bar, outcomes)
            finally:
                bar.close()
        finally:
            self.finalize()
        return outcomes


class InProcessRunner(BaseRunner):
    """The tasks one after another in this process (``cache``: the result cache they share)."""

    name = "inprocess"

    def __init__(self, cache: Any = None):
        self.cache = cache

    @classmethod
    def from_spec(cls, text: str) -> InProcessRunner | None:
        return cls() if text.strip() == cls.name else None

    def execute(self, tasks, bar, outcomes):  # noqa: D102 - BaseRunner.execute
        for task in tasks:
            bar.bar.set_description_str(task.label, refresh=False)
            out = task.execute(cache=self.cache, progress=lambda n, i=task.index: bar.update(i, "", n))
            bar.finish(task.index, out.result.frames)
            outcomes[task.index] = out


class _BuiltinRunners:
    """lanegraph's own runner, registered through the public hook like a third party's."""

    @hookimpl
    def lanegraph_runners(self) -> list[type]:
        return [InProcessRunner]


BUILTIN_RUNNERS = _BuiltinRunners()


def runner_types(pm: Any) -> list[type]:
    """Every registered runner type; the fallback ones (Dask's) last. lanegraph's own (in process) is
    registered on ``pm`` on first use (a plugin manager made by hand has it too; the others come with
    the plugins it loads)."""
    if not pm.is_registered(BUILTIN_RUNNERS):
        pm.register(BUILTIN_RUNNERS, name="lanegraph.runners")
    found: list[type] = []
    for provided in call_hook(pm, "lanegraph_runners"):  # guarded: a raising plugin is named
        for rt in provided or []:
            if rt not in found:
                found.append(rt)
    return sorted(found, key=lambda rt: bool(getattr(rt, "fallback", False)))


def select_runner(text: str | None, pm: Any, cache: Any = None) -> Runner:
    """The runner of ``--scheduler text``: in this process without one (sharing ``cache``), else
    the first registered runner type whose ``from_spec`` accepts the text."""
    if text is None:
        return InProcessRunner(cache)
    for rt in runner_types(pm):
        runner = rt.from_spec(text)
        if runner is not None:
            if isinstance(runner, InProcessRunner):
                runner.cache = cache
            return runner
    names = ", ".join(rt.name for rt in runner_types(pm))
    raise UsageError(f"--scheduler {text}: no runner takes it (runners: {names})")
