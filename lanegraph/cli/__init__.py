"""The ``lanegraph`` command line: a package of thin command modules.

Each command parses its options, calls the run service (:class:`lanegraph.service.Session`) and
exits with the status it returns, or with the exit code of the typed error it raised
(:mod:`lanegraph.cli._errors`, the one place errors become exit codes).

Exit codes: 0 ok, 1 failure while running (or frames that failed), 2 invalid graph or usage, or an
input that is unusable before any frame runs (no images, no calibration, an empty frame selection).
"""

from __future__ import annotations

import click

from .._version import __version__
from ..graph.files import allowed_roots, resolve_graph_path
from .ablate import ablate
from .cache import cache_cmd
from .evaluate import eval_cmd
from .nodes import builtin_node_types, nodes, nodes_markdown, schema, show, validate
from .report import report
from .run import run
from .start import data_cmd, graphs_cmd
from .tune import tune

__all__ = ["allowed_roots", "builtin_node_types", "main", "nodes_markdown", "resolve_graph_path"]


class _Lanegraph(click.Group):
    """The ``lanegraph`` group, recording the arguments it is invoked with (run.json keeps them)."""

    def main(self, args=None, *rest, **kwargs):  # noqa: D102 - click.Group.main
        import sys

        from ..records.provenance import set_command_line

        set_command_line(list(sys.argv[1:] if args is None else args))
        return super().main(args, *rest, **kwargs)

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
    tune,
    eval_cmd,
    report,
    graphs_cmd,
    data_cmd,
    cache_cmd,
):
    main.add_command(_command)


if __name__ == "__main__":  # pragma: no cover
    main()
