"""Building a report: evaluate every run's frames with :mod:`lanegraph.evaluation.metrics` (the same function
``lanegraph eval`` uses, so a frame fails here exactly when it fails there), write the pictures,
and assemble the page."""

from __future__ import annotations

import math
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lanegraph.api import POOLED, evaluate, evaluate_sequences, owned
from lanegraph.errors import InputError, LanegraphError, UsageError
from lanegraph.paths import new_temp_dir, new_temp_file, prepare_dir, safe_name
from lanegraph.plugins import PluginManager, get_plugin_manager

from . import _page
from ._collect import Collected, collect
from ._images import JpegWriter, choose_source, debug_pictures, read_left_images, recorded_debug_dir

#: widest left image in the report, pixels (KITTI's 1242 px: ~40 KiB per frame as JPEG)
IMAGE_WIDTH = 800
#: widest node picture, pixels
PICTURE_WIDTH = 640
#: marks an assets folder as the report's own, so a new report may clear it
_OWNED = ".lanegraph-report"


@dataclass
class ReportSummary:
    """What :func:`write_report` wrote."""

    index: Path
    kind: str
    frames: int
    failed: int  # failed frames of the first variant
    node_picture_frames: int
    files: int
    bytes: int
    seconds: float
    notes: list[str] = field(default_factory=list)
    variant: str = ""  # the first variant, whose failed frames are counted

    def line(self) -> str:
        mb = self.bytes / 1e6
        failed = f"{self.failed} failed" + (f" by {self.variant}" if self.kind == "ablation" else "")
        return (
            f"report: {self.index} ({self.frames} frame(s), {failed}, {self.node_picture_frames} with node "
            f"pictures; {mb:.1f} MB in {self.files} files) in {self.seconds:.1f} s"
        )


def write_report(
    run_dir: str | Path,
    out_dir: str | Path | None = None,
    *,
    gt: str | Path | None = None,
    dataset: Any = None,
    input_path: str | Path | None = None,
    frames: slice | None = None,
    sets: list[str] | tuple[str, ...] = (),
    debug_dir: str | Path | None = None,
    graph: Any = None,
    pm: PluginManager | None = None,
    image_width: int = IMAGE_WIDTH,
    progress: bool = True,
) -> ReportSummary:
    """Write a self-contained HTML report of a run or ablation output folder.

    Parameters
    ----------
    run_dir
        the output folder of ``lanegraph run`` (its lanes; with ``dataset``, a run folder
        ``<sequence>/`` per sequence) or of ``lanegraph ablate`` (``runs/``, ``results.csv``).
    out_dir
        where ``index.html`` and its ``assets/`` go (default ``run_dir/report``).
    gt, dataset, input_path, frames
        the ground truth (default: ``lanes_gt.jsonl`` in the input folder), or a dataset naming
        each sequence's input and ground truth; the input folder when ``run.json`` names none (an
        ablation over one ``--input``); the frame selection the run was made with (the ground truth
        is cut alike, as ``lanegraph ablate`` does).
    sets, graph
        the ``--set`` overrides the run was made with, or the graph itself: its source node reads
        the left images, and it is drawn with each node's times.
    debug_dir
        the ``--debug-dir`` folder of the run (default: one found inside ``run_dir``).
    image_width
        width of the left images in the report, pixels (they are JPEG files).

    Raises
    ------
    UsageError
        ``run_dir`` is not an output folder, or the options do not fit it (exit code 2).
    InputError
        a malformed file in it, or a malformed ground truth.
    LanegraphError
        the report could not be written (a full disk; exit code 1): the earlier report stays.
    """
    t0 = time.perf_counter()
    pm = pm or get_plugin_manager()
    run_dir = Path(run_dir)
    out = Path(out_dir) if out_dir is not None else run_dir / "report"
    opt = {
        "gt": Path(gt) if gt is not None else None,
        "input_path": Path(input_path) if input_path is not None else None,
    }
    data = collect(run_dir, dataset=dataset, frames=frames, sets=list(sets), graph=graph, pm=pm, **opt)
    debug = Path(debug_dir) if debug_dir is not None else None
    if debug is not None and not debug.is_dir():
        raise UsageError(f"--debug-dir {debug}: no such folder")
    log = _Log(progress)
    # a file, a file among its parents, a read-only file system: refused before anything is written
    prepare_dir(out, "--out" if out_dir is not None else "report folder")
    try:
        frames_json, failed, debug_frames = _assemble(data, out, pm, debug, image_width, log)
    except OSError as exc:  # a disk that fills up on the way: said, located; the earlier report stays
        where = Path(exc.filename) if exc.filename else out
        what = (
            "cannot write the report"
            if out.resolve() in [where.resolve(), *where.resolve().parents]
            else "error"
        )
        raise LanegraphError(f"{where}: {what}: {exc.strerror or exc}") from None
    files = [out / "index.html", *(p for p in (out / "assets").rglob("*") if p.is_file())]
    for note in data.notes:
        log(f"note: {note}")
    size = sum(p.stat().st_size for p in files)
    elapsed = time.perf_counter() - t0
    return ReportSummary(
        out / "index.html",
        data.kind,
        len(frames_json),
        failed,
        debug_frames,
        len(files),
        size,
        elapsed,
        data.notes,
        data.variants[0],
    )


