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

import contextlib
import inspect
import os
import re
import sys
import warnings
from dataclasses import dataclass
from importlib import metadata
from typing import Any

import pluggy

from . import hookspecs, interrupts
from .errors import HookError, did_you_mean
from .nodes import NodeType, node_type_of
from .port_types import BUILTIN_PORT_TYPES
from .types import PortType

ENTRY_POINT_GROUP = "lanegraph.plugins"
BUILTIN_DISTRIBUTION = "lanegraph"
#: the name of the plugin that registers lanegraph's own port types
BUILTIN_PLUGIN = "lanegraph"
#: the hooks a plugin may implement
HOOK_NAMES = sorted(n for n in dir(hookspecs) if n.startswith("lanegraph_"))
_PORT_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


def allowed(name: str, dist: str) -> bool:
    """Whether the environment lets a third party's plugin (entry point ``name`` of distribution
    ``dist``) load: not when ``LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD`` is set, nor when
    ``LANEGRAPH_PLUGINS`` (a comma-separated allowlist) names neither."""
    if os.environ.get("LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD", "") not in ("", "0"):
        return False
    allow = {s.strip() for s in os.environ.get("LANEGRAPH_PLUGINS", "").split(",") if s.strip()}
    return not allow or name in allow or dist in allow


@dataclass(frozen=True)
class PluginError:
    """A plugin the host runs without: it failed to import, implements a hook that has no spec,
    its registration hook raised, it provides a node type or port type another plugin already
    provides, or a node type whose class lacks what it declares (:mod:`lanegraph.lifecycle`). ``node_types``: the node types it holds, where known (a graph that uses one is told
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

        def dist_of(ep: Any) -> str:
            return ep.dist.name if ep.dist is not None else "?"

        eps = metadata.entry_points(group=group)
        # a plugin's prints go to stderr (stdout may be a command's JSON); a real Ctrl-C still stops
        # the command, a plugin's own SystemExit or KeyboardInterrupt only unloads that plugin
        with interrupts.handling(("SIGINT",)), contextlib.redirect_stdout(sys.stderr):
            for ep in sorted(eps, key=lambda e: (dist_of(e) != BUILTIN_DISTRIBUTION, e.name)):
                dist = dist_of(ep)
                builtin = dist == BUILTIN_DISTRIBUTION
                if not builtin and not allowed(ep.name, dist):
                    continue
                if self.get_plugin(ep.name) is not None or self.is_blocked(ep.name):
                    continue
                self._dists[ep.name] = dist
                try:
                    plugin = ep.load()
                    self.register(plugin, name=ep.name)
                except BaseException as exc:  # a broken plugin must not crash (or end) the host
                    if interrupts.is_interruption(exc):
                        raise
                    if self.get_plugin(ep.name) is not None:
                        super().unregister(name=ep.name)
                    self._reject(ep.name, f"failed to load: {_describe(exc)}", _load_hint(ep.name))
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
        own (:mod:`lanegraph.port_types`, registered first) and the plugins'."""
        self.node_types  # noqa: B018 - built together
        return self._port_types

    def _build(self) -> None:
        """Collect the registries; a plugin whose registration hooks raise or clash is unregistered
        (and recorded), then the registries are collected again without it. What the hooks print
        goes to stderr."""
        with contextlib.redirect_stdout(sys.stderr):
            self._build_registries()

    def _build_registries(self) -> None:
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
    def _provided(impl: Any, hook: str, bad: dict[Any, tuple[str, tuple[str, ...]]]) -> list[Any] | None:
        """What a registration hookimpl returns, as a list; None when it raised or returned no list
        (a plugin's bug, sys.exit included: noted in ``bad``, the host goes on)."""
        try:
            provided = impl.function()
            if provided is None:
                return []
            if isinstance(provided, (str, bytes)) or not hasattr(provided, "__iter__"):
                raise TypeError(f"expected a list, got {type(provided).__name__}")
            return list(provided)
        except BaseException as exc:
            if interrupts.is_interruption(exc):
                raise
            bad[impl.plugin] = (f"its {hook} hook raised {_describe(exc)}", ())
            return None

    def _collect_port_types(self) -> tuple[dict[str, PortType], dict[Any, tuple[str, tuple[str, ...]]]]:
        ports: dict[str, PortType] = {}
        owner: dict[str, Any] = {}  # port type name -> the plugin that registered it
        bad: dict[Any, tuple[str, tuple[str, ...]]] = {}
        for impl in self.hook.lanegraph_port_types.get_hookimpls():
            provided = self._provided(impl, "lanegraph_port_types", bad)
            if provided is None:
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
                problem = _storage_problem(pt, ports)
                if problem is not None:
                    bad[impl.plugin] = (f"port type {pt.name!r}: {problem}", ())
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
            provided = self._provided(impl, "lanegraph_node_types", bad)
            if provided is None:
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
            broken = next(
                ((nt, p) for nt in records if nt is not None and (p := nt.contract_problems())), None
            )
            if broken is not None:  # the declared contract (lanegraph.lifecycle) not kept
                nt, problems = broken
                what = nt.func.__qualname__
                bad[impl.plugin] = (f"node type {nt.name!r} ({what}) {'; '.join(problems)}", names)
                continue
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
                if nt.undeclared:
                    warnings.warn(
                        f"plugin {pname!r}: node type {nt.name!r} defines the methods of "
                        f"{', '.join(sorted(nt.undeclared))} without declaring them; declare "
                        f"implements={tuple(sorted(nt.undeclared))!r} in its "
                        "@node_type (lanegraph.lifecycle): a later lanegraph will not look for them",
                        DeprecationWarning,
                        stacklevel=2,
                    )
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


