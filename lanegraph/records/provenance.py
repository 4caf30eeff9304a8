"""How a result was made, recorded beside it: the resolved graph (``OUT/graph.yaml``), the command
line, the versions of everything that computed it, and the git commit of the graph's checkout.

- :func:`write_resolved_graph`: the graph after ``extends`` and every ``--set``, every param spelt
  out, as a graph file that runs as it is (``lanegraph run OUT/graph.yaml --input SAME`` gives the
  same lanes, byte for byte).
- :func:`versions`: Python, lanegraph, every plugin distribution loaded, NumPy, OpenCV, numba, and
  ONNX Runtime and Dask where the run used them (imported by then).
- :func:`git_commit`: the commit checked out where the graph file lies, read from the ``.git``
  files themselves: git is never run there (a repository's configuration can run programs).
"""

from __future__ import annotations

import os
import platform
import re
import stat
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

import yaml

from .._version import __version__
from ..paths import write_text_atomic

GRAPH_NAME = "graph.yaml"
#: libraries whose versions a record names when they are loaded: (module, name in the record)
_LIBRARIES = (
    ("numpy", "numpy"),
    ("cv2", "opencv"),
    ("numba", "numba"),
    ("scipy", "scipy"),
    ("onnxruntime", "onnxruntime"),
    ("dask", "dask"),
    ("distributed", "distributed"),
    ("mlflow", "mlflow"),
)
_ALWAYS = ("numpy", "cv2", "numba")
_SHA = re.compile(r"^[0-9a-f]{40}([0-9a-f]{24})?$")


def resolved_graph_yaml(resolved: dict[str, Any]) -> str:
    """A resolved graph (:meth:`lanegraph.graph.Graph.resolved_dict`) as graph-file YAML, with a
    comment saying what it is."""
    head = (
        "# The resolved graph of this run: extends and every --set applied, every param spelt out.\n"
        "# Runs as it is: lanegraph run graph.yaml --input <the same input> gives the same lanes.\n"
    )
    return head + yaml.safe_dump(resolved, sort_keys=False, allow_unicode=True, width=100)


def write_resolved_graph(folder: Path, resolved: dict[str, Any]) -> Path:
    """Write ``folder/graph.yaml`` (atomically, the umask's mode); returns its path."""
    path = Path(folder) / GRAPH_NAME
    write_text_atomic(path, resolved_graph_yaml(resolved))
    return path


def _version(module: Any, dist: str | None = None) -> str | None:
    v = getattr(module, "__version__", None)
    if isinstance(v, str):
        return v
    if dist:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return None
    return None


def plugin_distributions(pm: Any) -> dict[str, str]:
    """``{distribution: version}`` of the plugins ``pm`` has loaded (lanegraph's own included)."""
    out: dict[str, str] = {}
    dists = getattr(pm, "_dists", {})
    for name, _plugin in pm.list_name_plugin():
        dist = dists.get(name)
        if not dist or dist == "?" or dist in out:
            continue
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "unknown"
    return dict(sorted(out.items()))


def versions(pm: Any = None) -> dict[str, Any]:
    """The versions of what computed a result: ``python``, ``platform``, ``lanegraph``, the
    libraries (NumPy, OpenCV and numba always; ONNX Runtime, Dask, MLflow ... when loaded), and
    ``plugins``: every plugin distribution ``pm`` loaded."""
    out: dict[str, Any] = {
        "python": platform.python_version(),
        "platform": platform.platform(terse=True),
        "lanegraph": __version__,
    }
    for module, name in _LIBRARIES:
        mod = sys.modules.get(module)
        if mod is None and module in _ALWAYS:
            try:
                mod = __import__(module)
            except ImportError:
                mod = None
        if mod is not None:
            out[name] = (
                _version(mod, {"cv2": "opencv-contrib-python-headless"}.get(module, module)) or "unknown"
            )
    if pm is not None:
        out["plugins"] = plugin_distributions(pm)
    return out


#: the command line the ``lanegraph`` command was given (set by it: ``sys.argv`` is not it when the
#: command is invoked from Python, by a test runner say)
_INVOKED: list[str] | None = None


def set_command_line(args: list[str]) -> None:
    """Record the arguments the ``lanegraph`` command was invoked with (its first argument on)."""
    global _INVOKED
    _INVOKED = ["lanegraph", *args]


