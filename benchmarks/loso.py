"""Leave-one-sequence-out figures of a graph's thresholds over a dataset file.

    python benchmarks/loso.py [--graph graphs/paper.yaml] [--dataset graphs/datasets/dev.yaml]
                              [--sweep NODE.PARAM=V1,V2,... ...] [--out out/loso] [--markdown]

For every threshold, the graph runs once per value on every sequence (``lanegraph ablate --sweep``,
the work the values share computed once). Then, for each sequence left out, the value is chosen on
the other sequences alone (the highest detection ratio over their frames pooled; among equal ones the
middle of the widest run of equal values in the grid's order, so that a plateau's edge is not
preferred) and the left-out sequence's detection ratio at that value is reported, beside its figure
at the graph's own value. A threshold whose chosen value holds up on the sequence it never saw is
not tuned to that sequence.

The default sweep covers the thresholds of ``lanes.verify``'s paint check and ``fit.irls``'s near
fit: on the 2-core reference machine about 10 minutes over ``dev.yaml``.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]

DEFAULT_SWEEPS = [
    "verify.min_paint_contrast=0.1,0.2,0.25,0.3,0.35,0.4,0.5,0.7",
    "verify.min_width_m=0.0,0.05,0.07,0.09,0.11,0.13",
    "verify.max_foot_width_m=0.24,0.28,0.32,0.36,0.4,0.5,0.7,1.0",
    "verify.min_side_ratio=0.0,0.5,0.6,0.7,0.75,0.8,0.85,0.9",
    "verify.max_dark_side_texture=5,7,9,11,13,15,20",
    "verify.min_row_contrast=0.05,0.1,0.15,0.2,0.3",
    "fit.near_fit_m=15,20,25,30,35,45",
    "fit.near_fit_coverage=0.3,0.5,0.7,0.8,0.9,1.0",
]


def choose(values: list[str], scores: list[float]) -> str:
    """The value with the highest score; among equal ones the middle of the widest run of equal
    best scores (in the grid's order), the first such run on a tie."""
    best = max(scores)
    runs: list[list[int]] = []
    for i, s in enumerate(scores):
        if abs(s - best) < 1e-12:
            if runs and runs[-1][-1] == i - 1:
                runs[-1].append(i)
            else:
                runs.append([i])
    widest = max(runs, key=len)
    return values[widest[(len(widest) - 1) // 2]]


def pooled(rows: dict[str, dict], names: list[str]) -> float:
    """The detection ratio over the frames of ``names`` pooled (each sequence's ratio times its frames)."""
    frames = sum(int(rows[n]["frames"]) for n in names)
    return sum(float(rows[n]["detection_ratio"]) * int(rows[n]["frames"]) for n in names) / frames


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graph", default=str(ROOT / "graphs/paper.yaml"))
    ap.add_argument("--dataset", default=str(ROOT / "graphs/datasets/dev.yaml"))
    ap.add_argument(
        "--sweep",
        action="append",
        help="NODE.PARAM=V1,V2,... (repeatable; default: the paint check's and the fit's)",
    )
    ap.add_argument("--out", default="out/loso")
    ap.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    args = ap.parse_args(argv)
    sweeps = args.sweep or DEFAULT_SWEEPS
    out = Path(args.out)
    cmd = [
        sys.executable,
        "-m",
        "lanegraph",
        "ablate",
        args.graph,
        "--dataset",
        args.dataset,
        "--out",
        str(out),
        "--quiet",
    ]
    for s in sweeps:
        cmd += ["--sweep", s]
    print(
        f"running {sum(len(s.split('=', 1)[1].split(',')) for s in sweeps) + 1} variants over {args.dataset} ...",
        file=sys.stderr,
    )
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        print(r.stderr[-2000:], file=sys.stderr)
        return r.returncode
    table: dict[str, dict[str, dict]] = {}
    for row in csv.DictReader((out / "results.csv").open()):
        table.setdefault(row["variant"], {})[row["sequence"]] = row
    base = Path(args.graph).stem
    sequences = [s for s in table[base] if s != "all"]
    resolved = yaml.safe_load(
        subprocess.run(
            [sys.executable, "-m", "lanegraph", "show", args.graph], capture_output=True, text=True
        ).stdout
    )
    head = [
        "threshold",
        "graph's value",
        "values at the best pooled figure",
        *[f"{s} left out: chosen value -> its figure (graph's)" for s in sequences],
    ]
    rows_out = [head]
    for sw in sweeps:
        key, values = sw.split("=", 1)[0], sw.split("=", 1)[1].split(",")
        node, param = key.split(".", 1)
        own = (resolved["nodes"].get(node, {}).get("params") or {}).get(param, "default")
        everyone = [pooled(table[f"{base}[{key}={v}]"], sequences) for v in values]
        best = [v for v, sc in zip(values, everyone) if abs(sc - max(everyone)) < 1e-12]
        cells = [key, str(own), f"{', '.join(best)} ({100 * max(everyone):.1f} %)"]
        for left in sequences:
            others = [s for s in sequences if s != left]
            scores = [pooled(table[f"{base}[{key}={v}]"], others) for v in values]
            v = choose(values, scores)
            held = float(table[f"{base}[{key}={v}]"][left]["detection_ratio"])
            cells.append(
                f"{v} -> {100 * held:.1f} % ({100 * float(table[base][left]['detection_ratio']):.1f} %)"
            )
        rows_out.append(cells)
    if args.markdown:
        lines = ["| " + " | ".join(r) + " |" for r in rows_out]
        lines.insert(1, "|" + "---|" * len(head))
    else:
        widths = [max(len(r[i]) for r in rows_out) for i in range(len(head))]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in rows_out]
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