def _storage_problem(pt: PortType, ports: dict[str, PortType]) -> str | None:
    """What is wrong with a port type's storage (:mod:`lanegraph.storage`): ``stores`` a class
    with both ``encode`` and ``decode``, one not another port type's; or neither."""
    parts = {"stores": pt.stores, "encode": pt.encode, "decode": pt.decode}
    if all(v is None for v in parts.values()):
        return None
    missing = [k for k, v in parts.items() if v is None]
    if missing:
        return f"declares storage without {' and '.join(missing)} (stores, encode and decode go together)"
    if not isinstance(pt.stores, type) or not callable(pt.encode) or not callable(pt.decode):
        return "stores must be a class, encode and decode functions"
    other = next((o for o in ports.values() if o.stores is pt.stores and o.name != pt.name), None)
    if other is not None:
        return f"stores {pt.stores.__qualname__}, which port type {other.name!r} already stores"
    return None


def _describe(exc: BaseException) -> str:
    """``Type: message`` on one line (pluggy's messages span lines; ``SystemExit(0)`` says so)."""
    if isinstance(exc, SystemExit):
        return f"SystemExit: it called sys.exit({exc.code!r})"
    text = " ".join(f"{type(exc).__name__}: {exc}".split()).removesuffix(":")
    return text[:300]


def _load_hint(name: str) -> str:
    return (
        f"run `python -c 'import {name}'` to see the full traceback, or set "
        "LANEGRAPH_PLUGINS to load only the plugins you need"
    )


# --------------------------------------------------------------------------- guarded hook calls
def _is_image(value: Any) -> bool:
    import numpy as np

    return isinstance(value, np.ndarray) and value.ndim in (2, 3) and value.size > 0


def _is_calibration(value: Any) -> bool:
    from .types import Calibration

    return isinstance(value, Calibration)


#: what each hook may return besides None: (check, what the error says was expected); the
#: results of the other hooks are not used
HOOK_RESULTS: dict[str, tuple[Any, str]] = {
    "lanegraph_render": (_is_image, "an image (an HxW or HxWx3 array) or None"),
    "lanegraph_detect_source": (lambda v: isinstance(v, str), "a source node type name (str) or None"),
    "lanegraph_read_calibration": (_is_calibration, "a lanegraph.types.Calibration or None"),
    "lanegraph_runners": (
        lambda v: isinstance(v, (list, tuple)) and all(isinstance(t, type) for t in v),
        "a list of runner classes",
    ),
    "lanegraph_write_report": (
        lambda v: callable(getattr(v, "line", None)) and hasattr(v, "index"),
        "a report's summary (with index and line()) or None",
    ),
}


