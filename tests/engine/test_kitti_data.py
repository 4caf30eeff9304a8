"""`lanegraph data kitti`: KITTI downloads (zips built here the way KITTI packs them, from
../shared/data, or tiny stand-ins) checked and laid out, with the shipped lane ground truth."""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest
from click.testing import CliRunner
from lanegraph_data.kitti import GROUND_TRUTH, ground_truth_file

from lanegraph.cli import main
from lanegraph.evaluation.dataset import load_dataset

from ..conftest import SHARED

PNG = b"\x89PNG\r\n\x1a\n" + b"\x00\x00\x00\rIHDR" + (8).to_bytes(4, "big") + (4).to_bytes(4, "big") + b"rest"
DATE = "2011_09_26"


def _zip(path: Path, members: dict[str, bytes | Path]) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        for name, data in members.items():
            if isinstance(data, Path):
                z.write(data, name)
            else:
                z.writestr(name, data)
    return path


def _fake_drive(tmp: Path, drive: str = "0002", frames: int = 3, right: int | None = None) -> Path:
    name = f"{DATE}_drive_{drive}_sync"
    members: dict[str, bytes | Path] = {}
    for cam, n in (("image_02", frames), ("image_03", frames if right is None else right)):
        for k in range(n):
            members[f"{DATE}/{name}/{cam}/data/{k:010d}.png"] = PNG
        members[f"{DATE}/{name}/{cam}/timestamps.txt"] = b"2011-09-26 13:02:25.964389445\n" * n
    members[f"{DATE}/{name}/oxts/data/0000000000.txt"] = b"0 0 0\n"  # left out
    return _zip(tmp / f"{name}.zip", members)


def _fake_calib(tmp: Path) -> Path:
    return _zip(
        tmp / f"{DATE}_calib.zip", {f"{DATE}/calib_cam_to_cam.txt": b"P_rect_02: 1 0 0 0 0 1 0 0 0 0 1 0\n"}
    )


def _run(*args: str):
    return CliRunner().invoke(main, ["data", "kitti", *args])


def test_fake_drive_laid_out_without_ground_truth(tmp_path):
    out = tmp_path / "out"
    r = _run(str(_fake_drive(tmp_path)), str(_fake_calib(tmp_path)), "--out", str(out))
    assert r.exit_code == 0, r.output
    drive = out / "kitti_raw" / DATE / f"{DATE}_drive_0002_sync"
    assert sorted(p.name for p in (drive / "image_02" / "data").iterdir()) == [
        f"{k:010d}.png" for k in range(3)
    ]
    assert (drive / "image_03" / "timestamps.txt").is_file() and not (drive / "oxts").exists()
    assert (out / "kitti_raw" / DATE / "calib_cam_to_cam.txt").is_file()
    assert not (drive / "lanes_gt.jsonl").exists()  # lanegraph has no ground truth for drive 0002
    ds = load_dataset(out / "kitti.yaml")
    assert [(s.name, s.input, s.gt) for s in ds.sequences] == [("drive_0002", drive, None)]


