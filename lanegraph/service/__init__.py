"""The run service: the one path by which the commands run graphs (:class:`Session`)."""

from .session import Session

__all__ = ["Session"]
