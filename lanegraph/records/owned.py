"""What lanegraph owns in an output folder: the ownership record ``OUT/.lanegraph-owned.json``.

lanegraph removes or replaces a path of an output folder only when this record lists it and the
record is genuine for that very file:

- the record is a plain file written by lanegraph: it holds its own device and inode and those of
  the folder it describes (a copy, a link or a file written by hand is not genuine, nor one moved
  from another folder);
- each path it lists is relative, inside the folder with every link resolved (no link anywhere on
  the way: the path must be what it names), never ``.`` nor the folder itself, and still the file
  lanegraph wrote: a regular file of the inode, size and SHA-256 kept when it was written; a folder
  of the inode kept when lanegraph created it (a folder that was there before is never listed);
- a file still being written when the record was made (a run killed before its end) is listed by
  its inode alone (``open``), the checkpoint by its format (it is rewritten every frame).

A folder without a genuine record is a new folder: nothing in it is lanegraph's. :func:`taken` says
which of the names a command is about to write are there and not lanegraph's (the command is then
refused), :func:`clear` removes what the record lists, all or nothing (every path is moved aside
first; one that cannot be is put back with the others, and nothing is removed), and :func:`seal`
writes the record at the end of a command (and early, so that a killed run's files are known).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import stat
from collections.abc import Iterable, Mapping
from pathlib import Path, PurePosixPath
from typing import Any

from ..errors import UsageError
from ..paths import new_temp_dir, new_temp_file

LEDGER = ".lanegraph-owned.json"
FORMAT = "lanegraph-owned"
VERSION = 1
#: the most entries a record holds, and a folder walk visits (a larger tree is not lanegraph's)
MAX_ENTRIES = 200_000
_MAX_LEDGER_BYTES = 64 * 1024 * 1024
_CHECKPOINT_MARK = b'{"format":"lanegraph-checkpoint"'
#: per resolved folder, what a command is about to write there (its roots) and what of those was
#: there before it wrote and not lanegraph's (path -> its identity): see :func:`begin`
_BEFORE: dict[str, tuple[list[str], dict[str, tuple[int, int]]]] = {}


#: per resolved folder, the roots that were not there when the command was checked (its folders
#: are then made before it claims the folder: they are lanegraph's): see :func:`note_absent`
_ABSENT: dict[str, set[str]] = {}


def note_absent(folder: Path, roots: Iterable[str]) -> None:
    """Note which of ``roots`` are not in ``folder`` yet (before anything is made there): a folder
    among them made before :func:`begin` (the ``--debug-dir`` made when OUT is locked) is lanegraph's."""
    root = _real(folder)
    absent = set()
    for name in roots:
        rel = _relative(name)
        if rel is not None and not os.path.lexists(root / rel):
            absent.add(rel)
    _ABSENT[str(root)] = absent


def _ident(st: os.stat_result) -> tuple[int, int]:
    """What tells a path from a new one at its name: its inode, and for a file its status change
    time (a file removed and another created gets its inode number again on most file systems)."""
    return (st.st_ino, 0 if stat.S_ISDIR(st.st_mode) else st.st_ctime_ns)


#: the digests already taken, by file (device, inode, size, modification and change times)
_DIGESTS: dict[tuple[int, int, int, int, int], str] = {}


def _real(folder: Path) -> Path:
    return Path(os.path.realpath(folder))


def _relative(name: object) -> str | None:
    """``name`` as a clean relative path inside a folder, or None (absolute, ``..``, ``.``, empty)."""
    if not isinstance(name, str) or not name or "\x00" in name or "\\" in name:
        return None
    p = PurePosixPath(name)
    if p.is_absolute() or ".." in p.parts:
        return None
    parts = [x for x in p.parts if x not in ("", ".")]
    if not parts or parts == [LEDGER]:
        return None
    return "/".join(parts)


