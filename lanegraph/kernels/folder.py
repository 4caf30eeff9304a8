"""Where compiled kernels may be kept: a folder the user owns and no one else can write to.

The kernel folder is ``$NUMBA_CACHE_DIR`` or ``$LANEGRAPH_KERNEL_CACHE`` when set, else
``<user cache>/lanegraph/kernels`` (``$XDG_CACHE_HOME``, else ``$HOME/.cache``). It is never under
``$LANEGRAPH_CACHE_DIR``: a results cache may be shared between users, and machine code loaded from
it would run as whoever reads it. A folder is used only when it is a folder (links followed) owned
by this user that no one else can write to (lanegraph takes the group's and others' write bits off
a folder of the user's own); else, and with ``HOME`` empty or ``/`` and no ``XDG_CACHE_HOME``, the
kernels are compiled in every process, with a warning (:func:`kernel_folder` returns None).

This module imports no numba; a file in such a folder is written by
:func:`lanegraph.paths.write_bytes_atomic` with mode ``0o600``, never through a link.
"""

from __future__ import annotations

import os
import stat
import warnings
from pathlib import Path

#: the reason the last :func:`kernel_folder` call found none (for the notice and the tests)
_REFUSED: dict[str, str] = {}


class KernelCacheWarning(UserWarning):
    """A kernel cache folder or file was refused or could not be written: the kernels are compiled
    (or the run goes on without keeping them)."""


def user_cache_home() -> Path | None:
    """``$XDG_CACHE_HOME``, else ``$HOME/.cache`` (the password database's home when ``HOME`` is
    unset); None when neither is an absolute path other than ``/`` (never a cache at the root)."""
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    if os.path.isabs(xdg) and os.path.normpath(xdg) != "/":
        return Path(xdg)
    home = os.path.expanduser("~")
    if not os.path.isabs(home) or os.path.normpath(home) == "/":
        return None
    return Path(home) / ".cache"


def cache_root() -> Path:
    """lanegraph's results cache folder (``$LANEGRAPH_CACHE_DIR``, default ``~/.cache/lanegraph``);
    it never holds kernels."""
    if os.environ.get("LANEGRAPH_CACHE_DIR"):
        return Path(os.environ["LANEGRAPH_CACHE_DIR"])
    home = user_cache_home()
    return (home if home is not None else Path(os.path.expanduser("~")) / ".cache") / "lanegraph"


def private_folder_problem(folder: Path, create: bool = True) -> str | None:
    """Why ``folder`` may not hold machine code (None when it may): not a folder, another user's,
    or writable by others. Creates it (mode 0700) when missing and ``create``; takes the group's and
    others' write bits off a folder of this user's own."""
    try:
        if create:
            folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = os.stat(folder)
    except OSError as exc:
        return f"cannot be made or read ({exc.strerror or exc})"
    if not stat.S_ISDIR(st.st_mode):
        return "is not a folder"
    if st.st_uid != os.geteuid():
        return f"belongs to another user (uid {st.st_uid})"
    if st.st_mode & 0o022:
        try:
            os.chmod(folder, stat.S_IMODE(st.st_mode) & ~0o022)
        except OSError as exc:
            return f"is writable by others and cannot be changed ({exc.strerror or exc})"
    return None


def kernel_folder(warn: bool = True) -> Path | None:
    """The folder numba keeps lanegraph's compiled kernels in (see the module's text), or None when
    there is none that may hold machine code (a warning then says why, once per process)."""
    for var in ("NUMBA_CACHE_DIR", "LANEGRAPH_KERNEL_CACHE"):
        if os.environ.get(var):
            folder, named = Path(os.environ[var]), f"${var}"
            break
    else:
        home = user_cache_home()
        if home is None:
            return _refuse(None, "HOME is empty (or /) and XDG_CACHE_HOME is not set", warn)
        folder, named = home / "lanegraph" / "kernels", "the user cache"
    if not folder.is_absolute():
        return _refuse(folder, f"{named} is not an absolute path", warn)
    problem = private_folder_problem(folder)
    if problem:
        return _refuse(folder, f"{named} {folder} {problem}", warn)
    return folder


def _refuse(folder: Path | None, why: str, warn: bool) -> None:
    if warn and why not in _REFUSED.values():
        warnings.warn(
            f"no kernel cache: {why}; the numba kernels are compiled in every run "
            "(set LANEGRAPH_KERNEL_CACHE to a folder of your own)",
            KernelCacheWarning,
            stacklevel=3,
        )
    _REFUSED["last"] = why
    return None


__all__ = [
    "KernelCacheWarning",
    "cache_root",
    "kernel_folder",
    "private_folder_problem",
    "user_cache_home",
]
