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

import difflib
import os
import sys
from dataclasses import dataclass
from importlib import metadata
from typing import Any

import pluggy

from . import hookspecs
from .nodes import NodeType

ENTRY_POINT_GROUP = "lanegraph.plugins"
BUILTIN_DISTRIBUTION = "lanegraph"


@dataclass(frozen=True)
class PluginLoadError:
    """A plugin that could not be loaded; the host keeps running without it."""

    entry_point: str
    distribution: str
    error: str

    def __str__(self) -> str:
        return (
            f"plugin {self.entry_point!r} from distribution {self.distribution!r} failed to load: {self.error} "
            f"(hint: run `python -c 'import {self.entry_point}'` to see the full traceback, or set "
            f"LANEGRAPH_PLUGINS to load only the plugins you need)"
        )


class PluginManager(pluggy.PluginManager):
    """``pluggy.PluginManager("lanegraph")`` plus the node-type registry."""

    def __init__(self) -> None:
        super().__init__("lanegraph")
        self.add_hookspecs(hookspecs)
        self.load_errors: list[PluginLoadError] = []
        self._node_types: dict[str, NodeType] | None = None
        self.registry_errors: list[str] = []
        if os.environ.get("LANEGRAPH_TRACE_HOOKS"):
            self.trace.root.setwriter(lambda s: sys.stderr.write(s))
            self.enable_tracing()

    def register(self, plugin: Any, name: str | None = None) -> str | None:  # noqa: D102
        self._node_types = None
        return super().register(plugin, name)

    def unregister(self, plugin: Any = None, name: str | None = None) -> Any:  # noqa: D102
        self._node_types = None
        return super().unregister(plugin, name)

    def load_entrypoints(self, group: str = ENTRY_POINT_GROUP) -> None:
        """Load every plugin of ``group``, honouring the environment allowlist.

        A plugin that fails to import is recorded in :attr:`load_errors`.
        """
        no_autoload = os.environ.get("LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD", "") not in ("", "0")
        allow = {s.strip() for s in os.environ.get("LANEGRAPH_PLUGINS", "").split(",") if s.strip()}
        for ep in sorted(metadata.entry_points(group=group), key=lambda e: e.name):
            dist = ep.dist.name if ep.dist is not None else "?"
            builtin = dist == BUILTIN_DISTRIBUTION
            if not builtin and (no_autoload or (allow and ep.name not in allow and dist not in allow)):
                continue
            if self.get_plugin(ep.name) is not None or self.is_blocked(ep.name):
                continue
            try:
                plugin = ep.load()
                self.register(plugin, name=ep.name)
            except Exception as exc:  # a broken plugin must not crash the host
                self.load_errors.append(PluginLoadError(ep.name, dist, f"{type(exc).__name__}: {exc}"))
        self.check_pending()

    # -- registry -------------------------------------------------------------
    @property
    def node_types(self) -> dict[str, NodeType]:
        """All node types by name (computed once per set of registered plugins)."""
        if self._node_types is None:
            types: dict[str, NodeType] = {}
            self.registry_errors = []
            for impl in self.hook.lanegraph_node_types.get_hookimpls():
                pname = self.get_name(impl.plugin) or "?"
                try:
                    provided = impl.function() or []
                except Exception as exc:
                    self.registry_errors.append(f"plugin {pname!r}: lanegraph_node_types raised {exc!r}")
                    continue
                for nt in provided:
                    if not isinstance(nt, NodeType):
                        self.registry_errors.append(f"plugin {pname!r}: returned {nt!r}, expected a NodeType")
                        continue
                    if nt.name in types:
                        self.registry_errors.append(
                            f"node type {nt.name!r} is provided by both {types[nt.name].plugin!r} and {pname!r}; "
                            f"keeping {types[nt.name].plugin!r}"
                        )
                        continue
                    nt.plugin = nt.plugin or pname
                    types[nt.name] = nt
            self._node_types = dict(sorted(types.items()))
        return self._node_types

    def get_node_type(self, name: str) -> NodeType | None:
        return self.node_types.get(name)

    def suggest(self, name: str) -> str | None:
        """Did-you-mean for an unknown node type name."""
        close = difflib.get_close_matches(name, list(self.node_types), n=1, cutoff=0.5)
        return close[0] if close else None


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
