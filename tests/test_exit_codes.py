"""One place maps errors to exit codes (lanegraph.cli._errors): every usage or input error found
before the first frame exits 2 with one line, whatever raised it (issue 46)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from lanegraph import plugins
from lanegraph.cli import main

ROOT = Path(__file__).resolve().parents[1]
DEMO = str(ROOT / "graphs" / "demo_sgbm.yaml")
SMALL = ["--set", "src.type=io.synthetic", "--set", "src.scale=0.2", "--set", "src.frames=1",
         "--set", "disp.num_disparities=16"]  # fmt: skip


@pytest.fixture
def cli(installed_pm, monkeypatch, tmp_path):
    monkeypatch.setattr(plugins, "_default", installed_pm)
    monkeypatch.chdir(tmp_path)

    def invoke(*args: object) -> tuple[int, str]:
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
        assert "Traceback" not in r.output, r.output
        return r.exit_code, r.output

    return invoke


def one_line(output: str) -> str:
    lines = [ln for ln in output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), output
    return lines[0]


@pytest.mark.parametrize("n", [300, 5000])
def test_an_out_with_a_too_long_component(cli, tmp_path, n):
    code, output = cli("run", DEMO, *SMALL, "-q", "--out", tmp_path / ("a" * n))
    assert code == 2, output
    assert "File name too long" in one_line(output) and len(output) < 600


def test_a_debug_dir_error_is_a_usage_error(cli, tmp_path):
    out = tmp_path / "o"
    (out / "dbg").mkdir(parents=True)
    (out / "dbg" / "0000000000").symlink_to(tmp_path)  # a frame's folder leading out of it
    code, output = cli("run", DEMO, *SMALL, "-q", "--out", out, "--debug-dir", out / "dbg")
    assert code == 2, output
    line = one_line(output)
    assert line.startswith("error: --debug-dir: ") and "outside" in line and "DebugRecorder" not in line


@pytest.mark.parametrize("command", ["run", "ablate"])
def test_a_dataset_sequence_named_out_of_out(cli, tmp_path, command):
    ds = tmp_path / "ds.yaml"
    ds.write_text("name: d\nsequences:\n  - {name: ../../../x, input: .}\n")
    code, output = cli(command, DEMO, "--dataset", ds, "--out", tmp_path / "o", "-q")
    assert code == 2, output
    assert "sequence '../../../x'" in one_line(output)
    assert not (tmp_path.parent.parent / "x").exists()


def test_nodes_json_into_a_full_device(tmp_path):
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full on this system")
    with open("/dev/full", "w") as full:
        r = subprocess.run(
            [sys.executable, "-m", "lanegraph.cli", "nodes", "--json"],
            stdout=full, stderr=subprocess.PIPE, text=True, timeout=120,
        )  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "No space left on device" in one_line(r.stderr) and "Traceback" not in r.stderr


@pytest.mark.parametrize("frames", ["5:2", "0:-0", "0:10:-1"])
def test_eval_frames_selecting_no_frame_is_refused_like_run(cli, tmp_path, frames):
    gt = tmp_path / "gt.jsonl"
    pred = tmp_path / "pred.jsonl"
    gt.write_text("".join(f'{{"frame": "{i}", "markings": [], "ego": {{}}}}\n' for i in range(6)))
    pred.write_text("".join(f'{{"frame": "{i}", "lanes": []}}\n' for i in range(6)))
    code, output = cli("eval", pred, gt, "--frames", frames)
    assert code == 2, output
    line = one_line(output)
    assert "selects no frame" in line and "the ground truth has 6 frame(s)" in line and "n/a" not in output


@pytest.mark.parametrize("uri", ["javascript:alert(1)", "data:text/html,x", "gopher://x"])
def test_track_refuses_a_uri_that_is_no_tracking_store(cli, tmp_path, uri):
    out = tmp_path / "o"
    code, output = cli("run", DEMO, *SMALL, "-q", "--out", out, "--track", f"mlflow:{uri}")
    assert code == 2, output
    assert "is not a tracking store's scheme" in one_line(output)
    assert not out.exists() and not any(p.name == "mlruns" or ":" in p.name for p in tmp_path.iterdir())
