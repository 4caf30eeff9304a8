"""The plugin manager and the registry of node types.

Plugins are discovered through the entry-point group ``lanegraph.plugins``; the
built-in plugins under ``plugins/`` are registered exactly like third-party ones.

Environment variables
---------------------
``LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD=1``
    Load only the plugins shipped with lanegraph itself (no third-party ones).
``LANEGRAPH_PLUGINS=name,name``
    Allowlist: load only these entry points (by entry-point or distribution name);
    the built-in ones are always loaded.
``LANEGRAPH_TRACE_HOOKS=1``
    Print every hook call to stderr.
"""

from __future__ import annotations

import inspect
import os
import re
import sys
from dataclasses import dataclass
from importlib import metadata
from typing import Any

import pluggy

from . import hookspecs
from .errors import did_you_mean
from .nodes import NodeType, node_type_of
from .types import PortType

ENTRY_POINT_GROUP = "lanegraph.plugins"
BUILTIN_DISTRIBUTION = "lanegraph"
#: the name of the plugin that registers lanegraph's own port types
BUILTIN_PLUGIN = "lanegraph"
#: the hooks a plugin may implement
HOOK_NAMES = sorted(n for n in dir(hookspecs) if n.startswith("lanegraph_"))
_PORT_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class PluginError:
    """A plugin the host runs without: it failed to import, implements a hook that has no spec,
    its registration hook raised, or it provides a node type or port type another plugin already
    provides. ``node_types``: the node types it holds, where known (a graph that uses one is told
    why it is missing)."""

    plugin: str
    distribution: str
    error: str
    hint: str = ""
    node_types: tuple[str, ...] = ()

    @property
    def entry_point(self) -> str:
        return self.plugin

    def __str__(self) -> str:
        dist = f" from distribution {self.distribution!r}" if self.distribution else ""
        return f"plugin {self.plugin!r}{dist} {self.error}" + (f" (hint: {self.hint})" if self.hint else "")


#: the name of :class:`PluginError` before it covered more than import failures
PluginLoadError = PluginError


def _declared_node_types(plugin: Any) -> tuple[str, ...]:
    """The node types defined in (or imported into) a plugin module or class: the functions and
    classes with a :func:`~lanegraph.nodes.node_type` record among its attributes."""
    try:
        values = list(vars(plugin).values())
    except TypeError:
        return ()
    return tuple(sorted({nt.name for v in values if (nt := node_type_of(v)) is not None}))


