"""The ``lanegraph`` command line: a package of thin command modules.

Each command parses its options, calls the run service (:class:`lanegraph.service.Session`) and
exits with the status it returns, or with the exit code of the typed error it raised
(:mod:`lanegraph.cli._errors`, the one place errors become exit codes).

Commands are an open set too: a distribution adds one through the ``lanegraph.commands`` entry-point
group (``name = "module:click_command"``), loaded only when that command runs or ``--help`` lists
them, honouring the allowlist of :mod:`lanegraph.plugins` (``LANEGRAPH_PLUGINS``,
``LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD``). lanegraph's own add-ons (``tune``, ``report``) come the same
way, from their plugin packages (``eval`` and ``report`` from ``lanegraph_report``), and ``data kitti``
from ``lanegraph_data``. A command plugin imports :mod:`lanegraph.api`.

Exit codes: 0 ok, 1 failure while running (or frames that failed), 2 invalid graph or usage, or an
input that is unusable before any frame runs (no images, no calibration, an empty frame selection).
"""

from __future__ import annotations

from typing import Any

import click

from .._version import __version__
from ..graph.files import allowed_roots, resolve_graph_path
from .ablate import ablate
from .cache import cache_cmd
from .nodes import builtin_node_types, nodes, nodes_markdown, schema, show, validate
from .run import run
from .start import graphs_cmd

__all__ = [
    "COMMAND_GROUP",
    "allowed_roots",
    "builtin_node_types",
    "command_entry_points",
    "main",
    "nodes_markdown",
    "resolve_graph_path",
]

#: the entry-point group of the commands that distributions add
COMMAND_GROUP = "lanegraph.commands"


def command_entry_points() -> dict[str, Any]:
    """The ``lanegraph.commands`` entry points by command name, as the plugin allowlist lets them
    load: lanegraph's own always, the others unless ``LANEGRAPH_DISABLE_PLUGIN_AUTOLOAD`` is set or
    ``LANEGRAPH_PLUGINS`` names neither the entry point nor its distribution. Where two
    distributions name the same command, lanegraph's wins, then the first by distribution name."""
    from importlib import metadata

    from ..plugins import BUILTIN_DISTRIBUTION, allowed

    found: dict[str, Any] = {}
    eps = metadata.entry_points(group=COMMAND_GROUP)
    for ep in sorted(eps, key=lambda e: (_dist(e) != BUILTIN_DISTRIBUTION, _dist(e), e.name)):
        if ep.name not in found and (_dist(ep) == BUILTIN_DISTRIBUTION or allowed(ep.name, _dist(ep))):
            found[ep.name] = ep
    return found


def _entry_points(ctx: click.Context | None) -> dict[str, Any]:
    """:func:`command_entry_points`, read once per invocation (``--help`` asks for every command)."""
    if ctx is None:
        return command_entry_points()
    if COMMAND_GROUP not in ctx.meta:
        ctx.meta[COMMAND_GROUP] = command_entry_points()
    return ctx.meta[COMMAND_GROUP]


def _broken(name: str, why: str) -> click.Command:
    """A command that could not be loaded: listed by ``--help`` as such; run, it exits 2 saying why."""

    def refuse(**_: Any) -> None:
        raise click.UsageError(why)

    return click.Command(
        name,
        callback=refuse,
        help=why,
        short_help="(failed to load; run it to see why)",
        context_settings={"ignore_unknown_options": True, "allow_extra_args": True},
    )


def _dist(ep: Any) -> str:
    return ep.dist.name if ep.dist is not None else "?"


class _Lanegraph(click.Group):
    """The ``lanegraph`` group, recording the arguments it is invoked with (run.json keeps them)."""

    def main(self, args=None, *rest, **kwargs):  # noqa: D102 - click.Group.main
        import sys

        from ..records.provenance import set_command_line

        set_command_line(list(sys.argv[1:] if args is None else args))
        return super().main(args, *rest, **kwargs)

    def list_commands(self, ctx):  # noqa: D102 - click.Group.list_commands
        return sorted(set(super().list_commands(ctx)) | set(_entry_points(ctx)))

    def get_command(self, ctx, name):  # noqa: D102 - click.Group.get_command
        command = super().get_command(ctx, name)
        if command is not None:
            return command
        ep = _entry_points(ctx).get(name)
        if ep is None:
            return None
        where = f"the command {name!r} of {_dist(ep)} (entry point {ep.value!r} in {COMMAND_GROUP})"
        try:
            command = ep.load()
        except Exception as exc:  # a broken plugin: --help still lists the others, running it says why
            return _broken(name, f"{where} failed to load: {type(exc).__name__}: {exc}")
        if not isinstance(command, click.Command):
            return _broken(name, f"{where} is a {type(command).__name__}, expected a click command")
        return command

    def invoke(self, ctx):  # noqa: D102 - click.Group.invoke
        try:
            return super().invoke(ctx)
        except OSError as exc:  # every command (nodes --json > /dev/full): one line, exit 2
            from ._errors import os_error_exit

            os_error_exit(exc)


@click.group(cls=_Lanegraph, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="lanegraph")
def main() -> None:
    """lanegraph: stereo lane-marking detection as validated, plugin-based processing graphs."""


for _command in (
    run,
    validate,
    nodes,
    schema,
    show,
    ablate,
    graphs_cmd,
    cache_cmd,
):
    main.add_command(_command)


if __name__ == "__main__":  # pragma: no cover
    main()