def _assemble(
    data: Collected, out: Path, pm: PluginManager, debug: Path | None, image_width: int, log: _Log
) -> tuple[list[dict[str, Any]], int, int]:
    """Evaluate the frames, write the pictures and the page into ``out``; returns the frames, how
    many the first variant fails, and how many have node pictures."""
    frames_json, failed = _frames(data)
    # the new pictures go to a folder of their own; the earlier report stays whole until the end
    assets = _new_assets(out)
    try:
        _left_images(data, frames_json, assets, pm, image_width, log)
        debug_frames = _node_pictures(data, frames_json, assets, out, debug, log)
        page = _page.render(data, frames_json, _metrics(data))
        _swap_in(out, assets, page)
    finally:
        if assets.exists():
            shutil.rmtree(assets)
    return frames_json, failed, debug_frames


class _Log:
    def __init__(self, on: bool) -> None:
        self.on = on

    def __call__(self, text: str) -> None:
        if self.on:
            print(f"report: {text}", file=sys.stderr, flush=True)


def _record_of(out: Path) -> tuple[Path, str]:
    """The folder whose ownership record (:mod:`lanegraph.records.owned`) keeps the report's files, and
    their names' prefix there: the run or ablation folder around ``out`` when it has a genuine
    record (``RUN/report``), else ``out`` itself."""
    if owned.read(out.parent):
        return out.parent, f"{out.name}/"
    return out, ""


def _lanegraphs(out: Path, name: str) -> bool:
    """Whether ``out/name`` (a file, or a folder and all it holds) is listed by a genuine ownership
    record: ``out``'s own or that of the folder around it. A mark file alone proves nothing."""
    for folder, rel in ((out, name), (out.parent, f"{out.name}/{name}")):
        entries = owned.read(folder)
        if rel in entries and owned.owns_tree(folder, rel, entries) is None:
            return True
    return False


def _check_assets(out: Path) -> Path:
    """``out/assets`` when it is absent or an earlier report's (a plain folder that lanegraph's
    ownership record lists whole, holding the report's mark); anything else there is the user's,
    left alone: an error. The same for ``out/index.html``."""
    assets = out / "assets"
    if assets.is_symlink() or (
        assets.exists()
        and not (assets.is_dir() and (assets / _OWNED).is_file() and _lanegraphs(out, "assets"))
    ):
        raise UsageError(f"{assets} exists and was not written by `lanegraph report`: choose another --out")
    page = out / "index.html"
    if page.is_symlink():
        raise UsageError(f"{page} is a symbolic link: choose another --out")
    if page.exists() and not _lanegraphs(out, "index.html"):
        raise UsageError(f"{page} exists and was not written by `lanegraph report`: choose another --out")
    return assets


def _new_assets(out: Path) -> Path:
    _check_assets(out)
    out.mkdir(parents=True, exist_ok=True)
    new = new_temp_dir(out, prefix=".assets-")  # the umask's mode (mkdtemp's 0700 would stay private)
    (new / "frames").mkdir()
    (new / _OWNED).write_text("written by `lanegraph report`; replaced by the next report into this folder\n")
    return new