def _digest(path: Path) -> str | None:
    """The SHA-256 of the regular file ``path``, read without following a link; None if it cannot be."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            return None
        key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
        if key in _DIGESTS:  # read once per command (a check, a claim and a seal each ask)
            return _DIGESTS[key]
        h = hashlib.sha256()
        while chunk := os.read(fd, 1 << 20):
            h.update(chunk)
        if len(_DIGESTS) > 100_000:
            _DIGESTS.clear()
        _DIGESTS[key] = h.hexdigest()
        return _DIGESTS[key]
    except OSError:
        return None
    finally:
        os.close(fd)


def _plain_path(root: Path, rel: str) -> os.stat_result | None:
    """The ``lstat`` of ``root/rel`` when no link lies on the way to it (its folders are what they
    name, inside ``root``, itself resolved); None otherwise or when it is not there."""
    parent = PurePosixPath(rel).parent
    try:
        if str(parent) != "." and os.path.realpath(root / parent) != str(root / parent):
            return None
        return os.lstat(root / rel)
    except (OSError, ValueError):
        return None


def _genuine_entry(root: Path, dev: int, rel: str, entry: Any) -> bool:
    """Whether ``entry`` of the record is still what lanegraph wrote at ``root/rel``."""
    if not isinstance(entry, dict):
        return False
    st = _plain_path(root, rel)
    if st is None or st.st_dev != dev:
        return False
    kind = entry.get("kind")
    if kind == "dir":
        return stat.S_ISDIR(st.st_mode) and st.st_ino == entry.get("ino")
    if not stat.S_ISREG(st.st_mode):
        return False
    if kind == "open":
        return st.st_ino == entry.get("ino")
    if kind == "checkpoint":
        try:
            with open(root / rel, "rb") as fh:
                return fh.read(len(_CHECKPOINT_MARK)) == _CHECKPOINT_MARK
        except OSError:
            return False
    if kind == "file":
        return (
            st.st_ino == entry.get("ino")
            and st.st_size == entry.get("size")
            and _digest(root / rel) == entry.get("sha256")
        )
    return False


def read(folder: Path) -> dict[str, dict[str, Any]]:
    """The entries of ``folder``'s genuine record that are still what lanegraph wrote (``{}``: no
    genuine record, nothing there is lanegraph's)."""
    root = _real(folder)
    path = root / LEDGER
    try:
        st = os.lstat(path)
        root_st = os.stat(root)
    except OSError:
        return {}
    if not stat.S_ISREG(st.st_mode) or st.st_size > _MAX_LEDGER_BYTES:
        return {}
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as fh:
            data = json.loads(fh.read(_MAX_LEDGER_BYTES + 1))
    except (OSError, ValueError, RecursionError):
        return {}
    if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("version") != VERSION:
        return {}
    me, there = data.get("self") or {}, data.get("folder") or {}
    if not (isinstance(me, dict) and isinstance(there, dict)):
        return {}
    if (me.get("dev"), me.get("ino")) != (st.st_dev, st.st_ino):
        return {}  # a copy, or a file written by hand
    if (there.get("dev"), there.get("ino")) != (root_st.st_dev, root_st.st_ino):
        return {}  # moved here from another folder
    entries = data.get("entries")
    if not isinstance(entries, dict) or len(entries) > MAX_ENTRIES:
        return {}
    out = {}
    for name, entry in entries.items():
        rel = _relative(name)
        if rel is not None and rel == name and _genuine_entry(root, st.st_dev, rel, entry):
            out[rel] = entry
    return out


def _parents(rel: str) -> list[str]:
    """``a``, ``a/b``, ``a/b/c`` of ``a/b/c``."""
    parts = rel.split("/")
    return ["/".join(parts[: i + 1]) for i in range(len(parts))]


