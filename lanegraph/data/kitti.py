"""``lanegraph data kitti``: what a user downloads from the KITTI website, laid out as lanegraph's
sources read it, with the lane ground truth that ships with lanegraph.

Accepted (zip files, or the folders they unpack to; several at once):

- a raw drive, ``2011_09_26_drive_0001_sync.zip`` (members ``2011_09_26/2011_09_26_drive_0001_sync/
  image_0[0-3]/data/NNNNNNNNNN.png`` and ``timestamps.txt``; its ``oxts`` and ``velodyne_points`` are
  left out), with its date's ``2011_09_26_calib.zip`` (``2011_09_26/calib_cam_to_cam.txt`` ...);
- the odometry benchmark's ``data_odometry_gray.zip`` (``dataset/sequences/NN/image_[01]/NNNNNN.png``)
  with ``data_odometry_calib.zip`` (``dataset/sequences/NN/calib.txt``, ``times.txt``).

Laid out in OUT as ``kitti_raw/<date>/calib_*.txt``, ``kitti_raw/<date>/<drive>/image_0X/data/*.png``
and ``kitti_odometry/<NN>/{image_0,image_1,calib.txt,times.txt}`` (the layouts ``io.kitti_raw`` and
``io.kitti_odometry`` read), with ``lanes_gt.jsonl`` beside the frames of every sequence lanegraph
has ground truth for (:data:`GROUND_TRUTH`), and ``OUT/kitti.yaml``, a dataset file of the
sequences laid out (the built-in ``datasets/kitti_lanes.yaml`` names the ground truth's frames).

Everything is checked before a file is written: a file that is no zip or a truncated one, a
folder with nothing of KITTI's in it, a drive without its date's calibration, a sequence without
``calib.txt``, left and right cameras with different frames, frame numbers with gaps (a partial
download) are :class:`UsageError` (exit 2) naming the file and what was expected. Output paths are
made of the parts of a member's name that the patterns below match (a date, a drive number, a
camera, a frame number), never of the name itself: a member such as ``../../x`` matches nothing and
is never written, and every file is written inside OUT, never through a link found there.
"""

from __future__ import annotations

import os
import re
import shutil
import stat
import zipfile
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import yaml

from ..errors import UsageError
from ..paths import inside, prepare_dir

_PNG = b"\x89PNG\r\n\x1a\n"
_DATE = r"(?P<date>\d{4}_\d{2}_\d{2})"
RAW_IMAGE = re.compile(
    rf"(?:^|/){_DATE}/(?P<drive>(?P=date)_drive_(?P<num>\d{{4}})_sync)/(?P<cam>image_0[0-3])/data/(?P<frame>\d{{10}})\.png$"
)
RAW_TIMES = re.compile(
    rf"(?:^|/){_DATE}/(?P<drive>(?P=date)_drive_\d{{4}}_sync)/(?P<cam>image_0[0-3])/timestamps\.txt$"
)
RAW_CALIB = re.compile(
    rf"(?:^|/){_DATE}/(?P<file>calib_cam_to_cam\.txt|calib_velo_to_cam\.txt|calib_imu_to_velo\.txt)$"
)
ODO_IMAGE = re.compile(r"(?:^|/)sequences/(?P<seq>\d{2})/(?P<cam>image_[01])/(?P<frame>\d{6})\.png$")
ODO_FILE = re.compile(r"(?:^|/)sequences/(?P<seq>\d{2})/(?P<file>calib\.txt|times\.txt)$")
ODO_CALIB_FLAT = re.compile(
    r"(?:^|/)calib_(?P<seq>\d{2})\.txt$"
)  # some mirrors: one calib_NN.txt per sequence

#: the lane ground truth shipped with lanegraph: (kind, date or None, sequence folder) -> package data file
GROUND_TRUTH = {
    (
        "raw",
        "2011_09_26",
        "2011_09_26_drive_0001_sync",
    ): "kitti_raw_2011_09_26_drive_0001_sync.lanes_gt.jsonl",
}
#: the built-in dataset file naming the sequences (and frames) of :data:`GROUND_TRUTH`
DATASET_TEMPLATE = "datasets/kitti_lanes.yaml"

Progress = Callable[[str], None] | None


