from __future__ import annotations

import pytest

from lanegraph.plugins import PluginManager

from . import toyplugin


@pytest.fixture
def pm() -> PluginManager:
    """A plugin manager holding only the toy plugin (no auto-discovery)."""
    m = PluginManager()
    m.register(toyplugin, name="toy")
    return m


@pytest.fixture(scope="session")
def synthetic_dataset(tmp_path_factory):
    """A dataset file of two rendered sequences with ground truth: ``straight`` (5 frames) and
    ``curve`` (7 frames)."""
    from lanegraph_synthetic import preset, write_sequence

    root = tmp_path_factory.mktemp("dataset")
    write_sequence(preset("straight"), root / "a", 5)
    write_sequence(preset("curved"), root / "b", 7)
    ds = root / "two.yaml"
    ds.write_text(
        "name: two\nsequences:\n"
        "  - {name: straight, input: a, gt: a/lanes_gt.jsonl}\n"
        "  - {name: curve, input: b, gt: b/lanes_gt.jsonl}\n"
    )
    return ds
