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
download), an encrypted member or one of a compression method Python cannot read, a member
larger than its kind allows (:data:`MAX_TEXT` for a calibration or times file, as ``run`` reads
one; :data:`MAX_PNG` for an image, whose width and height are read from its PNG header: at most
:data:`MAX_PIXELS`), a whole larger than :data:`MAX_TOTAL` or than the free space in OUT, and a
name OUT already holds that lanegraph did not write there (its ownership record,
:mod:`lanegraph.records.owned`: the user's own ``kitti.yaml`` or edited calibration is never replaced)
are :class:`UsageError` (exit 2) naming the file and what was expected. The files are then
copied into a new folder of OUT and moved into place only when every one was copied whole (a CRC
error found while copying leaves OUT as it was). Output paths are
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

from lanegraph.errors import UsageError
from lanegraph.paths import inside, new_temp_dir, prepare_dir, write_text_atomic

_PNG = b"\x89PNG\r\n\x1a\n"
#: the largest calibration, timestamps or times file (the limit ``run`` reads a calibration with)
MAX_TEXT = 1024 * 1024
#: the largest image file, and the most pixels of an image (a KITTI image is 1242 x 375)
MAX_PNG, MAX_PIXELS = 64 * 1024 * 1024, 8_000_000
#: the most bytes laid out in all (the odometry benchmark's grey images are about 22 GB)
MAX_TOTAL = 64 * 1024**3
_METHODS = (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED, zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA)
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

    def unreadable(self, member: str) -> str | None:
        """Why a zip member cannot be read (encrypted, an unknown compression method), or None."""
        if self.zip is None:
            return None
        info = self.zip.getinfo(member)
        if info.flag_bits & 0x1:
            return "encrypted (a password is needed): lanegraph reads KITTI's plain zip files"
        if info.compress_type not in _METHODS:
            return f"compressed with method {info.compress_type}, which Python's zipfile cannot read"
        return None

    def head(self, member: str, n: int) -> bytes:
        with self.open(member) as fh:
            return fh.read(n)

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
    except (zipfile.BadZipFile, EOFError, zipfile.LargeZipFile, NotImplementedError, RuntimeError) as exc:
        tmp.unlink(missing_ok=True)
        raise UsageError(f"{src.path}: {member}: damaged or unreadable ({exc}); download it again") from None
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


def _plan(out: Path, seqs: dict[tuple, _Sequence], calib: dict) -> list[tuple[_Source, str, str, bool]]:
    """Every file to lay out: ``(source, member, path relative to OUT, is a PNG)``."""
    plan = []
    for date, files in sorted(calib.items()):
        if any(s.date == date for s in seqs.values()):
            plan += [
                (src, member, f"kitti_raw/{date}/{fname}", False)
                for fname, (src, member) in sorted(files.items())
            ]
    for key in sorted(seqs, key=lambda k: (k[0], k[1] or "", k[2])):
        s = seqs[key]
        base = s.folder()
        for cam, frames in sorted(s.images.items()):
            rel = f"{base}/{cam}/data" if s.kind == "raw" else f"{base}/{cam}"
            plan += [
                (src, member, f"{rel}/{frame}.png", True) for frame, (src, member) in sorted(frames.items())
            ]
        plan += [(src, member, f"{base}/{fname}", False) for fname, (src, member) in sorted(s.files.items())]
    return plan


def _check_members(plan: list[tuple[_Source, str, str, bool]], out: Path) -> None:
    """Bounds of what is unpacked, before a byte is written: each member readable, of a size its
    kind allows (a PNG's width and height from its header), the whole within :data:`MAX_TOTAL`
    and the free space of OUT."""
    problems: list[str] = []
    total = 0
    for src, member, _rel, png in plan:
        where = f"{src.path}: {member}" if src.zip is not None else member
        why = src.unreadable(member)
        if why is not None:
            problems.append(f"{where}: {why}")
            continue
        size = src.size(member)
        total += size
        limit = MAX_PNG if png else MAX_TEXT
        if size > limit:
            problems.append(
                f"{where}: {size} bytes, more than the {limit} a {'KITTI image' if png else 'calibration or times file'} may have"
            )
            continue
        if png:
            try:
                head = src.head(member, 24)
            except (zipfile.BadZipFile, EOFError, NotImplementedError, RuntimeError, OSError) as exc:
                problems.append(f"{where}: damaged ({exc})")
                continue
            if len(head) < 24 or head[:8] != _PNG:
                problems.append(f"{where}: not a PNG image (a damaged download?)")
                continue
            w, h = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
            if not (0 < w and 0 < h and w * h <= MAX_PIXELS):
                problems.append(
                    f"{where}: a {w} x {h} image, expected at most {MAX_PIXELS} pixels (a KITTI image is 1242 x 375)"
                )
        if len(problems) >= 20:
            break
    if total > MAX_TOTAL:
        problems.append(f"{total} bytes in all, more than the {MAX_TOTAL} lanegraph lays out")
    try:
        free = shutil.disk_usage(_existing(out)).free
    except OSError:
        free = None
    if not problems and free is not None and total > free:
        problems.append(f"--out {out}: {total} bytes to write, {free} free there")
    if problems:
        raise UsageError("; ".join(problems[:20]) + (" (and more)" if len(problems) > 20 else ""))


def _existing(p: Path) -> Path:
    p = Path(p).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_taken(out: Path, rels: list[str]) -> None:
    """Refuse a name OUT holds that lanegraph did not write there (its ownership record)."""
    from lanegraph.api import owned

    bad = owned.taken(out, dict.fromkeys(rels, "file"))
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise UsageError(
            f"--out {out}: {bad[0]} is there and not lanegraph's{more}: lanegraph never replaces what it "
            "did not write; move it away or choose another folder"
        )


def prepare_kitti(sources: list[Path], out: Path, progress: Progress = None) -> list[str]:
    """Check and lay out ``sources`` in ``out`` (see the module's text); returns the summary lines."""
    from lanegraph.api import owned

    if str(out) == "":
        raise UsageError("--out '': an empty folder name (it would be the current folder; give . for that)")
    say = progress or (lambda text: None)
    opened: list[_Source] = []
    try:
        for p in sources:
            opened.append(_Source(Path(p)))
        seqs, calib = _scan(opened)
        _check(seqs, calib)
        plan = _plan(out, seqs, calib)
        _check_members(plan, out)
        gts = {
            s.folder(): GROUND_TRUTH[(s.kind, s.date, s.name)]
            for s in seqs.values()
            if (s.kind, s.date, s.name) in GROUND_TRUTH
        }
        rels = [rel for _src, _m, rel, _png in plan] + [f"{b}/lanes_gt.jsonl" for b in gts] + ["kitti.yaml"]
        owned.note_absent(out, rels)
        if out.is_dir():
            _check_taken(out, rels)
        prepare_dir(out, "--out")
        owned.begin(out, rels)
        stage = new_temp_dir(out, prefix=".lanegraph-kitti-")
        try:
            done = 0
            for src, member, rel, png in plan:
                target = stage / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                _copy(src, member, target, png=png)
                done += 1
                if done % 500 == 0:
                    say(f"{done}/{len(plan)} file(s) checked and copied")
            for _src, _member, rel, _png in plan:  # every file whole: into place
                folder = _folder(out, str(Path(rel).parent))
                os.replace(stage / rel, folder / Path(rel).name)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
        lines = []
        entries = []
        for key in sorted(seqs, key=lambda k: (k[0], k[1] or "", k[2])):
            s = seqs[key]
            base = s.folder()
            frames = sorted(next(iter(v for v in s.images.values() if v)))
            entry: dict[str, str] = {"name": s.dataset_name(), "input": base}
            gt_note = ""
            if base in gts:
                gt_note = _write_gt(out, base, frames, gts[base], entry)
            entries.append(entry)
            lines.append(f"{s.label}: {len(frames)} frame(s) -> {out / base}{gt_note}")
        dataset = out / "kitti.yaml"
        _write_dataset(dataset, entries)
        owned.seal(out)
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
    from lanegraph.api import read_ground_truth

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
    from lanegraph.builtin import graphs_dir

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
