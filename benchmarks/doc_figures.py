"""The figures of README.md and docs/tutorial.md, from the code: regenerated, or checked against the
committed text.

Each generated block in the docs lies between ``<!-- figures: NAME ... -->`` and ``<!-- /figures -->``.

- ``readme/quick-start``: the score line ``lanegraph run`` ends with, on the default synthetic scene;
- ``tutorial/ablation-kerbs``: every graph of ``graphs/ablations/`` and ``paper`` on 40 frames of the
  synthetic ``kerbs`` street (its answers are exact);
- ``tutorial/eval-drive``, ``tutorial/ablation-drive``: ``lanegraph eval`` of ``paper`` and the same
  ablation on KITTI raw drive 0001 (``../shared/data``);
- ``readme/dev``: ``paper`` on the eight developer sources of ``graphs/datasets/dev.yaml``;
- ``plugins/tophat-drive``: the example plugin's graph (``docs/examples/lg_tophat``) on drive 0001,
  beside ``paper`` (the plugin made findable for the run when it is not installed).

The real ones need ``../shared/data`` (skipped with a note when it is absent). The tables leave out
``ms/frame``, which depends on the machine and its load (docs/pipeline.md has the timings).

    python benchmarks/doc_figures.py --write            # regenerate the blocks in the docs
    python benchmarks/doc_figures.py --check            # exit 1 when a committed block differs
    python benchmarks/doc_figures.py --check --only synthetic
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
DRIVE = SHARED / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"
DOCS = {
    "readme": ROOT / "README.md",
    "tutorial": ROOT / "docs" / "tutorial.md",
    "plugins": ROOT / "docs" / "writing-plugins.md",
}
BLOCK = re.compile(r"(<!-- figures: (?P<name>[\w/-]+)[^>]*-->\n)(?P<body>.*?)(<!-- /figures -->)", re.S)
#: every block the generators write, by the figures they need
BLOCKS = {
    "readme/quick-start": "synthetic",
    "tutorial/ablation-kerbs": "synthetic",
    "tutorial/eval-drive": "real",
    "tutorial/ablation-drive": "real",
    "readme/dev": "real",
    "plugins/tophat-drive": "real",
}
README_ROWS = {  # sequence of dev.yaml -> the row's label
    "drive_0001": "KITTI raw drive 0001, urban street, kerb and tram tracks (0-53)",
    "seq1": "KITTI odometry `seq1`, residential street without painted lines (0-25)",
    "seq2": "KITTI odometry `seq2`, curved highway, edge line beside grass (32-50)",
    "seq2_ramp": "KITTI odometry `seq2_ramp`, tight on-ramp bend onto a chevron-hatched gore area (0-15)",
    "kitti15_000024": "KITTI stereo 2015 #24, single pair: worn dashed centre line in dappled shade",
    "kitti12_000070": "KITTI stereo 2012 #70, single pair: faint dashed parking-strip line beside parked cars",
    "odom00": "KITTI odometry 00, two frames: tar-sealed cracks, no markings (0-1)",
    "kitti15_000005": "KITTI stereo 2015 #5, single pair: cobbled parking bays, no longitudinal markings",
}


def lanegraph(*args: str) -> str:
    proc = subprocess.run(
        [sys.executable, "-m", "lanegraph.cli", *args], cwd=ROOT, capture_output=True, text=True
    )
    if proc.returncode not in (0, 1):
        raise SystemExit(f"lanegraph {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return proc.stdout


def variants() -> list[str]:
    return [
        "graphs/paper.yaml",
        *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "graphs" / "ablations").glob("*.yaml")),
    ]


def pooled_table(results_md: Path) -> str:
    """The first (pooled) table of an ablation's results.md, without its ms/frame column: a time
    depends on the machine and its load (docs/pipeline.md has the timings of a quiet machine)."""
    lines = results_md.read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| variant |"))
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")), len(lines))
    assert lines[start].endswith("| ms/frame |"), lines[start]
    return "\n".join(line[: line.rstrip("|").rfind("|") + 1] for line in lines[start:end]) + "\n"


def ablation(tmp: Path, name: str, *source: str) -> Path:
    out = tmp / name
    lanegraph("ablate", *variants(), *source, "--out", str(out), "--cache-dir", str(tmp / "cache"), "--quiet")
    return out


def gen_kerbs(tmp: Path) -> dict[str, str]:
    from lanegraph_synthetic import preset, write_sequence

    seq = write_sequence(preset("kerbs"), tmp / "kerbs", 40)
    out = ablation(tmp, "ablation_kerbs", "--input", str(seq), "--gt", str(seq / "lanes_gt.jsonl"))
    return {"tutorial/ablation-kerbs": pooled_table(out / "results.md")}


def gen_quick_start(tmp: Path) -> dict[str, str]:
    """The quick start as a new user runs it: ``lanegraph run`` in an empty folder."""
    work = tmp / "quick_start"
    work.mkdir()
    proc = subprocess.run(
        [sys.executable, "-m", "lanegraph.cli", "run"], cwd=work, capture_output=True, text=True
    )
    lines = [line for line in proc.stdout.splitlines() if line.startswith("detection ratio")]
    if proc.returncode != 0 or len(lines) != 1:
        raise SystemExit(
            f"lanegraph run failed ({proc.returncode}):\n{proc.stdout[-2000:]}{proc.stderr[-3000:]}"
        )
    return {"readme/quick-start": f"```text\n{lines[0]}\n```\n"}


def _pct(x: float | None, digits: int = 1) -> str:
    if x is None:
        return "–"
    v = 100 * x
    return f"{v:.0f} %" if round(v, digits) == round(v) else f"{v:.{digits}f} %"


def gen_real(tmp: Path) -> dict[str, str]:
    from lanegraph.evaluation.dataset import load_dataset, read_gt
    from lanegraph.evaluation.metrics import evaluate

    out = ablation(tmp, "ablation_drive", "--input", str(DRIVE), "--gt", str(DRIVE / "lanes_gt.jsonl"))
    lanes = out / "runs" / "paper" / DRIVE.name / "lanes.jsonl"
    text = lanegraph("eval", str(lanes), str(DRIVE / "lanes_gt.jsonl"))
    blocks = {
        "tutorial/ablation-drive": pooled_table(out / "results.md"),
        "tutorial/eval-drive": f"```text\n{text}```\n",
    }
    dev = ROOT / "graphs" / "datasets" / "dev.yaml"
    runs = tmp / "dev"
    lanegraph("run", "graphs/paper.yaml", "--dataset", str(dev), "--out", str(runs), "--quiet")
    rows = ["| sequence (frames) | detection ratio | precision | ego recall |", "|---|---|---|---|"]
    for seq in load_dataset(dev).sequences:
        preds = [
            json.loads(line) for line in (runs / seq.name / "lanes.jsonl").read_text().splitlines() if line
        ]
        res = evaluate(preds, read_gt(seq, seq.frames) or [])
        det = _pct(res["detection_ratio"])
        if not any(g.get("markings") for g in read_gt(seq, seq.frames) or []):
            empty = sum(1 for p in preds if not p.get("lanes"))
            det += f" (no lane on {empty} of {res['frames']})"
        rows.append(
            f"| {README_ROWS.get(seq.name, seq.name)} | {det} | {_pct(res['precision'])} | {_pct(res['ego_recall'])} |"
        )
    blocks["readme/dev"] = "\n".join(rows) + "\n"
    return blocks


def _tophat_env(tmp: Path) -> dict[str, str]:
    """The environment of a run that finds the example plugin: as installed, or (not installed)
    through an entry point of a stand-in distribution on PYTHONPATH."""
    import os
    from importlib import metadata

    env = dict(os.environ)
    try:
        metadata.distribution("lanegraph-tophat")
        return env
    except metadata.PackageNotFoundError:
        pass
    info = tmp / "site" / "lanegraph_tophat_doc_figures-0.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: lanegraph-tophat-doc-figures\nVersion: 0.0\n"
    )
    (info / "entry_points.txt").write_text("[lanegraph.plugins]\nlg_tophat = lg_tophat\n")
    paths = [str(tmp / "site"), str(ROOT / "docs" / "examples" / "lg_tophat"), env.get("PYTHONPATH", "")]
    env["PYTHONPATH"] = os.pathsep.join(p for p in paths if p)
    return env


def gen_tophat(tmp: Path) -> dict[str, str]:
    rows = [
        "| graph (drive 0001, frames 0-53) | detection ratio | precision | ego recall |",
        "|---|---|---|---|",
    ]
    env = _tophat_env(tmp)
    for label, graph in (
        ("`paper_tophat` (features.tophat)", "docs/examples/lg_tophat/graphs/paper_tophat.yaml"),
        ("`paper` (features.eslt)", "graphs/paper.yaml"),
    ):
        out = tmp / f"tophat_{len(rows)}"
        run = [sys.executable, "-m", "lanegraph.cli", "run", graph, "--input", str(DRIVE), "--frames", "0:54"]
        proc = subprocess.run(
            [*run, "--out", str(out), "--quiet"], cwd=ROOT, env=env, capture_output=True, text=True
        )
        if proc.returncode not in (0, 1):
            raise SystemExit(f"{' '.join(run)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
        res = json.loads(
            lanegraph("eval", str(out), str(DRIVE / "lanes_gt.jsonl"), "--json").splitlines()[-1]
        )
        rows.append(
            f"| {label} | {_pct(res['detection_ratio'])} | {_pct(res['precision'])} | {_pct(res['ego_recall'])} |"
        )
    return {"plugins/tophat-drive": "\n".join(rows) + "\n"}


def comparable(name: str, text: str) -> str:
    """The text as compared: trailing blanks ignored."""
    return "\n".join(line.rstrip() for line in text.strip().splitlines())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument(
        "--write", action="store_true", help="regenerate the blocks in README.md and docs/tutorial.md"
    )
    mode.add_argument(
        "--check", action="store_true", help="exit 1 when a committed block differs from the code's"
    )
    ap.add_argument(
        "--only", choices=["synthetic", "real"], help="only the synthetic or only the real figures"
    )
    opt = ap.parse_args()
    gens: list[tuple[str, Callable[[Path], dict[str, str]]]] = []
    if opt.only in (None, "synthetic"):
        gens.append(("quick start", gen_quick_start))
        gens.append(("synthetic", gen_kerbs))
    if opt.only in (None, "real"):
        if (DRIVE / "image_02").is_dir():
            gens.append(("real", gen_real))
            gens.append(("example plugin's", gen_tophat))
        else:
            print(
                f"doc_figures: real sequences not found at {SHARED}: their figures are not checked",
                file=sys.stderr,
            )
    fresh: dict[str, str] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, gen in gens:
            print(f"doc_figures: computing the {label} figures ...", file=sys.stderr, flush=True)
            fresh.update(gen(Path(tmp)))
    stale = []
    for doc, path in DOCS.items():
        text = path.read_text(encoding="utf-8")
        found = {m["name"] for m in BLOCK.finditer(text)}
        for name in [n for n in fresh if n.startswith(doc + "/")]:
            if name not in found:
                raise SystemExit(f"{path}: no block '<!-- figures: {name} -->' ... '<!-- /figures -->'")

        def replace(m: re.Match[str], path: Path = path) -> str:
            name = m["name"]
            if name not in fresh:
                return m.group(0)
            if comparable(name, m["body"]) != comparable(name, fresh[name]):
                stale.append((path, name, m["body"], fresh[name]))
            return m.group(1) + fresh[name] + m.group(4)

        new = BLOCK.sub(replace, text)
        if opt.write and new != text:
            path.write_text(new, encoding="utf-8")
            print(f"doc_figures: wrote {path.relative_to(ROOT)}", file=sys.stderr)
    if opt.check and stale:
        for path, name, old, new in stale:
            print(
                f"{path.relative_to(ROOT)}: the figures '{name}' are stale; the code gives:\n{new}\ncommitted:\n{old}"
            )
        print("regenerate them: python benchmarks/doc_figures.py --write", file=sys.stderr)
        sys.exit(1)
    if opt.check:
        print(f"doc_figures: {len(fresh)} block(s) match the code", file=sys.stderr)


if __name__ == "__main__":
    main()