def _swap_in(out: Path, new_assets: Path, page: str) -> None:
    """Replace the earlier report (its assets and page) by the new one. The page is written to a
    new file and renamed over ``index.html``, so a link planted there is replaced, not followed."""
    old = _check_assets(out)
    if old.exists():
        shutil.rmtree(old)
    os.replace(new_assets, old)
    fd, tmp = new_temp_file(out, prefix=".index-", suffix=".html")  # the umask's mode, as any file
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(page)
    os.replace(tmp, out / "index.html")
    folder, prefix = _record_of(out)  # what a later report (or --overwrite) may replace: these files
    owned.seal(folder, [f"{prefix}assets", f"{prefix}index.html"])


# --------------------------------------------------------------------------- frames and outcomes
def _points(lane: dict[str, Any], where: str) -> list[list[float]]:
    """A polyline's points rounded to 0.1 px; points that are not finite are left out."""
    try:
        pts = [(float(x), float(y)) for x, y in (lane.get("points") or [])]
    except (TypeError, ValueError):
        raise InputError("points: expected a list of [x, y] numbers", path=where) from None
    return [[round(x, 1), round(y, 1)] for x, y in pts if math.isfinite(x) and math.isfinite(y)]


def _number(x: Any) -> float | None:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


def _metric_line(res: Any, n_lanes: int, missing: str | None, error: str | None) -> str:
    """A frame's line under its picture; ``missing``: the lanes file the frame is not in."""
    parts = []
    if missing:
        parts.append(f"not in {missing} (counted as nothing reported)")
    if error:
        parts.append(f"failed while running: {error}")
    if res is None:
        parts.insert(0, f"{n_lanes} lane(s) reported (no ground truth)")
        return " · ".join(parts)
    parts.append(f"{res.reported} lane(s) reported, {res.matched} matched")
    parts.append(
        f"ego boundaries {res.ego_matched}/{res.ego_total}" if res.ego_total else "no painted ego boundary"
    )
    if res.dx:
        parts.append(f"mean |dx| {sum(res.dx) / len(res.dx):.2f} px")
    parts.append("correct" if res.correct else "failed: " + "; ".join(res.reasons))
    return " · ".join(parts)


def _frames(data: Collected) -> tuple[list[dict[str, Any]], int]:
    """One entry per frame of every sequence (the ground truth's frames, as ``lanegraph eval``
    counts them; without ground truth the frames the runs wrote or failed on), each with every
    variant's lanes and their outcomes."""
    out: list[dict[str, Any]] = []
    failed_first = 0
    for si, seq in enumerate(data.sequences):
        per_variant = _variant_lanes(data, si, seq)
        if seq.gt is not None:
            ids = [str(g.get("frame")) for g in seq.gt]
            gts = {str(g.get("frame")): g for g in seq.gt}
        else:
            ids = list(dict.fromkeys(f for v in per_variant.values() for f in [*v["lanes"], *v["failures"]]))
            gts = {}
        absent: dict[int, int] = {}  # per variant: frames not in its lanes file
        for fid in ids:
            entry: dict[str, Any] = {"s": si, "id": fid, "img": None, "w": None, "h": None, "r": []}
            if fid in gts:
                _add_ground_truth(entry, gts[fid], str(seq.gt_path))
            for vi in range(len(data.variants)):
                v = per_variant.get(vi)
                entry["r"].append(None if v is None else _variant_frame(v, fid))
            for vi, r in enumerate(entry["r"]):
                if r is not None and r["missing"]:
                    absent[vi] = absent.get(vi, 0) + 1
            first = entry["r"][0] if entry["r"] else None
            failed_first += bool(first and first["fail"])
            out.append(entry)
        for vi, n in absent.items():
            if seq.gt is not None:
                name = per_variant[vi]["name"]
                data.notes.append(
                    f"{data.variants[vi]} on {seq.name}: {n} of {len(ids)} ground-truth frame(s) are not in {name} and count "
                    "as failed (as in lanegraph eval); was the run made with --frames? give the report the same --frames"
                )
    return out, failed_first


