"""lanegraph_dask without a cluster: the ``--scheduler`` texts it understands, and a plugin registered
through the ``lanegraph.plugins`` entry points like a third party's that imports neither Dask nor
its cluster module until a scheduler is asked for (the runs on real clusters:
``tests/engine/test_distributed.py``)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from lanegraph_dask.runner import DaskRunner, parse_scheduler

from lanegraph.batches.runners import select_runner
from lanegraph.errors import UsageError
from lanegraph.plugins import PluginManager


def test_scheduler_specs():
    assert parse_scheduler(None) is None
    assert parse_scheduler("local").local and parse_scheduler("local").workers is None
    assert parse_scheduler("local:3").workers == 3
    spec = parse_scheduler("tcp://10.0.0.5:8786")
    assert not spec.local and spec.address == "tcp://10.0.0.5:8786"
    for bad in ("local:0", "local:x", "local:-2", " "):
        with pytest.raises(UsageError, match="--scheduler"):
            parse_scheduler(bad)


def test_the_entry_point_registers_the_dask_runner_as_the_fallback():
    pm = PluginManager()
    pm.load_entrypoints()
    assert pm.get_plugin("lanegraph_dask") is not None, pm.plugin_errors
    runner = select_runner("tcp://10.0.0.5:8786", pm)
    assert isinstance(runner, DaskRunner) and runner.spec.address == "tcp://10.0.0.5:8786"
    assert select_runner("inprocess", pm).name == "inprocess"  # claimed before the fallback
    with pytest.raises(UsageError, match="unknown scheme 'ftp'"):
        select_runner("ftp://x", pm)  # refused where --scheduler is read, before any cluster


_LOAD = """
import sys
from lanegraph.plugins import get_plugin_manager
pm = get_plugin_manager()
assert pm.get_plugin("lanegraph_dask") is not None, pm.plugin_errors
print(sorted(m for m in sys.modules if m.split(".")[0] in ("dask", "distributed") or m.startswith("lanegraph_dask.")))
"""


def test_loading_the_plugin_imports_neither_dask_nor_the_runner():
    p = subprocess.run([sys.executable, "-c", _LOAD], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "[]", p.stdout
