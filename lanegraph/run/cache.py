"""A content-addressed, size-bounded, on-disk cache of node results.

A node's result on a frame is keyed by what determines it: the node type, its code (its plugin
package's and lanegraph's source files, :attr:`lanegraph.nodes.NodeType.code_version`), its params, the keys of
its inputs (recursively, down to the source) and, at the source, the identity of the input files
(path, size, modification time) or of the synthetic scene. Variants of a graph that share a node
with the same params and the same upstream -- typically the disparity -- share its results; a
changed param or input file changes the key of exactly that node and everything downstream of it.

The cache is a folder (``$LANEGRAPH_CACHE_DIR/results``, default ``~/.cache/lanegraph/results``,
or ``--cache-dir``) that several processes may use at once -- the workers of a Dask cluster on a
shared file system:

- an entry is written to a temporary file beside it and renamed into place, so a reader sees a
  whole entry or none, and two processes computing the same entry (same key, same content) never
  corrupt it;
- the size bound is kept across processes: each process rescans the folder after writing a tenth of
  the bound and when its estimate passes the bound, and evicts the least recently used entries under
  a lock file (``.evict.lock``; one process evicts at a time, the others go on);
- temporary files left by a process killed while writing are removed by the next eviction once
  they are an hour old.

Entries are data (:mod:`lanegraph.storage`: a value of a class is stored by the port type that
stores it, its ``encode`` / ``decode`` -- lanegraph's own value types and a plugin's alike), pickled
and read by a restricted unpickler (:func:`safe_loads`) that can build only builtin containers and
NumPy arrays, dtypes and scalars: a crafted entry in a shared folder cannot run code. An entry it
refuses is a miss (with a :class:`CacheWarning`) and is computed again and overwritten; a value no
registered port type stores is not stored.
"""

from __future__ import annotations

import io
import os
import pickle
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..kernels.folder import cache_root
from ..paths import new_temp_file
from ..port_types import PORT_TYPES
from ..storage import Codecs, StorageError, decode_value, digest, encode_value
from ..types import PortType

__all__ = ["CacheWarning", "Caching", "ResultCache", "digest", "safe_loads"]

DEFAULT_MAX_BYTES = 2 * 1024**3
#: a temporary entry file older than this (seconds) belongs to a writer that died
STALE_TMP_S = 3600.0


class CacheWarning(UserWarning):
    """A cache entry was refused or could not be stored; the run goes on without it."""


#: (module, name) pairs an entry may name: builtin containers, NumPy's reconstruction functions
#: (both spellings of numpy's private core module: 1.x ``numpy.core``, 2.x ``numpy._core``)
_ALLOWED_GLOBALS = {
    ("builtins", name)
    for name in (
        "list",
        "dict",
        "tuple",
        "set",
        "frozenset",
        "bytearray",
        "bytes",
        "complex",
        "slice",
        "range",
    )
} | {
    ("numpy", "dtype"),
    ("numpy", "ndarray"),
    *((f"numpy.{core}.multiarray", fn) for core in ("core", "_core") for fn in ("_reconstruct", "scalar")),
    *((f"numpy.{core}.numeric", "_frombuffer") for core in ("core", "_core")),
}