def _walk(root: Path, rel: str, budget: list[int]) -> Iterable[tuple[str, os.stat_result]]:
    """``(relative path, lstat)`` of ``root/rel`` and, for a folder (not a link), everything under
    it, depth first; :class:`OverflowError` past ``budget[0]`` paths (iterative: any depth)."""
    st = _plain_path(root, rel)
    if st is None:
        return
    todo = [(rel, st)]
    while todo:
        path, st = todo.pop()
        budget[0] -= 1
        if budget[0] < 0:
            raise OverflowError(rel)
        yield path, st
        if not stat.S_ISDIR(st.st_mode):
            continue
        try:
            names = sorted(os.listdir(root / path), reverse=True)
        except OSError:
            continue
        for name in names:
            try:
                todo.append((f"{path}/{name}", os.lstat(root / path / name)))
            except OSError:
                continue


def owns_tree(folder: Path, rel: str, entries: Mapping[str, Any] | None = None) -> str | None:
    """None when ``folder/rel`` is absent or lanegraph's whole (the folder and everything under it
    listed by the genuine record); else the first path there that is not lanegraph's."""
    root = _real(folder)
    entries = read(folder) if entries is None else entries
    try:
        for path, _st in _walk(root, rel, [MAX_ENTRIES]):
            if path not in entries:
                return path
    except OverflowError:
        return rel
    return None


def taken(folder: Path, writes: Mapping[str, str], entries: Mapping[str, Any] | None = None) -> list[str]:
    """The names of ``writes`` (relative path -> ``file`` replaced whole, ``dir`` written into,
    ``tree`` replaced whole with all it holds) that are in ``folder`` and not lanegraph's: what the
    command must not write."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    root = _real(folder)
    entries = read(folder) if entries is None else entries
    out = []
    for name, kind in writes.items():
        rel = _relative(name)
        if rel is None:
            continue
        p = root / rel
        if not (p.exists() or p.is_symlink()):
            continue
        st = _plain_path(root, rel)
        if st is None:
            out.append(rel)  # a link on the way: never written through
        elif kind == "dir":
            if not stat.S_ISDIR(st.st_mode):
                out.append(rel)
        elif kind == "tree":
            if owns_tree(folder, rel, entries) is not None:
                out.append(rel)
        elif rel not in entries:
            out.append(rel)
    return out


def begin(folder: Path, roots: Iterable[str]) -> None:
    """Note what ``roots`` (relative paths) hold now, before the command writes: what is there
    and not lanegraph's stays the user's when :func:`seal` records the command's files."""
    folder = Path(folder)
    root = _real(folder)
    seen: dict[str, tuple[int, int]] = {}
    mine = read(folder)
    absent = _ABSENT.pop(str(root), set())
    roots = [r for r in (_relative(n) for n in roots) if r is not None]
    roots = list(dict.fromkeys(p for r in roots for p in _parents(r)))  # sinks' folders
    for rel in roots:
        if rel in absent:
            continue  # made since the command was checked: by it
        try:
            for path, st in _walk(root, rel, [MAX_ENTRIES]):
                if path not in mine:
                    seen[path] = _ident(st)
        except OverflowError:
            continue
    _BEFORE[str(root)] = (roots, seen)


def seal(folder: Path, roots: Iterable[str] | None = None, *, final: bool = True) -> None:
    """Write ``folder``'s record: what the record listed before that is still lanegraph's, and what
    is under ``roots`` (default: those given to :func:`begin`) but the user's paths :func:`begin`
    found there, unchanged. ``final``: the files are complete (else a file is listed by its inode
    alone, as one still being written). Never raises for a folder it cannot write (the record is then not
    written, and the files are not lanegraph's)."""
    folder = Path(folder)
    root = _real(folder)
    try:
        root_st = os.stat(root)
    except OSError:
        return
    began, before = _BEFORE.get(str(root), ([], {}))
    roots = began if roots is None else list(roots)
    previous = read(folder)
    entries: dict[str, dict[str, Any]] = dict(previous)
    for name in roots:
        rel = _relative(name)
        if rel is None:
            continue
        try:
            walked = list(_walk(root, rel, [MAX_ENTRIES]))
        except OverflowError:
            continue
        for path, st in walked:
            if st.st_dev != root_st.st_dev or stat.S_ISLNK(st.st_mode):
                continue
            if before.get(path) == _ident(st):
                continue  # there before the command, and not lanegraph's: the user's
            if stat.S_ISDIR(st.st_mode):
                entries[path] = {"kind": "dir", "ino": st.st_ino}
            elif stat.S_ISREG(st.st_mode):
                entries[path] = _file_entry(root / path, st, final)
    entries = {k: v for k, v in entries.items() if v is not None}
    if not entries and not previous:
        return
    _write(root, root_st, entries)


