"""Frame selections: one parser and one rule for ``--frames`` and every source's ``frames`` param.

A selection is ``A:B``, ``A:B:S`` (Python slice semantics over the input's frame list) or a single
index ``A`` (``-1`` is the last frame). A selection that selects no frame of a non-empty input is an
input error found before any frame runs (exit code 2), with the input's frame count in the message.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

from .errors import InputError

T = TypeVar("T")


def parse_frames(text: str | None) -> slice | None:
    """``"A:B"``, ``"A:B:S"`` or ``"A"`` -> a slice over the frame list (``None`` for empty text).

    Raises ``ValueError`` with the reason for anything else (more than three parts, a part that is
    not an integer, a step of 0).
    """
    if text is None or not str(text).strip():
        return None
    text = str(text).strip()
    try:
        parts = [int(x) if x.strip() else None for x in text.split(":")]
    except ValueError:
        raise ValueError(f"expected A:B, A:B:S or A with integers, got {text!r}") from None
    if len(parts) > 3:
        raise ValueError(f"expected A:B or A:B:S, got {text!r}")
    if len(parts) == 1:
        a = parts[0]
        if a is None:
            return None
        return slice(a, a + 1 if a != -1 else None)  # -1: the last frame (a stop of 0 would select none)
    if len(parts) == 3 and parts[2] == 0:
        raise ValueError(f"the step S of A:B:S must not be 0, got {text!r}")
    return slice(*parts)


def selection_text(s: slice | None) -> str:
    """The ``A:B[:S]`` text of a selection (``""`` for none)."""
    if s is None:
        return ""
    text = f"{'' if s.start is None else s.start}:{'' if s.stop is None else s.stop}"
    return text + (f":{s.step}" if s.step not in (None, 1) else "")


def select_frames(
    items: Sequence[T], selections: Sequence[tuple[str, slice | None]], where: str | None = None
) -> list[T]:
    """``items`` cut by each ``(description, selection)`` in turn.

    ``description`` names where a selection came from (``"--frames 5:9"``, ``"the source's frames
    param '2:'"``). A selection that leaves no frame of a non-empty input raises an
    :class:`~lanegraph.errors.InputError` located at ``where`` (the input folder), naming the
    selections and the input's frame indices.
    """
    out = list(items)
    n = len(out)
    used = []
    for what, sel in selections:
        if sel is None:
            continue
        used.append(what)
        out = out[sel]
    if n and not out:
        raise InputError(
            f"{' and '.join(used) or 'the frame selection'} select(s) no frame: the input has {n} frame(s), indices 0..{n - 1}",
            path=where,
        )
    return out
