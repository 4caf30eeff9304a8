"""Logging through Python's :mod:`logging`: the console's level (``-v`` / ``-q``) and a run's own log
file, ``OUT/run.log``.

Everything lanegraph says while it works goes to the ``lanegraph`` logger (and its children,
``lanegraph.run``, ``lanegraph.tracking`` ...); Python warnings go to ``py.warnings`` while the
command line is set up (:func:`configure_console`). Two kinds of handler read them:

- the console (stderr): ``warning: ...`` and ``error: ...`` lines, notes at the default level and
  with ``-q`` (which only turns the progress bars off), the details with ``-v``; ``-qq`` keeps
  warnings and errors only, ``-qqq`` errors only (:func:`console_level`). Lines are written through
  :func:`tqdm.tqdm.write`, so a progress bar is not torn.
- :class:`RunLog`, attached for the duration of a run: ``OUT/run.log`` gets every record at INFO
  and above (DEBUG with ``-v``), time-stamped: what the run did, every warning, and every error a
  node raised on a frame (through the ``lanegraph_after_node`` hook, whatever the node's
  ``on_error`` then does with it). A resumed run appends to it.

A library user who does not call :func:`configure_console` gets Python's defaults: lanegraph adds
no handler of its own to the console.
"""

from __future__ import annotations

import io
import logging
import os
import re
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .hookspecs import hookimpl
from .paths import create_new

LOGGER = "lanegraph"
LOG_NAME = "run.log"
#: the loggers the console and a run's log read: lanegraph's own, and Python warnings
_SOURCES = (LOGGER, "py.warnings")


#: control characters (but tab and newline), C1 controls, and the lone surrogates a file name with
#: bytes that are not UTF-8 becomes: never written raw to a terminal or to run.log
_CONTROLS = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f\ud800-\udfff]")
_DIGITS = re.compile(r"\d+")


def _escape_one(m: re.Match[str]) -> str:
    c = ord(m.group())
    if 0xDC80 <= c <= 0xDCFF:  # a byte of a file name that is not UTF-8 (surrogateescape)
        return f"\\x{c - 0xDC00:02x}"
    return f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"


def escape_controls(text: str) -> str:
    """``text`` with its control characters (escape sequences, carriage returns, NUL...) and the
    bytes of a non-UTF-8 file name written as ``\\xNN``: what reaches a terminal or ``run.log``
    is text, one record a line, never a sequence the terminal runs."""
    return _CONTROLS.sub(_escape_one, text)


class Repeats:
    """Bounds what a handler writes: a warning said again (the same words, numbers aside) is shown
    ``first`` times, then counted; at most ``total`` warnings are shown in all. Errors always are.
    :meth:`summary` says what was counted and not shown."""

    def __init__(self, first: int, total: int):
        self.first, self.total = first, total
        self.counts: dict[tuple[str, str], int] = {}
        self.shown = 0
        self.hidden = 0

    def admit(self, record: logging.LogRecord, text: str) -> bool:
        if record.levelno != logging.WARNING:
            return True
        key = (record.name, _DIGITS.sub("#", text[:300]))
        n = self.counts[key] = self.counts.get(key, 0) + 1
        if (n <= self.first or getattr(record, "plain", False)) and self.shown < self.total:
            self.shown += 1
            return True
        self.hidden += 1
        return False

    def summary(self) -> str | None:
        if not self.hidden:
            return None
        return (
            f"{self.hidden} more warning(s) not shown: a warning said again is shown {self.first} times, "
            f"and at most {self.total} in all"
        )


def get_logger(name: str = "") -> logging.Logger:
    """The ``lanegraph`` logger, or its child ``lanegraph.<name>``."""
    return logging.getLogger(f"{LOGGER}.{name}" if name else LOGGER)


def console_level(verbose: int = 0, quiet: int = 0) -> int:
    """The console's level for ``-v`` given ``verbose`` times and ``-q`` given ``quiet`` times:
    INFO by default and with ``-q`` (which only turns the progress bars off: a long wait still says
    what it is doing), DEBUG with ``-v``, WARNING with ``-qq``, ERROR with ``-qqq``."""
    if verbose > 0:
        return logging.DEBUG
    return {0: logging.INFO, 1: logging.INFO, 2: logging.WARNING}.get(quiet, logging.ERROR)


class _ConsoleFormatter(logging.Formatter):
    """``warning: message`` / ``error: message``; a note as it is; a detail as ``debug: ...``."""

    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        if getattr(record, "plain", False):  # a line of a listing (failed frames): as it is
            return text
        if record.name == "py.warnings":  # "file:line: Category: message\n  source line"
            text = text.strip().splitlines()[0]
        if record.exc_info and record.levelno >= logging.ERROR:
            text += f" ({type(record.exc_info[1]).__name__}: {record.exc_info[1]})"
        if record.levelno >= logging.ERROR:
            return f"error: {text}"
        if record.levelno >= logging.WARNING:
            return f"warning: {text}"
        if record.levelno < logging.INFO:
            return f"debug: {text}"
        return text


