"""Remake ``graphs/paper.yaml``: the thresholds of ``graphs/paper_base.yaml`` that
``graphs/spaces/paper.yaml`` names, as ``lanegraph tune`` chooses them over the dev dataset.

    python benchmarks/tune_paper.py [--out out/tune_paper] [--check] [--overwrite]

It runs, from the checkout's root (the developers' ``../shared/data`` beside it)::

    lanegraph tune graphs/paper_base.yaml --dataset graphs/datasets/dev.yaml \\
        --space graphs/spaces/paper.yaml --sampler random --trials 40 --seed 1 --name paper --out OUT

and writes ``OUT/tuned.yaml`` (``name: paper``, ``extends: paper_base.yaml``, a description that
names that command and its pooled left-out figure) as ``graphs/paper.yaml`` -- **only if** no
sequence has more false lanes left out (scored by the fold that did not choose on it) than with
paper_base.yaml's own hand-set values (the tune's baseline column): a threshold set that adds a
false lane anywhere, counted left out, is not taken whatever it gains elsewhere (issue 44).
Otherwise ``graphs/paper.yaml`` sets paper_base.yaml's own values of the same params (the tune's
starting point, kept), and its description says so, which sequences stopped it, and the search.
Same code, same data, same seed: the same file (the random sampler is seeded per trial; the
description holds no path of this machine, no time).

``--check``: write nothing; exit 1 when graphs/paper.yaml differs from what the tune gives.
The search is cheap on a warm result cache: trials that differ only in late nodes share the
disparity and road profile. OUT/results.md is the table docs/pipeline.md shows.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "graphs" / "paper.yaml"

#: the search; the paths relative to the checkout's root, as the description of paper.yaml shows them
TUNE = [
    "tune", "graphs/paper_base.yaml",
    "--dataset", "graphs/datasets/dev.yaml",
    "--space", "graphs/spaces/paper.yaml",
    "--sampler", "random", "--trials", "40", "--seed", "1",
    "--name", "paper",
]  # fmt: skip

HEADER = (
    "# Written by `python benchmarks/tune_paper.py` (lanegraph tune over graphs/datasets/dev.yaml): do not\n"
    "# edit by hand. The structure and the hand-set starting values are in paper_base.yaml, the searched\n"
    "# ranges in spaces/paper.yaml; the left-out table in docs/pipeline.md.\n"
)


def new_false_lanes(results_csv: Path) -> list[str]:
    """The sequences with more false lanes left out than with the graph's own values (or without a
    left-out or baseline figure), each said in words."""
    bad = []
    with results_csv.open(newline="") as f:
        for row in csv.DictReader(f):
            if row["sequence"] == "all":
                continue
            left, base = row["left_out_false_lanes"], row["baseline_false_lanes"]
            if left == "" or base == "":
                bad.append(
                    f"{row['sequence']}: no left-out or baseline figure (left out {left!r}, baseline {base!r})"
                )
            elif int(left) > int(base):
                bad.append(
                    f"{row['sequence']}: {left} false lane(s) left out, {base} with paper_base.yaml's values"
                )
    return bad


#: the first sentence of paper.yaml's description (what `lanegraph graphs` shows)
LEAD = (
    "The paper's pipeline (graphs/paper_base.yaml: Ozgunalp, Fan et al., with the deviations its nodes "
    "name), every threshold of graphs/spaces/paper.yaml set by one rule: lanegraph tune over the dev dataset."
)


def paper_text(tuned: Path, bad: list[str]) -> str:
    """``graphs/paper.yaml``: ``tuned.yaml`` (or, when ``bad`` names sequences the tune's choice adds
    false lanes to, paper_base.yaml's own values of the searched params in its place, and why), its
    description led by :data:`LEAD`."""
    import yaml
    from lanegraph_tune.output import dump_graph

    doc = yaml.safe_load(tuned.read_text(encoding="utf-8"))
    if bad:
        doc = kept(doc, bad)
    doc["description"] = f"{LEAD} {doc['description']}"
    return HEADER + dump_graph(doc)


def kept(doc: dict, bad: list[str]) -> dict:
    """The tuned graph ``doc`` with paper_base.yaml's own values of the searched params in place of
    the tune's choice, and a description that says they were kept, why, and what the search was."""
    from lanegraph_tune.space import load_space

    from lanegraph.graph.files import load_graph_named

    base = load_graph_named(ROOT / "graphs" / "paper_base.yaml")
    nodes: dict[str, dict] = {}
    for key in load_space(ROOT / "graphs" / "spaces" / "paper.yaml", base).keys:
        node_id, _, param = key.partition(".")
        nodes.setdefault(node_id, {"params": {}})["params"][param] = getattr(
            base.nodes[node_id].params, param
        )
    doc["nodes"] = nodes
    doc["description"] = (
        "Here the starting values (paper_base.yaml's own) are kept: the search chose params that add false "
        f"lanes counted left out ({'; '.join(bad)}), and a threshold set that does is not taken (issue 44). "
        f"The search: {doc['description']}"
    )
    return doc


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "tune_paper", help="the tune's folder")
    ap.add_argument("--check", action="store_true", help="write nothing: exit 1 if graphs/paper.yaml differs")
    ap.add_argument(
        "--overwrite", action="store_true", help="passed to lanegraph tune (OUT holds another search)"
    )
    args = ap.parse_args(argv)
    cmd = [sys.executable, "-m", "lanegraph", *TUNE, "--out", str(args.out.resolve())]
    if args.overwrite:
        cmd.append("--overwrite")
    print("running:", " ".join(cmd[2:]), file=sys.stderr, flush=True)
    code = subprocess.run(cmd, cwd=ROOT, env=os.environ.copy()).returncode
    tuned = args.out / "tuned.yaml"
    if code != 0 or not tuned.is_file():
        print(
            f"tune_paper: lanegraph tune failed (exit {code}); graphs/paper.yaml left as it is",
            file=sys.stderr,
        )
        return 1
    bad = new_false_lanes(args.out / "results.csv")
    text = paper_text(tuned, bad)
    if bad:
        print(
            "tune_paper: the tuned params add false lanes, counted left out; paper_base.yaml's own values kept:\n  "
            + "\n  ".join(bad),
            file=sys.stderr,
        )
    if args.check:
        same = PAPER.is_file() and PAPER.read_text(encoding="utf-8") == text
        print(f"tune_paper: graphs/paper.yaml is {'what' if same else 'NOT what'} the tune gives ({tuned})")
        return 0 if same else 1
    PAPER.write_text(text, encoding="utf-8")
    what = "paper_base.yaml's own values (kept)" if bad else "the tune's choice"
    print(
        f"tune_paper: wrote {PAPER.relative_to(ROOT)}: {what}, from {tuned}; the table: {args.out / 'results.md'}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
