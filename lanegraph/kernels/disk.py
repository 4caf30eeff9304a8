"""The kernel folder's files, checked before numba reads them (imports numba).

numba keeps a compiled kernel as pickles: an index (``.nbi``) and a data file (``.nbc``) per kernel,
which it unpickles when it looks for a kernel. lanegraph's kernels (:func:`lanegraph.jit`) use
:class:`CheckedCache` instead of numba's own cache:

- it writes each file as ``lanegraph-kernel-cache 1`` + an HMAC-SHA256 + numba's pickle, signed with
  a key kept in the kernel folder (``.lanegraph-key``, 32 random bytes, mode 0600, made on first
  use) over the file's path in the folder and its contents; a new file (mode 0600) is replaced into
  place, so a link is never written through;
- it unpickles a file only when its signature holds; a file that is not a regular file, not
  lanegraph's, damaged or empty is passed over with a warning (:class:`KernelCacheWarning`, once per
  process) and the kernel is compiled again, and saved over it;
- a file that cannot be written (a full disk) turns the disk cache off for the process with a
  warning: the run goes on, compiling what it needs.
- a kernel the folder does not hold is looked up in its plugin's bundle of machine code
  (:func:`lanegraph.kernels.bundle.load`) before numba compiles it, and saved to the folder from
  there as numba saves a compiled one.

The folder itself is one the user owns and no one else can write to (:mod:`.folder`), so no one
else can read the key or replace it. numba keeps a kernel while its own source file is unchanged;
a kernel holds the machine code of the functions it calls, so lanegraph's are kept only while every
Python file of their package folder (and :mod:`.decorator`, whose flags shape the code) is
unchanged (:func:`lanegraph.kernels.bundle.package_digest`). Used only with the numba and llvmlite
versions it was tested with (:mod:`.compat`).
"""

from __future__ import annotations

import hashlib
import hmac
import os
import pickle
import stat
import warnings
from pathlib import Path

from numba.core import caching as _caching

from ..paths import write_bytes_atomic
from . import bundle
from .bundle import package_digest
from .folder import KernelCacheWarning, kernel_folder

MAGIC = b"lanegraph-kernel-cache 1\n"
_MAC = hashlib.sha256().digest_size
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
KEY_NAME = ".lanegraph-key"

#: the kernel folder and its key, found once per process; "off": the disk cache turned off
_STATE: dict = {"folder": None, "key": None, "found": False, "off": False, "warned": set()}


def warn_once(what: str, text: str) -> None:
    if what in _STATE["warned"]:
        return
    _STATE["warned"].add(what)
    warnings.warn(text, KernelCacheWarning, stacklevel=3)


def folder_and_key() -> tuple[Path | None, bytes | None]:
    """The kernel folder and its key (None, None without a usable one), found once per process."""
    if not _STATE["found"]:
        _STATE["found"] = True
        folder = kernel_folder()
        key = _read_key(folder) if folder is not None else None
        if key is not None:
            _STATE["folder"], _STATE["key"] = folder, key
    return _STATE["folder"], _STATE["key"]


def _read_key(folder: Path) -> bytes | None:
    """The folder's key, made (atomically: a complete file linked into place) when missing."""
    path = folder / KEY_NAME
    for _ in range(3):
        try:
            fd = os.open(path, os.O_RDONLY | _NOFOLLOW)
        except FileNotFoundError:
            tmp = folder / f"{KEY_NAME}.tmp.{os.getpid()}"
            try:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o600)
                with os.fdopen(fd, "wb") as fh:
                    fh.write(os.urandom(32))
                os.link(tmp, path)
            except FileExistsError:
                pass  # another process made it first
            except OSError as exc:
                warn_once(str(path), f"no kernel cache: {path}: cannot be written ({exc.strerror or exc})")
                return None
            finally:
                try:
                    os.unlink(tmp)
                except OSError:
                    pass
            continue
        except OSError as exc:  # a link (ELOOP), unreadable
            warn_once(str(path), f"no kernel cache: {path}: cannot be read ({exc.strerror or exc})")
            return None
        with os.fdopen(fd, "rb") as fh:
            st = os.fstat(fh.fileno())
            data = fh.read(64)
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.geteuid() or st.st_mode & 0o077 or len(data) != 32:
            warn_once(
                str(path),
                f"no kernel cache: {path} is not a key lanegraph made (a private file of 32 bytes); "
                "remove it to make a new one",
            )
            return None
        return data
    return None  # pragma: no cover - made and removed under our feet three times


