"""What a run on one input needs besides its executor: the checkpoint it resumes and keeps."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import UsageError
from ..run.resume import CHECKPOINT_NAME, LEGACY_NAME, load_checkpoint


def checkpoint_for(out_dir: Path, resume: bool) -> tuple[Any, Path]:
    """The checkpoint to resume (with ``--resume``, when OUT has one; validated) and where the run
    keeps its own; a checkpoint of an older lanegraph is never read."""
    checkpoint = out_dir / CHECKPOINT_NAME
    legacy = out_dir / LEGACY_NAME
    try:
        if resume and legacy.is_file() and not checkpoint.is_file():
            raise UsageError(
                f"{legacy}: a checkpoint of an older lanegraph (a pickle, which could run code); it is never read; "
                "cannot resume (start over with --overwrite in place of --resume: it removes only what lanegraph wrote there; or choose another output folder)"
            )
        # (a checkpoint.pkl of an older lanegraph is left where it is: never read, never removed by name)
        if checkpoint.exists() and not checkpoint.is_file():
            raise UsageError(f"{checkpoint}: exists and is not a file (lanegraph keeps its checkpoint there)")
        if resume and checkpoint.is_file():
            return load_checkpoint(checkpoint), checkpoint
        if not resume:
            checkpoint.unlink(missing_ok=True)
    except OSError as exc:
        raise UsageError(f"{out_dir}: {exc.strerror or exc}") from None
    return None, checkpoint


def resumed_frame_ids(out_dir: Path, ckpt: Any) -> list[str]:
    """The ids of the frames an interrupted run consumed before it is resumed (``ckpt.position``
    of them): its record's when it wrote one that far, else those of its lanes file and its failures."""
    from ..run.record import read_record
    from ..run.results import LANES, find_result

    record = read_record(out_dir)
    if record is not None and record.selection is not None and len(record.selection.ids) == ckpt.position:
        return list(record.selection.ids)
    ids: list[str] = []
    lanes = find_result(out_dir, LANES)
    if lanes is not None:
        from ..evaluation.metrics import read_jsonl

        try:
            ids = [str(r.get("frame")) for r in read_jsonl(lanes)]
        except Exception:  # noqa: BLE001 - an unreadable lanes file: the resume itself refuses it
            ids = []
    failed = [str(f.frame) for f in ckpt.failures if f.frame is not None]
    return list(dict.fromkeys([*ids, *failed]))