@pytest.mark.parametrize(
    "case, expected",
    [
        ("no calib", "give 2011_09_26_calib.zip too"),
        ("right camera short", "image_02 has 3 frame(s), image_03 2"),
        ("gap", "frame 1 missing (a partial download?)"),
        ("truncated zip", "not a complete zip file"),
        ("not kitti", "nothing of a KITTI download"),
        ("calib only", "no images"),
        ("missing file", "no such file or folder"),
    ],
)
def test_wrong_or_partial_downloads_exit_2_before_writing(tmp_path, case, expected):
    out = tmp_path / "out"
    calib = _fake_calib(tmp_path)
    if case == "no calib":
        args = [_fake_drive(tmp_path)]
    elif case == "right camera short":
        args = [_fake_drive(tmp_path, right=2), calib]
    elif case == "gap":
        z = _fake_drive(tmp_path)
        with zipfile.ZipFile(z) as src, zipfile.ZipFile(tmp_path / "gap.zip", "w") as dst:
            for info in src.infolist():
                if "0000000001.png" not in info.filename:
                    dst.writestr(info, src.read(info))
        args = [tmp_path / "gap.zip", calib]
    elif case == "truncated zip":
        z = _fake_drive(tmp_path)
        data = z.read_bytes()
        z.write_bytes(data[: len(data) // 2])
        args = [z, calib]
    elif case == "not kitti":
        args = [_zip(tmp_path / "photos.zip", {"holiday/beach.png": PNG}), calib]
    elif case == "calib only":
        args = [calib]
    else:
        args = [tmp_path / "nope.zip"]
    r = _run(*map(str, args), "--out", str(out))
    assert r.exit_code == 2, r.output
    assert expected in r.output and "Traceback" not in r.output
    assert r.output.startswith("error: ") and r.output.count("\n") == 1  # one located line
    assert not out.exists()  # checked before anything is written


def test_zip_members_never_write_outside_out(tmp_path):
    """Names with '..', absolute names and links planted in OUT: nothing lands outside OUT."""
    name = f"{DATE}_drive_0002_sync"
    members: dict[str, bytes | Path] = {}
    for cam in ("image_02", "image_03"):
        members[f"../../{DATE}/{name}/{cam}/data/0000000000.png"] = PNG  # matched: written inside OUT
    members["../../escaped.txt"] = b"x"
    members["/tmp/absolute.txt"] = b"x"
    members[f"{DATE}/{name}/image_02/data/../../../../../../evil.png"] = PNG
    z = _zip(tmp_path / "evil.zip", members)
    out = tmp_path / "a" / "b" / "out"
    r = _run(str(z), str(_fake_calib(tmp_path)), "--out", str(out))
    assert r.exit_code == 0, r.output
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    assert all(w.startswith("a/b/out/") or w.endswith(".zip") for w in written), written
    assert (out / "kitti_raw" / DATE / name / "image_02" / "data" / "0000000000.png").read_bytes() == PNG
    # a link planted in OUT that leads outside it is refused, not followed
    out2 = tmp_path / "out2"
    out2.mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (out2 / "kitti_raw").symlink_to(elsewhere)
    r = _run(str(z), str(_fake_calib(tmp_path)), "--out", str(out2))
    assert r.exit_code == 2 and "outside" in r.output
    assert not any(elsewhere.iterdir())


def test_shipped_ground_truth_is_the_project_one():
    gt = ground_truth_file(GROUND_TRUTH[("raw", DATE, f"{DATE}_drive_0001_sync")])
    shared = SHARED / "kitti_raw" / DATE / f"{DATE}_drive_0001_sync" / "lanes_gt.jsonl"
    if not shared.is_file():
        pytest.skip(f"real KITTI data not found at {shared} (a fresh clone has no ../shared/data)")
    assert gt.read_bytes() == shared.read_bytes()


@pytest.mark.kitti
def test_real_drive_zips_give_the_developer_layout(kitti_drive, tmp_path):
    """Drive 0001 zipped as KITTI ships it (with its calibration zip, and velodyne points left
    out) gives the folder ../shared/data has: same images, calibration and ground truth, so a run
    on it gives the README's figures."""
    date_dir = kitti_drive.parent
    members: dict[str, bytes | Path] = {}
    for f in sorted(kitti_drive.rglob("*")):
        if f.is_file() and f.name != "lanes_gt.jsonl":
            members[f"{DATE}/{kitti_drive.name}/{f.relative_to(kitti_drive).as_posix()}"] = f
    members[f"{DATE}/{kitti_drive.name}/velodyne_points/data/0000000000.bin"] = b"\x00" * 16
    raw = _zip(tmp_path / f"{kitti_drive.name}.zip", members)
    calib = _zip(
        tmp_path / f"{DATE}_calib.zip", {f"{DATE}/{f.name}": f for f in date_dir.glob("calib_*.txt")}
    )
    out = tmp_path / "kitti"
    r = _run(str(raw), str(calib), "--out", str(out), "--quiet")
    assert r.exit_code == 0, r.output
    drive = out / "kitti_raw" / DATE / kitti_drive.name
    for f in sorted(kitti_drive.rglob("*")):
        if f.is_file():
            assert (drive / f.relative_to(kitti_drive)).read_bytes() == f.read_bytes(), f
    assert (out / "kitti_raw" / DATE / "calib_cam_to_cam.txt").read_bytes() == (
        date_dir / "calib_cam_to_cam.txt"
    ).read_bytes()
    ds = load_dataset(out / "kitti.yaml")
    (seq,) = ds.sequences
    assert (seq.name, seq.input, seq.gt, seq.frames) == (
        "drive_0001",
        drive,
        drive / "lanes_gt.jsonl",
        slice(0, 54),
    )
    # the unpacked folders work as well as the zips (here: the date folder holding drive and calibration)
    r = _run(str(date_dir), "--out", str(tmp_path / "from_folder"), "--quiet")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "from_folder" / "kitti_raw" / DATE / kitti_drive.name / "lanes_gt.jsonl").is_file()
    # the drive folder alone: its date's calibration is taken from the folder above it
    r = _run(str(kitti_drive), "--out", str(tmp_path / "from_drive"), "--quiet")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "from_drive" / "kitti_raw" / DATE / "calib_cam_to_cam.txt").is_file()


@pytest.mark.kitti
def test_real_odometry_zips(tmp_path):
    seq = SHARED / "kitti_odometry" / "seq2"
    if not (seq / "image_0").is_dir():
        pytest.skip(f"real KITTI data not found at {seq} (a fresh clone has no ../shared/data)")
    frames = sorted(p.name for p in (seq / "image_0").glob("*.png"))[:3]
    gray = {
        f"dataset/sequences/05/{cam}/{f}": seq / cam / f for cam in ("image_0", "image_1") for f in frames
    }
    calib = {"dataset/sequences/05/calib.txt": seq / "calib.txt"}
    z1, z2 = (
        _zip(tmp_path / "data_odometry_gray.zip", gray),
        _zip(tmp_path / "data_odometry_calib.zip", calib),
    )
    out = tmp_path / "kitti"
    r = _run(str(z1), "--out", str(out))
    assert r.exit_code == 2 and "give data_odometry_calib.zip too" in r.output
    r = _run(str(z1), str(z2), "--out", str(out))
    assert r.exit_code == 0, r.output
    got = out / "kitti_odometry" / "05"
    assert (got / "calib.txt").read_bytes() == (seq / "calib.txt").read_bytes()
    assert len(list((got / "image_1").glob("*.png"))) == len(list((got / "image_0").glob("*.png"))) > 0
    assert [s.name for s in load_dataset(out / "kitti.yaml").sequences] == ["odometry_05"]


