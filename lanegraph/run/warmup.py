"""The warm-up piece of a run: a chunk of a longer sequence starts from the frames before it."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class WarmUp:
    """The first ``frames`` frames of a run only bring the feedback edges and the stateful nodes up
    to date: the sinks do not see them, their times and failures are not recorded, ``on_frame``
    is not called for them (:mod:`lanegraph.batches.batch` runs a chunk after the frames before it)."""

    frames: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.frames, bool) or not isinstance(self.frames, int) or self.frames < 0:
            raise ValueError(f"WarmUp: frames: expected an integer >= 0, got {self.frames!r}")

    def warming(self, index: int) -> bool:
        """Whether frame ``index`` of the run (counted from the first warm-up frame) is a warm-up frame."""
        return index < self.frames