class _Source:
    """One SOURCE argument: a zip file or a folder, as (member name, reader) pairs."""

    def __init__(self, path: Path):
        self.path = path
        self.zip: zipfile.ZipFile | None = None
        if path.is_dir():
            self.kind = "folder"
        elif path.is_file():
            self.kind = "zip"
            try:
                self.zip = zipfile.ZipFile(path)
            except (zipfile.BadZipFile, OSError) as exc:
                raise UsageError(
                    f"{path}: not a complete zip file ({exc}); a partial download? download it again"
                ) from None
        else:
            raise UsageError(f"{path}: no such file or folder")

    def members(self) -> Iterator[str]:
        """Member names, '/'-separated; a folder's are its files' absolute paths (so a pattern can
        see the date and drive folders above the one given)."""
        if self.zip is not None:
            for info in self.zip.infolist():
                if not info.is_dir():
                    yield info.filename
            return
        top = self.path.resolve()
        for f in sorted(top.parent.glob("calib_*.txt")):  # a drive folder given: its date's calibration
            if f.is_file() and not f.is_symlink():
                yield f.as_posix()
        for dirpath, _dirs, files in os.walk(self.path):  # links to folders are not followed
            for name in files:
                full = Path(dirpath) / name
                try:
                    if stat.S_ISREG(full.lstat().st_mode):
                        yield full.resolve().as_posix()
                except OSError:
                    continue

    def open(self, member: str) -> IO[bytes]:
        if self.zip is not None:
            return self.zip.open(member)
        return open(member, "rb")

    def size(self, member: str) -> int:
        if self.zip is not None:
            return self.zip.getinfo(member).file_size
        return Path(member).stat().st_size

    def close(self) -> None:
        if self.zip is not None:
            self.zip.close()


@dataclass
class _Sequence:
    kind: str  # "raw" or "odometry"
    date: str | None
    name: str  # drive folder or two-digit sequence
    images: dict[str, dict[str, tuple[_Source, str]]] = field(default_factory=lambda: defaultdict(dict))
    files: dict[str, tuple[_Source, str]] = field(default_factory=dict)  # timestamps, calib.txt, times.txt

    @property
    def label(self) -> str:
        return self.name if self.kind == "raw" else f"odometry sequence {self.name}"

    def folder(self) -> str:
        if self.kind == "raw":
            return f"kitti_raw/{self.date}/{self.name}"
        return f"kitti_odometry/{self.name}"

    def dataset_name(self) -> str:
        if self.kind == "raw":
            m = re.search(r"drive_(\d{4})_sync$", self.name)
            return (
                f"drive_{m.group(1)}"
                if self.date == "2011_09_26" and m
                else f"{self.date}_drive_{m.group(1) if m else self.name}"
            )
        return f"odometry_{self.name}"


def _scan(sources: list[_Source]) -> tuple[dict[tuple, _Sequence], dict[str, dict[str, tuple[_Source, str]]]]:
    seqs: dict[tuple, _Sequence] = {}
    calib: dict[str, dict[str, tuple[_Source, str]]] = defaultdict(dict)
    odo_calib: dict[str, tuple[_Source, str]] = {}
    for src in sources:
        found = 0
        for name in src.members():
            if m := RAW_IMAGE.search(name):
                s = seqs.setdefault(("raw", m["date"], m["drive"]), _Sequence("raw", m["date"], m["drive"]))
                s.images[m["cam"]][m["frame"]] = (src, name)
            elif m := RAW_TIMES.search(name):
                s = seqs.setdefault(("raw", m["date"], m["drive"]), _Sequence("raw", m["date"], m["drive"]))
                s.files[f"{m['cam']}/timestamps.txt"] = (src, name)
            elif m := RAW_CALIB.search(name):
                calib[m["date"]][m["file"]] = (src, name)
            elif m := ODO_IMAGE.search(name):
                s = seqs.setdefault(("odometry", None, m["seq"]), _Sequence("odometry", None, m["seq"]))
                s.images[m["cam"]][m["frame"]] = (src, name)
            elif m := ODO_FILE.search(name):
                s = seqs.setdefault(("odometry", None, m["seq"]), _Sequence("odometry", None, m["seq"]))
                s.files[m["file"]] = (src, name)
            elif m := ODO_CALIB_FLAT.search(name):
                odo_calib[m["seq"]] = (src, name)
            else:
                continue
            found += 1
        if not found:
            raise UsageError(
                f"{src.path}: nothing of a KITTI download in this {src.kind}: expected a raw drive "
                "(DATE/DATE_drive_NNNN_sync/image_02/data/*.png), its date's calibration (DATE/calib_cam_to_cam.txt) "
                "or the odometry data (dataset/sequences/NN/image_0/*.png, calib.txt)"
            )
    for seq, member in odo_calib.items():
        if ("odometry", None, seq) in seqs:
            seqs[("odometry", None, seq)].files.setdefault("calib.txt", member)
    return seqs, calib


