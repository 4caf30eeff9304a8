"""Shared fixtures: the real KITTI data (skipped with a reason when absent) and the installed plugins."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

# the first run's helper process (lanegraph.kernels.first_run) makes the plugins' kernels beside a
# run; the suite's runs compile what they use in their own process (tests/engine/test_kernel_cache.py
# tests the helper)
os.environ.setdefault("LANEGRAPH_PRECOMPILE", "0")

# The tests that stop a run with Ctrl-C send SIGINT to this process or to a child. A suite started in
# the background by a shell without job control (`pytest &` in a script, a detached CI step) inherits
# SIGINT ignored, which lanegraph rightly keeps ignoring (`nohup`), and which every child inherits;
# those tests would then see runs that no Ctrl-C stops. The suite itself gets Python's usual handler
# (children get the default action).
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("LANEGRAPH_SHARED_DATA", ROOT.parent / "shared" / "data"))
KITTI_DRIVE = SHARED / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"


@pytest.fixture(scope="session")
def kitti_drive() -> Path:
    """The real KITTI raw drive 0001 folder; the test is skipped when ../shared/data is absent."""
    if not (KITTI_DRIVE / "image_02" / "data").is_dir():
        pytest.skip(f"real KITTI data not found at {KITTI_DRIVE} (a fresh clone has no ../shared/data)")
    return KITTI_DRIVE


@pytest.fixture(scope="session")
def kitti_calib():
    """Calibration of the KITTI colour pair (P_rect_02 / P_rect_03)."""
    from lanegraph.types import Calibration

    return Calibration(f=721.5377, cx=609.5593, cy=172.8540, baseline=0.5327, width=1242, height=375)


@pytest.fixture(scope="module")
def installed_pm():
    """The installed plugins in a manager of their own (other tests swap the process-wide one)."""
    from lanegraph.plugins import PluginManager

    pm = PluginManager()
    pm.load_entrypoints()
    return pm