#: the console: a warning said again is shown this many times, and at most this many in all
CONSOLE_REPEATS, CONSOLE_WARNINGS = 3, 200
#: run.log: the same, more generous (every failed frame of a long run is there)
LOG_REPEATS, LOG_WARNINGS = 1000, 50_000


class _ConsoleHandler(logging.Handler):
    """To the current ``sys.stderr`` at every record (a test runner may swap it), through tqdm;
    control characters escaped, repeated warnings counted (:class:`Repeats`)."""

    def __init__(self, level: int = logging.NOTSET):
        super().__init__(level)
        self.repeats = Repeats(CONSOLE_REPEATS, CONSOLE_WARNINGS)

    def emit(self, record: logging.LogRecord) -> None:
        if getattr(record, "file_only", False):  # for run.log (what a run was), not the terminal
            return
        try:
            from tqdm import tqdm

            text = escape_controls(self.format(record))
            if not self.repeats.admit(record, text):
                return
            tqdm.write(text, file=sys.stderr)
            sys.stderr.flush()  # in order with what the command prints on stdout
        except Exception:  # noqa: BLE001 - logging must never stop the run
            self.handleError(record)


def _set_level(logger: logging.Logger) -> None:
    """The logger's level: the lowest of its handlers' (records no handler wants are not made)."""
    levels = [h.level for h in logger.handlers if isinstance(h, (_ConsoleHandler, _FileHandler))]
    logger.setLevel(min(levels) if levels else logging.NOTSET)


def configure_console(verbose: int = 0, quiet: int = 0) -> Callable[[], None]:
    """Send lanegraph's records (and Python warnings) to stderr at :func:`console_level`; returns
    the function that undoes it. Calling it again replaces the console handler."""
    level = console_level(verbose, quiet)
    handler = _ConsoleHandler(level)
    handler.setFormatter(_ConsoleFormatter())
    olds: list[tuple[logging.Logger, list[logging.Handler], bool]] = []
    for name in _SOURCES:
        logger = logging.getLogger(name)
        mine = [h for h in logger.handlers if isinstance(h, _ConsoleHandler)]
        for h in mine:
            logger.removeHandler(h)
        olds.append((logger, mine, logger.propagate))
        logger.addHandler(handler)
        logger.propagate = False  # printed once, by us, not again by a root handler
        _set_level(logger)
    logging.captureWarnings(True)

    def undo() -> None:
        said = handler.repeats.summary()
        if said is not None:
            handler.repeats = Repeats(0, 0)
            try:
                print(f"warning: {said}", file=sys.stderr, flush=True)
            except (OSError, ValueError):
                pass
        logging.captureWarnings(False)
        for logger, mine, propagate in olds:
            logger.removeHandler(handler)
            for h in mine:
                logger.addHandler(h)
            logger.propagate = propagate
            _set_level(logger)

    return undo


class _FileHandler(logging.StreamHandler):
    """A handler on a file opened by :class:`RunLog` (never through a link planted at its name);
    control characters escaped, repeated warnings counted (:class:`Repeats`)."""

    def __init__(self, stream: Any):
        super().__init__(stream)
        self.repeats = Repeats(LOG_REPEATS, LOG_WARNINGS)

    def format(self, record: logging.LogRecord) -> str:
        return escape_controls(super().format(record))

    def emit(self, record: logging.LogRecord) -> None:
        try:
            if not self.repeats.admit(record, record.getMessage()):
                return
        except Exception:  # noqa: BLE001 - logging must never stop the run
            pass
        super().emit(record)


class _NodeErrors:
    """A plugin that logs every error a node raises on a frame (``lanegraph_after_node``)."""

    def __init__(self) -> None:
        self.log = get_logger("run")

    @hookimpl
    def lanegraph_after_node(
        self, node_id: str, node_type: str, frame: str | None, error: BaseException | None
    ) -> None:
        if error is not None:
            where = f"frame {frame}: " if frame is not None else ""
            self.log.warning(
                "%snode '%s' (%s) raised %s: %s", where, node_id, node_type, type(error).__name__, error
            )


