"""Digests of every graph's lanes.jsonl, to check that a refactoring changes no result.

Runs every graph in graphs/ and graphs/ablations/ with `lanegraph run` on the built-in synthetic
scene and, with `--dataset graphs/datasets/dev.yaml`, on the developer sequences (every sequence the
dataset file names: drive 0001, seq1, seq2, seq2_ramp), and prints one line per (graph, sequence): the SHA-256 of its lanes.jsonl. With --compare, it
reads an earlier output of this script and says which digests differ.

    python benchmarks/lanes_digests.py --lanegraph /path/to/before/.venv/bin/lanegraph > before.txt
    python benchmarks/lanes_digests.py --compare before.txt > after.txt

A graph that cannot run here (paper_onnx.yaml needs an ONNX model file) is listed with the one-line
error it gave, which is compared like a digest.
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "missing"


def _run(lanegraph: str, graph: Path, out: Path, extra: list[str], cwd: Path) -> tuple[int, str]:
    proc = subprocess.run(
        [lanegraph, "run", str(graph), "--out", str(out), "--quiet", *extra],
        cwd=cwd,
        capture_output=True,
        text=True,
    )
    last = (proc.stderr.strip().splitlines() or [""])[-1]
    return proc.returncode, last.replace(str(cwd), "<root>")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lanegraph", default=str(Path(sys.executable).parent / "lanegraph"))
    ap.add_argument("--root", type=Path, default=ROOT, help="checkout whose graphs/ are run")
    ap.add_argument("--compare", type=Path, help="an earlier output of this script")
    ap.add_argument("--no-dataset", action="store_true", help="only the synthetic scene")
    args = ap.parse_args()
    root = args.root.resolve()
    graphs = sorted((root / "graphs").glob("*.yaml")) + sorted((root / "graphs" / "ablations").glob("*.yaml"))
    dataset = root / "graphs" / "datasets" / "dev.yaml"
    sequences = (
        [str(q["name"]) for q in yaml.safe_load(dataset.read_text())["sequences"]]
        if dataset.is_file()
        else []
    )
    lines: list[str] = []
    tmp = Path(tempfile.mkdtemp(prefix="lanes_digests_"))
    try:
        for graph in graphs:
            name = str(graph.relative_to(root / "graphs"))
            out = tmp / name.replace("/", "_")
            rc, err = _run(args.lanegraph, graph, out / "synthetic", [], root)
            row = _digest(out / "synthetic" / "lanes.jsonl") if rc == 0 else f"rc={rc} {err}"
            lines.append(f"{name}\tsynthetic\t{row}")
            print(lines[-1], flush=True)
            if args.no_dataset or not dataset.is_file():
                continue
            rc, err = _run(args.lanegraph, graph, out / "dev", ["--dataset", str(dataset)], root)
            for seq in sequences:
                row = _digest(out / "dev" / seq / "lanes.jsonl") if rc == 0 else f"rc={rc} {err}"
                lines.append(f"{name}\t{seq}\t{row}")
                print(lines[-1], flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if args.compare is None:
        return 0
    before = {tuple(x.split("\t")[:2]): x.split("\t")[2] for x in args.compare.read_text().splitlines() if x}
    after = {tuple(x.split("\t")[:2]): x.split("\t")[2] for x in lines}
    differ = [k for k in sorted(set(before) | set(after)) if before.get(k) != after.get(k)]
    same = len(set(before) & set(after)) - len([k for k in differ if k in before and k in after])
    for k in differ:
        print(f"DIFFERS {k[0]} {k[1]}: {before.get(k)} -> {after.get(k)}", file=sys.stderr)
    print(f"{same} identical, {len(differ)} differ", file=sys.stderr)
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
