"""One exception hierarchy for everything lanegraph reports to a user.

Every error says *where* (file, node id, field or port, frame) and *what* was
expected versus found. :class:`GraphError` carries all problems of one graph
file at once so a user can fix them in one go.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from dataclasses import dataclass, field


def did_you_mean(
    word: object, choices: Iterable[object], *, listing: str | None = None, cutoff: float = 0.6
) -> str | None:
    """The hint for a name that is not one of ``choices``: ``did you mean 'X'?`` for the closest
    one (``difflib``, similarity at least ``cutoff``); otherwise ``LISTING: a, b, c`` (``(none)``
    when there are no choices) when a ``listing`` label is given, else None."""
    names = [str(c) for c in choices]
    close = difflib.get_close_matches(str(word), names, n=1, cutoff=cutoff)
    if close:
        return f"did you mean '{close[0]}'?"
    if listing is not None:
        return f"{listing}: {', '.join(names) or '(none)'}"
    return None


class LanegraphError(Exception):
    """Base class of every error lanegraph raises on purpose."""

    exit_code = 1


@dataclass(frozen=True)
class Problem:
    """One located problem in a graph file.

    Rendered as ``FILE: node 'ID' (TYPE): FIELD: MESSAGE [hint: HINT]``.
    """

    message: str
    file: str | None = None
    node: str | None = None
    node_type: str | None = None
    field: str | None = None
    hint: str | None = None

    def __str__(self) -> str:
        parts = []
        if self.file:
            parts.append(self.file)
        if self.node:
            where = f"node '{self.node}'"
            if self.node_type:
                where += f" ({self.node_type})"
            parts.append(where)
        if self.field:
            parts.append(self.field)
        text = ": ".join([*parts, self.message])
        if self.hint:
            text += f" (hint: {self.hint})"
        return text


@dataclass
class GraphError(LanegraphError):
    """A graph file (or ``--set`` override) is invalid; lists every problem found."""

    problems: list[Problem] = field(default_factory=list)
    exit_code = 2

    def __post_init__(self) -> None:
        super().__init__(str(self))

    def __str__(self) -> str:
        if len(self.problems) == 1:
            return str(self.problems[0])
        lines = [f"{len(self.problems)} problems:"]
        lines += [f"  - {p}" for p in self.problems]
        return "\n".join(lines)


class UsageError(LanegraphError):
    """Bad command-line usage (exit code 2)."""

    exit_code = 2


class InputError(LanegraphError):
    """Bad input data: a missing, truncated or inconsistent file.

    ``path`` and ``frame`` locate it.
    """

    def __init__(self, message: str, *, path: str | None = None, frame: str | None = None):
        self.path = path
        self.frame = frame
        where = []
        if path:
            where.append(str(path))
        if frame is not None:
            where.append(f"frame {frame}")
        super().__init__(": ".join([*where, message]))


class NodeError(LanegraphError):
    """A node raised while processing a frame."""

    def __init__(self, node_id: str, node_type: str, frame: str | None, cause: BaseException):
        self.node_id = node_id
        self.node_type = node_type
        self.frame = frame
        self.cause = cause
        super().__init__(
            f"node '{node_id}' ({node_type}) failed on frame {frame}: {type(cause).__name__}: {cause}"
        )


class HookError(LanegraphError):
    """A plugin's hook implementation raised (any ``BaseException`` but the user's interruption:
    ``SystemExit`` and ``KeyboardInterrupt`` included) or returned what its hook does not allow.

    ``plugin``, ``hook``: whose and which; ``cause``: what it raised, or None for a wrong return
    value. Exit code 1: a failure while running, as a node's."""

    def __init__(self, plugin: str, hook: str, message: str, cause: BaseException | None = None):
        self.plugin = plugin
        self.hook = hook
        self.cause = cause
        super().__init__(f"plugin {plugin!r}: hook {hook}: {message}")


class NotStarted(LanegraphError):
    """A run that could not start: its input, checkpoint or output folder is unusable before any
    frame ran (exit 2, like a bad ``--input``). Says what ``cause`` says."""

    exit_code = 2

    def __init__(self, cause: BaseException):
        super().__init__(str(cause))
        self.cause = cause


class RunStopped(LanegraphError):
    """A run that started and stopped (``cause``: why); its record says how far it got. Exit 1, or
    130 when interrupted (Ctrl-C)."""

    def __init__(self, message: str, cause: BaseException | None = None, exit_code: int = 1):
        super().__init__(message)
        self.cause = cause
        self.exit_code = exit_code