def _file_entry(path: Path, st: os.stat_result, final: bool) -> dict[str, Any] | None:
    if path.name == "checkpoint.json":
        return {"kind": "checkpoint"}
    if not final:
        return {"kind": "open", "ino": st.st_ino}
    digest = _digest(path)
    if digest is None:
        return None
    st2 = os.lstat(path)
    return {"kind": "file", "ino": st2.st_ino, "size": st2.st_size, "sha256": digest}


def _write(root: Path, root_st: os.stat_result, entries: Mapping[str, Any]) -> None:
    """The record, through a new file renamed into place; it names its own inode (known once the
    file is created) so that a copy of it is not genuine."""
    try:
        fd, tmp = new_temp_file(root, prefix=".lanegraph-owned.", suffix=".tmp")
    except OSError:
        return
    try:
        st = os.fstat(fd)
        doc = {
            "format": FORMAT,
            "version": VERSION,
            "about": "what lanegraph wrote in this folder: --overwrite removes these files, nothing else",
            "self": {"dev": st.st_dev, "ino": st.st_ino},
            "folder": {"dev": root_st.st_dev, "ino": root_st.st_ino},
            "entries": dict(sorted(entries.items())),
        }
        with os.fdopen(fd, "wb") as fh:
            fh.write(json.dumps(doc, indent=1).encode("utf-8"))
        os.replace(tmp, root / LEDGER)
    except OSError:
        try:
            os.unlink(tmp)
        except OSError:
            pass


def clear(folder: Path, option: str = "--overwrite") -> list[Path]:
    """``--overwrite``: remove every path the genuine record lists (files first; a folder lanegraph
    created only once empty: what the user put in it stays), then the record. All or nothing: every
    file is first moved aside into a new folder of ``folder``; when one cannot be (an immutable
    file, a folder that cannot be written), those already moved are put back and a
    :class:`UsageError` says which, with nothing removed. Returns what was removed."""
    folder = Path(folder)
    root = _real(folder)
    entries = read(folder)
    if not entries:
        return []
    files = sorted((r for r, e in entries.items() if e.get("kind") != "dir"), key=lambda r: -r.count("/"))
    dirs = sorted((r for r, e in entries.items() if e.get("kind") == "dir"), key=lambda r: -r.count("/"))
    try:
        trash = new_temp_dir(root, prefix=".lanegraph-removing-")
    except OSError as exc:
        raise UsageError(f"{option}: cannot remove anything in {folder}: {exc.strerror or exc}") from None
    moved: list[tuple[Path, Path]] = []
    for i, rel in enumerate([*files, LEDGER]):
        src, dst = root / rel, trash / str(i)
        try:
            os.rename(src, dst)
        except FileNotFoundError:
            continue
        except OSError as exc:
            for a, b in reversed(moved):
                try:
                    os.rename(b, a)
                except OSError:
                    pass
            try:
                os.rmdir(trash)
            except OSError:
                pass
            raise UsageError(
                f"{option}: cannot remove {folder / rel}: {exc.strerror or exc}; nothing was removed"
            ) from None
        moved.append((src, dst))
    removed = [
        folder / str(src.relative_to(root)) for src, _ in moved if src.name != LEDGER or src.parent != root
    ]
    for rel in dirs:
        try:
            os.rmdir(root / rel)
            removed.append(folder / rel)
        except OSError:
            continue  # not empty (the user's files are in it) or not removable: it stays
    shutil.rmtree(trash, ignore_errors=True)
    _BEFORE.pop(str(root), None)
    return removed


__all__ = ["LEDGER", "begin", "clear", "owns_tree", "read", "seal", "taken"]
