"""Telling a user's interruption from a plugin that raises ``KeyboardInterrupt`` itself.

A command that runs plugin code installs :func:`handling` for the signals that stop it: Ctrl-C
(SIGINT), SIGTERM and SIGHUP. A signal then raises :class:`Interrupted` (a ``KeyboardInterrupt``
naming its signal) wherever the main thread is, so that every path that handles Ctrl-C handles the
others alike. Code that runs plugin code guarded (:func:`lanegraph.plugins.call_hook`, the plugin
loader, a node call) asks :func:`is_interruption` of what it caught: a signal's
:class:`Interrupted` stops the command; any other ``KeyboardInterrupt`` (or ``SystemExit``) came
from the plugin, and is that plugin's failure. Without :func:`handling` installed (lanegraph used
as a library) every ``KeyboardInterrupt`` counts as the user's.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

#: the exit code of a command stopped by each signal (128 + its number)
EXIT_CODES = {"SIGINT": 130, "SIGTERM": 143, "SIGHUP": 129}
_NAMES = {"SIGINT": "Ctrl-C", "SIGTERM": "SIGTERM", "SIGHUP": "SIGHUP"}

_depth = 0  # how many handling() blocks are open (nested ones leave the handlers alone)
_signalled: str | None = None  # the signal that stopped the command (while handling() is open)


class Interrupted(KeyboardInterrupt):
    """The command was stopped by a signal (``name``: ``SIGINT``, ``SIGTERM``, ``SIGHUP``)."""

    def __init__(self, name: str = "SIGINT"):
        self.name = name
        super().__init__(f"interrupted ({_NAMES.get(name, name)})")

    @property
    def exit_code(self) -> int:
        return EXIT_CODES.get(self.name, 130)

    @property
    def label(self) -> str:
        """How messages name it: ``Ctrl-C``, ``SIGTERM``, ``SIGHUP``."""
        return _NAMES.get(self.name, self.name)


def _raise(signum: int, frame: object) -> None:
    global _signalled
    _signalled = signal.Signals(signum).name
    raise Interrupted(_signalled)


def signalled() -> str | None:
    """The signal that is stopping the command (``SIGTERM``...), or None: work that would make it
    wait (a node computed ahead on a thread) is then abandoned, not waited for."""
    return _signalled


def label_and_code(exc: BaseException) -> tuple[str, int]:
    """How a message names an interruption and the exit code it gives: ``("SIGTERM", 143)``; a
    plain ``KeyboardInterrupt`` is Ctrl-C (130)."""
    if isinstance(exc, Interrupted):
        return exc.label, exc.exit_code
    return "Ctrl-C", 130


def active() -> bool:
    """Whether :func:`handling` is installed (then a plain ``KeyboardInterrupt`` is a plugin's)."""
    return _depth > 0


def is_interruption(exc: BaseException) -> bool:
    """Whether ``exc``, caught around plugin code, is the user's interruption (a signal) rather
    than the plugin's own ``KeyboardInterrupt``/``SystemExit``/other ``BaseException``."""
    if isinstance(exc, Interrupted):
        return True
    return isinstance(exc, KeyboardInterrupt) and not active()


@contextlib.contextmanager
def handling(names: tuple[str, ...] = ("SIGINT", "SIGTERM", "SIGHUP")) -> Iterator[None]:
    """Within the block, the signals ``names`` raise :class:`Interrupted` in the main thread; the
    handlers before it are put back after it. Outside the main thread, or nested, it changes
    nothing."""
    global _depth, _signalled
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {}
    if _depth == 0:
        _signalled = None
        for name in names:
            sig = getattr(signal, name, None)
            if sig is None:  # pragma: no cover - not a POSIX system
                continue
            if signal.getsignal(sig) == signal.SIG_IGN:  # nohup: the user asked for it to be ignored
                continue
            try:
                saved[sig] = signal.signal(sig, _raise)
            except (ValueError, OSError):  # pragma: no cover - not allowed here
                continue
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        for sig, old in saved.items():
            signal.signal(sig, old)
