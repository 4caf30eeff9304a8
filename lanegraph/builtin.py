"""lanegraph's built-in graph and dataset files, found from any folder.

The repository keeps them in ``graphs/`` at its root; the wheel installs the same files as
``lanegraph/graphs/`` (``setup.py`` copies them in at build time). :func:`graphs_dir` is whichever
of the two this lanegraph has: the installed copy, else the checkout's folder (an editable install).

A graph argument (``lanegraph run paper``, ``ablations/slt``) is a file path, else a name looked up
in ``./graphs`` and then among the built-in graphs (:func:`find_graph`); ``extends: paper.yaml`` in a
user's own graph falls back to the built-in file of that name (:func:`builtin_base`).
"""

from __future__ import annotations

import re
from pathlib import Path

from .errors import GraphError, Problem, did_you_mean

_PACKAGE = Path(__file__).resolve().parent


def graphs_dir() -> Path:
    """The folder of the built-in graphs: ``lanegraph/graphs`` in an installed wheel, ``graphs/`` at
    the root of a checkout."""
    installed = _PACKAGE / "graphs"
    if (installed / "paper.yaml").is_file():
        return installed
    return _PACKAGE.parent / "graphs"


def graph_names(kind: str = "graphs") -> list[str]:
    """The built-in names, sorted: graphs (``paper``, ``ablations/slt``) or, with ``kind="datasets"``,
    dataset files (``datasets/dev``), with ``kind="spaces"`` the search spaces of ``lanegraph tune``
    (``spaces/paper``); each usable wherever a graph, dataset or space file is expected."""
    root = graphs_dir()
    if not root.is_dir():
        return []
    names = []
    for p in root.rglob("*.yaml"):
        rel = p.relative_to(root).with_suffix("").as_posix()
        top = rel.split("/")[0] if "/" in rel else ""
        if top == kind or (kind == "graphs" and top not in ("datasets", "spaces")):
            names.append(rel)
    return sorted(names)


def describe(path: Path) -> str:
    """The first sentence of a graph or dataset file's ``description`` (or ``doc``), whole; '' if none."""
    import yaml

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return ""
    text = ""
    if isinstance(data, dict):
        text = str(data.get("description") or data.get("doc") or "")
    text = " ".join(text.split())
    m = re.search(r"(?<=[.!?])\s+(?=[A-Z(`])", text)
    return text[: m.start()] if m else text  # the first sentence, whole


def find_graph(name: str) -> Path:
    """A graph argument as a file: the path itself, else ``graphs/NAME[.yaml]`` in the current folder,
    else the built-in graph of that name. A name that is none of these is a :class:`GraphError` with
    the closest built-in name (``did you mean 'paper'?``)."""
    p = Path(name)
    if p.is_file():
        return p
    for base in (Path("graphs"), graphs_dir()):
        for cand in (base / name, base / f"{name}.yaml"):
            if cand.is_file():
                return cand
    builtin = _as_builtin(p)  # graphs/paper.yaml, as a checkout's docs write it, from any folder
    if builtin is not None:
        return builtin
    try:
        a_path = (
            p.is_absolute()
            or p.suffix.lower() in (".yaml", ".yml", ".json", ".toml")
            or p.exists()
            or p.is_symlink()
            or (p.parent != Path(".") and p.parent.is_dir())
        )
    except (OSError, ValueError):  # a NUL byte, a name too long
        a_path = True
    names = graph_names()
    if a_path:
        guess = _builtin_name(p)
        hint = did_you_mean(guess, names) if guess and not p.exists() else None
        if hint and not p.is_symlink():
            raise GraphError(
                [Problem("graph file not found", file=name, hint=f"{hint}; `lanegraph graphs` lists them")]
            )
        return p  # a file's path: reported where it is by the loader (not found, a folder, a link loop)
    hint = did_you_mean(name, names, listing="built-in graphs") or ""
    raise GraphError(
        [
            Problem(
                f"no graph file and no built-in graph named {name!r}",
                file=name,
                hint=f"{hint}; `lanegraph graphs` lists them" if hint else "`lanegraph graphs` lists them",
            )
        ]
    )


def _builtin_name(p: Path) -> str | None:
    """The built-in name a path may mean: ``graphs/paper.yaml`` -> ``paper``."""
    parts = p.with_suffix("").parts if p.suffix.lower() in (".yaml", ".yml") else p.parts
    if parts and parts[0] == "graphs":
        parts = parts[1:]
    if not parts or p.is_absolute() or ".." in parts:
        return None
    return "/".join(parts)


def _as_builtin(p: Path) -> Path | None:
    """The built-in file a ``graphs/...`` path names where the current folder has none."""
    if p.is_absolute() or len(p.parts) < 2 or p.parts[0] != "graphs" or ".." in p.parts:
        return None
    rel = Path(*p.parts[1:])
    for cand in (graphs_dir() / rel, graphs_dir() / f"{rel}.yaml"):
        if cand.is_file():
            return cand
    return None


def find_dataset(name: str | Path) -> Path:
    """A dataset argument as a file: the path itself, else a built-in dataset file
    (``datasets/kitti_lanes``, ``graphs/datasets/kitti_lanes.yaml``), else the path as given (its
    reader says it is not found, with the closest built-in name)."""
    p = Path(name)
    if p.is_file():
        return p
    for cand in (graphs_dir() / p, graphs_dir() / f"{p}.yaml"):
        if not p.is_absolute() and ".." not in p.parts and cand.is_file():
            return cand
    return _as_builtin(p) or p


def builtin_base(ext: str) -> Path | None:
    """The built-in graph an ``extends: EXT`` names when no file ``EXT`` lies beside the graph
    (``extends: paper.yaml`` in a user's own folder), resolved; None when there is none."""
    rel = Path(ext)
    if rel.is_absolute() or ".." in rel.parts:
        return None
    root = graphs_dir()
    for cand in (root / rel, root / f"{ext}.yaml"):
        try:
            if cand.is_file():
                return cand.resolve()
        except OSError:
            return None
    return None


__all__ = ["builtin_base", "describe", "find_graph", "graph_names", "graphs_dir"]
