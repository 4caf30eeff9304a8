"""`lanegraph report`: the HTML report of a run and of an ablation, checked as files and in a real
headless Chromium (Debian's ``chromium`` driven by Playwright's Python API; the browser tests skip
with the reason when either is missing).

The scene: 4 frames of the synthetic ``kerbs`` street at half the KITTI size. The run's ground
truth is the scene's exact one; a copy with frame 1's markings moved 150 px to the right makes that
frame fail, so the "failed only" filter has something to list. The ablation runs ``paper`` and
``paper_literal``, which picks an outer line on this street (every frame fails) — two variants that
disagree, for the side-by-side view.

Set ``LANEGRAPH_UPDATE_DOCS_IMAGES=1`` to write the screenshots shown in README.md and
docs/tutorial.md to ``docs/img/``.
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from lanegraph.cli import main
from lanegraph.evaluation.metrics import match_frame, read_jsonl

ROOT = Path(__file__).resolve().parents[2]
N_FRAMES = 4
MOVED_FRAME = "0000000001"


def _page_data(index: Path) -> dict:
    m = re.search(
        r'<script type="application/json" id="report-data">(.*?)</script>',
        index.read_text(encoding="utf-8"),
        re.S,
    )
    assert m, f"{index}: no report data"
    return json.loads(m.group(1))


def _eval_failed(lanes: Path, gt: Path) -> list[str]:
    r = CliRunner().invoke(main, ["eval", str(lanes), str(gt), "--json"])
    assert r.exit_code == 0, r.output
    return [f["frame"] for f in json.loads(r.output)["failed_frames"]]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A written synthetic sequence, its exact ground truth and a moved copy of it."""
    from lanegraph_synthetic import KITTI_CALIB, preset, write_sequence

    d = tmp_path_factory.mktemp("report")
    seq = write_sequence(preset("kerbs", calib=KITTI_CALIB.scaled(0.5)), d / "kerbs", N_FRAMES)
    moved = []
    for rec in read_jsonl(seq / "lanes_gt.jsonl"):
        if rec["frame"] == MOVED_FRAME:
            for m in rec["markings"]:
                m["points"] = [[x + 150, y] for x, y in m["points"]]
        moved.append(json.dumps(rec))
    (d / "moved_gt.jsonl").write_text("\n".join(moved) + "\n")
    return {"dir": d, "seq": seq, "gt": seq / "lanes_gt.jsonl", "moved_gt": d / "moved_gt.jsonl"}


@pytest.fixture(scope="module")
def run_out(scene):
    """`lanegraph run --report` with node pictures of frame 2."""
    out = scene["dir"] / "run"
    args = [
        "run", str(ROOT / "graphs/paper.yaml"), "--input", str(scene["seq"]), "--out", str(out), "--quiet",
        "--debug-dir", str(out / "debug"), "--debug-frames", "2", "--report",
    ]  # fmt: skip
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    return out, r.output


@pytest.fixture(scope="module")
def moved_report(scene, run_out):
    """`lanegraph report` of the same run against the moved ground truth."""
    out, _ = run_out
    r = CliRunner().invoke(
        main,
        ["report", str(out), "--gt", str(scene["moved_gt"]), "--out", str(scene["dir"] / "moved"), "--quiet"],
    )
    assert r.exit_code == 0, r.output
    return scene["dir"] / "moved" / "index.html"


@pytest.fixture(scope="module")
def ablation_out(scene):
    """`lanegraph ablate --report` of paper and paper_literal."""
    out = scene["dir"] / "ablation"
    args = [
        "ablate", str(ROOT / "graphs/paper.yaml"), str(ROOT / "graphs/ablations/paper_literal.yaml"),
        "--input", str(scene["seq"]), "--gt", str(scene["gt"]), "--out", str(out),
        "--cache-dir", str(scene["dir"] / "cache"), "--quiet", "--report",
    ]  # fmt: skip
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    return out


