"""Choosing and opening the source node that reads an input, for any installed source.

The engine knows no input layout. A graph's source node either reads the input itself, or stands
for other sources (the ``select_source`` capability of its class, see :mod:`lanegraph.nodes`): it
names the source node type that reads the input, helped by every plugin's
``lanegraph_detect_source`` hook. :func:`select_source` applies that capability (the executor, the
report and the batch planner use it); :func:`open_source` opens a source on an input outside a run
(the report's left images, a calibration read for ``lanegraph eval``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import GraphError, LanegraphError, NodeError, Problem
from ..lifecycle import close, closing, constants_of
from ..nodes import NodeParams, NodeType, RunContext
from ..plugins import PluginManager, call_hook


def select_source(
    pm: PluginManager,
    node_type: NodeType,
    params: NodeParams,
    input_path: Path | None,
    *,
    file: str | None = None,
    node: str | None = None,
) -> NodeType:
    """The source node type that runs for a source node of ``node_type`` with ``params`` on
    ``input_path`` (``None``: no ``--input``): ``node_type`` itself, or the type its
    ``select_source`` names. Raises a :class:`GraphError` located at ``file`` / ``node`` when
    none fits or the named type is not an installed source."""
    if not node_type.selects_source:
        return node_type
    detect = lambda path: call_hook(pm, "lanegraph_detect_source", path=path)  # noqa: E731
    try:
        name = node_type.func.select_source(params, input_path, detect)
    except ValueError as exc:
        raise GraphError([Problem(str(exc), file=file, node=node, node_type=node_type.name)]) from None
    chosen = pm.get_node_type(name) if isinstance(name, str) else None
    if chosen is None or not chosen.source:
        raise GraphError([Problem(f"source node type {name!r} is not installed", file=file, node=node)])
    return chosen


def chosen_params(
    chosen: NodeType, params: NodeParams, *, file: str | None = None, node: str | None = None
) -> NodeParams:
    """The params the source ``chosen`` by a selecting source runs with: its defaults, and every
    field the selecting source's ``params`` set explicitly (in the graph) that ``chosen``'s params
    have too (``io.auto``'s ``read_ahead`` for a KITTI or folder source); a field the chosen type
    does not have, or set to the selecting source's own default, is not passed. Raises a :class:`GraphError` located at ``file`` / ``node`` and
    the field when the chosen type refuses a value."""
    from pydantic import ValidationError

    from ..graph.validation import _pydantic_problems

    fields, own = chosen.params.model_fields, type(params).model_fields
    # a value equal to the selecting source's own default is no choice (a resolved graph spells every
    # param out, and must run as the graph it was resolved from)
    shared = {
        k: getattr(params, k)
        for k in sorted(params.model_fields_set)
        if k in fields and not (k in own and getattr(params, k) == own[k].default)
    }
    try:
        return chosen.params(**shared)
    except ValidationError as exc:
        raise GraphError(_pydantic_problems(exc, file or "", node, chosen.name, "params")) from None


def default_selector(pm: PluginManager) -> NodeType | None:
    """An installed source that selects the source for an input (the first by name), for a
    command that reads an input without a graph; None when no installed source does."""
    return next((nt for nt in pm.node_types.values() if nt.selects_source), None)


def detect_source(pm: PluginManager, input_path: Path | None) -> NodeType | None:
    """The source for ``input_path`` outside a graph: the type a plugin's
    ``lanegraph_detect_source`` names for it, or (no input, or none named) what an installed
    selecting source chooses with its default params; None when nothing reads it."""
    name = call_hook(pm, "lanegraph_detect_source", path=input_path) if input_path is not None else None
    if name is not None:
        nt = pm.get_node_type(name)
        return nt if nt is not None and nt.source else None
    selector = default_selector(pm)
    if selector is None:
        return None
    try:
        return select_source(pm, selector, selector.params(), input_path)
    except GraphError:
        return None


def open_source(
    node_type: NodeType,
    params: NodeParams,
    input_path: Path | None,
    frames: slice | None = None,
    node_id: str = "src",
) -> Any:
    """An instance of source ``node_type`` on ``input_path`` (``frames`` selected); close it when
    done. Raises what opening raises (a :class:`LanegraphError` such as an unusable input), any
    other exception as a :class:`NodeError`."""
    ctx = RunContext(input_path=input_path, frames=frames, node_id=node_id)
    try:
        return node_type.func(params, ctx)
    except LanegraphError:
        raise
    except Exception as exc:  # noqa: BLE001 - a third-party source's bug, located
        raise NodeError(node_id, node_type.name, None, exc) from exc


def close_source(instance: Any, node_type: NodeType | None = None) -> None:
    """Close a source of ``node_type`` opened by :func:`open_source` (:func:`lanegraph.lifecycle.close`)."""
    close(instance, node_type)


def read_calibration(pm: PluginManager, path: Path) -> Any:
    """The :class:`~lanegraph.types.Calibration` of ``path``: of an input folder, the constant
    ``calibration`` output of the source that reads it; of a file, what a plugin's
    ``lanegraph_read_calibration`` reads. Raises an :class:`~lanegraph.errors.InputError` naming
    the path when nothing installed reads it, or the one a plugin raised for a malformed file of its
    format (a plugin's other errors are :class:`~lanegraph.errors.HookError` naming it)."""
    from ..errors import HookError, InputError

    path = Path(path)
    if not path.is_dir():
        if not path.is_file():
            raise InputError("calibration file not found", path=str(path))
        try:
            calib = call_hook(pm, "lanegraph_read_calibration", path=path)
        except HookError as exc:  # a file of the plugin's format that is malformed: its InputError as it is
            if isinstance(exc.cause, InputError):
                raise exc.cause from None
            raise
        if calib is None:
            raise InputError(
                "no installed plugin reads this calibration file (by its format)", path=str(path)
            )
        return calib
    nt = detect_source(pm, path)
    port = (
        next(
            (name for name, p in nt.outputs.items() if p.type == "calibration" and p.rate == "constant"), None
        )
        if nt
        else None
    )
    if nt is None or port is None:
        raise InputError("no installed source reads a calibration from this folder", path=str(path))
    with closing(open_source(nt, nt.params(), path), nt) as source:
        consts = constants_of(source, nt)
    if consts.get(port) is None:
        raise InputError(f"source {nt.name!r} gives no calibration for this folder", path=str(path))
    return consts[port]
