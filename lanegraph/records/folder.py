"""One run per output folder: a folder holds the results of one run (or one ablation, one dataset
run), and a command refuses, before any frame and without touching it, a folder that holds another's.

What a folder holds is read from what lanegraph wrote there: the record (``run.json`` of a run,
``command.json`` of an ablation or a dataset run) with its ``identity`` (:func:`run_identity`,
:func:`command_identity`) and the list of what it ``wrote``, and ``checkpoint.json`` (an unfinished
run, killed before it could write its record); a link planted at one of these names is not a
record. :func:`check` (before anything is written) and :func:`claim` (under the folder's lock)
compare that with the command about to run:

- an empty folder, or one holding no record of lanegraph's: a new folder; the run goes on, its
  files beside the user's, or is refused when one of the names it writes is taken by a path that
  is not lanegraph's (:mod:`lanegraph.records.owned`: lanegraph replaces or removes only what its
  genuine ownership record lists, for the very file);
- the same run (same graph and params, input and frames), finished: it is run again into the folder;
- the same run, unfinished (interrupted, killed, stopped): refused unless ``--resume`` continues it;
- another run's results (another graph, params, input or frames; another ablation's variants):
  refused, saying what differs;

each refusal with the hint: ``--resume``, ``--overwrite`` or a new folder, exit 2. ``--overwrite``
removes what the ownership record lists (:func:`lanegraph.records.owned.clear`: all or nothing), nothing
else; then the run starts in a folder as good as new.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..errors import UsageError
from ..paths import OutputLock
from ..runlog import get_logger
from . import owned

log = get_logger("run")

RECORD = "run.json"
COMMAND_RECORD = "command.json"
CHECKPOINT = "checkpoint.json"
#: the files a run writes into its folder under fixed names (besides its sinks' files)
#: (lanes_gt.jsonl: the synthetic scene's exact ground truth, written by its source)
RUN_NAMES = ("run.json", "timings.json", "checkpoint.json", "graph.yaml", "run.log", "lanes_gt.jsonl")
#: the files an ablation or a dataset run writes into OUT under fixed names (besides its runs)
COMMAND_NAMES = ("command.json", "run.log")
#: an ablation's tables and plots
ABLATION_NAMES = ("results.csv", "results.md", "accuracy.png", "accuracy_vs_ms.png")
HINT = "continue it with --resume, replace it with --overwrite (removes only what lanegraph wrote there), or choose another output folder"
_HINT_OTHER = (
    "replace it with --overwrite (removes only what lanegraph wrote there) or choose another output folder"
)


def run_identity(graph_digest: str, input_path: str | None, frames: str | None) -> dict[str, Any]:
    """What makes a single run the run it is: the resolved graph's digest (every param, ``--set``
    included), the input's path (resolved) and the frame selection."""
    return {"kind": "run", "graph_digest": graph_digest, "input": input_path, "frames": frames or ""}


def command_identity(
    kind: str, variants: list[str], inputs: dict[str, str | None], frames: str | None
) -> dict[str, Any]:
    """What makes an ablation (``kind`` "ablation") or a dataset run ("dataset") the one it is: its
    variants by name, its sequences and their inputs, the frame selection. (A variant whose graph
    changed is run again in its place; another set of variants is another ablation.)"""
    return {"kind": kind, "variants": list(variants), "inputs": dict(inputs), "frames": frames or ""}


def _read_json(path: Path) -> dict[str, Any] | None:
    """A record lanegraph wrote: a plain file (a link planted at its name is not one) of JSON."""
    if path.is_symlink() or not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    return data if isinstance(data, dict) else None


def read_state(folder: Path) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """The folder's record (``run.json``, else ``command.json``) and its checkpoint, as dicts
    (None where absent or unreadable)."""
    folder = Path(folder)
    record = _read_json(folder / RECORD) or _read_json(folder / COMMAND_RECORD)
    return record, _read_json(folder / CHECKPOINT)


def difference(
    recorded: dict[str, Any],
    current: dict[str, Any],
    folder: Path | None = None,
    resolved: dict[str, Any] | None = None,
) -> str | None:
    """What differs between two identities, in words (the first param that differs when the folder
    holds the previous run's ``graph.yaml`` and ``resolved`` is given); None when they are the same."""
    if recorded.get("kind") != current.get("kind"):
        return f"it holds the results of {_kind(recorded)}, this is {_kind(current)}"
    if current.get("kind") == "run":
        if recorded.get("graph_digest") != current.get("graph_digest"):
            what = _first_param_difference(folder, resolved)
            return "another graph or params" + (f" ({what})" if what else "")
        if recorded.get("input") != current.get("input"):
            return f"another input: {recorded.get('input') or '(the synthetic scene)'} there, {current.get('input') or '(the synthetic scene)'} now"
        if (recorded.get("frames") or "") != (current.get("frames") or ""):
            return (
                f"other frames: {recorded.get('frames') or 'all'} there, {current.get('frames') or 'all'} now"
            )
        return None
    if list(recorded.get("variants") or []) != list(current.get("variants") or []):
        return f"other variants: {', '.join(recorded.get('variants') or []) or 'none'} there, {', '.join(current.get('variants') or [])} now"
    if dict(recorded.get("inputs") or {}) != dict(current.get("inputs") or {}):
        return (
            "other sequences or inputs: "
            + (", ".join(f"{k}={v}" for k, v in (recorded.get("inputs") or {}).items()) or "none")
            + " there"
        )
    if (recorded.get("frames") or "") != (current.get("frames") or ""):
        return f"other frames: {recorded.get('frames') or 'all'} there, {current.get('frames') or 'all'} now"
    return None


