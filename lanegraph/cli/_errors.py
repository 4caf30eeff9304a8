"""The one place where errors become exit codes.

Every command is wrapped by :func:`handled`: the run service and the loaders raise typed errors
(:class:`~lanegraph.errors.LanegraphError` and its kinds, each with its ``exit_code``: 2 for a graph,
usage or an input unusable before anything ran, 1 for a failure while running, 130 for Ctrl-C,
143 for SIGTERM, 129 for SIGHUP),
and the command prints ``error: ...`` on stderr and exits with that code -- never a traceback. A
command returns its status (0, 1 when frames or runs failed) and exits with it.

Exit codes: 0 ok, 1 failure while running (or frames that failed), 2 invalid graph or usage, or an
input that is unusable before any frame runs (no images, no calibration, an empty frame selection).
"""

from __future__ import annotations

import errno
import functools
import os
import sys
from collections.abc import Callable
from typing import Any

import click

from .. import interrupts
from ..errors import GraphError, InputError, LanegraphError, UsageError


def exit_code(exc: LanegraphError, input_exit: int | None = None, every_exit: int | None = None) -> int:
    """The exit code of ``exc``: its own, unless the command says otherwise for its inputs
    (``input_exit``: for an :class:`InputError`) or for every error (``every_exit``)."""
    if every_exit is not None:
        return every_exit
    if input_exit is not None and isinstance(exc, (InputError, UsageError, GraphError)):
        return input_exit
    return exc.exit_code


def os_error(exc: OSError) -> str:
    """One line for an :class:`OSError`: the file it names (shortened when it is absurdly long)
    and the system's reason."""
    name = exc.filename if exc.filename is not None else None
    where = "cannot write the output: " if name is None else ""
    if name is not None:
        text = os.fsdecode(name) if isinstance(name, bytes) else str(name)
        where = (text if len(text) <= 200 else f"{text[:100]}...{text[-60:]} ({len(text)} characters)") + ": "
    return f"{where}{exc.strerror or exc}"


def _quiet_stdout(exc: OSError) -> None:
    """After a failed write to stdout (``> /dev/full``), point it at ``/dev/null`` so that the
    interpreter's last flush does not fail a second time with a traceback."""
    if exc.errno not in (errno.ENOSPC, errno.EPIPE, errno.EIO, errno.EDQUOT):
        return
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError, AttributeError):
        pass


def os_error_exit(exc: OSError, code: int = 2) -> None:
    """Say ``exc`` in one line on stderr and exit with ``code`` (2: a path, a folder or an output
    the system refuses, found before any frame: a run's own failures are said by the run)."""
    _quiet_stdout(exc)
    click.echo(f"error: {os_error(exc)}", err=True)
    sys.exit(code)


def handled(
    *, input_exit: int | None = None, every_exit: int | None = None
) -> Callable[[Callable], Callable]:
    """Wrap a command: its :class:`LanegraphError` printed as one line and turned into its exit
    code (:func:`exit_code`); an int it returns is its exit status."""

    def wrap(command: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(command)
        def run(*args: Any, **kwargs: Any) -> None:
            try:
                # Ctrl-C, SIGTERM and SIGHUP raise lanegraph.interrupts.Interrupted while it runs
                with interrupts.handling():
                    status = command(*args, **kwargs)
            except LanegraphError as exc:
                click.echo(f"error: {exc}", err=True)
                sys.exit(exit_code(exc, input_exit, every_exit))
            except KeyboardInterrupt as exc:  # stopped outside a run (which says more itself)
                label, code = interrupts.label_and_code(exc)
                click.echo(f"error: interrupted ({label})", err=True)
                sys.exit(code)
            except OSError as exc:  # a path or an output the system refuses, before any frame: 2
                os_error_exit(exc, every_exit if every_exit is not None else 2)
            if status is not None:
                sys.exit(status)

        return run

    return wrap
