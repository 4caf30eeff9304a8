"""Result files: the files a run's sinks write that other commands read back.

The engine does not name them. A sink declares them (the ``result_files(params)`` capability of
its class, see :mod:`lanegraph.nodes`) by *kind*; a run records them in its folder's ``run.json``
(``"results": {kind: path relative to the folder}``), and ``lanegraph ablate``, ``eval
--dataset``, ``report`` and ``run --dataset`` find them there. A folder whose ``run.json`` names
none (a run of an older lanegraph, a folder written by hand) is searched for the default file of
every installed sink type that declares the kind.

Kinds the engine reads:

``lanes`` (:data:`LANES`)
    JSON lines, one record per frame as :func:`lanegraph.evaluation.metrics.read_predictions` reads them:
    ``{"frame": id, "lanes": [{"points": [[x, y], ...], "side": ..., "score": ...}, ...]}``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import UsageError
from ..paths import inside
from ..plugins import PluginManager, get_plugin_manager
from .record import read_record

#: the kind of the lanes a run reports, the predictions the metrics read
LANES = "lanes"


def graph_result_files(graph: Any) -> dict[str, str]:
    """``{kind: path relative to the output folder}`` of a validated graph's sinks (the first sink
    in execution order that declares a kind)."""
    out: dict[str, str] = {}
    for nid in graph.order:
        n = graph.nodes[nid]
        if n.type.sink and n.params is not None:
            for kind, path in n.type.result_files(n.params).items():
                out.setdefault(kind, path)
    return out


def recorded_result_files(folder: Path) -> dict[str, str]:
    """What ``folder/run.json`` records under ``results`` (empty when it records nothing)."""
    record = read_record(Path(folder))
    return dict(record.results) if record is not None else {}


def recorded_selection(folder: Path) -> tuple[str | None, list[str]] | None:
    """The frames the run in ``folder`` selected, as its ``run.json`` records them
    (``"selection": {"frames": "0:20", "ids": [frame ids]}``): ``(the --frames text, the ids)``;
    None when it records none (a run of an older lanegraph: every frame of the ground truth is
    scored). ``eval`` and ``report`` score exactly these frames."""
    record = read_record(Path(folder))
    if record is None or record.selection is None:
        return None
    return record.selection.frames or None, list(record.selection.ids)


def default_names(kind: str, pm: PluginManager | None = None) -> list[str]:
    """The files installed sink types write for ``kind`` with their default params."""
    pm = pm or get_plugin_manager()
    names: list[str] = []
    for nt in pm.node_types.values():
        if not nt.sink:
            continue
        try:
            path = nt.result_files(nt.params()).get(kind)
        except Exception:  # noqa: BLE001 - a sink whose params have no defaults declares nothing here
            continue
        if path and path not in names:
            names.append(path)
    return names


def find_result(
    folder: Path, kind: str = LANES, pm: PluginManager | None = None, record: Any = None
) -> Path | None:
    """The file of ``kind`` in run folder ``folder``: the one its ``run.json`` records (``record``:
    that record, when the caller has it), else the default file of an installed sink type; None
    when there is none. A recorded path that leads out of the folder is refused
    (:class:`~lanegraph.errors.UsageError`)."""
    folder = Path(folder)
    files = record.results if record is not None else recorded_result_files(folder)
    recorded = files.get(kind)
    if recorded is not None:
        path = inside(folder, recorded, f"{folder / 'run.json'}: results.{kind}")
        return path if path.is_file() else None
    for name in default_names(kind, pm):
        try:
            path = inside(folder, name, f"{folder}: {kind}")
        except UsageError:
            continue
        if path.is_file():
            return path
    return None


def describe(folder: Path, kind: str = LANES, pm: PluginManager | None = None) -> str:
    """How a run folder's ``kind`` file is looked for, for a message saying it is missing."""
    recorded = recorded_result_files(Path(folder)).get(kind)
    if recorded is not None:
        return f"{Path(folder) / recorded} (named by run.json)"
    names = default_names(kind, pm)
    if not names:
        return f"a {kind} file (no installed sink declares one)"
    return " or ".join(str(Path(folder) / n) for n in names)