def _variant_lanes(data: Collected, si: int, seq: Any) -> dict[int, dict[str, Any]]:
    """Per variant that ran on sequence ``si``: its lanes by frame, their outcomes against the
    ground truth, its failed frames and its lanes file."""
    per_variant: dict[int, dict[str, Any]] = {}
    for vi in range(len(data.variants)):
        rf = data.runs.get((vi, si))
        if rf is None:
            continue
        results = None
        if seq.gt is not None:
            results = {r.frame: r for r in evaluate(rf.records, seq.gt)["per_frame"]}
        lanes_file = rf.lanes_file or rf.folder
        per_variant[vi] = {
            "lanes": {str(r.get("frame")): list(r.get("lanes") or []) for r in rf.records},
            "results": results,
            "failures": rf.failures,
            "file": str(lanes_file),
            "name": lanes_file.name,
        }
    return per_variant


def _add_ground_truth(entry: dict[str, Any], g: dict[str, Any], where: str) -> None:
    """A frame's image size and markings (with the ego side each one is) from its ground truth."""
    size = g.get("image_size")
    if isinstance(size, list) and len(size) == 2:
        entry["w"], entry["h"] = size
    ego = g.get("ego") or {}

    def side(m: dict[str, Any]) -> str | None:
        return next(
            (s for s in ("left", "right") if ego.get(s) is not None and ego.get(s) == m.get("id")), None
        )

    entry["gt"] = [
        {"id": m.get("id"), "kind": str(m.get("kind", "")), "ego": side(m), "pts": _points(m, where)}
        for m in g.get("markings") or []
    ]


def _variant_frame(v: dict[str, Any], fid: str) -> dict[str, Any]:
    """One variant's lanes on frame ``fid`` with their outcomes and the frame's metric line."""
    lanes = v["lanes"].get(fid)
    missing = lanes is None
    lanes = lanes or []
    res = v["results"].get(fid) if v["results"] is not None else None
    m = res.match if res is not None else None
    outcomes = m.lane_outcomes() if m is not None else [None] * len(lanes)
    error = v["failures"].get(fid)
    return {
        "lanes": [
            {
                "pts": _points(ln, f"{v['file']}: frame {fid}"),
                "side": str(ln.get("side", "")),
                "score": _number(ln.get("score")),
                "o": outcomes[i],
                "dx": None if m is None or m.lane_dx[i] is None else round(m.lane_dx[i], 2),
            }
            for i, ln in enumerate(lanes)
        ],
        "mo": m.marking_outcomes() if m is not None else None,
        "ok": None if res is None else res.correct,
        "missing": missing,
        "fail": (not res.correct) if res is not None else error is not None,
        "line": _metric_line(
            res, len(lanes), v["name"] if missing and (res is not None or error is None) else None, error
        ),
    }


def _left_images(
    data: Collected, frames: list[dict[str, Any]], assets: Path, pm: PluginManager, width: int, log: _Log
) -> None:
    """Read each sequence's left images through its source node and write them as JPEG files."""
    writer = JpegWriter()
    try:
        for si, seq in enumerate(data.sequences):
            entries = {f["id"]: f for f in frames if f["s"] == si}
            if not entries or (seq.input is None and not seq.default_source):
                continue
            choice = choose_source(pm, data.graph, seq.input, allow_default=seq.default_source)
            if choice is None:
                data.notes.append(
                    f"sequence {seq.name}: no installed source reads {seq.input}: no left images"
                )
                continue
            order = _sequence_images(data, si, seq, choice, entries, assets, writer, width, log)
            if order is not None and seq.gt is None:  # without ground truth: the source's order
                rank = {fid: k for k, fid in enumerate(order)}
                block = sorted(
                    (f for f in frames if f["s"] == si), key=lambda f: rank.get(f["id"], len(rank))
                )
                idx = [k for k, f in enumerate(frames) if f["s"] == si]
                for k, f in zip(idx, block):
                    frames[k] = f
    finally:
        errors = writer.wait()
    if errors:
        raise LanegraphError(f"writing the report's images failed: {errors[0]}")
    for f in frames:  # a size for frames without image or ground-truth size: from what is drawn
        if f["w"] is None:
            pts = [p for r in f["r"] if r for ln in r["lanes"] for p in ln["pts"]] + [
                p for m in f.get("gt") or [] for p in m["pts"]
            ]
            f["w"] = int(max((p[0] for p in pts), default=1242) * 1.05)
            f["h"] = int(max((p[1] for p in pts), default=375) * 1.05)


