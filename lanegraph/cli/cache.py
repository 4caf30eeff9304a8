"""``lanegraph cache info|clear``: the result cache (``lanegraph.run.cache``), where it is and how
big; cleared of its own entries only."""

from __future__ import annotations

from pathlib import Path

import click

from ._errors import handled

_DIR = click.option(
    "--cache-dir",
    type=click.Path(path_type=Path, file_okay=False),
    help="the result cache's folder (default: $LANEGRAPH_CACHE_DIR/results, else ~/.cache/lanegraph/results)",
)


def _cache(cache_dir: Path | None):
    from ..run.cache import ResultCache

    return ResultCache(cache_dir)


@click.group(name="cache")
def cache_cmd() -> None:
    """The result cache: node results that ablations (and runs with a cache) share between variants,
    kept on disk up to a size bound (2 GiB unless --cache-max-gb says otherwise), least recently
    used first out. Compiled kernels are kept apart (~/.cache/lanegraph/kernels) and left alone."""


@cache_cmd.command(name="info")
@_DIR
@handled(every_exit=2)
def info(cache_dir: Path | None) -> None:
    """Where the result cache is, its entries and its size."""
    from ..run.cache import DEFAULT_MAX_BYTES

    c = _cache(cache_dir)
    click.echo(f"result cache: {c.root}")
    click.echo(f"entries:      {c.entries()}")
    click.echo(
        f"size:         {c.size_bytes / 1e6:.1f} MB (bound: {DEFAULT_MAX_BYTES / 1024**3:.0f} GiB by default)"
    )


@cache_cmd.command(name="clear")
@_DIR
@handled(every_exit=2)
def clear(cache_dir: Path | None) -> None:
    """Remove the result cache's entries (nothing else in its folder)."""
    c = _cache(cache_dir)
    n = c.entries()
    freed = c.clear()
    click.echo(f"removed {n} entr{'y' if n == 1 else 'ies'} ({freed / 1e6:.1f} MB) from {c.root}")
