"""Reading a source ahead: the prefetch piece of the executor (:class:`Prefetch`).

:func:`timed` times each item a source yields and hands its errors on as items (a source may yield
or raise an :class:`~lanegraph.errors.InputError` for one frame and go on); :func:`prefetched` does
the same on a background thread that stays ``depth`` items ahead, so that decoding the next images
overlaps computing this frame (image decoding releases the GIL).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from ..errors import LanegraphError


def timed(it: Iterator[Any]) -> Iterator[tuple[str, Any, float]]:
    """(kind, item, ms) for each item of ``it``; an error ends nothing but that item."""
    while True:
        t0 = time.perf_counter()
        try:
            item = next(it)
        except StopIteration:
            return
        except Exception as exc:  # noqa: BLE001 - handed to the caller with its frame
            yield "error", exc, 0.0
            if not isinstance(exc, LanegraphError):
                return
            continue
        if isinstance(item, BaseException):  # a source may yield the error of one frame and go on
            yield "error", item, 0.0
            continue
        yield "item", item, (time.perf_counter() - t0) * 1000.0


def prefetched(it: Iterator[Any], depth: int) -> Iterator[tuple[str, Any, float]]:
    """:func:`timed` run by a background thread, ``depth`` items ahead."""
    import queue
    import threading

    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    done = object()

    def work() -> None:
        try:
            for entry in timed(it):
                while not stop.is_set():
                    try:
                        q.put(entry, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
        finally:
            while not stop.is_set():
                try:
                    q.put(done, timeout=0.1)
                    break
                except queue.Full:
                    continue

    th = threading.Thread(target=work, name="lanegraph-prefetch", daemon=True)
    th.start()
    try:
        while True:
            entry = q.get()
            if entry is done:
                return
            yield entry
    finally:
        stop.set()
        th.join(timeout=5)


@dataclass(frozen=True)
class Prefetch:
    """The prefetch piece of a run: the source read ``depth`` frames ahead on a background thread
    (:func:`prefetched`), or in the executor's own thread with ``depth`` 0 (:func:`timed`)."""

    depth: int = 1

    def __post_init__(self) -> None:
        if isinstance(self.depth, bool) or not isinstance(self.depth, int) or self.depth < 0:
            raise ValueError(f"Prefetch: depth: expected an integer >= 0, got {self.depth!r}")

    def read(self, it: Iterator[Any]) -> Iterator[tuple[str, Any, float]]:
        """``(kind, item, ms)`` for each item of the source iterator ``it``; close it to stop the
        read-ahead thread (it is joined)."""
        return prefetched(it, self.depth) if self.depth > 0 else timed(it)
