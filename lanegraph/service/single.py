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
                "cannot resume (run without --resume to start over)"
            )
        legacy.unlink(missing_ok=True)
        if checkpoint.exists() and not checkpoint.is_file():
            raise UsageError(f"{checkpoint}: exists and is not a file (lanegraph keeps its checkpoint there)")
        if resume and checkpoint.is_file():
            return load_checkpoint(checkpoint), checkpoint
        if not resume:
            checkpoint.unlink(missing_ok=True)
    except OSError as exc:
        raise UsageError(f"{out_dir}: {exc.strerror or exc}") from None
    return None, checkpoint