def _check(seqs: dict[tuple, _Sequence], calib: dict[str, dict[str, tuple[_Source, str]]]) -> None:
    """Every problem of the downloads, before anything is written."""
    problems = []
    for s in seqs.values():
        if s.kind == "raw":
            if "calib_cam_to_cam.txt" not in calib.get(s.date or "", {}):
                problems.append(
                    f"{s.label}: no calibration: give {s.date}_calib.zip too (it holds {s.date}/calib_cam_to_cam.txt)"
                )
            pairs = [("image_02", "image_03"), ("image_00", "image_01")]
            what = "colour (image_02/03) or grey (image_00/01) images"
        else:
            if "calib.txt" not in s.files:
                problems.append(
                    f"{s.label}: no calib.txt: give data_odometry_calib.zip too (it holds dataset/sequences/{s.name}/calib.txt)"
                )
            pairs = [("image_0", "image_1")]
            what = "images (image_0 and image_1)"
        complete = 0
        for left, right in pairs:
            lf, rf = s.images.get(left, {}), s.images.get(right, {})
            if not lf and not rf:
                continue
            if set(lf) != set(rf):
                only = sorted(set(lf) ^ set(rf))
                problems.append(
                    f"{s.label}: {left} has {len(lf)} frame(s), {right} {len(rf)}; frame {only[0]} is in one only "
                    "(a partial download?)"
                )
                continue
            numbers = sorted(int(f) for f in lf)
            if numbers[-1] - numbers[0] + 1 != len(numbers):
                gap = next(a + 1 for a, b in zip(numbers, numbers[1:]) if b != a + 1)
                problems.append(
                    f"{s.label}: {left}: frames {numbers[0]}-{numbers[-1]} with frame {gap} missing (a partial download?)"
                )
                continue
            complete += 1
        if not complete and not any(f"{s.label}:" in p for p in problems):
            problems.append(f"{s.label}: no {what} (only {', '.join(sorted(s.files)) or 'nothing'})")
    if not seqs:
        problems.append(
            "no images: give a raw drive's *_sync.zip or data_odometry_gray.zip (calibration alone is not enough)"
        )
    if problems:
        raise UsageError("; ".join(problems))


def _copy(src: _Source, member: str, target: Path, png: bool) -> None:
    """Copy one member to ``target`` (a new file: never through a link already there), checking a
    PNG's signature; a damaged member (a CRC error) is a :class:`UsageError` naming it."""
    tmp = target.with_name(f".{target.name}.part")
    try:
        tmp.unlink(missing_ok=True)
        with src.open(member) as fin:
            head = fin.read(8)
            if png and head != _PNG:
                raise UsageError(f"{src.path}: {member}: not a PNG image (a damaged download?)")
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o644)
            with os.fdopen(fd, "wb") as fout:
                fout.write(head)
                shutil.copyfileobj(fin, fout, 1 << 20)
        os.replace(tmp, target)
    except (zipfile.BadZipFile, EOFError, zipfile.LargeZipFile) as exc:
        tmp.unlink(missing_ok=True)
        raise UsageError(f"{src.path}: {member}: damaged ({exc}); download it again") from None
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise UsageError(f"{target}: cannot write: {exc.strerror or exc}") from None


def _folder(out: Path, rel: str) -> Path:
    """``out/rel`` created, refused when it (a link planted there) leads outside ``out``."""
    p = inside(out, rel, "--out")
    p.mkdir(parents=True, exist_ok=True)
    inside(out, rel, "--out")  # after creation: still inside
    return p


def ground_truth_file(name: str) -> Path:
    """The package data file of :data:`GROUND_TRUTH`."""
    return Path(__file__).resolve().parent / name