# ------------------------------------------------------------------ bounds, everything checked first
def _png_of(w: int, h: int) -> bytes:
    return (
        b"\x89PNG\r\n\x1a\n" + b"\x00\x00\x00\rIHDR" + w.to_bytes(4, "big") + h.to_bytes(4, "big") + b"rest"
    )


def _members_of(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as z:
        return {n: z.read(n) for n in z.namelist()}


def _tree(folder: Path) -> dict[str, bytes | None]:
    return {
        str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None) for p in sorted(folder.rglob("*"))
    } if folder.exists() else {}  # fmt: skip


def test_a_huge_png_is_refused_from_its_header_before_writing(tmp_path):
    drive = _fake_drive(tmp_path)
    members = _members_of(drive)
    members[f"{DATE}/{DATE}_drive_0002_sync/image_02/data/0000000001.png"] = _png_of(40000, 30000)
    _zip(drive, members)
    out = tmp_path / "out"
    r = _run(str(drive), str(_fake_calib(tmp_path)), "--out", str(out))
    assert r.exit_code == 2 and "a 40000 x 30000 image, expected at most 8000000 pixels" in r.output, r.output
    assert _tree(out) == {}


def test_a_calibration_above_1_mb_is_refused_before_writing(tmp_path):
    calib = _zip(tmp_path / f"{DATE}_calib.zip", {f"{DATE}/calib_cam_to_cam.txt": b"P" * (1024 * 1024 + 1)})
    out = tmp_path / "out"
    r = _run(str(_fake_drive(tmp_path)), str(calib), "--out", str(out))
    assert r.exit_code == 2 and "more than the 1048576 a calibration or times file may have" in r.output, (
        r.output
    )
    assert _tree(out) == {}


@pytest.mark.parametrize("how", ["encrypted", "method 99"])
def test_an_unreadable_member_is_refused_with_one_line(tmp_path, how):
    drive = _fake_drive(tmp_path)
    raw = bytearray(drive.read_bytes())
    for sig, flag_at, method_at in ((b"PK\x03\x04", 6, 8), (b"PK\x01\x02", 8, 10)):  # every header
        offset = raw.find(sig)
        while offset >= 0:
            if how == "encrypted":
                raw[offset + flag_at] |= 0x1
            else:
                raw[offset + method_at : offset + method_at + 2] = (99).to_bytes(2, "little")
            offset = raw.find(sig, offset + 4)
    drive.write_bytes(bytes(raw))
    out = tmp_path / "out"
    r = _run(str(drive), str(_fake_calib(tmp_path)), "--out", str(out))
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in r.output, r.output
    assert ("encrypted" if how == "encrypted" else "method 99") in lines[0]
    assert _tree(out) == {}


def test_a_crc_error_leaves_out_as_it_was(tmp_path):
    drive = _fake_drive(tmp_path, frames=5)
    raw = bytearray(drive.read_bytes())
    at = raw.rfind(b"rest")  # the last image's bytes (stored): its CRC no longer matches
    raw[at : at + 4] = b"REST"
    drive.write_bytes(bytes(raw))
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("the user's")
    r = _run(str(drive), str(_fake_calib(tmp_path)), "--out", str(out))
    assert r.exit_code == 2 and "damaged" in r.output, r.output
    assert _tree(out) == {"notes.txt": b"the user's"}


def test_out_given_as_an_empty_string_is_refused(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = _run(str(_fake_drive(tmp_path)), str(_fake_calib(tmp_path)), "--out", "")
    assert r.exit_code == 2 and "--out" in r.output, r.output
    assert not (tmp_path / "kitti_raw").exists() and not (tmp_path / "kitti.yaml").exists()


def test_the_users_files_in_out_are_kept_or_refused(tmp_path):
    out = tmp_path / "out"
    args = [str(_fake_drive(tmp_path)), str(_fake_calib(tmp_path)), "--out", str(out)]
    assert _run(*args).exit_code == 0
    assert _run(*args).exit_code == 0  # its own files: replaced
    (out / "kitti.yaml").write_text("name: mine\n")  # the user's own dataset file now
    calib = out / "kitti_raw" / DATE / "calib_cam_to_cam.txt"
    before = _tree(out)
    r = _run(*args)
    assert r.exit_code == 2 and "kitti.yaml is there and not lanegraph's" in r.output, r.output
    assert _tree(out) == before
    (out / "kitti.yaml").unlink()
    calib.write_text("P_rect_02: edited by hand\n")
    r = _run(*args)
    assert r.exit_code == 2 and "calib_cam_to_cam.txt is there and not lanegraph's" in r.output, r.output
    assert calib.read_text() == "P_rect_02: edited by hand\n"