# --------------------------------------------------------------------------- the files
def test_run_report_files(scene, run_out):
    out, output = run_out
    index = out / "report" / "index.html"
    assert index.is_file() and f"report: {index}" in output and "MB in" in output
    data = _page_data(index)
    # the ground truth in the input folder was found; every frame has its reduced left image
    assert data["sequences"] == [{"name": "kerbs", "gt": True}]
    assert [f["id"] for f in data["frames"]] == [f"{k:010d}" for k in range(N_FRAMES)]
    for f in data["frames"]:
        img = cv2.imread(str(out / "report" / f["img"]))
        assert img is not None and img.shape[1] == 621  # half KITTI width, under the 800 px limit
        assert (f["w"], f["h"]) == (621, 188)
    # each lane's outcome is metrics.match_frame's
    lanes = {r["frame"]: r["lanes"] for r in read_jsonl(out / "lanes.jsonl")}
    for f, g in zip(data["frames"], read_jsonl(scene["gt"])):
        m = match_frame(lanes[f["id"]], g)
        assert [ln["o"] for ln in f["r"][0]["lanes"]] == m.lane_outcomes()
        assert f["r"][0]["mo"] == m.marking_outcomes()
    # node pictures of frame 2 only, one per rendered output, in graph order
    dbg = [f for f in data["frames"] if f.get("dbg")]
    assert [f["id"] for f in dbg] == ["0000000002"]
    caps = [p["cap"] for p in dbg[0]["dbg"]]
    written = sorted(
        p.name[: -len(".png")] for p in (out / "debug" / "0000000002").glob("*.png") if p.name != "mosaic.png"
    )
    assert sorted(caps) == written
    order = [
        "src",
        "gray",
        "disp",
        "road",
        "roadmask",
        "ipm",
        "features",
        "tmask",
        "follow",
        "masked",
        "verify_followed",
        "verify_straddled",
        "orientation",
        "hough",
        "fit",
        "verify",
        "merge",
        "near",
        "project",
    ]
    ranks = [order.index(c.split(".")[0]) for c in caps]
    assert ranks == sorted(ranks) and caps[0] == "src.left"
    assert all(cv2.imread(str(out / "report" / p["src"])) is not None for p in dbg[0]["dbg"])
    # the resolved graph is drawn with the times of timings.json
    page = index.read_text()
    timings = json.loads((out / "timings.json").read_text())["nodes"]
    assert f"{timings['disp']['median_ms']:.1f} / {timings['disp']['p90_ms']:.1f} ms" in page
    assert 'data-node="verify"' in page and "io.folder" in page  # io.auto as it was resolved


def test_report_references_only_its_own_folder(run_out):
    out, _ = run_out
    page = (out / "report" / "index.html").read_text()
    refs = re.findall(r'(?:src|href)="([^"]*)"', page)
    assert all(not re.match(r"^[a-z]+:", r) and not r.startswith("/") and ".." not in r for r in refs)
    # no URL but the SVG namespace, which is a name and never fetched
    assert set(re.findall(r"https?://[^\s\"'<>)]+", page)) <= {"http://www.w3.org/2000/svg"}
    assert "Content-Security-Policy" in page


def test_failed_frames_are_lanegraph_evals(scene, run_out, moved_report):
    out, _ = run_out
    want = _eval_failed(out / "lanes.jsonl", scene["moved_gt"])
    assert MOVED_FRAME in want and len(want) < N_FRAMES
    data = _page_data(moved_report)
    assert [f["id"] for f in data["frames"] if f["r"][0]["fail"]] == want
    frame = next(f for f in data["frames"] if f["id"] == MOVED_FRAME)
    assert {ln["o"] for ln in frame["r"][0]["lanes"]} == {"false"} and "missed_ego" in frame["r"][0]["mo"]
    assert "failed: " in frame["r"][0]["line"]


def test_ablation_report_files(ablation_out):
    data = _page_data(ablation_out / "report" / "index.html")
    assert data["kind"] == "ablation" and data["variants"] == ["paper", "paper_literal"]
    assert all(len(f["r"]) == 2 and f["img"] for f in data["frames"])
    page = (ablation_out / "report" / "index.html").read_text()
    assert 'id="results-table"' in page and 'id="accuracy-vs-time"' in page and "paper_literal" in page


def test_ablation_report_later_needs_the_input(scene, ablation_out, tmp_path):
    """An ablation folder does not record its input: without --input no images; with it, the
    images and the ground truth in the input folder, as `ablate --report` had them."""
    r = CliRunner().invoke(main, ["report", str(ablation_out), "--out", str(tmp_path / "a")])
    assert r.exit_code == 0 and "no input given (--input or --dataset)" in r.output
    assert not any(f["img"] for f in _page_data(tmp_path / "a" / "index.html")["frames"])
    r = CliRunner().invoke(
        main,
        ["report", str(ablation_out), "--input", str(scene["seq"]), "--out", str(tmp_path / "b"), "--quiet"],
    )
    assert r.exit_code == 0, r.output
    later = _page_data(tmp_path / "b" / "index.html")
    assert later["frames"] == _page_data(ablation_out / "report" / "index.html")["frames"]


