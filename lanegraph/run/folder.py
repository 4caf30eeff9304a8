"""One run per output folder: a folder holds the results of one run (or one ablation, one dataset
run), and a command refuses, before any frame and without touching it, a folder that holds another's.

What a folder holds is read from what lanegraph wrote there: the record (``run.json`` of a run,
``command.json`` of an ablation or a dataset run) with its ``identity`` (:func:`run_identity`,
:func:`command_identity`) and the list of what it ``wrote``, and ``checkpoint.json`` (an unfinished
run, killed before it could write its record); a link planted at one of these names is not a
record. :func:`check` (before anything is written) and :func:`claim` (under the folder's lock)
compare that with the command about to run:

- an empty folder, or one holding no record of lanegraph's: the run goes on (files of the user's
  beside are left alone); a record of an older lanegraph, without an identity: replaced, with a
  warning;
- the same run (same graph and params, input and frames), finished: it is run again into the folder;
- the same run, unfinished (interrupted, killed, stopped): refused unless ``--resume`` continues it;
- another run's results (another graph, params, input or frames; another ablation's variants):
  refused, saying what differs;

each refusal with the hint: ``--resume``, ``--overwrite`` or a new folder, exit 2. ``--overwrite``
removes what lanegraph wrote there (:func:`written_paths`: its result files, run files, debug
pictures, report, ``runs/``), nothing else, then the run starts in a folder as good as new.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from ..errors import UsageError
from ..paths import OutputLock
from ..runlog import get_logger

log = get_logger("run")

RECORD = "run.json"
COMMAND_RECORD = "command.json"
CHECKPOINT = "checkpoint.json"
#: files and folders lanegraph writes into an output folder under fixed names (what a folder of an
#: older lanegraph, whose record lists nothing, is known to hold)
KNOWN_NAMES = (
    "run.json",
    "command.json",
    "timings.json",
    "checkpoint.json",
    "checkpoint.pkl",
    "run.log",
    "graph.yaml",
    "run_key.txt",
    "lanes_gt.jsonl",  # the synthetic scene's ground truth, written by its source
    "results.csv",
    "results.md",
    "accuracy.png",
    "accuracy_vs_ms.png",
    "runs",
)
#: the mark the report leaves in its assets folder (a report folder with it is lanegraph's)
REPORT_MARK = ".lanegraph-report"
LOCK = ".lanegraph.lock"
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


def holds_results(folder: Path) -> bool:
    """Whether ``folder`` holds any file lanegraph writes under a fixed name (or its report)."""
    folder = Path(folder)
    if not folder.is_dir():
        return False
    return (
        any((folder / n).exists() or (folder / n).is_symlink() for n in [*KNOWN_NAMES, *_result_names()])
        or (folder / "report" / "assets" / REPORT_MARK).is_file()
    )


def _result_names() -> list[str]:
    """The default files of the installed sinks' result kinds (``lanes.jsonl``: the lanes writer's)."""
    from .results import LANES, default_names

    try:
        return default_names(LANES)
    except Exception:  # noqa: BLE001 - no plugin manager to ask: the fixed names only
        return []


def _describe_identity(ident: dict[str, Any]) -> str:
    if ident.get("kind") == "run":
        return f"input {ident.get('input') or '(the synthetic scene)'}, frames {ident.get('frames') or 'all'}"
    return f"{len(ident.get('variants') or [])} variant(s) {', '.join(ident.get('variants') or [])} on {', '.join(ident.get('inputs') or {}) or '?'}, frames {ident.get('frames') or 'all'}"


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
) -> None:
    """Refuse (:class:`UsageError`, exit 2) a folder that may not take the run of ``identity`` (see
    the module's doc); reads only, writes nothing. With ``overwrite`` every folder may. ``locked``:
    the caller holds the folder's lock (else a run writing there now is said first)."""
    folder = Path(folder)
    if not locked:
        OutputLock(folder).probe()  # a run writing there now is said first, as the lock says it
    if overwrite or not folder.is_dir():
        return
    if resume and any((folder / n).exists() for n in (CHECKPOINT, "checkpoint.pkl")):
        return  # --resume checks its checkpoint against this run itself, naming what differs
    record, ckpt = read_state(folder)
    recorded = record.get("identity") if record is not None else None
    if not isinstance(recorded, dict) and ckpt is not None and identity.get("kind") == "run":
        recorded = _checkpoint_identity(ckpt)  # killed before its record, or an older record
    if not isinstance(recorded, dict):
        if record is not None:  # an older lanegraph's run: no identity to compare; replaced
            log.warning(
                "%s %s: holds a run of an older lanegraph (its %s records no identity): this run replaces its results",
                option, folder, RECORD if (folder / RECORD).is_file() else COMMAND_RECORD,
            )  # fmt: skip
        return
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
    resume: bool = False,
    overwrite: bool = False,
    resolved: dict[str, Any] | None = None,
    option: str = "--out",
) -> list[Path]:
    """:func:`check` (the caller holding the folder's lock), then with ``overwrite`` :func:`clear`:
    returns what was removed."""
    check(folder, identity, resume=resume, overwrite=overwrite, resolved=resolved, option=option, locked=True)
    return clear(folder) if overwrite and holds_results(folder) else []


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


def written_paths(folder: Path, record: dict[str, Any] | None) -> list[Path]:
    """What lanegraph wrote in ``folder``: what its record lists (``written``, ``results``,
    ``debug_dir``), the files of :data:`KNOWN_NAMES` and a report folder with lanegraph's mark.
    Only paths inside ``folder`` (no absolute path, no ``..``); links count as themselves."""
    folder = Path(folder)
    names: list[str] = [*KNOWN_NAMES, *_result_names()]
    if record is not None:
        for key in ("written",):
            names += [str(p) for p in record.get(key) or [] if isinstance(p, str)]
        names += [str(p) for p in (record.get("results") or {}).values() if isinstance(p, str)]
        if isinstance(record.get("debug_dir"), str):
            names.append(record["debug_dir"])
    if (folder / "report" / "assets" / REPORT_MARK).is_file() or (
        (folder / "report" / "index.html").is_file() and not (folder / "report" / "assets").exists()
    ):
        names.append("report")
    out: list[Path] = []
    for name in dict.fromkeys(names):
        parts = Path(name).parts
        if not name or Path(name).is_absolute() or ".." in parts:
            continue
        p = folder / name
        if (p.exists() or p.is_symlink()) and p not in out:
            out.append(p)
    return out


def clear(folder: Path, record: dict[str, Any] | None = None) -> list[Path]:
    """``--overwrite``: remove what lanegraph wrote in ``folder`` (:func:`written_paths`; a link is
    removed, never followed), nothing else; returns what was removed."""
    folder = Path(folder)
    if record is None:
        record, _ = read_state(folder)
    removed = []
    for p in written_paths(folder, record):
        try:
            if p.is_symlink() or not p.is_dir():
                p.unlink()
            else:
                shutil.rmtree(p)
        except FileNotFoundError:
            continue
        except OSError as exc:
            raise UsageError(f"--overwrite: cannot remove {p}: {exc.strerror or exc}") from None
        removed.append(p)
    return removed