class _CheckedLocator(_caching.UserProvidedCacheLocator):
    """numba's locator, in lanegraph's kernel folder, whose source stamp also covers the other files
    of the kernel's package (the module's text). No file is touched until a kernel is saved."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        folder, _ = folder_and_key()
        self._cache_path = os.path.join(str(folder), self.get_suitable_cache_subpath(py_file))

    def ensure_cache_path(self):
        os.makedirs(self._cache_path, mode=0o700, exist_ok=True)

    def get_source_stamp(self):
        own = super().get_source_stamp()
        return (own, package_digest(os.path.dirname(os.path.abspath(self._py_file))))

    @classmethod
    def from_function(cls, py_func, py_file):
        folder, key = folder_and_key()
        if folder is None or key is None or not os.path.isfile(py_file):
            return None
        return cls(py_func, py_file)


class _CheckedImpl(_caching.CompileResultCacheImpl):
    _locator_classes = [_CheckedLocator]


class _CheckedFile(_caching.IndexDataCacheFile):
    """numba's index and data files, signed when written and checked before they are unpickled."""

    def __init__(self, cache_path, filename_base, source_stamp, folder: Path, key: bytes):
        super().__init__(cache_path=cache_path, filename_base=filename_base, source_stamp=source_stamp)
        self._folder, self._key = folder, key

    def _mac(self, path: str, payload: bytes) -> bytes:
        name = os.path.relpath(path, self._folder).encode()
        return hmac.new(self._key, name + b"\0" + payload, hashlib.sha256).digest()

    def _read(self, path: str) -> bytes | None:
        """The payload of a signed file; None when missing or refused (with a warning)."""
        try:
            fd = os.open(path, os.O_RDONLY | _NOFOLLOW)
        except FileNotFoundError:
            return None
        except OSError as exc:
            return _refuse(path, f"cannot be read ({exc.strerror or exc})")
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                return _refuse(path, "is not a regular file")
            data = fh.read()
        head = len(MAGIC) + _MAC
        if not data.startswith(MAGIC) or len(data) <= head:
            return _refuse(path, "is not a kernel cache file lanegraph wrote (or it is cut short)")
        mac, payload = data[len(MAGIC) : head], data[head:]
        if not hmac.compare_digest(mac, self._mac(path, payload)):
            return _refuse(
                path, "does not carry lanegraph's signature (altered, or written by another program)"
            )
        return payload

    def _write(self, path: str, payload: bytes) -> None:
        write_bytes_atomic(Path(path), MAGIC + self._mac(path, payload) + payload, mode=0o600)

    def _load_index(self):
        payload = self._read(self._index_path)
        if payload is None:
            return {}
        try:
            version, stamp, overloads = pickle.loads(payload)
        except Exception as exc:  # noqa: BLE001 - signed but unreadable: compiled again
            _refuse(self._index_path, f"cannot be read back ({type(exc).__name__})")
            return {}
        if version != self._version or stamp != self._source_stamp or not isinstance(overloads, dict):
            return {}
        return overloads

    def _save_index(self, overloads):
        self._write(self._index_path, self._dump((self._version, self._source_stamp, overloads)))

    def _load_data(self, name):
        path = self._data_path(name)
        payload = self._read(path)
        if payload is None:
            raise OSError(f"{path}: refused")  # numba's load() then returns None: compiled again
        try:
            return pickle.loads(payload)
        except Exception as exc:  # noqa: BLE001
            _refuse(path, f"cannot be read back ({type(exc).__name__})")
            raise OSError(f"{path}: refused") from exc

    def _save_data(self, name, data):
        self._write(self._data_path(name), self._dump(data))