def test_frames_option_cuts_the_ground_truth_like_ablate(scene, run_out, tmp_path):
    out, _ = run_out
    r = CliRunner().invoke(
        main, ["report", str(out), "--frames", "1:3", "--out", str(tmp_path / "r"), "--quiet"]
    )
    assert r.exit_code == 0, r.output
    data = _page_data(tmp_path / "r" / "index.html")
    assert [f["id"] for f in data["frames"]] == ["0000000001", "0000000002"]
    assert all(f["img"] for f in data["frames"])


def test_report_without_ground_truth_or_graph(scene, run_out, tmp_path):
    """A run folder whose run.json names a graph and input that are gone: given --input, the
    installed source that recognises the folder reads the images; no metric, no drawing."""
    out, _ = run_out
    copy = tmp_path / "run"
    copy.mkdir()
    for name in ("lanes.jsonl", "timings.json"):
        shutil.copy(out / name, copy / name)
    (copy / "run.json").write_text(
        json.dumps({"graph": str(tmp_path / "gone.yaml"), "input": str(tmp_path / "gone"), "failures": []})
    )
    seq = tmp_path / "seq"
    shutil.copytree(scene["seq"], seq)
    (seq / "lanes_gt.jsonl").unlink()
    r = CliRunner().invoke(main, ["report", str(copy), "--input", str(seq), "--quiet"])
    assert r.exit_code == 0, r.output
    index = copy / "report" / "index.html"
    data = _page_data(index)
    assert data["sequences"][0]["gt"] is False and all(f["img"] and "gt" not in f for f in data["frames"])
    assert all(f["r"][0]["ok"] is None and not f["r"][0]["fail"] for f in data["frames"])
    assert "gone.yaml" in index.read_text()  # the note says why there is no graph


def test_node_pictures_come_only_from_the_runs_own_record(run_out, tmp_path):
    """The pictures of the folder run.json records as its --debug-dir, never those of another
    folder that happens to hold pictures of the same frames (another run's)."""
    out, _ = run_out
    copy = tmp_path / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    record = json.loads((copy / "run.json").read_text())
    assert record["debug_dir"] == "debug"
    r = CliRunner().invoke(main, ["report", str(copy), "--out", str(tmp_path / "own"), "--quiet"])
    assert r.exit_code == 0, r.output
    assert [f["id"] for f in _page_data(tmp_path / "own" / "index.html")["frames"] if f.get("dbg")] == [
        "0000000002"
    ]
    # the same pictures, now another run's folder: this run recorded none
    (copy / "debug").rename(copy / "dbg")
    record["debug_dir"] = None
    (copy / "run.json").write_text(json.dumps(record))
    r = CliRunner().invoke(main, ["report", str(copy), "--out", str(tmp_path / "other"), "--quiet"])
    assert r.exit_code == 0, r.output
    assert not [f for f in _page_data(tmp_path / "other" / "index.html")["frames"] if f.get("dbg")]


def test_a_new_report_replaces_its_own_assets_and_nothing_else(run_out, tmp_path):
    out, _ = run_out
    target = tmp_path / "r"
    for _ in range(2):
        r = CliRunner().invoke(main, ["report", str(out), "--out", str(target), "--quiet"])
        assert r.exit_code == 0, r.output
    assert len(list((target / "assets" / "frames").rglob("*.jpg"))) == N_FRAMES
    foreign = tmp_path / "foreign"
    (foreign / "assets").mkdir(parents=True)
    (foreign / "assets" / "mine.txt").write_text("keep")
    r = CliRunner().invoke(main, ["report", str(out), "--out", str(foreign), "--quiet"])
    assert r.exit_code == 2 and "was not written by `lanegraph report`" in r.output
    assert (foreign / "assets" / "mine.txt").read_text() == "keep" and not (foreign / "index.html").exists()