def _png_size(path: Path) -> tuple[int, int] | None:
    with open(path, "rb") as fh:
        head = fh.read(24)
    if len(head) < 24 or head[:8] != _PNG:
        return None
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def prepare_kitti(sources: list[Path], out: Path, progress: Progress = None) -> list[str]:
    """Check and lay out ``sources`` in ``out`` (see the module's text); returns the summary lines."""
    say = progress or (lambda text: None)
    opened: list[_Source] = []
    try:
        for p in sources:
            opened.append(_Source(Path(p)))
        seqs, calib = _scan(opened)
        _check(seqs, calib)
        prepare_dir(out, "--out")
        lines = []
        for date, files in sorted(calib.items()):
            if not any(s.date == date for s in seqs.values()):
                continue
            folder = _folder(out, f"kitti_raw/{date}")
            for fname, (src, member) in sorted(files.items()):
                _copy(src, member, folder / fname, png=False)
        entries = []
        for key in sorted(seqs, key=lambda k: (k[0], k[1] or "", k[2])):
            s = seqs[key]
            base = s.folder()
            n_files = sum(len(v) for v in s.images.values())
            say(f"{s.label}: {n_files} image(s) -> {out / base}")
            done = 0
            for cam, frames in sorted(s.images.items()):
                rel = f"{base}/{cam}/data" if s.kind == "raw" else f"{base}/{cam}"
                folder = _folder(out, rel)
                for frame, (src, member) in sorted(frames.items()):
                    _copy(src, member, folder / f"{frame}.png", png=True)
                    done += 1
                    if done % 500 == 0:
                        say(f"{s.label}: {done}/{n_files} image(s)")
            for fname, (src, member) in sorted(s.files.items()):
                _copy(
                    src,
                    member,
                    _folder(out, f"{base}/{Path(fname).parent}".rstrip("/.")) / Path(fname).name,
                    png=False,
                )
            frames = sorted(next(iter(v for v in s.images.values() if v)))
            entry: dict[str, str] = {"name": s.dataset_name(), "input": base}
            gt_note = ""
            gt_name = GROUND_TRUTH.get((s.kind, s.date, s.name))
            if gt_name is not None:
                gt_note = _write_gt(out, base, frames, gt_name, entry)
            entries.append(entry)
            lines.append(f"{s.label}: {len(frames)} frame(s) -> {out / base}{gt_note}")
        dataset = out / "kitti.yaml"
        _write_dataset(dataset, entries)
        lines.append(
            f"dataset file: {dataset} ({len(entries)} sequence(s)); e.g. "
            f"lanegraph ablate paper ablations/slt --dataset {dataset} --out out/kitti"
        )
        return lines
    finally:
        for src in opened:
            src.close()


def _write_gt(out: Path, base: str, frames: list[str], gt_name: str, entry: dict[str, str]) -> str:
    """``lanes_gt.jsonl`` beside the frames, when they hold the ground truth's frames and image size."""
    from ..evaluation.metrics import read_ground_truth
    from ..paths import write_text_atomic

    gt_path = ground_truth_file(gt_name)
    records = read_ground_truth(gt_path)
    names = [str(r["frame"]) for r in records]
    if frames[: len(names)] != names:
        return f" (no lane ground truth: it needs frames {names[0]}-{names[-1]})"
    cam = "image_02" if (out / base / "image_02").is_dir() else "image_00"
    size = _png_size(out / base / cam / "data" / f"{names[0]}.png")
    want = tuple(records[0].get("image_size") or ()) or None
    if want is not None and size is not None and tuple(size) != want:
        return f" (no lane ground truth: its images are {want[0]}x{want[1]}, these {size[0]}x{size[1]})"
    target = inside(out, f"{base}/lanes_gt.jsonl", "--out")
    target.unlink(missing_ok=True)  # never through a link planted there
    write_text_atomic(target, gt_path.read_text(encoding="utf-8"))
    entry["gt"] = f"{base}/lanes_gt.jsonl"
    if len(names) < len(frames):
        entry["frames"] = f"0:{len(names)}"
    return f", lane ground truth of frames {names[0]}-{names[-1]} (lanes_gt.jsonl)"


def _write_dataset(path: Path, entries: list[dict[str, str]]) -> None:
    from ..builtin import graphs_dir
    from ..paths import write_text_atomic

    template = graphs_dir() / DATASET_TEMPLATE
    description = (
        "KITTI sequences laid out by `lanegraph data kitti`; the lane ground truth is lanegraph's "
        f"(see {DATASET_TEMPLATE}). Paths are relative to this file."
    )
    doc = {"name": "kitti", "description": description, "sequences": entries}
    if template.is_file():  # the built-in file's frames win for the sequences it names
        known = {
            s["name"]: s
            for s in (yaml.safe_load(template.read_text(encoding="utf-8")) or {}).get("sequences", [])
        }
        for e in entries:
            if e["name"] in known and "gt" in e and known[e["name"]].get("frames"):
                e["frames"] = known[e["name"]]["frames"]
    path.unlink(missing_ok=True)
    write_text_atomic(path, yaml.safe_dump(doc, sort_keys=False))


__all__ = ["GROUND_TRUTH", "prepare_kitti"]