class PluginManager(pluggy.PluginManager):
    """``pluggy.PluginManager("lanegraph")`` plus the registries of node types and port types.

    Discovery never crashes the host: a plugin that cannot be used is unregistered and recorded in
    :attr:`plugin_errors` (every command prints them as warnings), and the others go on.
    """

    def __init__(self) -> None:
        super().__init__("lanegraph")
        self.add_hookspecs(hookspecs)
        self.plugin_errors: list[PluginError] = []
        self._dists: dict[str, str] = {}
        self._node_types: dict[str, NodeType] | None = None
        self._port_types: dict[str, PortType] = {}
        from .presentation.port_types import BUILTIN_PORT_TYPES

        # lanegraph's own port types come through the same hook as a plugin's, registered first
        self.register(BUILTIN_PORT_TYPES, name=BUILTIN_PLUGIN)
        if os.environ.get("LANEGRAPH_TRACE_HOOKS"):
            self.trace.root.setwriter(lambda s: sys.stderr.write(s))
            self.enable_tracing()

    @property
    def load_errors(self) -> list[PluginError]:
        """:attr:`plugin_errors` (the name it had when only import failures were recorded)."""
        return self.plugin_errors

    def register(self, plugin: Any, name: str | None = None) -> str | None:
        """Register ``plugin``; a plugin implementing a hook that has no spec (a misspelt hook) is
        not registered: it is recorded in :attr:`plugin_errors` and None is returned."""
        self._node_types = None
        pname = super().register(plugin, name)
        if pname is None:
            return None
        problem = self._hook_problem(plugin)
        if problem is not None:
            super().unregister(plugin)
            self._reject(
                pname,
                problem,
                hint="the hooks are the functions of lanegraph.hookspecs",
                node_types=_declared_node_types(plugin),
            )
            return None
        return pname

    def unregister(self, plugin: Any = None, name: str | None = None) -> Any:  # noqa: D102
        self._node_types = None
        return super().unregister(plugin, name)

    def _hook_problem(self, plugin: Any) -> str | None:
        """Why ``plugin``'s hooks cannot be used: a hookimpl without a spec (with a did-you-mean),
        or a function named like a hook that is not marked with ``@lanegraph.hookimpl``."""
        for caller in self.get_hookcallers(plugin) or []:
            if caller.has_spec():
                continue
            if all(impl.optionalhook for impl in caller.get_hookimpls() if impl.plugin is plugin):
                continue
            hint = did_you_mean(caller.name, HOOK_NAMES, listing="hooks")
            return f"is not loaded: hook {caller.name!r} has no spec ({hint})"
        marked = {c.name for c in self.get_hookcallers(plugin) or []}
        for attr in dir(plugin):
            if attr in HOOK_NAMES and attr not in marked and inspect.isroutine(getattr(plugin, attr, None)):
                return f"is not loaded: its function {attr!r} is not marked with @lanegraph.hookimpl"
        return None

    def _reject(self, name: str, error: str, hint: str = "", node_types: tuple[str, ...] = ()) -> None:
        self.plugin_errors.append(PluginError(name, self._dists.get(name, ""), error, hint, node_types))

    def load_entrypoints(self, group: str = ENTRY_POINT_GROUP) -> None:
        """Load every plugin of ``group``, honouring the environment allowlist: lanegraph's own
        first, then the others by name (so a third-party plugin never displaces a built-in node
        type). A plugin that fails to import or cannot be used is recorded in :attr:`plugin_errors`.
        """
        no_autoload = os.environ.get("LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD", "") not in ("", "0")
        allow = {s.strip() for s in os.environ.get("LANEGRAPH_PLUGINS", "").split(",") if s.strip()}

        def dist_of(ep: Any) -> str:
            return ep.dist.name if ep.dist is not None else "?"

        eps = metadata.entry_points(group=group)
        for ep in sorted(eps, key=lambda e: (dist_of(e) != BUILTIN_DISTRIBUTION, e.name)):
            dist = dist_of(ep)
            builtin = dist == BUILTIN_DISTRIBUTION
            if not builtin and (no_autoload or (allow and ep.name not in allow and dist not in allow)):
                continue
            if self.get_plugin(ep.name) is not None or self.is_blocked(ep.name):
                continue
            self._dists[ep.name] = dist
            try:
                plugin = ep.load()
                self.register(plugin, name=ep.name)
            except Exception as exc:  # a broken plugin must not crash the host
                error = " ".join(f"{type(exc).__name__}: {exc}".split())  # pluggy's messages span lines
                hint = (
                    f"run `python -c 'import {ep.name}'` to see the full traceback, or set "
                    "LANEGRAPH_PLUGINS to load only the plugins you need"
                )
                self._reject(ep.name, f"failed to load: {error}", hint)
        self.node_types  # noqa: B018 - build the registries now: their errors are discovery's

    # -- registries -------------------------------------------------------------
    @property
    def node_types(self) -> dict[str, NodeType]:
        """All node types by name (computed once per set of registered plugins)."""
        if self._node_types is None:
            self._build()
        assert self._node_types is not None
        return self._node_types

    @property
    def port_types(self) -> dict[str, PortType]:
        """Every port type by name, each registered through ``lanegraph_port_types``: lanegraph's
        own (:mod:`lanegraph.presentation.port_types`, registered first) and the plugins'."""
        self.node_types  # noqa: B018 - built together
        return self._port_types

    def _build(self) -> None:
        """Collect the registries; a plugin whose registration hooks raise or clash is unregistered
        (and recorded), then the registries are collected again without it."""
        while True:
            ports, port_bad = self._collect_port_types()
            nodes, node_bad = self._collect_node_types(port_bad)
            bad = {**port_bad, **node_bad}
            if not bad:
                break
            for plugin, (error, node_types) in bad.items():
                name = self.get_name(plugin) or "?"
                super().unregister(plugin)
                self._reject(
                    name, f"is not loaded: {error}", node_types=node_types or _declared_node_types(plugin)
                )
        self._port_types = ports
        self._node_types = dict(sorted(nodes.items()))

    @staticmethod
    def _provided(impl: Any) -> list[Any]:
        """What a registration hookimpl returns, as a list (it raises what the hookimpl raises)."""
        provided = impl.function()
        if provided is None:
            return []
        if isinstance(provided, (str, bytes)) or not hasattr(provided, "__iter__"):
            raise TypeError(f"expected a list, got {type(provided).__name__}")
        return list(provided)

    def _collect_port_types(self) -> tuple[dict[str, PortType], dict[Any, tuple[str, tuple[str, ...]]]]:
        ports: dict[str, PortType] = {}
        owner: dict[str, Any] = {}  # port type name -> the plugin that registered it
        bad: dict[Any, tuple[str, tuple[str, ...]]] = {}
        for impl in self.hook.lanegraph_port_types.get_hookimpls():
            try:
                provided = self._provided(impl)
            except Exception as exc:  # noqa: BLE001 - a plugin's bug: reported, the host goes on
                bad[impl.plugin] = (f"its lanegraph_port_types hook raised {type(exc).__name__}: {exc}", ())
                continue
            for pt in provided:
                if not isinstance(pt, PortType) or not (
                    isinstance(pt.name, str) and _PORT_NAME.match(pt.name)
                ):
                    what = f"port type name {pt.name!r}" if isinstance(pt, PortType) else repr(pt)[:80]
                    bad[impl.plugin] = (
                        f"lanegraph_port_types returned {what}, expected a PortType named by a lower-case identifier",
                        (),
                    )
                    break
                if pt.name in ports and ports[pt.name] != pt:
                    by = self.get_name(owner[pt.name])
                    by = "lanegraph" if by == BUILTIN_PLUGIN else repr(by)
                    bad[impl.plugin] = (f"port type {pt.name!r} is already registered by {by}", ())
                    break
                ports[pt.name] = pt
                owner.setdefault(pt.name, impl.plugin)
        for name, plugin in owner.items():
            chain, parent = [name], ports[name].parent
            while parent is not None and parent in ports and parent not in chain:
                chain.append(parent)
                parent = ports[parent].parent
            if parent is not None and plugin not in bad:
                why = (
                    "is not a registered port type"
                    if parent not in ports
                    else f"closes a cycle ({' -> '.join([*chain, parent])})"
                )
                bad[plugin] = (f"port type {name!r}: its parent {parent!r} {why}", ())
        return ports, bad

    def _collect_node_types(
        self, skip: dict[Any, Any]
    ) -> tuple[dict[str, NodeType], dict[Any, tuple[str, tuple[str, ...]]]]:
        types: dict[str, NodeType] = {}
        bad: dict[Any, tuple[str, tuple[str, ...]]] = {}
        for impl in self.hook.lanegraph_node_types.get_hookimpls():
            if impl.plugin in skip:
                continue
            pname = self.get_name(impl.plugin) or "?"
            try:
                provided = self._provided(impl)
            except Exception as exc:  # noqa: BLE001 - a plugin's bug: reported, the host goes on
                bad[impl.plugin] = (f"its lanegraph_node_types hook raised {type(exc).__name__}: {exc}", ())
                continue
            records = [node_type_of(item) for item in provided]
            wrong = next((item for item, nt in zip(provided, records) if nt is None), None)
            if wrong is not None:
                bad[impl.plugin] = (
                    f"lanegraph_node_types returned {wrong!r:.80}, expected a function or class decorated with @lanegraph.node_type",
                    (),
                )
                continue
            names = tuple(nt.name for nt in records if nt is not None)
            clash = next((n for n in names if n in types), None)
            if clash is not None:
                first = types[clash].plugin
                error = (
                    f"node type {clash!r} is provided by both {first!r} and {pname!r}; keeping {first!r}'s"
                )
                bad[impl.plugin] = (error, names)
                continue
            for nt in records:
                assert nt is not None
                nt.plugin = nt.plugin or pname
                types[nt.name] = nt
        return types, bad

    def get_node_type(self, name: str) -> NodeType | None:
        return self.node_types.get(name)

    def suggest(self, name: str) -> str | None:
        """Did-you-mean for an unknown node type name."""
        hint = did_you_mean(name, list(self.node_types), cutoff=0.5)
        return hint[len("did you mean '") : -2] if hint else None

    def missing_type_hint(self, name: str) -> str | None:
        """Why node type ``name`` may be missing: the plugin that holds it is not loaded (or some
        plugins are not, and one may hold it); None when every plugin loaded."""
        holder = next((e for e in self.plugin_errors if name in e.node_types), None)
        if holder is not None:
            return f"it is a node type of plugin {holder.plugin!r}, which is not loaded: {holder.error.removeprefix('is not loaded: ')}"
        if self.plugin_errors:
            names = ", ".join(repr(e.plugin) for e in self.plugin_errors)
            return f"plugin(s) {names} could not be loaded (see the warnings): one may provide it"
        return None


_default: PluginManager | None = None


def get_plugin_manager(*, autoload: bool = True) -> PluginManager:
    """The process-wide plugin manager, loading entry points on first use."""
    global _default
    if _default is None:
        pm = PluginManager()
        if autoload:
            pm.load_entrypoints()
        _default = pm
    return _default


def set_plugin_manager(pm: PluginManager | None) -> None:
    """Replace the process-wide plugin manager (tests; embedding)."""
    global _default
    _default = pm