class _RestrictedUnpickler(pickle.Unpickler):
    """An unpickler that resolves only the globals of :data:`_ALLOWED_GLOBALS`; anything else
    (``os.system``, ``builtins.eval``, any class, lanegraph's and a plugin's too) is refused before
    it is even imported."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _ALLOWED_GLOBALS:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"{module}.{name} is not a type a cache entry may hold")


def safe_loads(data: bytes) -> Any:
    """Unpickle ``data`` with the restricted unpickler; raises ``pickle.UnpicklingError`` for a
    pickle naming anything but builtin containers and NumPy arrays, dtypes and scalars."""
    return _RestrictedUnpickler(io.BytesIO(data)).load()


try:  # POSIX: one process evicts at a time
    import fcntl
except ImportError:  # pragma: no cover - Windows: evictions are not serialised
    fcntl = None  # type: ignore[assignment]


class ResultCache:
    """``get(key)`` / ``put(key, value)`` on disk under ``root``, bounded by ``max_bytes``; safe for
    several processes sharing ``root`` (see the module's doc)."""

    MISS = object()

    def __init__(self, root: str | Path | None = None, max_bytes: int = DEFAULT_MAX_BYTES):
        self.root = Path(root) if root else cache_root() / "results"
        self.root.mkdir(parents=True, exist_ok=True)
        self.max_bytes = int(max_bytes)
        self.hits = 0
        self.misses = 0
        self._size = self._scan()
        self._written = 0  # bytes this process wrote since its last scan

    def _path(self, key: str) -> Path:
        return self.root / key[:2] / f"{key}.pkl"

    def _scan(self) -> int:
        total = 0
        for p in self.root.glob("*/*.pkl"):
            try:
                total += p.stat().st_size
            except FileNotFoundError:  # evicted by another process meanwhile
                pass
        return total

    def get(self, key: str, port_types: Mapping[str, PortType] | Codecs | None = None) -> Any:
        """The value stored under ``key``, its values of other classes than data decoded by the
        port types of ``port_types`` that store them (default: lanegraph's own); :attr:`MISS`
        when there is none, or it cannot be read or decoded."""
        p = self._path(key)
        try:
            data = p.read_bytes()
        except OSError:
            self.misses += 1
            return self.MISS
        try:
            value = decode_value(safe_loads(data), "entry", PORT_TYPES if port_types is None else port_types)
        except (pickle.UnpicklingError, StorageError) as exc:
            warnings.warn(
                f"result cache: {p}: entry refused ({exc}); computed again", CacheWarning, stacklevel=2
            )
            self.misses += 1
            return self.MISS
        except Exception:  # noqa: BLE001 - a truncated or foreign file is a miss, never an error
            self.misses += 1
            return self.MISS
        try:
            os.utime(p)  # LRU by modification time
        except OSError:  # evicted by another process meanwhile
            pass
        self.hits += 1
        return value

    def put(self, key: str, value: Any, port_types: Mapping[str, PortType] | Codecs | None = None) -> bool:
        """Store ``value`` as data (:func:`lanegraph.storage.encode_value`: a value of another
        class by the port type of ``port_types`` that stores it, default lanegraph's own); returns
        whether it was stored (not when larger than the bound, or when no port type stores one of
        its values)."""
        try:
            encoded = encode_value(
                value, "result", PORT_TYPES if port_types is None else port_types, arrays="native"
            )
            data = pickle.dumps(encoded, protocol=pickle.HIGHEST_PROTOCOL)
            if len(data) > self.max_bytes:
                return False
            safe_loads(data)  # store only what a reader will accept
        except (StorageError, pickle.UnpicklingError) as exc:
            warnings.warn(f"result cache: a result was not stored: {exc}", CacheWarning, stacklevel=2)
            return False
        p = self._path(key)
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = new_temp_file(p.parent, prefix=".", suffix=".tmp")  # the umask's mode, as any file
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            try:
                old = p.stat().st_size
            except FileNotFoundError:
                old = 0
            os.replace(tmp, p)  # atomic: readers see the old entry or the new one
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        self._size += len(data) - old
        self._written += len(data)
        if self._size > self.max_bytes or self._written > self.max_bytes // 10:
            self._written = 0
            self._size = self._scan()  # what every process sharing the folder wrote
            if self._size > self.max_bytes:
                self.evict()
        return True

    def evict(self) -> None:
        """Remove least recently used entries until the cache is within 80 % of its bound, and
        temporary files of writers that died. Skipped when another process is evicting."""
        lock = None
        if fcntl is not None:
            lock = open(self.root / ".evict.lock", "a+b")  # noqa: SIM115 - held until the end
            try:
                fcntl.flock(lock.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                lock.close()
                return
        try:
            entries = []
            for p in self.root.glob("*/*.pkl"):
                try:
                    st = p.stat()
                except FileNotFoundError:
                    continue
                entries.append((st.st_mtime, st.st_size, p))
            entries.sort()
            total = sum(e[1] for e in entries)
            for _, size, p in entries:
                if total <= 0.8 * self.max_bytes:
                    break
                p.unlink(missing_ok=True)
                total -= size
            self._size = total
            now = time.time()
            for p in self.root.glob("*/.*.tmp"):
                try:
                    if now - p.stat().st_mtime > STALE_TMP_S:
                        p.unlink(missing_ok=True)
                except FileNotFoundError:
                    pass
        finally:
            if lock is not None:
                lock.close()  # releases the lock

    @property
    def size_bytes(self) -> int:
        return self._size

    def entries(self) -> int:
        """How many entries the folder holds now (every process's)."""
        return sum(1 for _ in self.root.glob("*/*.pkl"))

    def clear(self) -> int:
        """Remove every entry (the cache's own files only: ``XX/<key>.pkl`` and the sub-folders
        that held nothing else); returns the bytes freed."""
        freed = 0
        for p in self.root.glob("*/*.pkl"):
            try:
                freed += p.stat().st_size
                p.unlink()
            except FileNotFoundError:  # evicted by another process meanwhile
                pass
        for sub in self.root.iterdir():
            if sub.is_dir() and not sub.is_symlink() and len(sub.name) == 2:
                try:
                    sub.rmdir()  # only when empty
                except OSError:
                    pass
        self._size = self._scan()
        return freed


class Caching:
    """The result-cache piece of a run: ``cache`` keeps the results of the graph's ``nodes`` (None:
    every stateless node), each keyed by :meth:`key`."""

    def __init__(self, cache: ResultCache, nodes: set[str] | None = None):
        self.cache = cache
        self.nodes = None if nodes is None else set(nodes)

    def nodes_of(self, graph: Any) -> set[str]:
        """The nodes of ``graph`` whose results are cached."""
        if self.nodes is not None:
            return set(self.nodes)
        return {nid for nid, n in graph.nodes.items() if not n.type.stateful}

    @staticmethod
    def key(
        node: Any, keys: dict[tuple[str, str], str | None], prev_keys: dict[tuple[str, str], str | None]
    ) -> str | None:
        """The content key of ``node``'s result this frame (its type, plugin, code version, params
        and the keys of its inputs; a feedback input's key of the frame before), or None when it
        is not determined by its inputs (a stateful node, or an input without a key)."""
        if node.type.stateful:
            return None
        parts = []
        for port in sorted(node.inputs):
            e = node.inputs[port]
            if e.previous:
                k = prev_keys.get((e.src_node, e.src_port), "first-frame") if prev_keys else "first-frame"
            else:
                k = keys.get((e.src_node, e.src_port))
            if k is None:
                return None
            parts.append((port, k))
        return digest(
            node.type.name,
            node.type.plugin,
            node.type.code_version,
            node.params.model_dump(mode="json"),
            parts,
        )
