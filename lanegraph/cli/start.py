"""The newcomer's command ``lanegraph graphs`` (the built-in graph and dataset files); ``lanegraph
data kitti`` is the plugin ``lanegraph_data``'s (:mod:`lanegraph_data.cli`). ``lanegraph.cli`` registers it."""

from __future__ import annotations

import textwrap

import click

from ..builtin import describe, graph_names, graphs_dir


@click.command(name="graphs")
@click.option("--paths", is_flag=True, help="print each file's path instead of its description")
def graphs_cmd(paths: bool) -> None:
    """List the built-in graphs and dataset files: each NAME works wherever a graph file is expected
    (`lanegraph run NAME`, `lanegraph ablate paper ablations/slt`, `extends: NAME.yaml`)."""
    root = graphs_dir()
    for title, kind in (("graphs", "graphs"), ("dataset files", "datasets")):
        names = graph_names(kind)
        click.echo(f"{title} ({root}):" if not paths else f"# {title}")
        width = max((len(n) for n in names), default=0)
        for name in names:
            file = root / f"{name}.yaml"
            if paths:
                click.echo(f"  {file}")
                continue
            lead = f"  {name:<{width}}  "
            text = textwrap.fill(describe(file), 108, initial_indent=lead, subsequent_indent=" " * len(lead))
            click.echo(text.rstrip() or lead.rstrip())


__all__ = ["graphs_cmd"]