def test_a_planted_mark_does_not_make_a_users_folder_the_reports(run_out, tmp_path):
    # the report's mark file alone proves nothing: only lanegraph's ownership record does (issue 46)
    out, _ = run_out
    target = tmp_path / "photos"
    (target / "assets").mkdir(parents=True)
    (target / "assets" / "holiday.jpg").write_bytes(b"mine")
    (target / "assets" / ".lanegraph-report").write_text("planted")
    r = CliRunner().invoke(main, ["report", str(out), "--out", str(target), "--quiet"])
    assert r.exit_code == 2 and "was not written by `lanegraph report`" in r.output
    assert (target / "assets" / "holiday.jpg").read_bytes() == b"mine"
    # a page of the user's at index.html is not replaced either
    page = tmp_path / "site"
    page.mkdir()
    (page / "index.html").write_text("my page")
    r = CliRunner().invoke(main, ["report", str(out), "--out", str(page), "--quiet"])
    assert r.exit_code == 2 and (page / "index.html").read_text() == "my page"


def test_a_report_inside_a_run_folder_is_kept_by_the_runs_record(run_out, tmp_path):
    # lanegraph report RUN (into RUN/report) twice, then the run again with --overwrite: each step
    # replaces only what lanegraph wrote, and a user's file beside them stays
    out, _ = run_out
    run = tmp_path / "copy"
    r = CliRunner().invoke(main, ["run", "--frames", "0:2", "--out", str(run), "--quiet"])
    assert r.exit_code == 0, r.output
    (run / "notes.txt").write_text("mine")
    for _ in range(2):
        r = CliRunner().invoke(main, ["report", str(run), "--quiet"])
        assert r.exit_code == 0, r.output
    assert (run / "report" / "index.html").is_file()
    r = CliRunner().invoke(main, ["run", "--frames", "0:2", "--out", str(run), "--quiet", "--overwrite"])
    assert r.exit_code == 0, r.output
    assert (run / "notes.txt").read_text() == "mine"


def test_nothing_planted_in_the_report_folder_is_followed(run_out, tmp_path):
    out, _ = run_out
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    target = tmp_path / "r"
    target.mkdir()
    (target / "index.html").symlink_to(victim)
    r = CliRunner().invoke(main, ["report", str(out), "--out", str(target), "--quiet"])
    assert r.exit_code == 2 and "symbolic link" in r.output and victim.read_text() == "keep"
    (target / "index.html").unlink()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / ".lanegraph-report").write_text("")
    (target / "assets").symlink_to(elsewhere, target_is_directory=True)
    r = CliRunner().invoke(main, ["report", str(out), "--out", str(target), "--quiet"])
    assert r.exit_code == 2 and "was not written by `lanegraph report`" in r.output
    assert (elsewhere / ".lanegraph-report").exists()


def test_a_report_that_fails_leaves_the_earlier_one_whole(run_out, tmp_path, monkeypatch):
    from lanegraph_report import _page

    out, _ = run_out
    target = tmp_path / "r"
    r = CliRunner().invoke(main, ["report", str(out), "--out", str(target), "--quiet"])
    assert r.exit_code == 0, r.output
    before = sorted(str(p.relative_to(target)) for p in target.rglob("*"))
    page = (target / "index.html").read_text()

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(_page, "render", broken)
    r = CliRunner().invoke(main, ["report", str(out), "--out", str(target), "--quiet"])
    assert r.exit_code == 1, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert f"error: {target}: cannot write the report: disk full" in r.output, r.output
    assert sorted(str(p.relative_to(target)) for p in target.rglob("*")) == before
    assert (target / "index.html").read_text() == page


def test_a_report_out_that_cannot_be_a_folder(run_out, tmp_path, monkeypatch):
    """Issue 31, item 8: ``--out FILE`` gave a FileExistsError traceback, a read-only file system
    an OSError one; both are located usage errors (exit 2), the file left as it was."""
    out, _ = run_out
    f = tmp_path / "afile"
    f.write_text("keep me\n")
    for target, words in [(f, "exists and is not a folder"), (f / "sub", f"{f} is a file, not a folder")]:
        r = CliRunner().invoke(main, ["report", str(out), "--out", str(target), "--quiet"])
        assert r.exit_code == 2 and f"error: --out {target}: {words}" in r.output, r.output
        assert "Traceback" not in r.output
    assert f.read_text() == "keep me\n"

    def refuse(self, *a, **k):
        raise OSError(errno.EROFS, "Read-only file system", str(self))

    monkeypatch.setattr(Path, "mkdir", refuse)
    r = CliRunner().invoke(main, ["report", str(out), "--out", str(tmp_path / "ro"), "--quiet"])
    assert r.exit_code == 2, r.output
    assert f"error: --out {tmp_path / 'ro'}: cannot write there: Read-only file system" in r.output, r.output


