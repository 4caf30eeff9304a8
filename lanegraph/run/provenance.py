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


def _git_dir(start: Path) -> Path | None:
    """The git folder of the checkout holding ``start`` (``.git``, or the folder a ``.git`` file
    of a worktree or submodule names), or None."""
    for folder in [start, *start.parents]:
        dot = folder / ".git"
        try:
            if dot.is_dir():
                return dot
            if dot.is_file():
                text = dot.read_text(encoding="utf-8", errors="replace")[:4096].strip()
                if text.startswith("gitdir:"):
                    target = Path(text[len("gitdir:") :].strip())
                    return target if target.is_absolute() else (folder / target)
                return None
        except OSError:
            return None
    return None


def _read_ref(git_dir: Path, common: Path, ref: str) -> str | None:
    for base in (git_dir, common):
        try:
            value = (base / ref).read_text(encoding="utf-8").strip()
            if _SHA.match(value):
                return value
        except (OSError, ValueError):
            pass
    try:  # packed refs: "<sha> <ref>" lines
        for line in (common / "packed-refs").read_text(encoding="utf-8").splitlines():
            parts = line.split()
            if len(parts) == 2 and parts[1] == ref and _SHA.match(parts[0]):
                return parts[0]
    except OSError:
        pass
    return None


def git_commit(path: Path) -> dict[str, str] | None:
    """``{"commit": sha, "branch": name}`` (no ``branch`` on a detached head) of the git checkout
    holding ``path``, read from its ``.git`` files (git is not run); None outside a checkout or
    when the files are not readable."""
    try:
        start = Path(path).resolve()
    except (OSError, RuntimeError):
        return None
    git_dir = _git_dir(start if start.is_dir() else start.parent)
    if git_dir is None:
        return None
    common = git_dir
    try:
        cd = (git_dir / "commondir").read_text(encoding="utf-8").strip()
        common = Path(cd) if os.path.isabs(cd) else (git_dir / cd)
    except OSError:
        pass
    try:
        head = (git_dir / "HEAD").read_text(encoding="utf-8").strip()
    except OSError:
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
