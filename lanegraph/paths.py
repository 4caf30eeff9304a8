"""Where a run may write: every sink path and every debug picture stays inside the folder the user named.

- A sink names what it writes with params typed :data:`OutputFile` or :data:`OutputDir`: a relative
  path inside ``--out`` (no absolute path, no ``..``, no NUL, no backslash). Graph validation checks
  them (:func:`output_problems`): two sinks writing one file (or one inside the other's folder) and a
  sink writing one of the run's own files (:data:`RUN_FILES`) are validation errors naming node and
  param.
- At run time :func:`inside` resolves such a path against the output folder (symbolic links
  followed) and refuses one that ends up outside it.
- :func:`safe_name` makes one file name out of free text (a frame id, a node id): never ``..``,
  never a hidden or empty name, never a separator.
- :class:`OutputLock` locks an output folder for one run at a time.
"""

from __future__ import annotations

import errno
import json
import os
import re
import secrets
import time
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Annotated, Any

from pydantic import AfterValidator

from .errors import UsageError

#: the files a run writes into ``--out`` itself; no sink may write them (the record, the timings,
#: the checkpoint, the lock, the resolved graph of ``lanegraph.records.provenance``, the log of
#: ``lanegraph.runlog``, a batch run's key)
RUN_FILES = (
    "timings.json",
    "run.json",
    "checkpoint.json",
    "checkpoint.pkl",
    ".lanegraph.lock",
    "graph.yaml",
    "run.log",
    "run_key.txt",
)
LOCK_NAME = ".lanegraph.lock"


@dataclass(frozen=True)
class OutputPath:
    """Marks a params field as a path a sink writes, relative to ``--out``: ``kind`` is "file" or "dir"."""

    kind: str


def relative_output(value: str) -> str:
    """Check and normalise a path relative to the output folder (``a/./b`` -> ``a/b``).

    Raises ``ValueError`` (pydantic reports it as a validation error of the param) for an empty or
    absolute path, a ``..`` component, a NUL byte or a backslash.
    """
    if not isinstance(value, str) or not value.strip():
        raise ValueError("expected a path relative to --out, got an empty one")
    if "\x00" in value:
        raise ValueError("a path must not contain a NUL byte")
    if "\\" in value:
        raise ValueError(f"use '/' to separate folders, got {value!r}")
    p = PurePosixPath(value)
    if p.is_absolute() or re.match(r"^[A-Za-z]:", value):
        raise ValueError(f"expected a path relative to --out, got the absolute path {value!r}")
    if ".." in p.parts:
        raise ValueError(f"a path relative to --out must stay inside it: no '..', got {value!r}")
    parts = [x for x in p.parts if x not in ("", ".")]
    if not parts:
        raise ValueError(f"expected a file or folder inside --out, got {value!r}")
    return "/".join(parts)


#: a params field: a file a sink writes, relative to --out
OutputFile = Annotated[str, AfterValidator(relative_output), OutputPath("file")]
#: a params field: a folder a sink writes into, relative to --out
OutputDir = Annotated[str, AfterValidator(relative_output), OutputPath("dir")]


def output_fields(params_model: type) -> dict[str, str]:
    """``{field name: "file" | "dir"}`` of the params fields marked :data:`OutputFile` / :data:`OutputDir`."""
    out = {}
    for name, f in getattr(params_model, "model_fields", {}).items():
        for m in f.metadata:
            if isinstance(m, OutputPath):
                out[name] = m.kind
    return out