def call_hook(pm: pluggy.PluginManager, name: str, /, **kwargs: Any) -> Any:
    """Call hook ``name`` as pluggy would (the same implementations in the same order; the first
    result for a ``firstresult`` hook, else the list of results), with every implementation
    guarded: one that raises -- ``SystemExit``, ``KeyboardInterrupt`` and any ``BaseException``
    included -- or returns what the hook does not allow (:data:`HOOK_RESULTS`) is a
    :class:`~lanegraph.errors.HookError` naming the plugin and the hook. The user's interruption
    (:func:`lanegraph.interrupts.is_interruption`) and a :class:`HookError` raised by a nested call
    pass through unchanged."""
    hook = getattr(pm.hook, name)
    impls = hook.get_hookimpls()
    firstresult = bool(hook.spec is not None and hook.spec.opts.get("firstresult"))
    check = HOOK_RESULTS.get(name)
    if any(impl.hookwrapper or impl.wrapper for impl in impls):
        return _call_wrapped(pm, hook, name, impls, firstresult, check, kwargs)
    exec_ = getattr(pm, "_hookexec", None)  # pluggy's own call path: tracing and monitoring stay
    results = []
    for impl in reversed(impls):
        try:
            if exec_ is not None:
                out = exec_(name, [impl], kwargs, False)
                res = out[0] if out else None
            else:  # pragma: no cover - a pluggy without _hookexec
                res = impl.function(*(kwargs[a] for a in impl.argnames))
        except HookError:
            raise
        except BaseException as exc:
            if interrupts.is_interruption(exc):
                raise
            raise HookError(_plugin_name(pm, impl.plugin), name, f"raised {_describe(exc)}", exc) from exc
        if res is None:
            continue
        if check is not None and not check[0](res):
            raise HookError(
                _plugin_name(pm, impl.plugin),
                name,
                f"returned {type(res).__name__} {str(res)[:40]!r}, expected {check[1]}",
            )
        if firstresult:
            return res
        results.append(res)
    return None if firstresult else results


def _call_wrapped(
    pm: pluggy.PluginManager,
    hook: Any,
    name: str,
    impls: list[Any],
    firstresult: bool,
    check: tuple[Any, str] | None,
    kwargs: dict[str, Any],
) -> Any:
    """:func:`call_hook` when a plugin wraps the hook (a hookwrapper must wrap the whole call): the
    raising plugin is found in the traceback."""
    try:
        out = hook(**kwargs)
    except HookError:
        raise
    except BaseException as exc:
        if interrupts.is_interruption(exc):
            raise
        codes = {getattr(impl.function, "__code__", None): impl.plugin for impl in impls}
        culprit = None
        tb = exc.__traceback__
        while tb is not None:
            culprit = codes.get(tb.tb_frame.f_code, culprit)
            tb = tb.tb_next
        raise HookError(_plugin_name(pm, culprit), name, f"raised {_describe(exc)}", exc) from exc
    values = [out] if firstresult else list(out or [])
    for res in values:
        if res is not None and check is not None and not check[0](res):
            raise HookError(
                "?", name, f"returned {type(res).__name__} {str(res)[:40]!r}, expected {check[1]}"
            )
    return out


def _plugin_name(pm: pluggy.PluginManager, plugin: Any) -> str:
    """The name a plugin was registered under; for one registered without a name (pluggy names it
    by its id), its module's or class's name."""
    if plugin is None:
        return "?"
    name = pm.get_name(plugin)
    if name and not name.isdigit():
        return name
    return getattr(plugin, "__name__", None) or type(plugin).__name__


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
