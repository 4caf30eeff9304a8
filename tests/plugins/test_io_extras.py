"""The ``io`` extra: lanegraph and lanegraph_io import without rosbags, PyAV, mcap and foxglove-sdk,
and a node that needs one says which extra to install."""

from __future__ import annotations

import subprocess
import sys

CODE = """
import sys
for name in ("rosbags", "av", "mcap", "foxglove"):
    sys.modules[name] = None  # import NAME raises ImportError
import lanegraph.cli, lanegraph_io, lanegraph_image
from lanegraph.errors import InputError
from lanegraph_io._rosbag import need_rosbags
from lanegraph_io._video import need_av
from lanegraph_io._mcap_sink import need_foxglove
for need in (need_rosbags, need_av, need_foxglove):
    try:
        need()
    except InputError as exc:
        print(exc)
loaded = [m for m in ("rosbags", "av", "mcap", "foxglove") if sys.modules.get(m) is not None]
print("loaded:", loaded)
"""


def test_the_plugins_import_without_the_io_extra():
    r = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "io.rosbag needs the 'rosbags' package: pip install 'lanegraph[io]'"
    assert lines[1] == "io.video needs the 'av' package (PyAV): pip install 'lanegraph[io]'"
    assert (
        lines[2] == "io.write_mcap needs the 'mcap' and 'foxglove-sdk' packages: pip install 'lanegraph[io]'"
    )
    assert lines[3] == "loaded: []"