def test_a_run_of_part_of_the_frames_needs_its_frames(scene, run_out, tmp_path):
    """Frames of the ground truth the run did not write count as failed, as in `lanegraph eval`;
    the report says so, and --frames cuts the ground truth like the run's selection."""
    out, _ = run_out
    part = tmp_path / "part"
    part.mkdir()
    (part / "lanes.jsonl").write_text("".join((out / "lanes.jsonl").read_text().splitlines(True)[:2]))
    (part / "run.json").write_text(
        json.dumps({"graph": str(ROOT / "graphs/paper.yaml"), "input": str(scene["seq"]), "failures": []})
    )
    r = CliRunner().invoke(main, ["report", str(part), "--out", str(tmp_path / "a")])
    assert r.exit_code == 0, r.output
    assert "2 of 4 ground-truth frame(s) are not in lanes.jsonl" in r.output and "same --frames" in r.output
    data = _page_data(tmp_path / "a" / "index.html")
    assert [f["id"] for f in data["frames"] if f["r"][0]["fail"]] == _eval_failed(
        part / "lanes.jsonl", scene["gt"]
    )
    assert [f["r"][0]["fail"] for f in data["frames"]] == [False, False, True, True]
    r = CliRunner().invoke(main, ["report", str(part), "--out", str(tmp_path / "b"), "--frames", "0:2"])
    assert r.exit_code == 0 and "not in lanes.jsonl" not in r.output
    assert [f["id"] for f in _page_data(tmp_path / "b" / "index.html")["frames"]] == [
        "0000000000",
        "0000000001",
    ]


def test_bad_folders_and_files_exit_2_saying_where(run_out, tmp_path):
    out, _ = run_out
    r = CliRunner().invoke(main, ["report", str(tmp_path / "nothing")])
    assert r.exit_code == 2 and "no such folder" in r.output
    (tmp_path / "empty").mkdir()
    r = CliRunner().invoke(main, ["report", str(tmp_path / "empty")])
    assert (
        r.exit_code == 2
        and f"not a run folder (no lanes file: {tmp_path / 'empty' / 'lanes.jsonl'})" in r.output
    ), r.output
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "lanes.jsonl").write_text('{"frame": "0", "lanes": []}\n{"frame": \n')
    r = CliRunner().invoke(main, ["report", str(bad)])
    assert r.exit_code == 2 and f"{bad / 'lanes.jsonl'}: line 2: not valid JSON" in r.output
    r = CliRunner().invoke(main, ["report", str(out), "--gt", str(tmp_path / "no.jsonl")])
    assert r.exit_code == 2 and "--gt" in r.output
    r = CliRunner().invoke(
        main, ["report", str(out), "--gt", str(out / "lanes.jsonl"), "--dataset", str(tmp_path / "d.yaml")]
    )
    assert r.exit_code == 2
    (bad / "lanes.jsonl").write_text('{"frame": "0", "lanes": [{"points": [["a", 1]]}]}\n')
    r = CliRunner().invoke(main, ["report", str(bad), "--out", str(tmp_path / "r")])
    assert r.exit_code == 2 and "frame 0" in r.output and "points" in r.output


def _dataset(scene, path: Path) -> Path:
    """Two sequences: the scene with its ground truth, and the scene with the moved one."""
    path.write_text(
        "name: two\nsequences:\n"
        f"  - {{name: exact, input: {scene['seq']}, gt: {scene['gt']}}}\n"
        f"  - {{name: moved, input: {scene['seq']}, gt: {scene['moved_gt']}, frames: '0:3'}}\n"
    )
    return path


def test_run_dataset_folder_as_eval_dataset_reads_it(scene, run_out, tmp_path):
    """`run --dataset` writes RUN_DIR/<sequence>/lanes.jsonl: the report's failed frames are the
    pooled ones of `lanegraph eval RUN_DIR --dataset FILE`."""
    out, _ = run_out
    ds = _dataset(scene, tmp_path / "ds.yaml")
    pred = tmp_path / "pred"
    for name, sel in (("exact", slice(None)), ("moved", slice(0, 3))):
        (pred / name).mkdir(parents=True)
        lines = (out / "lanes.jsonl").read_text().splitlines()[sel]
        (pred / name / "lanes.jsonl").write_text("\n".join(lines) + "\n")
    r = CliRunner().invoke(main, ["eval", str(pred), "--dataset", str(ds), "--json"])
    assert r.exit_code == 0, r.output
    want = [f["frame"] for f in json.loads(r.output)["sequences"]["all"]["failed_frames"]]
    assert want == [f"moved/{MOVED_FRAME}"]
    r = CliRunner().invoke(main, ["report", str(pred), "--dataset", str(ds), "--quiet"])
    assert r.exit_code == 0, r.output
    data = _page_data(pred / "report" / "index.html")
    assert [s["name"] for s in data["sequences"]] == ["exact", "moved"]
    names = [s["name"] for s in data["sequences"]]
    assert len(data["frames"]) == N_FRAMES + 3 and all(f["img"] for f in data["frames"])
    assert [f"{names[f['s']]}/{f['id']}" for f in data["frames"] if f["r"][0]["fail"]] == want
    page = (pred / "report" / "index.html").read_text()
    assert "all (pooled)" in page


