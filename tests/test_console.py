"""Console output is bounded and plain text (lanegraph.runlog): a warning said again is counted,
not repeated; control characters are escaped on the console and in run.log; a file name that is
not UTF-8 does not break logging (issue 46)."""

from __future__ import annotations

import os
import warnings

import pytest
import yaml
from click.testing import CliRunner

from lanegraph import NodeParams, hookimpl, node_type, plugins
from lanegraph.cli import main
from lanegraph.runlog import escape_controls

from .test_bad_input import DEMO, SMALL, pair_folder


class NoisyParams(NodeParams):
    pass


@node_type("noisy.warn", inputs={"image": "image"}, outputs={"n": "number"})
def noisy(params: NoisyParams, image):
    """20,000 warnings a frame, each with an escape sequence (red text) and a number."""
    for i in range(20_000):
        warnings.warn(f"\x1b[31mpixel {i} looks odd\x1b[0m", stacklevel=1)
    return {"n": 1.0}


class _Noisy:
    @hookimpl
    def lanegraph_node_types(self):
        return [noisy]


def test_a_node_warning_20000_times_a_frame_is_counted_not_repeated(installed_pm, monkeypatch, tmp_path):
    monkeypatch.setattr(plugins, "_default", installed_pm)
    installed_pm.register(_Noisy(), name="noisy")
    try:
        graph = tmp_path / "noisy.yaml"
        graph.write_text(
            yaml.safe_dump(
                {
                    "name": "noisy",
                    "nodes": {
                        "src": {"type": "io.synthetic", "params": {"scale": 0.2, "frames": 2}},
                        "noisy": {"type": "noisy.warn", "inputs": {"image": "src.left"}},
                        "write": {"type": "io.write_lanes", "inputs": {"frame": "src.frame"}},
                    },
                }
            )
        )
        out = tmp_path / "out"
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            r = CliRunner().invoke(main, ["run", str(graph), "--out", str(out), "--quiet"])
    finally:
        installed_pm.unregister(name="noisy")
    assert r.exit_code == 0, r.output[-2000:]
    lines = r.output.splitlines()
    assert len(lines) < 250, len(lines)
    assert "\x1b" not in r.output and "\\x1b[31mpixel 0 looks odd" in r.output
    assert any("more warning(s) not shown" in ln for ln in lines), lines[-5:]
    log = (out / "run.log").read_text(encoding="utf-8")
    assert "\x1b" not in log
    assert len(log.splitlines()) < 3100  # 1000 of each warning (two lines each), then counted


def test_control_characters_of_argv_are_escaped_in_run_log(installed_pm, monkeypatch, tmp_path):
    monkeypatch.setattr(plugins, "_default", installed_pm)
    out = tmp_path / "out"
    args = ["run", str(DEMO), "--out", str(out), "-q", "--frames", "0:1", *SMALL,
            "--set", "src.type=io.synthetic", "--set", "src.scale=0.2", "--set", "src.frames=1",
            "--set", "disp.block_size=3"]  # fmt: skip
    r = CliRunner().invoke(main, [*args, "--debug-dir", str(out / "dbg\x1b]0;owned\x07")])
    assert r.exit_code == 0, r.output
    log = (out / "run.log").read_text(encoding="utf-8")
    assert "dbg\\x1b]0;owned\\x07" in log  # the command line, escaped
    assert "\x1b" not in log and "\x07" not in log
    assert "\x1b" not in r.output


@pytest.mark.skipif(os.name != "posix", reason="file names as bytes: POSIX")
def test_an_input_path_that_is_not_utf8_does_not_break_logging(installed_pm, monkeypatch, tmp_path, capfd):
    monkeypatch.setattr(plugins, "_default", installed_pm)
    raw = os.fsencode(str(tmp_path)) + b"/in\xff"
    pair_folder(tmp_path / "made", n=2)  # (OpenCV cannot write to such a name)
    os.rename(os.fsencode(str(tmp_path / "made")), raw)
    out = tmp_path / "out"
    r = CliRunner().invoke(
        main, ["run", str(DEMO), "--input", os.fsdecode(raw), "--out", str(out), "-q", *SMALL]
    )
    assert r.exit_code == 0, r.output
    assert "Logging error" not in r.output and "Logging error" not in capfd.readouterr().err
    log = (out / "run.log").read_text(encoding="utf-8")
    assert "in\\xff" in log


def test_escape_controls():
    assert escape_controls("a\x1b[31mb\r\x00\x9b\udcff\tc\nd") == "a\\x1b[31mb\\x0d\\x00\\x9b\\xff\tc\nd"
