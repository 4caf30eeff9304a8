"""A content-addressed, size-bounded, on-disk cache of node results.

A node's result on a frame is keyed by what determines it: the node type, its params, the keys of
its inputs (recursively, down to the source) and, at the source, the identity of the input files
(path, size, modification time) or of the synthetic scene. Variants of a graph that share a node
with the same params and the same upstream -- typically the disparity -- share its results; a
changed param or input file changes the key of exactly that node and everything downstream of it.

Entries are pickles written by lanegraph itself into the user's cache directory
(``$LANEGRAPH_CACHE_DIR/results``, default ``~/.cache/lanegraph/results``); the least recently used
entries are evicted beyond ``max_bytes``.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import tempfile
from pathlib import Path
from typing import Any

from ._numba import cache_root

DEFAULT_MAX_BYTES = 2 * 1024**3


def digest(*parts: Any) -> str:
    """A stable hex digest of JSON-able parts."""
    h = hashlib.sha256()
    for p in parts:
        h.update(json.dumps(p, sort_keys=True, default=str).encode())
        h.update(b"\0")
    return h.hexdigest()


class ResultCache:
    """``get(key)`` / ``put(key, value)`` on disk under ``root``, bounded by ``max_bytes``."""

    MISS = object()

    def __init__(self, root: str | Path | None = None, max_bytes: int = DEFAULT_MAX_BYTES):
        self.root = Path(root) if root else cache_root() / "results"
        self.root.mkdir(parents=True, exist_ok=True)
        self.max_bytes = int(max_bytes)
        self.hits = 0
        self.misses = 0
        self._size = sum(p.stat().st_size for p in self.root.glob("*/*.pkl"))

    def _path(self, key: str) -> Path:
        return self.root / key[:2] / f"{key}.pkl"

    def get(self, key: str) -> Any:
        p = self._path(key)
        try:
            with p.open("rb") as fh:
                value = pickle.load(fh)  # noqa: S301 - entries are written by lanegraph itself
        except (OSError, EOFError, pickle.UnpicklingError):
            self.misses += 1
            return self.MISS
        os.utime(p)  # LRU by modification time
        self.hits += 1
        return value

    def put(self, key: str, value: Any) -> None:
        p = self._path(key)
        p.parent.mkdir(parents=True, exist_ok=True)
        data = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
        if len(data) > self.max_bytes:
            return
        fd, tmp = tempfile.mkstemp(dir=p.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        old = p.stat().st_size if p.exists() else 0
        os.replace(tmp, p)
        self._size += len(data) - old
        if self._size > self.max_bytes:
            self.evict()

    def evict(self) -> None:
        """Remove least recently used entries until the cache is within 80 % of its bound."""
        entries = sorted((p.stat().st_mtime, p.stat().st_size, p) for p in self.root.glob("*/*.pkl"))
        total = sum(e[1] for e in entries)
        for _, size, p in entries:
            if total <= 0.8 * self.max_bytes:
                break
            p.unlink(missing_ok=True)
            total -= size
        self._size = total

    @property
    def size_bytes(self) -> int:
        return self._size

    def clear(self) -> None:
        for p in self.root.glob("*/*.pkl"):
            p.unlink(missing_ok=True)
        self._size = 0