class RunLog:
    """``OUT/run.log`` for the duration of a run (a context manager).

    Parameters
    ----------
    folder
        The run's output folder; the log is ``folder/run.log``.
    append
        Continue the file (a resumed run); otherwise it is written anew.
    verbose
        Record DEBUG details too (``-v``).
    pm
        A plugin manager to register the node-error logger with (every error a node raises on a
        frame is then recorded, with the frame and the node).
    """

    def __init__(self, folder: Path, append: bool = False, verbose: bool = False, pm: Any = None) -> None:
        self.path = Path(folder) / LOG_NAME
        self.append = append
        self.level = logging.DEBUG if verbose else logging.INFO
        self.pm = pm
        self._handler: _FileHandler | None = None
        self._plugin: _NodeErrors | None = None

    def __enter__(self) -> RunLog:
        if self.append and self.path.is_file() and not self.path.is_symlink():
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | getattr(os, "O_NOFOLLOW", 0))
            fh: Any = os.fdopen(fd, "a", encoding="utf-8", buffering=1)
        else:  # anew: a file or a link at its name is replaced, never written through
            fh = io.TextIOWrapper(
                io.BufferedWriter(create_new(self.path)), encoding="utf-8", line_buffering=True
            )
        handler = _FileHandler(fh)
        handler.setLevel(self.level)
        formatter = logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s", "%Y-%m-%d %H:%M:%S")
        formatter.converter = time.gmtime
        handler.setFormatter(formatter)
        for name in _SOURCES:
            logger = logging.getLogger(name)
            logger.addHandler(handler)
            _set_level(logger)
        self._handler = handler
        if self.pm is not None:
            self._plugin = _NodeErrors()
            self.pm.register(self._plugin)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._plugin is not None and self.pm is not None:
            self.pm.unregister(self._plugin)
            self._plugin = None
        if self._handler is not None:
            said = self._handler.repeats.summary()
            if said is not None:
                self._handler.repeats = Repeats(0, 0)
                rec = logging.LogRecord(LOGGER, logging.WARNING, __file__, 0, said, None, None)
                logging.StreamHandler.emit(self._handler, rec)
            for name in _SOURCES:
                logger = logging.getLogger(name)
                logger.removeHandler(self._handler)
                _set_level(logger)
            self._handler.close()
            self._handler.stream.close()  # logging's close() leaves a stream it did not open
            self._handler = None


_FAILURE_LINE = re.compile(r"^\s+frame .*|.*\bframe\(s\) failed\b.*")


def say(message: str, logger: logging.Logger | None = None) -> None:
    """One line a command says on stderr, as a log record: ``error: ...`` and ``warning: ...`` at
    their levels (the prefix is the console's), the lines listing failed frames as warnings shown as
    they are, any other line a note (INFO: shown with ``-q``, hidden by ``-qq``). Everything reaches
    ``run.log``."""
    log = logger or get_logger("run")
    for prefix, level in (("error: ", logging.ERROR), ("warning: ", logging.WARNING)):
        if message.startswith(prefix):
            log.log(level, message[len(prefix) :])
            return
    if _FAILURE_LINE.match(message):
        log.warning(message, extra={"plain": True})
    else:
        log.info(message)


#: seconds between two progress lines when stderr is not a terminal
PIPED_INTERVAL_S = 10.0


class PipedProgress:
    """A progress bar's stand-in when stderr is not a terminal (a pipe, a log file, a batch
    system): a bar redrawn with carriage returns would pile up there as one endless line, and
    tqdm's own choice on a non-terminal is to print nothing at all, so a long run said nothing
    until it ended. This one prints a line when it starts (``desc: 0/N frames``) and then at most
    every ``interval`` seconds (``desc: k/N frames (p %), r frames/s[, postfix]``). It has the
    part of tqdm's interface lanegraph uses: ``n``, ``update``, ``refresh``, ``set_postfix_str``,
    ``set_description_str``, ``close``."""

    def __init__(
        self,
        total: int | None,
        desc: str,
        unit: str = "frame",
        interval: float = PIPED_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.total, self.desc, self.unit = total, desc, unit
        self.interval, self._clock = interval, clock
        self.n = 0
        self._postfix = ""
        self._start = self._last = clock()
        self._closed = False
        self._write(f"{desc}: 0{'/' + str(total) if total else ''} {unit}s")

    def _write(self, line: str) -> None:
        stream = sys.stderr
        stream.write(line + "\n")
        stream.flush()

    def update(self, k: int = 1) -> None:
        self.n += k
        self.refresh()

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self._postfix = s
        if refresh:
            self.refresh()

    def set_description_str(self, desc: str = "", refresh: bool = True) -> None:
        self.desc = desc
        if refresh:
            self.refresh()

    def refresh(self) -> None:
        now = self._clock()
        if self._closed or now - self._last < self.interval:
            return
        self._last = now
        done = f"{self.n}/{self.total}" if self.total else f"{self.n}"
        share = f" ({100.0 * self.n / self.total:.0f} %)" if self.total else ""
        rate = self.n / (now - self._start) if now > self._start else 0.0
        post = f", {self._postfix}" if self._postfix else ""
        self._write(f"{self.desc}: {done} {self.unit}s{share}, {rate:.1f} {self.unit}s/s{post}")

    def close(self) -> None:
        self._closed = True


def progress_bar(
    total: int | None, desc: str, enabled: bool = True, unit: str = "frame", leave: bool = True
) -> Any:
    """The progress display of a command: tqdm's bar on a terminal, :class:`PipedProgress`'s
    occasional lines when stderr is not one, nothing when ``enabled`` is false (``-q``)."""
    from tqdm import tqdm

    if enabled and not _is_terminal(sys.stderr):
        return PipedProgress(total, desc, unit=unit)
    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        disable=not enabled,
        file=sys.stderr,
        dynamic_ncols=True,
        leave=leave,
    )


def _is_terminal(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # a closed or stand-in stream
        return False