def test_ablation_folder_over_a_dataset(scene, run_out, tmp_path):
    """An ablation folder over two sequences (runs/<variant>/<sequence>/): each variant's lanes on
    each sequence, with the dataset's inputs and ground truths."""
    out, _ = run_out
    ds = _dataset(scene, tmp_path / "ds.yaml")
    abl = tmp_path / "abl"
    lines = (out / "lanes.jsonl").read_text().splitlines()
    rows = [
        "variant,sequence,frames,detection_ratio,precision,ego_recall,mean_abs_dx_px,culane_f1,ms_per_frame,ms_disp,ms_fit"
    ]
    for variant in ("a", "b[x=1]"):
        for name, sel in (("exact", slice(None)), ("moved", slice(0, 3))):
            recs = [json.loads(x) for x in lines[sel]]
            if variant != "a":  # b reports nothing on frame 0
                recs[0]["lanes"] = []
            (abl / "runs" / variant / name).mkdir(parents=True)
            (abl / "runs" / variant / name / "lanes.jsonl").write_text(
                "".join(json.dumps(x) + "\n" for x in recs)
            )
            rows.append(f"{variant},{name},,,,,,,50,30,20")
        rows.append(f"{variant},all,,,,,,,50,30,20")
    (abl / "results.csv").write_text("\n".join(rows) + "\n")
    r = CliRunner().invoke(main, ["report", str(abl), "--dataset", str(ds), "--quiet"])
    assert r.exit_code == 0, r.output
    data = _page_data(abl / "report" / "index.html")
    assert data["kind"] == "ablation" and data["variants"] == ["a", "b[x=1]"]
    assert [s["name"] for s in data["sequences"]] == ["exact", "moved"] and len(
        data["frames"]
    ) == N_FRAMES + 3
    zero = [f for f in data["frames"] if f["id"] == "0000000000"]
    assert len(zero) == 2 and all(f["r"][1]["fail"] and f["r"][1]["lanes"] == [] for f in zero)
    # results.csv had no accuracy (an ablation without ground truth): computed from the dataset's
    page = (abl / "report" / "index.html").read_text()
    # pooled detection ratios: a 4/4 + 2/3 frames correct, b (nothing on both frames 0) 3/4 + 1/3
    assert "85.7 %" in page and "57.1 %" in page and 'id="stage-times"' in page
    # a sequence folder the dataset does not name is an error only when nothing matches
    r = CliRunner().invoke(
        main, ["report", str(abl), "--input", str(scene["seq"]), "--quiet", "--out", str(tmp_path / "r2")]
    )
    assert r.exit_code == 2 and "give --dataset" in r.output


def test_open_shows_the_report_in_the_browser(run_out, tmp_path, monkeypatch):
    import webbrowser

    out, _ = run_out
    opened = []
    monkeypatch.setattr(webbrowser, "open", lambda url: opened.append(url))
    r = CliRunner().invoke(main, ["report", str(out), "--out", str(tmp_path / "r"), "--open", "--quiet"])
    assert r.exit_code == 0, r.output
    assert opened == [(tmp_path / "r" / "index.html").resolve().as_uri()]


def test_open_without_a_browser_says_so(tmp_path, monkeypatch, capsys):
    import webbrowser

    from lanegraph_report.cli import open_in_browser

    page = tmp_path / "report" / "index.html"
    monkeypatch.setattr(webbrowser, "open", lambda url: False)  # what it returns with no browser
    assert open_in_browser(page) is False
    err = capsys.readouterr().err
    assert "no web browser found" in err and str(page) in err

    def broken(url):
        raise webbrowser.Error("could not locate runnable browser")

    monkeypatch.setattr(webbrowser, "open", broken)
    assert open_in_browser(page) is False and "no web browser found" in capsys.readouterr().err


