"""What the sweep scripts (sweep_kitti.py, sweep_synthetic.py) share: run a graph on one input in a
fresh ``lanegraph run`` process and print the lane metric's row."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from lanegraph.errors import InputError
from lanegraph.records.results import describe, find_result

KEYS = ("detection_ratio", "precision", "ego_recall")
HEADER = f"{'detection':>9s} {'precision':>9s} {'ego rec.':>9s} {'lanes':>6s}"


def run_graph(graph: str, data: Path, out: Path, sets: list[str], extra: list[str] = ()) -> str | None:
    """``lanegraph run GRAPH --input DATA --out OUT --quiet`` with ``--set`` for each of ``sets`` and
    ``extra`` arguments; None when it succeeds, else what failed (exit status, end of stderr)."""
    cmd = [
        sys.executable,
        "-m",
        "lanegraph",
        "run",
        graph,
        "--input",
        str(data),
        "--out",
        str(out),
        "--quiet",
        *extra,
    ]
    for s in sets:
        cmd += ["--set", s]
    r = subprocess.run(cmd, capture_output=True, text=True)
    return (
        None
        if r.returncode == 0
        else f"lanegraph run failed (exit {r.returncode}): {r.stderr.strip()[-300:]}"
    )


def lanes_file(out: Path) -> Path:
    """The lanes file of run folder ``out``, as its sinks declared it (``run.json``); raises naming
    where it was looked for when there is none (:class:`InputError`)."""
    path = find_result(out)
    if path is None:
        raise InputError(f"no lanes in {out}: looked for {describe(out)}")
    return path


def pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def lanes_reported(pred: list[dict]) -> int:
    """The number of lanes in prediction records (one per frame, ``lanes`` a list)."""
    return sum(len(p.get("lanes") or []) for p in pred)


def metric_row(res: dict, n_lanes: int, blank: bool = False) -> str:
    """Detection ratio, precision and ego recall of ``evaluate``'s result (``-`` each when ``blank``)
    and the number of lanes reported, in the columns of :data:`HEADER`."""
    return " ".join(f"{'-' if blank else pct(res.get(k)):>9s}" for k in KEYS) + f" {n_lanes:6d}"