def _kind(ident: dict[str, Any]) -> str:
    return {"run": "a run", "ablation": "an ablation", "dataset": "a dataset run"}.get(
        str(ident.get("kind")), "a run"
    )


def _first_param_difference(folder: Path | None, resolved: dict[str, Any] | None) -> str | None:
    if folder is None or resolved is None:
        return None
    try:
        import yaml

        before = yaml.safe_load((Path(folder) / "graph.yaml").read_text(encoding="utf-8"))
    except Exception:  # noqa: BLE001 - no graph file there, or not one: the difference stays unnamed
        return None
    from .resume import _first_difference

    text = _first_difference(before, resolved) if isinstance(before, dict) else None
    return text.replace(" in the checkpoint,", " there,") if text else None


def _checkpoint_identity(ckpt: dict[str, Any]) -> dict[str, Any]:
    return run_identity(str(ckpt.get("graph_digest")), ckpt.get("input"), ckpt.get("frames"))


def check(
    folder: Path,
    identity: dict[str, Any],
    *,
    resume: bool = False,
    overwrite: bool = False,
    resolved: dict[str, Any] | None = None,
    option: str = "--out",
    locked: bool = False,
    writes: Mapping[str, str] | None = None,
) -> None:
    """Refuse (:class:`UsageError`, exit 2) a folder that may not take the run of ``identity`` (see
    the module's doc); reads only, writes nothing. With ``overwrite`` a folder of another run may.
    ``locked``: the caller holds the folder's lock (else a run writing there now is said first).
    ``writes``: the paths the command writes (:func:`lanegraph.records.owned.taken`); one of them there
    and not lanegraph's is refused, with or without ``overwrite``."""
    folder = Path(folder)
    if not locked:
        OutputLock(folder).probe()  # a run writing there now is said first, as the lock says it
        owned.note_absent(folder, writes or {})  # what is not there yet, the command makes
    if not folder.is_dir():
        return
    if resume and any((folder / n).exists() for n in (CHECKPOINT, "checkpoint.pkl")):
        return  # --resume checks its checkpoint against this run itself, naming what differs
    if not overwrite:
        _check_identity(folder, identity, resume, resolved, option)
    bad = owned.taken(folder, writes or {})
    if bad:
        more = (
            f" (and {len(bad) - 1} more: {', '.join(bad[1:4])}{', ...' if len(bad) > 4 else ''})"
            if len(bad) > 1
            else ""
        )
        raise UsageError(
            f"{option} {folder}: {bad[0]} is there and not lanegraph's{more}: no genuine record of lanegraph "
            "in the folder lists it, and lanegraph never replaces or removes what it did not write; "
            "move it away or choose another output folder"
        )


def _check_identity(
    folder: Path, identity: dict[str, Any], resume: bool, resolved: dict[str, Any] | None, option: str
) -> None:
    record, ckpt = read_state(folder)
    recorded = record.get("identity") if record is not None else None
    if not isinstance(recorded, dict) and ckpt is not None and identity.get("kind") == "run":
        recorded = _checkpoint_identity(ckpt)  # killed before its record, or an older record
    if not isinstance(recorded, dict):
        return  # no record (or an older lanegraph's): what it holds is not lanegraph's (taken)
    diff = difference(recorded, identity, folder, resolved)
    if diff is not None:
        raise UsageError(
            f"{option} {folder}: holds the results of another {_kind(recorded).split()[-1]}: {diff}; its files "
            f"would be mixed with this one's; {_HINT_OTHER}"
        )
    if identity.get("kind") == "run" and not resume:
        unfinished = _unfinished(record, ckpt)
        if unfinished is not None:
            raise UsageError(f"{option} {folder}: holds this run, unfinished ({unfinished}); {HINT}")


def claim(
    folder: Path,
    identity: dict[str, Any],
    *,
    overwrite: bool = False,
    writes: Mapping[str, str] | None = None,
    **options: Any,
) -> list[Path]:
    """:func:`check` (the caller holding the folder's lock; ``options``: its ``resume``, ``resolved``,
    ``option``), then with ``overwrite`` :func:`lanegraph.records.owned.clear`; notes what ``writes``
    hold before the command writes (:func:`lanegraph.records.owned.begin`, for :func:`seal`, what
    the command wrote: what a later ``--overwrite`` may remove). Returns what was removed."""
    check(folder, identity, overwrite=overwrite, locked=True, writes=writes, **options)
    removed = owned.clear(folder, "--overwrite") if overwrite else []
    owned.begin(folder, writes or {})
    return removed


def _unfinished(record: dict[str, Any] | None, ckpt: dict[str, Any] | None) -> str | None:
    """Why the run in the folder is unfinished (its frames done and where it stopped), or None."""
    if ckpt is not None and ckpt.get("complete") is False:
        done = f"{ckpt.get('position', 0)} of {ckpt.get('total') if ckpt.get('total') is not None else '?'} frame(s) done"
        stopped = (record or {}).get("stopped") or {}
        why = stopped.get("error") if isinstance(stopped, dict) else None
        return f"{done}; stopped: {why}" if why else f"{done}; it was killed or is still being written"
    if record is not None and record.get("status") == "stopped" and ckpt is None:
        return f"stopped: {(record.get('stopped') or {}).get('error') or record.get('error') or 'unknown'}"
    return None