def test_data_cannot_close_the_script_element():
    from lanegraph_report._page import dumps_for_html

    text = dumps_for_html({"frame": "</script><script>alert(1)</script>&"})
    assert "<" not in text and ">" not in text and "&" not in text
    assert json.loads(text) == {"frame": "</script><script>alert(1)</script>&"}


# --------------------------------------------------------------------------- in a real browser
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run",
]  # fmt: skip


def _chromium() -> str | None:
    for cand in (
        os.environ.get("LANEGRAPH_CHROMIUM"),
        "/usr/bin/chromium",
        shutil.which("chromium"),
        shutil.which("chromium-browser"),
    ):
        if cand and Path(cand).is_file():
            return cand
    return None


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright import sync_api
    except ImportError as exc:
        pytest.skip(f"playwright is not installed ({exc}): pip install -e '.[browser]'")
    exe = _chromium()
    if exe is None:
        pytest.skip(
            "no Chromium found (/usr/bin/chromium; Debian: apt-get install chromium; or set LANEGRAPH_CHROMIUM)"
        )
    with sync_api.sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
        yield b
        b.close()


class Page:
    """A report opened from file://, recording console errors and every request."""

    def __init__(self, browser, index: Path):
        self.page = browser.new_page(viewport={"width": 1280, "height": 820})
        self.errors: list[str] = []
        self.requests: list[str] = []
        self.page.on(
            "console",
            lambda m: self.errors.append(f"console {m.type}: {m.text}") if m.type == "error" else None,
        )
        self.page.on("pageerror", lambda e: self.errors.append(f"page error: {e}"))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.goto(index.resolve().as_uri())
        self.page.wait_for_selector("body[data-ready='1']")
        self.page.wait_for_load_state("load")

    def __getattr__(self, name):
        return getattr(self.page, name)

    def frame_ids(self, selector: str) -> list[str]:
        return self.page.eval_on_selector_all(selector, "els => els.map(e => e.dataset.frame)")

    def check_clean(self) -> None:
        assert self.errors == []
        assert self.requests and all(u.startswith("file://") for u in self.requests), self.requests

    def images_loaded(self, selector: str) -> int:
        return self.page.eval_on_selector_all(
            selector, "els => els.filter(e => e.complete && e.naturalWidth > 0).length"
        )


def _not_blank(png: Path) -> None:
    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] > 100
    assert float(img.std()) > 20 and len(np.unique(img.reshape(-1, 3), axis=0)) > 500


def _save_for_docs(png: Path, name: str) -> None:
    if os.environ.get("LANEGRAPH_UPDATE_DOCS_IMAGES") == "1":
        img = cv2.imread(str(png))
        cv2.imwrite(str(ROOT / "docs" / "img" / name), img, [cv2.IMWRITE_JPEG_QUALITY, 82])


def test_run_report_in_chromium(browser, scene, run_out, moved_report, tmp_path):
    out, _ = run_out
    p = Page(browser, moved_report)
    first = p.text_content("#frame-id")
    href = p.get_attribute("#frame-view svg image", "href")
    assert first.startswith("0000000000") and href.endswith(".jpg")
    p.keyboard.press("ArrowRight")
    assert p.text_content("#frame-id").startswith("0000000001")
    assert p.get_attribute("#frame-view svg image", "href") != href
    # the moved frame is drawn failed: false lanes, and the ego boundaries it missed
    assert p.locator("#frame-view polyline.lane.false").count() >= 1
    assert p.locator("#frame-view polyline.gt.missed_ego").count() >= 1
    assert "failed: " in p.text_content("#metric-line")
    # "failed only" lists exactly what `lanegraph eval` reports as failed
    want = _eval_failed(out / "lanes.jsonl", scene["moved_gt"])
    assert p.frame_ids("#frame-list li.frame") == [f"{k:010d}" for k in range(N_FRAMES)]
    p.check("#failed-only")
    assert p.frame_ids("#frame-list li.frame") == want
    assert p.frame_ids("#frame-list li.frame.failed") == want
    # the node pictures of frame 2, and the graph drawing
    p.uncheck("#failed-only")
    p.click('#frame-list li.frame[data-frame="0000000002"]')
    p.click("#tab-nodes")
    n = p.locator("#node-pictures img").count()
    assert n > 10
    p.wait_for_function(f"document.querySelectorAll('#node-pictures img').length === {n} && "
                        "[...document.querySelectorAll('#node-pictures img')].every(i => i.complete)")  # fmt: skip
    assert p.images_loaded("#node-pictures img") == n
    assert p.locator("#graph svg g.node").count() == 20  # paper.yaml's nodes
    p.click("#tab-metrics")
    assert p.locator("#metrics-table tbody tr").count() == 1 and p.locator("#node-times svg").count() == 1
    p.check_clean()


