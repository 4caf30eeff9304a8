"""benchmarks/sweep_kitti.py: the changed sequences it writes (on tiny KITTI raw and KITTI odometry
layouts made here) and its table over a dataset file (a row per sequence, a pooled row)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from lanegraph_io._sources import KittiOdometryParams, KittiOdometrySource, KittiRawParams, KittiRawSource

from lanegraph.errors import InputError
from lanegraph.nodes import RunContext

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(
    0, str(ROOT / "benchmarks")
)  # as when the script runs: its folder first (benchmarks/_sweep.py)
_spec = importlib.util.spec_from_file_location("sweep_kitti", ROOT / "benchmarks" / "sweep_kitti.py")
sweep_kitti = importlib.util.module_from_spec(_spec)
sys.modules["sweep_kitti"] = sweep_kitti  # its dataclass looks its module up
_spec.loader.exec_module(sweep_kitti)

# KITTI's colour pair with the principal point moved into the 320 x 60 images of these tests
P2 = "7.215377e+02 0 1.605593e+02 4.485728e+01 0 7.215377e+02 3.02854e+01 2.163791e-01 0 0 1 2.745884e-03"
P3 = "7.215377e+02 0 1.605593e+02 -3.395242e+02 0 7.215377e+02 3.02854e+01 2.199936e+00 0 0 1 2.729905e-03"
W, H, SHIFT = 320, 60, 8


def tiny_drive(tmp_path: Path) -> Path:
    """Two frames of a random texture seen with disparity SHIFT everywhere, and a ground truth."""
    drive = tmp_path / "2011_09_26" / "2011_09_26_drive_0001_sync"
    rng = np.random.default_rng(0)
    gt = []
    for k in range(2):
        tex = cv2.GaussianBlur(rng.integers(0, 256, (H, W + SHIFT)).astype(np.uint8), (0, 0), 1.0)
        left, right = tex[:, :W], tex[:, SHIFT:]  # left(x) = right(x - SHIFT): disparity SHIFT
        for cam, im in (("image_02", left), ("image_03", right)):
            (drive / cam / "data").mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(drive / cam / "data" / f"{k:010d}.png"), np.dstack([im] * 3))
        gt.append(
            {
                "frame": f"{k:010d}",
                "image_size": [W, H],
                "markings": [{"id": 2, "kind": "dashed", "points": [[200.0, 20], [210.0, 40]]}],
                "ego": {"left": 2, "right": None},
            }
        )
    (drive / "lanes_gt.jsonl").write_text("\n".join(json.dumps(g) for g in gt) + "\n")
    (drive.parent / "calib_cam_to_cam.txt").write_text(
        f"S_rect_02: {W} {H}\nP_rect_02: {P2}\nP_rect_03: {P3}\n"
    )
    return drive


def calib_of(drive: Path):
    return KittiRawSource(KittiRawParams(), RunContext(input_path=drive)).constants()["calib"]


@pytest.mark.parametrize(
    "spec, expected",
    [
        ("recorded", ("recorded", None)),
        ("gain:0.5", ("gain", 0.5)),
        ("crop:1224x368", ("crop", (1224, 368))),
        ("step:3", ("step", 3.0)),
        ("noise:4", ("noise", 4.0)),
    ],
)
def test_parse_variant(spec, expected):
    assert sweep_kitti.parse_variant(spec) == expected


@pytest.mark.parametrize(
    "spec, words",
    [
        ("gain", "gain:NUMBER"),
        ("step:1.5", "integer"),
        ("crop:12", "WIDTHxHEIGHT"),
        ("fog:2", "unknown"),
        ("mirror:1", "no argument"),
        ("gain:-1", "positive"),
        ("gain:nan", "positive"),
        ("blur:inf", "positive"),
    ],
)
def test_parse_variant_errors(spec, words):
    with pytest.raises(ValueError, match=words):
        sweep_kitti.parse_variant(spec)


def test_mirror_swaps_the_cameras_and_moves_the_ground_truth(tmp_path):
    drive = tiny_drive(tmp_path)
    out = sweep_kitti.write_variant(drive, tmp_path / "m", "mirror", None)
    old, new = calib_of(drive), calib_of(out)
    assert new.cx == pytest.approx(W - 1 - old.cx, abs=1e-3) and new.cy == pytest.approx(old.cy, abs=1e-3)
    assert new.f == pytest.approx(old.f, rel=1e-6) and new.baseline == pytest.approx(old.baseline, rel=1e-5)
    old_right = cv2.imread(str(drive / "image_03" / "data" / "0000000001.png"))
    np.testing.assert_array_equal(
        cv2.imread(str(out / "image_02" / "data" / "0000000001.png")), cv2.flip(old_right, 1)
    )
    rec = json.loads((out / "lanes_gt.jsonl").read_text().splitlines()[1])
    # (x, y) of the left image is (x - SHIFT, y) in the right one, mirrored
    np.testing.assert_allclose(
        rec["markings"][0]["points"], [[W - 1 - (200 - SHIFT), 20], [W - 1 - (210 - SHIFT), 40]], atol=0.6
    )
    assert rec["ego"] == {"left": None, "right": 2}


def test_gain_and_crop_variants(tmp_path):
    drive = tiny_drive(tmp_path)
    src = cv2.imread(str(drive / "image_03" / "data" / "0000000000.png"))
    dark = sweep_kitti.write_variant(drive, tmp_path / "g", "gain", 0.5)
    np.testing.assert_array_equal(
        cv2.imread(str(dark / "image_03" / "data" / "0000000000.png")), (src * 0.5).astype(np.uint8)
    )
    crop = sweep_kitti.write_variant(drive, tmp_path / "c", "crop", (300, 50))
    assert cv2.imread(str(crop / "image_02" / "data" / "0000000000.png")).shape == (50, 300, 3)
    c = calib_of(crop)
    assert (c.width, c.height) == (300, 50) and c.cx == pytest.approx(calib_of(drive).cx)
    assert (crop / "lanes_gt.jsonl").read_text() == (drive / "lanes_gt.jsonl").read_text()


def test_a_missing_frame_is_named(tmp_path):
    drive = tiny_drive(tmp_path)
    (drive / "image_03" / "data" / "0000000001.png").unlink()
    with pytest.raises(InputError, match="0000000001.png has no right partner in .*image_03/data"):
        sweep_kitti.write_variant(drive, tmp_path / "g", "gain", 0.5)
    (drive / "image_02" / "data" / "0000000001.png").unlink()  # the ground truth still lists frame 1
    with pytest.raises(
        InputError,
        match=r"lanes_gt.jsonl: frame 0000000001 of the ground truth is not among the images of .*image_02/data",
    ):
        sweep_kitti.write_variant(drive, tmp_path / "g", "gain", 0.5)
    assert not (tmp_path / "g").exists()  # found before anything is written


def test_unpainted_inpaints_along_the_markings_only(tmp_path):
    drive = tiny_drive(tmp_path)
    left = cv2.imread(str(drive / "image_02" / "data" / "0000000000.png"))
    bright = left.copy()
    cv2.line(bright, (200, 20), (210, 40), (255, 255, 255), 3)  # paint on the annotated polyline
    cv2.imwrite(str(drive / "image_02" / "data" / "0000000000.png"), bright)
    out = sweep_kitti.write_variant(drive, tmp_path / "u", "unpainted", None)
    got = cv2.imread(str(out / "image_02" / "data" / "0000000000.png")).astype(int)
    assert got[30, 205].max() < 230  # the paint is gone
    np.testing.assert_array_equal(got[:, :150], left[:, :150])  # far from the marking: untouched
    rec = json.loads((out / "lanes_gt.jsonl").read_text().splitlines()[0])
    assert rec["markings"] == [] and rec["ego"] == {"left": None, "right": None}


# KITTI odometry: grey image_0 / image_1, calib.txt with the P0, P1, P2 rows and Tr (as the real
# files), the principal point moved into the 320 x 60 images of these tests
P0 = "7.070912e+02 0 1.518873e+02 0 0 7.070912e+02 2.81104e+01 0 0 0 1 0"
P1 = "7.070912e+02 0 1.518873e+02 -3.798145e+02 0 7.070912e+02 2.81104e+01 0 0 0 1 0"
OTHER_ROWS = [
    "P2: 7.070912e+02 0 1.518873e+02 4.688783e+01 0 7.070912e+02 2.81104e+01 1.178601e-01 0 0 1 6.203223e-03",
    "Tr: 1 0 0 0 0 1 0 0 0 0 1 0",
]


def tiny_odometry(tmp_path: Path, n: int = 2, markings: bool = True, name: str = "seq7") -> Path:
    """``n`` grey frames of a random texture seen with disparity SHIFT everywhere, numbered from 32
    (as seq2's excerpt), and a ground truth with a marking (at x >= 128, where the mirror's SGBM with
    128 disparities measures one) or none."""
    seq = tmp_path / name
    rng = np.random.default_rng(1)
    gt = []
    for k in range(32, 32 + n):
        tex = cv2.GaussianBlur(rng.integers(40, 216, (H, W + SHIFT)).astype(np.uint8), (0, 0), 1.0)
        for cam, im in (("image_0", tex[:, :W]), ("image_1", tex[:, SHIFT:])):
            (seq / cam).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(seq / cam / f"{k:06d}.png"), im)
        marks = [{"id": 1, "kind": "dashed", "points": [[230.0, 20], [220.0, 40]]}] if markings else []
        gt.append(
            {
                "frame": f"{k:06d}",
                "image_size": [W, H],
                "markings": marks,
                "ego": {"left": 1 if markings else None, "right": None},
            }
        )
    (seq / "lanes_gt.jsonl").write_text("\n".join(json.dumps(g) for g in gt) + "\n")
    (seq / "calib.txt").write_text("\n".join([f"P0: {P0}", f"P1: {P1}", *OTHER_ROWS]) + "\n")
    (seq / "times.txt").write_text("".join(f"{0.1 * k:e}\n" for k in range(n)))
    return seq


def odometry_calib_of(seq: Path):
    return KittiOdometrySource(KittiOdometryParams(), RunContext(input_path=seq)).constants()["calib"]


def grey(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None and img.ndim == 2, f"{path}: expected a grey image"
    return img


def test_the_layout_is_told_from_the_folder(tmp_path):
    raw = sweep_kitti.open_sequence(tiny_drive(tmp_path))
    assert (raw.source, raw.cameras, raw.keys, raw.gray) == (
        "io.kitti_raw",
        (Path("image_02/data"), Path("image_03/data")),
        ("P_rect_02", "P_rect_03"),
        False,
    )
    assert raw.calib_path.name == "calib_cam_to_cam.txt" and list(raw.images) == ["0000000000", "0000000001"]
    odo = sweep_kitti.open_sequence(tiny_odometry(tmp_path))
    assert (odo.source, odo.cameras, odo.keys, odo.gray) == (
        "io.kitti_odometry",
        (Path("image_0"), Path("image_1")),
        ("P0", "P1"),
        True,
    )
    assert odo.calib.baseline == pytest.approx(379.8145 / 707.0912) and list(odo.images) == [
        "000032",
        "000033",
    ]
    (tmp_path / "pairs" / "left").mkdir(parents=True)
    (tmp_path / "pairs" / "right").mkdir()
    with pytest.raises(
        InputError, match="a folder for io.folder: expected a KITTI raw drive .* or a KITTI odometry sequence"
    ):
        sweep_kitti.open_sequence(tmp_path / "pairs")


# the variants that change every pixel alike: (variant, argument, what each image of the pair becomes)
POINTWISE = [
    ("gain", 0.5, lambda L, R: ((L * 0.5).astype(np.uint8), (R * 0.5).astype(np.uint8))),
    ("right_gain", 0.75, lambda L, R: (L, (R * 0.75).astype(np.uint8))),
    ("haze", 0.6, lambda L, R: tuple(np.clip(i * 0.6 + 0.4 * 128, 0, 255).astype(np.uint8) for i in (L, R))),
    ("blur", 1.2, lambda L, R: tuple(cv2.GaussianBlur(i, (0, 0), 1.2) for i in (L, R))),
]


@pytest.mark.parametrize("kind, arg, expected", POINTWISE, ids=[p[0] for p in POINTWISE])
def test_odometry_variants_keep_the_layout(tmp_path, kind, arg, expected):
    seq = tiny_odometry(tmp_path)
    out = sweep_kitti.write_variant(seq, tmp_path / "v", kind, arg)
    assert out == tmp_path / "v" / "seq7"
    assert sorted(p.name for p in out.iterdir()) == [
        "calib.txt",
        "image_0",
        "image_1",
        "lanes_gt.jsonl",
        "times.txt",
    ]
    for fr in ("000032", "000033"):
        want = expected(*(grey(seq / cam / f"{fr}.png") for cam in ("image_0", "image_1")))
        for cam, w in zip(("image_0", "image_1"), want):
            np.testing.assert_array_equal(grey(out / cam / f"{fr}.png"), w)
    assert (out / "calib.txt").read_text().splitlines() == (seq / "calib.txt").read_text().splitlines()
    assert (out / "lanes_gt.jsonl").read_text() == (seq / "lanes_gt.jsonl").read_text()
    assert odometry_calib_of(out) == odometry_calib_of(seq)


def test_odometry_noise_is_grey_and_independent_per_image(tmp_path):
    seq = tiny_odometry(tmp_path)
    out = sweep_kitti.write_variant(seq, tmp_path / "n", "noise", 4.0)
    diffs = [
        grey(out / cam / "000032.png").astype(float) - grey(seq / cam / "000032.png")
        for cam in ("image_0", "image_1")
    ]
    for d in diffs:
        assert np.std(d) == pytest.approx(4.0, rel=0.1) and np.mean(d) == pytest.approx(
            -0.5, abs=0.1
        )  # uint8 truncates: -0.5 on average
    assert abs(np.corrcoef(diffs[0].ravel(), diffs[1].ravel())[0, 1]) < 0.05


def test_odometry_crop_keeps_the_projections(tmp_path):
    seq = tiny_odometry(tmp_path)
    out = sweep_kitti.write_variant(seq, tmp_path / "c", "crop", (300, 50))
    assert grey(out / "image_1" / "000033.png").shape == (50, 300)
    np.testing.assert_array_equal(
        grey(out / "image_0" / "000033.png"), grey(seq / "image_0" / "000033.png")[:50, :300]
    )
    assert (out / "calib.txt").read_text() == (
        seq / "calib.txt"
    ).read_text()  # no image size in calib.txt; cx stays
    c = odometry_calib_of(out)
    assert (c.cx, c.cy, c.f) == (
        odometry_calib_of(seq).cx,
        odometry_calib_of(seq).cy,
        odometry_calib_of(seq).f,
    )


def test_odometry_mirror_swaps_the_cameras_and_moves_the_ground_truth(tmp_path):
    seq = tiny_odometry(tmp_path)
    out = sweep_kitti.write_variant(seq, tmp_path / "m", "mirror", None)
    old, new = odometry_calib_of(seq), odometry_calib_of(out)
    assert new.cx == pytest.approx(W - 1 - old.cx, abs=1e-3) and new.cy == pytest.approx(old.cy, abs=1e-3)
    assert new.f == pytest.approx(old.f, rel=1e-6) and new.baseline == pytest.approx(old.baseline, rel=1e-5)
    rows = (out / "calib.txt").read_text().splitlines()
    assert rows[2:] == OTHER_ROWS  # only the pair's rows change
    np.testing.assert_array_equal(
        grey(out / "image_0" / "000033.png"), cv2.flip(grey(seq / "image_1" / "000033.png"), 1)
    )
    np.testing.assert_array_equal(
        grey(out / "image_1" / "000033.png"), cv2.flip(grey(seq / "image_0" / "000033.png"), 1)
    )
    rec = json.loads((out / "lanes_gt.jsonl").read_text().splitlines()[1])
    assert rec["frame"] == "000033"
    np.testing.assert_allclose(
        rec["markings"][0]["points"], [[W - 1 - (230 - SHIFT), 20], [W - 1 - (220 - SHIFT), 40]], atol=0.6
    )
    assert rec["ego"] == {"left": None, "right": 1}


def test_odometry_unpainted(tmp_path):
    seq = tiny_odometry(tmp_path)
    left = grey(seq / "image_0" / "000032.png")
    bright = left.copy()
    cv2.line(bright, (230, 20), (220, 40), 255, 3)  # paint on the annotated polyline
    cv2.imwrite(str(seq / "image_0" / "000032.png"), bright)
    out = sweep_kitti.write_variant(seq, tmp_path / "u", "unpainted", None)
    got = grey(out / "image_0" / "000032.png")
    assert got[30, 225] < 230  # the paint is gone
    np.testing.assert_array_equal(got[:, :150], left[:, :150])  # far from the marking: untouched
    assert [json.loads(ln)["markings"] for ln in (out / "lanes_gt.jsonl").read_text().splitlines()] == [
        [],
        [],
    ]


def test_a_frame_selection_writes_those_frames_only(tmp_path):
    seq = tiny_odometry(tmp_path, n=3)
    gt = [json.loads(ln) for ln in (seq / "lanes_gt.jsonl").read_text().splitlines()][1:]
    out = sweep_kitti.write_variant(sweep_kitti.open_sequence(seq), tmp_path / "g", "gain", 0.5, gt)
    assert sorted(p.name for p in (out / "image_0").iterdir()) == ["000033.png", "000034.png"]
    assert [json.loads(ln)["frame"] for ln in (out / "lanes_gt.jsonl").read_text().splitlines()] == [
        "000033",
        "000034",
    ]


# a graph that reports no lane on any frame: the sweep's table is then known exactly
NOTHING = "name: nothing\nnodes:\n  src: {type: io.auto}\n  out: {type: io.write_lanes, inputs: {frame: src.frame}}\n"


def test_dataset_rows_per_sequence_and_pooled(tmp_path, capsys):
    """A raw drive (2 frames, an ego marking on each: nothing reported is wrong) and an odometry
    sequence without markings, its frames 1: of 4 chosen in the dataset (nothing reported is right):
    a row per sequence and a pooled row over the frames of both (3 / 5, not the sequences' mean
    1 / 2), per variant; the step variant runs every 2nd frame of each sequence's selection."""
    tiny_drive(tmp_path)
    tiny_odometry(tmp_path, n=4, markings=False)
    (tmp_path / "ds.yaml").write_text(
        "sequences:\n"
        "  - {name: drive, input: 2011_09_26/2011_09_26_drive_0001_sync, gt: 2011_09_26/2011_09_26_drive_0001_sync/lanes_gt.jsonl}\n"
        "  - {name: odo, input: seq7, gt: seq7/lanes_gt.jsonl, frames: '1:'}\n"
    )
    (tmp_path / "nothing.yaml").write_text(NOTHING)
    work = tmp_path / "work"
    rc = sweep_kitti.main(
        [
            str(tmp_path / "nothing.yaml"),
            "--dataset",
            str(tmp_path / "ds.yaml"),
            "--variants",
            "gain:0.5,step:2",
            "--work",
            str(work),
            "--quiet",
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    rows = {(r["variant"], r["sequence"]): r for r in json.loads((work / "sweep.json").read_text())["rows"]}
    assert set(rows) == {(v, s) for v in ("gain:0.5", "step:2") for s in ("drive", "odo", "all")}
    figures = {k: (r["frames"], r["detection_ratio"], r["ego_recall"], r["lanes"]) for k, r in rows.items()}
    assert figures == {
        ("gain:0.5", "drive"): (2, 0.0, 0.0, 0),
        ("gain:0.5", "odo"): (3, 1.0, None, 0),
        ("gain:0.5", "all"): (5, 0.6, 0.0, 0),
        ("step:2", "drive"): (1, 0.0, 0.0, 0),  # frame 0
        ("step:2", "odo"): (2, 1.0, None, 0),  # frames 1 and 3 of 1:
        ("step:2", "all"): (3, pytest.approx(2 / 3), 0.0, 0),
    }
    # the step ran on the frames chosen, the variant on its own copy in the input's layout
    assert [
        json.loads(ln)["frame"]
        for ln in (work / "runs" / "step_2" / "odo" / "lanes.jsonl").read_text().splitlines()
    ] == ["000033", "000035"]
    assert sorted(p.name for p in (work / "data" / "gain_0.5" / "odo" / "seq7" / "image_0").iterdir()) == [
        "000033.png",
        "000034.png",
        "000035.png",
    ]
    lines = [ln.split() for ln in out.splitlines()]
    assert lines[1][:2] == ["variant", "sequence"]
    assert [ln[:2] for ln in lines[2:]] == [
        [v, s] for v in ("gain:0.5", "step:2") for s in ("drive", "odo", "all")
    ]
    assert lines[4][2:] == ["60.0", "%", "-", "0.0", "%", "0"]  # the pooled row of gain:0.5


def test_dataset_errors_stop_before_any_run(tmp_path, capsys):
    seq = tiny_odometry(tmp_path)
    (seq / "lanes_gt.jsonl").unlink()
    (tmp_path / "ds.yaml").write_text("sequences:\n  - {name: odo, input: seq7}\n")
    assert (
        sweep_kitti.main(["g.yaml", "--dataset", str(tmp_path / "ds.yaml"), "--work", str(tmp_path / "w")])
        == 2
    )
    assert "sequence 'odo' of " in capsys.readouterr().err and not (tmp_path / "w").exists()
    assert sweep_kitti.main(["g.yaml", "--input", str(seq), "--work", str(tmp_path / "w")]) == 2
    assert "--input: no ground truth" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        sweep_kitti.main(["g.yaml", "--input", str(seq), "--dataset", str(tmp_path / "ds.yaml")])
    assert exc.value.code == 2 and "instead of --input" in capsys.readouterr().err


@pytest.mark.kitti
def test_the_developer_sequences_open_and_mirror(tmp_path):
    """graphs/datasets/dev.yaml: every sequence opens in its own layout with its ground truth's
    frames; two real odometry frames mirrored read back with the cx mirrored."""
    if not (ROOT.parent / "shared" / "data" / "kitti_odometry" / "seq2").is_dir():
        pytest.skip("real KITTI data not found at ../shared/data (a fresh clone has none)")
    args = sweep_kitti.argparse.Namespace(dataset=str(ROOT / "graphs" / "datasets" / "dev.yaml"), input="")
    ds, opened = sweep_kitti._open_dataset(args)
    assert {n: (seq.source, str(seq.cameras[0]), len(gt)) for n, (seq, gt) in opened.items()} == {
        "drive_0001": ("io.kitti_raw", "image_02/data", 54),
        "seq1": ("io.kitti_odometry", "image_0", 26),
        "seq2": ("io.kitti_odometry", "image_0", 19),
        "seq2_ramp": ("io.kitti_odometry", "image_0", 16),
        # the single pairs of other streets: colour (image_2/image_3, P2/P3 of calib.txt)
        "kitti15_000024": ("io.kitti_odometry", "image_2", 1),
        "kitti12_000070": ("io.kitti_odometry", "image_2", 1),
        "odom00": ("io.kitti_odometry", "image_2", 2),
        "kitti15_000005": ("io.kitti_odometry", "image_2", 1),
    }
    seq, gt = opened["seq2"]
    out = sweep_kitti.write_variant(seq, tmp_path, "mirror", None, gt[:2])
    old, new = odometry_calib_of(seq.root), odometry_calib_of(out)
    assert new.cx == pytest.approx(1240 - old.cx, abs=1e-3) and new.baseline == pytest.approx(
        old.baseline, rel=1e-5
    )
    recs = [json.loads(ln) for ln in (out / "lanes_gt.jsonl").read_text().splitlines()]
    assert [r["ego"] for r in recs] == [
        {"left": g["ego"]["right"], "right": g["ego"]["left"]} for g in gt[:2]
    ]
    for r in recs:  # every moved point inside the image
        assert all(0 <= x < 1241 for m in r["markings"] for x, _ in m["points"])