def _refuse(path: str, why: str) -> None:
    """Warn, once per process (the first file refused is named: after an upgrade every file of the
    older format is refused alike), that a file is passed over."""
    warn_once("refused", f"kernel cache file {path} {why}: the kernel is compiled again (and saved over it)")
    return None


class CheckedCache(_caching.FunctionCache):
    """numba's function cache over :class:`_CheckedFile` in lanegraph's kernel folder (the module's
    text). RuntimeError when there is no usable folder."""

    _impl_class = _CheckedImpl

    def __init__(self, py_func):
        folder, key = folder_and_key()
        if folder is None or key is None:
            raise RuntimeError("no kernel folder")
        super().__init__(py_func)
        if not isinstance(self._impl.locator, _CheckedLocator):  # NUMBA_CACHE_LOCATOR_CLASSES
            raise RuntimeError("numba's cache locators are overridden")
        self._cache_file = _CheckedFile(
            self._cache_path, self._impl.filename_base, self._cache_file._source_stamp, folder, key
        )

    def load_overload(self, sig, target_context):
        """The kernel for ``sig`` from the kernel folder, else from its plugin's bundle (then saved to
        the folder: :func:`lanegraph.kernels.bundle.load`); None: numba compiles it."""
        cres = None
        if not _STATE["off"]:
            try:
                cres = super().load_overload(sig, target_context)
            except Exception as exc:  # noqa: BLE001 - a signed entry numba cannot rebuild: compiled again
                warn_once(
                    f"load:{self._cache_path}", f"kernel cache {self._cache_path}: {exc}: compiled again"
                )
        if cres is None:
            try:
                target_context.refresh()  # numba's runtime and registries, as its cache's load does
                made = bundle.load(self._py_func, sig, target_context)
            except Exception as exc:  # noqa: BLE001 - a bundle entry numba cannot rebuild: compiled
                warn_once(
                    f"bundle:{self._cache_path}", f"kernel bundle entry of {self._name}: {exc}: compiled"
                )
                made = None
            if made is not None:
                cres, payload = made
                self.save_payload(sig, target_context.codegen(), payload)
        return cres

    def save_payload(self, sig, codegen, payload: tuple) -> None:
        """Save what numba's cache keeps of a kernel (a bundle's entry: the library as object code)
        for ``sig`` to the kernel folder, as :meth:`save_overload` saves a compiled one."""
        if _STATE["off"]:
            return
        try:
            self._impl.locator.ensure_cache_path()
            self._cache_file.save(self._index_key(sig, codegen), payload)
        except OSError as exc:
            self._go_without(exc)

    def save_overload(self, sig, data):
        if _STATE["off"]:
            return
        try:
            super().save_overload(sig, data)
        except OSError as exc:
            self._go_without(exc)

    def _go_without(self, exc: OSError) -> None:
        """A full disk, a folder made read-only: the run goes on without a kernel cache, saying so."""
        _STATE["off"] = True
        warn_once(
            "off",
            f"kernel cache {self._cache_path}: cannot be written ({exc.strerror or exc}): "
            "running without a kernel cache (the kernels compile again in the next run)",
        )


def attach(dispatcher) -> bool:
    """Give a numba dispatcher lanegraph's checked disk cache; False (the dispatcher keeps numba's
    no-op cache: compiled in every process) without a usable kernel folder."""
    try:
        dispatcher._cache = CheckedCache(dispatcher.py_func)
    except (RuntimeError, OSError):
        return False
    return True


__all__ = ["CheckedCache", "KernelCacheWarning", "MAGIC", "attach", "folder_and_key"]
