"""Fault isolation: the paper's pipeline over a sequence in which one frame's left image is
truncated and one node raises on another frame. With the error policy ``skip`` the run goes on:
every other frame is in ``lanes.jsonl`` (whole JSON lines), both failures are recorded in
``run.json`` (node id, frame, error) and listed at the end of the CLI output, and ``lanegraph run``
exits with 1 (frames failed while running).

Run on the first frames of the real KITTI drive (skipped when ``../shared/data`` is absent) and on
a synthetic sequence written by ``lanegraph_synthetic.write_sequence`` (always).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner
from pydantic import Field

from lanegraph import NodeParams, Port, hookimpl, node_type, plugins
from lanegraph.cli import main
from lanegraph.plugins import PluginManager

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "graphs" / "paper.yaml"
N_FRAMES = 8
BAD_IMAGE = 2  # index of the frame whose left PNG is cut to its first 200 bytes
BAD_NODE = 5  # index of the frame on which the injected node raises


class FailOnParams(NodeParams):
    frame: str = Field("", description="id of the frame on which to raise (empty: never)")


@node_type(
    "faulty.passthrough",
    inputs={"frame": Port("frame_id"), "lanes": Port("lanes", optional=True)},
    outputs={"lanes": "lanes"},
)
def passthrough(params: FailOnParams, frame: str, lanes=None) -> dict:
    """Passes the lanes on unchanged; raises on the frame ``params.frame``."""
    if frame == params.frame:
        raise RuntimeError(f"injected failure on frame {frame}")
    return {"lanes": lanes}


@node_type("faulty.once", inputs={"calib": Port("calibration", rate="constant")}, outputs={"y": "number"})
def once(params: NodeParams, calib) -> dict:
    """Depends on the calibration only, so it runs once per run; always raises."""
    raise RuntimeError("injected failure of a run-once node")


class FaultyPlugin:
    """A tiny third-party plugin providing the node types above."""

    @staticmethod
    @hookimpl
    def lanegraph_node_types():
        return [passthrough, once]


@pytest.fixture
def cli(monkeypatch) -> CliRunner:
    """The CLI with the installed plugins plus :class:`FaultyPlugin` in its plugin manager."""
    pm = PluginManager()
    pm.load_entrypoints()
    pm.register(FaultyPlugin, name="faulty")
    monkeypatch.setattr(plugins, "_default", pm)
    return CliRunner()


def faulty_graph(tmp_path: Path, fail_frame: str) -> Path:
    """graphs/paper.yaml (an allowed ``extends`` root, given by absolute path) with the error policy
    ``skip`` and ``faulty.passthrough`` inserted between the projection and the lanes writer."""
    g = {
        "extends": str(PAPER),
        "name": "paper_faulty",
        "on_error": "skip",
        "nodes": {
            "boom": {
                "type": "faulty.passthrough",
                "params": {"frame": fail_frame},
                "inputs": {"frame": "src.frame", "lanes": "project.lanes"},
            },
            "write": {"inputs": {"lanes": "boom.lanes"}},
        },
    }
    path = tmp_path / "paper_faulty.yaml"
    path.write_text(yaml.safe_dump(g, sort_keys=False))
    return path


def truncate(png: Path, keep: int = 200) -> None:
    """Replace ``png`` by its first ``keep`` bytes (a new file: never written through a link)."""
    head = png.read_bytes()[:keep]
    png.unlink()
    png.write_bytes(head)


def run_and_check(
    cli: CliRunner, tmp_path: Path, source: Path, stems: list[str], source_type: str, bad_png: Path
) -> None:
    bad_image, bad_node = stems[BAD_IMAGE], stems[BAD_NODE]
    out = tmp_path / "out"
    graph = faulty_graph(tmp_path, bad_node)
    r = cli.invoke(main, ["run", str(graph), "--input", str(source), "--out", str(out), "--quiet"])
    assert r.exit_code == 1, r.output  # frames failed while running (cli.py: 0 ok, 1 failures, 2 usage)

    # every other frame is written, in order, as whole JSON lines
    records = [json.loads(line) for line in (out / "lanes.jsonl").read_text().splitlines()]
    expected = [s for i, s in enumerate(stems) if i not in (BAD_IMAGE, BAD_NODE)]
    assert [rec["frame"] for rec in records] == expected
    assert all(isinstance(rec["lanes"], list) for rec in records)

    # both failures recorded with node id, node type, frame, index and error
    run = json.loads((out / "run.json").read_text())
    assert run["frames_ok"] == len(expected)
    failures = sorted(run["failures"], key=lambda f: f["index"])
    assert [(f["frame"], f["index"], f["node"], f["type"]) for f in failures] == [
        (bad_image, BAD_IMAGE, "src", source_type),
        (bad_node, BAD_NODE, "boom", "faulty.passthrough"),
    ]
    assert bad_png.name in failures[0]["error"] and "cannot decode" in failures[0]["error"]
    assert failures[1]["error"] == f"RuntimeError: injected failure on frame {bad_node}"
    assert json.loads((out / "timings.json").read_text())["frames"] == len(expected)

    # listed at the end of the output: the failure block closes stderr, the summary closes stdout
    err = r.stderr.rstrip().splitlines()
    assert err[-3] == "2 frame(s) failed:", r.stderr
    assert err[-2].startswith(f"  frame {bad_image} (#{BAD_IMAGE}): node 'src' ({source_type}): ")
    assert bad_png.name in err[-2]
    assert (
        err[-1]
        == f"  frame {bad_node} (#{BAD_NODE}): node 'boom' (faulty.passthrough): RuntimeError: injected failure on frame {bad_node}"
    )
    assert r.stdout.rstrip().splitlines()[-1].startswith(f"{len(expected)} frame(s) processed")


@pytest.mark.kitti
def test_faults_are_isolated_on_kitti(cli, kitti_drive, tmp_path):
    """The first frames of the real drive, in KITTI's own layout (date folder with its calibration)."""
    date = tmp_path / "data" / kitti_drive.parent.name
    drive = date / kitti_drive.name
    date.mkdir(parents=True)
    shutil.copyfile(kitti_drive.parent / "calib_cam_to_cam.txt", date / "calib_cam_to_cam.txt")
    for cam in ("image_02", "image_03"):
        (drive / cam / "data").mkdir(parents=True)
        for png in sorted((kitti_drive / cam / "data").glob("*.png"))[:N_FRAMES]:
            shutil.copyfile(png, drive / cam / "data" / png.name)
    lefts = sorted((drive / "image_02" / "data").glob("*.png"))
    assert len(lefts) == N_FRAMES
    truncate(lefts[BAD_IMAGE])
    run_and_check(cli, tmp_path, drive, [p.stem for p in lefts], "io.kitti_raw", lefts[BAD_IMAGE])


