"""The paint check's cues, measured on every lane the fit proposes, split by what the lane is.

    python benchmarks/paint_cues.py [--graph graphs/paper.yaml] [--dataset graphs/datasets/dev.yaml] [--work DIR]

Runs GRAPH on every sequence of the dataset with ``lanes.verify``'s paint-check thresholds opened
(every fitted lane passes the paint check; the crossing check stays), so that each reported lane
carries the measured cues (``extra["paint"]``), and matches each lane against the ground truth with
the lane metric's matching. Prints, per sequence, the range (min, 10th percentile, median, 90th
percentile, max) of each cue over the lanes that match a painted marking and over the ones that do
not (kerbs, gutters, the asphalt's border): a threshold between the two ranges on every sequence is
one that carries from one road to the next.

The lanes the fit proposes depend on the previous frame's (feedback edges); with every lane passing,
later frames see more candidates than in a normal run. The figures are therefore the cues of a
superset of what the paint check is shown in the normal run.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from _sweep import lanes_file, run_graph  # benchmarks/ (the script's folder)

from lanegraph.evaluation.dataset import load_dataset, read_gt
from lanegraph.evaluation.metrics import match_frame, read_jsonl

ROOT = Path(__file__).resolve().parents[1]
OPEN = [
    "verify.min_paint_contrast=0",
    "verify.min_width_m=0",
    "verify.max_foot_width_m=5",
    "verify.min_side_ratio=0",
    "verify.min_painted_rows=1",
]
CUES = (
    ("contrast", "min_paint_contrast", 1.0),
    ("width_m", "min_width_m", 100.0),
    ("foot_width_m", "max_foot_width_m", 100.0),
    ("side_ratio", "min_side_ratio", 1.0),
)


def summary(values: list[float], scale: float) -> str:
    if not values:
        return "-"
    q = np.percentile(np.asarray(values) * scale, [0, 10, 50, 90, 100])
    return " / ".join(f"{v:.2f}" if scale == 1.0 else f"{v:.0f}" for v in q)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graph", default=str(ROOT / "graphs/paper.yaml"))
    ap.add_argument("--dataset", default=str(ROOT / "graphs/datasets/dev.yaml"))
    ap.add_argument("--work", help="output folder of the runs (default: a temporary one)")
    args = ap.parse_args(argv)
    ds = load_dataset(args.dataset)
    work = Path(args.work or tempfile.mkdtemp(prefix="lanegraph-cues-"))
    print("cue: min / p10 / median / p90 / max (contrast and side ratio relative, widths in cm)")
    for seq in ds:
        out = work / seq.name
        extra = (
            ["--frames", f"{seq.frames.start or ''}:{seq.frames.stop or ''}:{seq.frames.step or ''}"]
            if seq.frames
            else []
        )
        err = run_graph(args.graph, seq.input, out, OPEN, extra)
        if err:
            print(f"{seq.name}: {err}", file=sys.stderr)
            return 1
        gt = {str(g["frame"]): g for g in (read_gt(seq, None) or [])}
        groups: dict[str, dict[str, list[float]]] = {"paint": {}, "not paint": {}}
        for rec in read_jsonl(lanes_file(out)):
            lanes = rec.get("lanes") or []
            g = gt.get(str(rec["frame"]))
            if g is None:
                continue
            m = match_frame(lanes, g)
            for i, lane in enumerate(lanes):
                cues = lane.get("paint")
                if not cues:
                    continue
                kind = "paint" if m.lane_marking[i] is not None else "not paint"
                for key, _, _ in CUES:
                    if cues.get(key) is not None and np.isfinite(cues[key]):
                        groups[kind].setdefault(key, []).append(float(cues[key]))
        for kind, cues in groups.items():
            n = len(cues.get("contrast", []))
            print(
                f"{seq.name:12s} {kind:9s} ({n:3d} lanes): "
                + "; ".join(f"{key} {summary(cues.get(key, []), s)}" for key, _, s in CUES)
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