def _sequence_images(
    data: Collected,
    si: int,
    seq: Any,
    choice: Any,
    entries: dict[str, Any],
    assets: Path,
    writer: JpegWriter,
    width: int,
    log: _Log,
) -> list[str] | None:
    """The left images of one sequence's frames in ``entries`` as JPEG files (their paths and
    sizes set in the entries); returns the source's frame order (None when it could not be read)."""
    from lanegraph.runlog import progress_bar

    folder = assets / "frames" / f"s{si}"
    folder.mkdir(parents=True, exist_ok=True)
    log(f"reading the left images of {len(entries)} frame(s) of {seq.name} ({choice.node_type.name}) ...")
    numbers = {fid: k for k, fid in enumerate(entries)}

    def on_image(fid: str, left: Any) -> None:
        e = entries[fid]
        name = f"f{numbers[fid]:05d}.jpg"
        writer.submit(folder / name, left, width)
        e["img"] = f"assets/frames/{folder.name}/{name}"
        e["h"], e["w"] = int(left.shape[0]), int(left.shape[1])

    bar = progress_bar(len(entries), f"report: {seq.name}", enabled=log.on, leave=False)
    try:
        order = read_left_images(
            choice, seq.input, seq.frames, set(entries), on_image, on_frame=lambda: bar.update(1)
        )
    except LanegraphError as exc:
        data.notes.append(f"sequence {seq.name}: the left images could not be read: {exc}")
        return None
    finally:
        bar.close()
    missing = [fid for fid, e in entries.items() if e["img"] is None]
    if missing:
        data.notes.append(
            f"sequence {seq.name}: {len(missing)} frame(s) not read by the source (e.g. {missing[0]}): shown without image"
        )
    return order


def _node_pictures(
    data: Collected, frames: list[dict[str, Any]], assets: Path, out: Path, debug_dir: Path | None, log: _Log
) -> int:
    """The ``--debug-dir`` pictures of the run's frames, as JPEG files, in graph order."""
    if data.kind != "run":
        return 0
    entries = {f["id"]: f for f in frames if f["s"] == 0}
    if debug_dir is None:
        debug_dir = recorded_debug_dir(data.run_dir)  # only the run's own pictures
    if debug_dir is None:
        return 0

    g = data.graph
    order = list(g.order) if g is not None else []
    ports = {nid: list(g.nodes[nid].type.outputs) for nid in order} if g is not None else {}
    writer = JpegWriter()
    count = 0
    for k, (fid, e) in enumerate(entries.items()):
        folder = debug_dir / safe_name(fid)
        if not folder.is_dir():
            continue
        pics = debug_pictures(folder, order, ports)
        if not pics:
            continue
        target = assets / "nodes" / f"f{k:05d}"
        target.mkdir(parents=True, exist_ok=True)
        e["dbg"] = []
        for i, (cap, path) in enumerate(pics):
            name = f"{i:02d}.jpg"
            writer.submit_file(target / name, path, PICTURE_WIDTH)
            e["dbg"].append({"cap": cap, "src": f"assets/nodes/{target.name}/{name}"})
        count += 1
    if count:
        log(f"{count} frame(s) with node pictures from {debug_dir}")
    errors = writer.wait()
    if errors:
        data.notes.append(f"{len(errors)} node picture(s) could not be converted: {errors[0]}")
    return count


# --------------------------------------------------------------------------- metrics
def _metrics(data: Collected) -> dict[str, Any]:
    """Per variant: each sequence's figures and the pooled ones (:func:`evaluate_sequences`)."""
    out: dict[str, Any] = {}
    for vi, name in enumerate(data.variants):
        pairs = [
            (seq.name, data.runs[(vi, si)].records, seq.gt)
            for si, seq in enumerate(data.sequences)
            if seq.gt is not None and (vi, si) in data.runs
        ]
        if pairs:
            res = evaluate_sequences(pairs)
            if len(pairs) == 1:
                res.pop(POOLED)
            out[name] = res
    return out