def output_problems(sinks: list[tuple[str, str, dict[str, tuple[str, str]]]]) -> list[tuple[str, str, str]]:
    """Clashes between the outputs of a graph's nodes.

    ``sinks``: ``(node id, node type, {field: (kind, relative path)})``. Returns ``(node id, field,
    message)`` for a path that is one of :data:`RUN_FILES`, and for two outputs that are the same
    file or lie one inside the other (a file in another sink's folder, nested folders).
    """
    problems = []
    seen: list[tuple[str, str, str, str, str]] = []  # (node, type, field, kind, path)
    for nid, ntype, fields in sinks:
        for fname, (kind, path) in fields.items():
            first = path.split("/")[0]
            if path in RUN_FILES or (kind == "dir" and first in RUN_FILES):
                problems.append(
                    (
                        nid,
                        fname,
                        f"{path!r} is a file of the run itself ({', '.join(RUN_FILES[:3])}); choose another name",
                    )
                )
                continue
            for onid, ontype, ofield, okind, opath in seen:
                same = path == opath
                nested = path.startswith(opath + "/") or opath.startswith(path + "/")
                if same or nested:
                    other = f"node '{onid}' ({ontype}) params.{ofield}"
                    if same:
                        msg = f"{path!r} is also written by {other}"
                    elif path.startswith(opath + "/"):
                        msg = f"{path!r} lies inside {opath!r}, the {okind} of {other}"
                    else:
                        msg = f"{path!r} contains {opath!r}, the {okind} of {other}"
                    problems.append((nid, fname, msg + "; two sinks must not write one file"))
                    break
            seen.append((nid, ntype, fname, kind, path))
    return problems


def inside(base: Path, relative: str, what: str) -> Path:
    """``base / relative``, refused (:class:`UsageError`) when it resolves outside ``base``
    (an absolute or ``..`` path, or a symbolic link inside ``base`` that points out of it)."""
    base_r = _resolve(base, what)
    target = base / relative
    target_r = _resolve(target, what)
    if target_r != base_r and not target_r.is_relative_to(base_r):
        raise UsageError(
            f"{what}: {target} resolves to {target_r}, outside {base}; outputs stay inside the output folder"
        )
    return target


def _resolve(p: Path, what: str) -> Path:
    try:
        return p.resolve()
    except (OSError, RuntimeError) as exc:  # a symbolic link loop
        raise UsageError(f"{what}: cannot resolve {p}: {exc}") from None


_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def safe_name(text: object) -> str:
    """One file name made of ``text``: characters other than letters, digits, ``.``, ``_`` and ``-``
    become ``_``; a name that would be empty, start with a dot (``.``, ``..``, hidden files) or be
    longer than 200 characters is prefixed or cut so it stays one ordinary name in its folder."""
    name = _UNSAFE.sub("_", str(text))
    if not name or name.startswith("."):
        name = "_" + name
    return name[:200]


