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
