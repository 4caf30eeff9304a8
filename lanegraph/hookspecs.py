"""The lanegraph hook contract: every hook a plugin may implement.

Implementations may accept any subset of a hook's arguments, so hooks can gain
arguments without breaking plugins. Mark implementations with
``lanegraph.hookimpl``.
"""

from __future__ import annotations

from typing import Any

import pluggy

hookspec = pluggy.HookspecMarker("lanegraph")
hookimpl = pluggy.HookimplMarker("lanegraph")


@hookspec
def lanegraph_node_types() -> list[Any]:
    """Return the node types this plugin provides: functions and classes decorated with
    :func:`lanegraph.node_type` (or their :class:`~lanegraph.nodes.NodeType` records)."""


@hookspec
def lanegraph_port_types() -> list[Any]:
    """Return the port types this plugin adds (:class:`lanegraph.types.PortType`: a name, what a
    value of it is, and the parent type whose ports it may feed). Node types of any plugin may use
    them; a graph that wires a port of a type no installed plugin registers is invalid."""


@hookspec
def lanegraph_runners() -> list[Any]:
    """Return the runner types this plugin adds (:mod:`lanegraph.batches.runners`): classes with a
    ``name`` and a class method ``from_spec(text)`` that returns a runner -- an object with
    ``run(tasks, progress, echo, done)``, such as a :class:`lanegraph.api.BaseRunner` -- for a
    ``--scheduler`` text it understands, or None; one with ``fallback = True`` is asked last (the
    Dask runner, which takes any address). ``run --dataset`` and ``ablate`` run their units of work
    on it."""


@hookspec
def lanegraph_before_node(node_id: str, node_type: str, frame: str | None, inputs: dict[str, Any]) -> None:
    """Called right before a node processes a frame (for tracing and profiling)."""


@hookspec
def lanegraph_after_node(
    node_id: str,
    node_type: str,
    frame: str | None,
    outputs: dict[str, Any] | None,
    elapsed_ms: float,
    error: BaseException | None,
) -> None:
    """Called right after a node processed a frame, with its outputs and wall time in ms.

    ``error`` is None when the node succeeded (``outputs`` then holds what it returned, ``{}`` for
    a sink); when it raised, ``error`` is the exception and ``outputs`` None, whatever the node's
    error policy does next (so a tracing or caching plugin can tell a failure from an empty
    output). The source node (an iterator read ahead) fires only this hook: once with its
    constants (``frame`` None), once per frame, and with the error of a frame it could not read.
    Nodes that run once (constant inputs only) fire it with ``frame`` None.
    """


@hookspec
def lanegraph_run_start(graph: Any, context: Any) -> None:
    """Called once when a run starts, with the compiled graph and the run context."""


@hookspec
def lanegraph_run_end(graph: Any, context: Any, frames: int) -> None:
    """Called once when a run ends (also after a failure), with the number of frames processed."""


@hookspec(firstresult=True)
def lanegraph_render(node_type: str, port: str, value: Any) -> Any:
    """Render a node output as a BGR uint8 image for debugging; return None to decline."""


@hookspec(firstresult=True)
def lanegraph_detect_source(path: Any) -> str | None:
    """Return the name of the source node type that reads ``path`` (a folder or file), or None."""


@hookspec(firstresult=True)
def lanegraph_read_calibration(path: Any) -> Any:
    """Read the calibration file ``path`` if this plugin knows its format: a
    :class:`lanegraph.types.Calibration`, or None to decline. Raise an
    :class:`~lanegraph.errors.InputError` for a file of its format that is malformed."""


@hookspec
def lanegraph_trackers() -> list[Any]:
    """Return the experiment trackers this plugin provides, chosen with ``--track NAME[:URI]`` on
    ``run`` and ``ablate``: classes with a class attribute ``name`` (what ``--track`` calls them),
    made with the URI (or None) and implementing :class:`lanegraph.tracking.Tracker` (``start``
    before any frame, ``log_run`` per variant and sequence once evaluated, ``end``). Import the
    tracker's library in those methods only, so that the plugin costs nothing until asked for."""


@hookspec
def lanegraph_kernels() -> Any:
    """Return the path of this plugin's kernel list, a JSON file inside the plugin's package folder
    (``benchmarks/record_kernels.py`` writes it: module, name and argument types of each
    :func:`lanegraph.jit` kernel its nodes call, longest compilation first), or None. Their machine
    code may lie beside it with the suffix ``.bundle`` (``record_kernels.py`` writes it, for
    x86-64-v3 CPUs): a run loads each kernel from it when first called, where it fits this
    machine and the installed sources; the first run of an installation compiles ahead the default
    run's kernels no bundle holds (:mod:`lanegraph.kernels`). Entries naming a module outside the plugin's
    package, and a list outside its folder, are ignored."""


@hookspec(firstresult=True)
def lanegraph_write_report(
    run_dir: Any,
    out_dir: Any,
    dataset: Any,
    gt: Any,
    input_path: Any,
    frames: slice | None,
    sets: tuple[str, ...],
    debug_dir: Any,
    graph: Any,
    pm: Any,
    progress: bool,
) -> Any:
    """Write the report of ``run_dir`` (the output folder of ``lanegraph run`` or ``lanegraph
    ablate``) into ``out_dir`` (None: the plugin's default) and return its summary, an object with
    ``index`` (the page's path) and ``line()`` (the line the command says); or None to decline.
    What ``lanegraph report``, ``run --report`` and ``ablate --report`` call (``Session.report``);
    the built-in plugin ``lanegraph_report`` implements it.

    ``dataset`` (a dataset, or None), ``gt``, ``input_path``, ``frames``, ``sets``, ``debug_dir``:
    what the run was made with, as the command was given it; ``graph``: the validated graph that
    ran, or None; ``pm``: the plugin manager (the sources that read the images); ``progress``: say
    what it does on stderr. A :class:`~lanegraph.errors.LanegraphError` it raises (a
    :class:`~lanegraph.errors.UsageError`: the folder or the options do not fit) or an ``OSError``
    reaches the user as it is."""