def command_line(argv: list[str] | None = None) -> list[str]:
    """The command as typed: ``lanegraph`` and its arguments (the program's path shortened)."""
    args = list((_INVOKED or sys.argv) if argv is None else argv)
    if args:
        prog = Path(args[0]).name
        args[0] = "lanegraph" if prog in ("lanegraph", "__main__.py", "-m") else prog
    return args


#: the largest ``.git`` file read (``HEAD``, a ref, ``commondir``, a ``.git`` file); ``packed-refs``
_SMALL, _PACKED = 64 * 1024, 4 * 1024 * 1024
_KINDS = {stat.S_IFIFO: "a FIFO", stat.S_IFCHR: "a device", stat.S_IFBLK: "a device",
          stat.S_IFSOCK: "a socket", stat.S_IFDIR: "a folder"}  # fmt: skip


class _Skipped(Exception):
    """A ``.git`` file that is not read: not a regular file, too large, not UTF-8 text."""


def _read_small(path: Path, limit: int = _SMALL) -> str | None:
    """The text of the regular file ``path`` (a link followed), read as bytes up to ``limit`` and
    decoded as UTF-8; None when it is not there. Never blocks (a FIFO), never reads a device
    (``/dev/zero``) or more than ``limit``: :class:`_Skipped` says why."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    if not stat.S_ISREG(st.st_mode):
        raise _Skipped(f"{path}: {_KINDS.get(stat.S_IFMT(st.st_mode), 'not a regular file')}, not read")
    if st.st_size > limit:
        raise _Skipped(f"{path}: {st.st_size} bytes, more than the {limit} read")
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):  # replaced since: not read
            raise _Skipped(f"{path}: not a regular file, not read")
        data = os.read(fd, limit + 1)
    except OSError:
        return None
    finally:
        os.close(fd)
    if len(data) > limit:
        raise _Skipped(f"{path}: more than the {limit} bytes read")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise _Skipped(f"{path}: not UTF-8 text, not read") from None


def _git_dir(start: Path) -> Path | None:
    """The git folder of the checkout holding ``start`` (``.git``, or the folder a ``.git`` file
    of a worktree or submodule names), or None."""
    for folder in [start, *start.parents]:
        dot = folder / ".git"
        try:
            if dot.is_dir():
                return dot
            if dot.exists():
                text = (_read_small(dot) or "").strip()
                if text.startswith("gitdir:"):
                    target = Path(text[len("gitdir:") :].strip())
                    return target if target.is_absolute() else (folder / target)
                return None
        except (OSError, ValueError):
            return None
    return None


def _read_ref(git_dir: Path, common: Path, ref: str) -> str | None:
    for base in (git_dir, common):
        value = (_read_small(base / ref) or "").strip()
        if _SHA.match(value):
            return value
    for line in (_read_small(common / "packed-refs", _PACKED) or "").splitlines():  # "<sha> <ref>"
        parts = line.split()
        if len(parts) == 2 and parts[1] == ref and _SHA.match(parts[0]):
            return parts[0]
    return None


def git_commit(path: Path) -> dict[str, str] | None:
    """``{"commit": sha, "branch": name}`` (no ``branch`` on a detached head) of the git checkout
    holding ``path``, read from its ``.git`` files (git is not run); None outside a checkout or
    when the files are not there. The files are read only when they are regular files, small and
    UTF-8 text (never a FIFO, a device or a huge file): otherwise ``{"skipped": why}``, a note of
    the record, and the run goes on."""
    try:
        start = Path(path).resolve()
    except (OSError, RuntimeError):
        return None
    try:
        return _commit(start)
    except _Skipped as exc:
        return {"skipped": f"{exc}: the graph's git commit is not recorded"}


def _commit(start: Path) -> dict[str, str] | None:
    git_dir = _git_dir(start if start.is_dir() else start.parent)
    if git_dir is None:
        return None
    common = git_dir
    cd = (_read_small(git_dir / "commondir") or "").strip()
    if cd:
        common = Path(cd) if os.path.isabs(cd) else (git_dir / cd)
    head = (_read_small(git_dir / "HEAD") or "").strip()
    if not head:
        return None
    if _SHA.match(head):
        return {"commit": head}
    if head.startswith("ref:"):
        ref = head[4:].strip()
        if not ref.startswith("refs/") or ".." in ref:
            return None
        sha = _read_ref(git_dir, common, ref)
        if sha is not None:
            return {"commit": sha, "branch": ref.removeprefix("refs/heads/")}
    return None