def prepare_dir(path: Path, what: str) -> Path:
    """Create the folder ``path`` (and its parents); any reason it cannot be a writable folder
    (an existing file, a file among its parents, a read-only file system, no permission) is a
    :class:`UsageError` naming the option."""
    try:
        if path.is_symlink() and not path.exists():
            raise UsageError(
                f"{what} {path}: a symbolic link that leads nowhere (a loop, or its target is gone)"
            )
        if path.exists() and not path.is_dir():
            raise UsageError(f"{what} {path}: exists and is not a folder")
        for parent in path.parents:
            if parent.exists() and not parent.is_dir():
                raise UsageError(f"{what} {path}: {parent} is a file, not a folder")
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".lanegraph-write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except UsageError:
        raise
    except (OSError, RuntimeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise UsageError(f"{what} {path}: cannot write there: {reason}") from None
    return path


class OutputLock:
    """An exclusive lock on an output folder, held for one run (or ablation).

    The lock is an advisory ``flock`` held on the folder itself (an open descriptor of the
    directory), so it does not depend on any file name staying in place: deleting or replacing
    ``DIR/.lanegraph.lock`` (or any other file) does not let a second run in. The lock file is
    only where the holder says who it is (pid, command, start), and is locked too, for runs of an
    older lanegraph that lock only it; the lock removes it at its end when it created it (a refused
    or finished run leaves none), and it is harmless to leave or delete.
    Where a file system cannot lock a directory (some network file systems), the lock file alone
    is locked. A second run into the folder gets a :class:`UsageError` saying which process holds
    it. The lock dies with its process: a killed run leaves no stale lock.
    """

    def __init__(self, folder: Path, command: str = "run"):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.command = command
        self._fh: Any = None
        self._dir_fd: int | None = None
        self._created = False

    def acquire(self) -> OutputLock:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not a POSIX system: no lock
            return self
        try:
            self._lock_folder(fcntl)
            self._lock_file(fcntl)
        except BaseException:
            self.release()
            raise
        return self

    def _lock_folder(self, fcntl: Any) -> None:
        try:
            fd = os.open(self.folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        except OSError as exc:
            raise UsageError(f"{self.folder}: cannot open the output folder: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise self._busy() from None
            return  # a file system that cannot lock a folder: the lock file alone
        self._dir_fd = fd

    def _lock_file(self, fcntl: Any) -> None:
        nofollow = getattr(os, "O_NOFOLLOW", 0)
        try:  # never through a link planted at the lock's name (it would be truncated)
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL | nofollow, _FILE_MODE)
                self._created = True  # removed again at the end: no lock file left in the folder
            except FileExistsError:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | nofollow, _FILE_MODE)
            fh = os.fdopen(fd, "r+", encoding="utf-8")
        except OSError as exc:
            raise UsageError(f"{self.path}: cannot create the lock file: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            fh.close()
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise UsageError(
                    f"{self.path}: cannot lock the output folder: {exc.strerror or exc}"
                ) from None
            raise self._busy() from None
        fh.seek(0)
        fh.truncate()
        fh.write(
            json.dumps(
                {"pid": os.getpid(), "command": self.command, "started": time.strftime("%Y-%m-%d %H:%M:%S")}
            )
            + "\n"
        )
        fh.flush()
        self._fh = fh

    def _busy(self) -> UsageError:
        """The error for a folder another run holds, naming it from the lock file (if still there)."""
        try:
            fd = os.open(self.path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
            with os.fdopen(fd, "r", encoding="utf-8", errors="replace") as fh:
                holder = _holder(fh.read(4096))
        except OSError:
            holder = "run (holder unknown: its lock file was removed)"
        return UsageError(
            f"{self.folder}: in use by another lanegraph {holder}; "
            "wait for it to finish or choose another output folder"
        )

    def probe(self) -> None:
        """Raise the :class:`UsageError` of :meth:`acquire` when another process holds the lock
        (on the folder, or on the lock file of an older lanegraph), without creating or writing
        anything: a folder refused for another reason stays as it was."""
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not a POSIX system: no lock
            return
        for path, flags in (
            (self.folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0)),
            (self.path, os.O_RDONLY),
        ):
            try:
                fd = os.open(path, flags | getattr(os, "O_NOFOLLOW", 0) * (path == self.path))
            except OSError as exc:
                try:
                    planted = path == self.path and self.path.is_symlink()
                except OSError:
                    planted = False
                if planted:  # a link planted at the lock file's name: what acquire() would say
                    raise UsageError(
                        f"{self.path}: cannot create the lock file: {exc.strerror or exc}"
                    ) from None
                return  # no folder or no lock file: nobody holds it (prepare_dir says why there is none)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise self._busy() from None
                continue  # a file system that cannot lock it
            else:
                fcntl.flock(fd, fcntl.LOCK_UN)
            finally:
                os.close(fd)

    def release(self) -> None:
        if self._fh is not None:
            if self._created:  # the lock file this lock made, if it is still that file
                try:
                    st, mine = os.lstat(self.path), os.fstat(self._fh.fileno())
                    if (st.st_dev, st.st_ino) == (mine.st_dev, mine.st_ino):
                        os.unlink(self.path)
                except OSError:
                    pass
                self._created = False
            self._fh.close()  # closing releases the flock
            self._fh = None
        if self._dir_fd is not None:
            os.close(self._dir_fd)
            self._dir_fd = None

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _holder(text: str) -> str:
    try:
        info = json.loads(text)
        return f"{info.get('command', 'run')} (pid {int(info['pid'])}, started {info.get('started', '?')})"
    except (ValueError, KeyError, TypeError):
        return "run (holder unknown)"


#: the mode a new file or folder asks for; the umask takes from it, as for any file ``open()`` creates
_FILE_MODE, _DIR_MODE = 0o666, 0o777
_NEW_FILE = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


def new_temp_file(
    folder: Path, prefix: str = ".", suffix: str = ".tmp", mode: int = _FILE_MODE
) -> tuple[int, Path]:
    """A new file of a name no other has in ``folder``, opened for writing: ``(descriptor, path)``.

    Unlike :func:`tempfile.mkstemp` (always ``0600``) it is created with the mode a plain ``open()``
    gives under the process's umask, so a file written here and renamed into place is as readable as
    any other file the command writes (``0644`` under umask 022, ``0600`` under 077), or ``mode``
    under the umask. Never through a link (``O_EXCL``, ``O_NOFOLLOW``)."""
    for _ in range(100):
        path = Path(folder) / f"{prefix}{secrets.token_hex(6)}{suffix}"
        try:
            return os.open(path, _NEW_FILE, mode), path
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no unused temporary file name", str(folder))


def new_temp_dir(folder: Path, prefix: str = ".") -> Path:
    """A new, empty folder of a name no other has in ``folder``, with the mode ``mkdir`` gives under
    the umask (:func:`tempfile.mkdtemp` makes it ``0700``, which a rename into place would keep)."""
    for _ in range(100):
        path = Path(folder) / f"{prefix}{secrets.token_hex(6)}"
        try:
            os.mkdir(path, _DIR_MODE)
            return path
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no unused temporary folder name", str(folder))


def relative_inside(path: Path | None, folder: Path) -> str | None:
    """``path`` relative to ``folder`` (both resolved) when it lies inside it, else None."""
    if path is None:
        return None
    try:
        return str(Path(path).resolve().relative_to(Path(folder).resolve()))
    except (ValueError, OSError):
        return None


def write_bytes_atomic(path: Path, data: bytes, mode: int = _FILE_MODE) -> None:
    """Write ``data`` to ``path`` through a new temporary file in the same folder and a rename: never
    half a file, and never through a symbolic or hard link planted at ``path`` (the rename replaces
    the link itself). The file ends with the mode a plain ``open()`` would give it (the umask's), or
    ``mode`` under the umask (``0o600``: a file only its owner may read). OSError when it cannot be
    written."""
    fd, tmp = new_temp_file(path.parent, prefix=f".{path.name[:100]}.", suffix=".tmp", mode=mode)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def write_text_atomic(path: Path, text: str) -> None:
    """:func:`write_bytes_atomic` of UTF-8 text."""
    write_bytes_atomic(path, text.encode("utf-8"))


def create_new(path: Path) -> Any:
    """``path`` opened for writing as a new, empty file (unbuffered): an existing file, or a link
    planted at its name, is removed first, so writing never goes through a link to elsewhere."""
    try:
        path.unlink()
    except FileNotFoundError:
        pass
    fd = os.open(path, _NEW_FILE, _FILE_MODE)
    return os.fdopen(fd, "wb", buffering=0)


__all__ = [
    "LOCK_NAME",
    "RUN_FILES",
    "OutputDir",
    "OutputFile",
    "OutputLock",
    "OutputPath",
    "inside",
    "output_fields",
    "output_problems",
    "prepare_dir",
    "relative_inside",
    "relative_output",
    "safe_name",
    "create_new",
    "new_temp_dir",
    "new_temp_file",
    "write_bytes_atomic",
    "write_text_atomic",
]