def test_faults_are_isolated_on_a_synthetic_sequence(cli, tmp_path):
    """The same on a synthetic sequence (``io.folder`` layout), so it is tested without the data."""
    from lanegraph_synthetic import KITTI_CALIB, preset, write_sequence

    seq = write_sequence(preset("straight", calib=KITTI_CALIB.scaled(0.5)), tmp_path / "seq", N_FRAMES)
    lefts = sorted((seq / "left").glob("*.png"))
    truncate(lefts[BAD_IMAGE])
    run_and_check(cli, tmp_path, seq, [p.stem for p in lefts], "io.folder", lefts[BAD_IMAGE])


def test_a_run_once_node_failing_under_skip_stops_the_run(cli, tmp_path):
    """A node computed once for the whole run (constant inputs) has no frame to drop: under ``skip``
    its failure is a located NodeError and exit 1, not a crash."""
    g = tmp_path / "once.yaml"
    g.write_text(
        yaml.safe_dump(
            {
                "extends": str(PAPER),
                "on_error": "skip",
                "nodes": {"once": {"type": "faulty.once", "inputs": {"calib": "src.calib"}}},
            }
        )
    )
    r = cli.invoke(main, ["run", str(g), "--out", str(tmp_path / "out"), "--quiet", "--frames", "0:2"])
    assert r.exit_code == 1, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    assert (
        "error: node 'once' (faulty.once) failed on frame None: RuntimeError: injected failure of a run-once node"
        in r.stderr
    )
