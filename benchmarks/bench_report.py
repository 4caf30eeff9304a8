"""Time to write the HTML report of a run, and its size.

    python benchmarks/bench_report.py [RUN_DIR] [--input DRIVE] [--gt GT] [--repeat 3]

Without RUN_DIR, first runs ``graphs/paper.yaml`` on KITTI raw drive 0001 (54 frames, from
``../shared/data``) with node pictures of frames 0 and 20 (``--debug-dir``) into a temporary
folder, then times ``lanegraph_report.write_report`` of it with the drive's ground truth (the
median of ``--repeat`` reports) and prints the report's size and the size per frame, projected to
a 1,000-frame run. Target: <= 10 s for the 54-frame drive; a 1,000-frame report under 100 MB.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DRIVE = ROOT.parent / "shared" / "data" / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "run_dir", nargs="?", type=Path, help="a run folder (default: run paper.yaml on drive 0001 first)"
    )
    ap.add_argument(
        "--input", type=Path, default=DRIVE, help="the drive (default: ../shared/data drive 0001)"
    )
    ap.add_argument("--gt", type=Path, help="ground truth (default: lanes_gt.jsonl in the input folder)")
    ap.add_argument("--repeat", type=int, default=3, help="reports to write; the median time is printed")
    args = ap.parse_args()

    from lanegraph_report import write_report

    tmp = None
    run_dir = args.run_dir
    if run_dir is None:
        if not (args.input / "image_02" / "data").is_dir():
            sys.exit(f"no KITTI drive at {args.input} (give --input or a RUN_DIR)")
        tmp = tempfile.TemporaryDirectory(prefix="bench_report_")
        run_dir = Path(tmp.name) / "run"
        print(
            f"running graphs/paper.yaml on {args.input} (54 frames, node pictures of frames 0 and 20) ...",
            flush=True,
        )
        cmd = [
            sys.executable, "-m", "lanegraph", "run", str(ROOT / "graphs" / "paper.yaml"), "--input", str(args.input),
            "--out", str(run_dir), "--debug-dir", str(run_dir / "debug"), "--debug-frames", "0,20", "--quiet",
        ]  # fmt: skip
        subprocess.run(cmd, check=True)
    gt = args.gt or args.input / "lanes_gt.jsonl"
    times = []
    summary = None
    for k in range(max(args.repeat, 1)):
        t0 = time.perf_counter()
        summary = write_report(run_dir, run_dir / f"report{k}", gt=gt, input_path=args.input, progress=False)
        times.append(time.perf_counter() - t0)
    assert summary is not None
    out = summary.index.parent
    pictures = sum(p.stat().st_size for p in (out / "assets" / "nodes").rglob("*") if p.is_file())
    per_frame = (summary.bytes - pictures) / max(summary.frames, 1)  # left image + the frame's data
    print(summary.line())
    print(
        f"report time: median {statistics.median(times):.2f} s over {len(times)} (min {min(times):.2f} s, max {max(times):.2f} s)"
    )
    print(
        f"report size: {summary.bytes / 1e6:.2f} MB ({summary.frames} frames; node pictures of {summary.node_picture_frames} "
        f"frames {pictures / 1e6:.2f} MB; page {(out / 'index.html').stat().st_size / 1e6:.2f} MB)"
    )
    print(
        f"per frame without node pictures: {per_frame / 1e3:.1f} kB -> {per_frame * 1000 / 1e6:.0f} MB for 1,000 frames"
    )
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