def test_run_report_screenshot(browser, run_out, tmp_path):
    out, _ = run_out
    p = Page(browser, out / "report" / "index.html")
    p.keyboard.press("ArrowRight")
    p.keyboard.press("ArrowRight")
    p.wait_for_function("document.querySelector('#frame-view svg image') !== null")
    shot = tmp_path / "frames.png"
    p.screenshot(path=str(shot), clip={"x": 0, "y": 0, "width": 1280, "height": 470})
    _not_blank(shot)
    _save_for_docs(shot, "report_frames.jpg")
    p.check_clean()


def test_ablation_report_in_chromium(browser, ablation_out, tmp_path):
    p = Page(browser, ablation_out / "report" / "index.html")
    # the frames tab follows the chosen variant: paper_literal fails where paper does not
    p.select_option("#variant", "1")
    failed_literal = p.locator("#frame-list li.frame.failed").count()
    p.select_option("#variant", "0")
    assert failed_literal > p.locator("#frame-list li.frame.failed").count()
    # sortable results table: by detection ratio, ascending puts paper_literal first
    p.click("#tab-metrics")
    p.click("#results-table th:nth-child(4)")
    assert p.text_content("#results-table tbody tr:first-child td:first-child") == "paper_literal"
    p.click("#results-table th:nth-child(4)")
    assert p.text_content("#results-table tbody tr:first-child td:first-child") == "paper"
    # side by side: two variants on the same frame, the frames where they disagree first
    p.click("#tab-compare")
    assert p.text_content("#cmp-name-a") == "A: paper" and p.text_content("#cmp-name-b") == "B: paper_literal"
    assert p.locator("#cmp-view-a svg image").count() == 1 and p.locator("#cmp-view-b svg image").count() == 1
    classes = p.eval_on_selector_all(
        "#cmp-list li.frame", "els => els.map(e => e.classList.contains('disagree'))"
    )
    assert classes[0] and classes == sorted(classes, reverse=True)
    assert (
        p.locator("#cmp-view-b polyline.lane.false").count()
        + p.locator("#cmp-view-b polyline.gt.missed_ego").count()
        > 0
    )
    shown = p.text_content("#cmp-frame-id")
    p.keyboard.press("ArrowRight")
    assert p.text_content("#cmp-frame-id") != shown
    p.keyboard.press("ArrowLeft")
    shot = tmp_path / "side_by_side.png"
    p.screenshot(path=str(shot), clip={"x": 0, "y": 0, "width": 1280, "height": 400})
    _not_blank(shot)
    _save_for_docs(shot, "report_side_by_side.jpg")
    p.select_option("#cmp-b", "0")
    assert (
        p.text_content("#cmp-name-b") == "B: paper" and p.locator("#cmp-list li.frame.disagree").count() == 0
    )
    p.check_clean()


def test_svg_drawings_escape_their_text_and_draw_every_node_and_edge():
    from lanegraph_report import _svg

    edges = [
        ("a", "x", "b", "in", False),
        ("b", "y", "c", "in", False),
        ("a", "x", "c", "other", False),
        ("c", "z", "b", "prev", True),
    ]
    svg = _svg.graph_svg(
        ["a", "b", "c"], {"a": "t.a", "b": "t.b", "c": "t.c"}, edges, {"b": {"median_ms": 3.0, "p90_ms": 4.5}}
    )
    assert (
        svg.count('<g class="node"') == 3
        and svg.count("marker-end=") == 4
        and svg.count("stroke-dasharray") == 1
    )
    assert "3.0 / 4.5 ms" in svg and "no timing" in svg
    scatter = _svg.scatter_svg([("<b>x</b>", 10.0, 0.5), ("no time", None, 1.0)], "ms", "ratio")
    assert (
        "&lt;b&gt;x&lt;/b&gt;" in scatter and "<b>" not in scatter and scatter.count('<g class="point"') == 1
    )
    bars = _svg.stage_times_svg(["v&1"], ["disp", "fit"], {"v&1": {"disp": 30.0, "fit": None}})
    assert "v&amp;1" in bars and "30.0 ms" in bars
