"""The paint decision measured on candidates: every lane that reaches ``lanes.verify`` is an example.

    python benchmarks/paint_candidates.py [--graph graphs/paper.yaml] [--dataset graphs/datasets/dev.yaml]
        [--kinds bends,gore,shade,worn,parked,single,unpainted,verges] [--frames 10] [--work DIR]
        [--corpus FILE.csv] [--write-model FILE.json] [--fold-models DIR]

Runs GRAPH (in this process, a recorder on the node hooks) on every source of the dataset and on
the synthetic scenes of each kind (``benchmarks/sweep_synthetic.py``'s, ``--frames`` frames each;
``unpainted``: its streets without markings; ``verges``: painted streets with kerbs, heavy shadows
or rough verges beside the lines), and takes every lane that
reaches a ``lanes.verify`` node (the fit's and the followed ones) as a candidate. Each candidate is

- measured: the features of ``lanegraph_lanes._paint.paint_features`` (paint width and its
  constancy, contrast to the road on both sides, the rougher side's texture, flatness on the road
  plane from the disparity, parallelism to the other candidates, dash runs);
- labelled from the ground truth: *paint* when, projected into the image, it matches a marking
  under the lane metric of ``../shared/data/README.md`` (alone against every marking); else *not
  paint*, and what else it lies on where the measures tell: ``on paint, off`` (within 40 px of a
  marking on average, a misplaced lane), ``kerb`` (the road's height steps by 5 cm or more across
  it, from the disparity), ``rail`` (a narrow line with a second one 1.3-1.6 m beside it, parallel),
  ``shadow edge`` (one side much darker, and smooth), ``crack`` (the line darker than the road
  beside it), or ``other``;
- decided by the hand-set check (whether the graph's ``lanes.verify`` kept it).

Prints the hand-set check's precision and recall of *paint* per source and per kind (its
thresholds were set on the four developer sequences before; nothing is fitted here), and the same
for a logistic regression over the features (scikit-learn; standardised features) trained leave
one source out: each dev source and each synthetic kind is one group, the model of a fold trained
on every other group and its figures measured on the group left out. ``--write-model`` writes the
model trained on every group as the JSON that ``lanes.verify_learned`` reads (no pickle);
``--fold-models DIR`` writes each fold's model as ``DIR/<group>.json`` (for frame-level left-out
runs). ``--corpus`` keeps (or with ``--reuse`` reads back) the candidate table as CSV.

scikit-learn is needed by this script only (``pip install "lanegraph[paint-model]"``); the node reads the
weights with NumPy.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from loso import choose  # noqa: E402  benchmarks/
from sweep_synthetic import KIND_SCENES, SCENES, SINGLE_PAIRS  # noqa: E402  benchmarks/

from lanegraph import hookimpl  # noqa: E402
from lanegraph.evaluation.dataset import load_dataset, read_gt  # noqa: E402
from lanegraph.evaluation.metrics import match_score, read_jsonl  # noqa: E402
from lanegraph.graph.validation import load_graph  # noqa: E402
from lanegraph.nodes import RunContext  # noqa: E402
from lanegraph.run.executor import Executor  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

#: the synthetic scenes without markings or with edges that are no paint (kind ``unpainted``)
UNPAINTED = ["no_markings_kerbs", "no_markings_walls", "no_markings_urban"]
#: painted streets with kerbs, heavy shadows or rough verges beside the lines (kind ``verges``)
VERGES = ["heavy_shadows", "rough_verge_0.5m", "very_rough_verge_0.3m", "kerbs_curve_left"]

#: lanes.verify's step_side_ratio (the graph's): the flatness rule asks a side darker than this
VERIFY_SIDE_RATIO = 0.45

#: lanes.verify's max_step_m and obstacle_height_m (the graph's): every lane's sides level to within
#: a kerb's height, unless the higher side rises beyond the obstacle height 0.8-1.2 m out
VERIFY_MAX_STEP = 0.10
VERIFY_OBSTACLE = 0.20

#: the grid of ``lanes.verify``'s ``max_dark_side_step_m`` chosen leave one group out (None: off)
STEP_GRID = [0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1, 0.12, 0.15, None]


def _features_mod():
    from lanegraph_lanes import _paint

    return _paint


class Recorder:
    """Node hooks: per frame, the disparity, road and calibration; at each ``lanes.verify`` node its
    input lanes (the candidates) measured, and which of them it kept."""

    def __init__(self, source: str, kind: str, gt: dict[str, dict]) -> None:
        self.source, self.kind, self.gt = source, kind, gt
        self.rows: list[dict] = []
        self.calib = None
        self.disparity = None
        self.road = None
        self.pending: dict[str, dict] = {}
        self.paint = _features_mod()
        from lanegraph_lanes._temporal import ToImageParams, to_image
        from lanegraph_lanes._verify import VerifyParams, road_level, verify

        self.verify = verify
        self.params: dict = {}  # node id -> its VerifyParams, from the run's graph

        self.to_image = lambda lanes, g: to_image(ToImageParams(), lanes=lanes, geometry=g, calib=self.calib)
        self.road_level, self.vp = road_level, VerifyParams()

    @hookimpl
    def lanegraph_before_node(self, node_id, node_type, frame, inputs):
        if node_type == "lanes.verify":
            self.pending[node_id] = dict(inputs)

    @hookimpl
    def lanegraph_after_node(self, node_id, node_type, frame, outputs, elapsed_ms, error):
        if not outputs:
            return
        if "calib" in outputs and outputs["calib"] is not None:
            self.calib = outputs["calib"]
        if node_type.startswith("disparity.") and "disparity" in outputs:
            self.disparity = outputs["disparity"]
        if node_type == "road.profile":
            self.road = outputs.get("road")
        if node_type == "lanes.verify" and node_id in self.pending:
            self._measure(node_id, str(frame), self.pending.pop(node_id), outputs.get("lanes") or [])

    def _measure(self, node_id: str, frame: str, inputs: dict, kept: list) -> None:
        lanes = list(inputs.get("lanes") or [])
        if not lanes:
            return
        image, g, mask = inputs["image"], inputs["geometry"], inputs.get("mask")
        level = self.road_level(np.asarray(image), mask, self.vp.level_quantile)
        gain = self.vp.reference_level / level if level else 1.0
        kept_keys = {tuple(np.round(k.coeffs, 9)) for k in kept}
        # the same check without the side's flatness rule: the rule's threshold is chosen below (no
        # disparity: nor the every-lane flatness rule, which is applied from the features)
        vp = self.params.get(node_id) or self.vp
        flat = self.verify(
            vp.model_copy(update={"max_dark_side_step_m": None}),
            **{k: v for k, v in inputs.items() if k in ("lanes", "image", "geometry", "mask")},
        )["lanes"]
        flat_keys = {tuple(np.round(k.coeffs, 9)) for k in flat}
        gt = self.gt.get(frame)
        for ln in lanes:
            f = self.paint.paint_features(
                image,
                ln,
                g,
                others=lanes,
                gain=gain,
                disparity=self.disparity,
                road=self.road,
                calib=self.calib,
            )
            proj = self.to_image([ln], g)["lanes"]
            pts = np.asarray(proj[0].points).tolist() if proj else []
            label, near = "not paint", math.inf
            for m in (gt or {}).get("markings") or []:
                if match_score(pts, m.get("points") or []) is not None:
                    label = "paint"
                near = min(near, _mean_dx(pts, m.get("points") or []))
            self.rows.append(
                {
                    "source": self.source,
                    "kind": self.kind,
                    "frame": frame,
                    "node": node_id,
                    "side": ln.side,
                    "label": label,
                    "what": label if label == "paint" else _what(f, near, ln, lanes, g),
                    "kept": int(tuple(np.round(ln.coeffs, 9)) in kept_keys),
                    "kept_no_step": int(tuple(np.round(ln.coeffs, 9)) in flat_keys),
                    **{k: f[k] for k in self.paint.FEATURES},
                    "step_beyond_m": f.get("step_beyond_m", math.nan),
                }
            )


def _mean_dx(pts, gt_pts) -> float:
    from lanegraph.evaluation.metrics import polyline_x_at

    gt = np.asarray(gt_pts, np.float64).reshape(-1, 2)
    if len(gt) == 0 or len(pts) < 2:
        return math.inf
    xp = polyline_x_at(pts, gt[:, 1])
    ok = ~np.isnan(xp)
    return float(np.abs(xp[ok] - gt[ok, 0]).mean()) if ok.any() else math.inf


def _what(f: dict, near_px: float, lane, lanes, g) -> str:
    """What a candidate that matches no marking lies on, where the measures tell."""
    if near_px <= 40.0:
        return "on paint, off"
    if np.isfinite(f["height_step_m"]) and f["height_step_m"] >= 0.05:
        return "kerb"
    if np.isfinite(f["width_m"]) and f["width_m"] < 0.09:
        for o in lanes:
            if o is lane:
                continue
            gap = abs(o.coeffs[0] - lane.coeffs[0]) * g.resolution
            if 1.3 <= gap <= 1.6:
                return "rail"
    if np.isfinite(f["side_ratio"]) and f["side_ratio"] < 0.75 and f["dark_texture"] <= 11.0:
        return "shadow edge"
    if not np.isfinite(f["contrast"]) or f["painted_fraction"] < 0.1:
        return "crack"
    return "other"


def run_source(
    graph: Path, name: str, kind: str, data: Path, gt_records: list[dict], frames=None
) -> list[dict]:
    """The candidates of one run of ``graph`` on ``data``."""
    rec = Recorder(name, kind, {str(g["frame"]): g for g in gt_records})
    with tempfile.TemporaryDirectory(prefix="lanegraph-cand-") as tmp:
        ex = Executor(load_graph(graph), RunContext(input_path=data, out_dir=Path(tmp), frames=frames))
        rec.params = {n.id: n.params for n in ex.graph.nodes.values() if n.type.name == "lanes.verify"}
        ex.pm.register(rec)
        try:
            ex.run()
        finally:
            ex.pm.unregister(rec)
    return rec.rows


def synthetic_sources(kinds: list[str], frames: int, work: Path):
    """(name, kind, folder) of the synthetic scenes of ``kinds``, rendered into ``work`` once."""
    from lanegraph_synthetic import preset, write_pairs, write_sequence

    todo = [(n, k, b, o) for n, (k, b, o) in KIND_SCENES.items() if k in kinds]
    if "unpainted" in kinds:
        todo += [(n, "unpainted", *SCENES[n]) for n in UNPAINTED]
    if "verges" in kinds:
        todo += [(n, "verges", *SCENES[n]) for n in VERGES]
    if "single" in kinds:
        todo.append(("single_pairs", "single", None, None))
    for name, kind, base, over in todo:
        seq = work / "scenes" / f"{name}_{frames}"
        if not (seq / "lanes_gt.jsonl").is_file():
            print(f"rendering {name} ({frames} frames) ...", file=sys.stderr, flush=True)
            if base is None:
                write_pairs([preset(b, **o) for b, o in SINGLE_PAIRS], seq)
            else:
                write_sequence(preset(base, **over), seq, frames)
        yield name, kind, seq


# --------------------------------------------------------------------------- figures
def pr(decided: np.ndarray, paint: np.ndarray) -> tuple[float, float, int, int]:
    """Precision and recall of *paint* of a decision, and the numbers of paint and other candidates."""
    tp = int(np.sum(decided & paint))
    precision = tp / int(decided.sum()) if decided.any() else math.nan
    recall = tp / int(paint.sum()) if paint.any() else math.nan
    return precision, recall, int(paint.sum()), int((~paint).sum())


def _pct(v: float) -> str:
    return "-" if not np.isfinite(v) else f"{100 * v:.1f} %"


def matrix(rows: list[dict], names: tuple[str, ...]) -> np.ndarray:
    return np.array([[float(r[k]) if r[k] not in ("", None) else math.nan for k in names] for r in rows])


def fit_model(x: np.ndarray, y: np.ndarray, names: tuple[str, ...], fill: np.ndarray) -> dict:
    """A logistic regression on the standardised features (NaN filled), as the JSON of
    ``lanes.verify_learned``; its threshold the one of the best F0.5 (precision first) on ``x``."""
    from sklearn.linear_model import LogisticRegression

    xf = np.where(np.isfinite(x), x, fill)
    mean, scale = xf.mean(axis=0), xf.std(axis=0)
    scale[scale <= 1e-9] = 1.0
    lr = LogisticRegression(C=1.0, max_iter=2000, class_weight="balanced")
    lr.fit((xf - mean) / scale, y)
    p = lr.predict_proba((xf - mean) / scale)[:, 1]
    best, thr = -1.0, 0.5
    for t in np.linspace(0.2, 0.95, 31):
        d = p >= t
        tp = np.sum(d & y)
        prec = tp / max(d.sum(), 1)
        rec = tp / max(y.sum(), 1)
        f = 1.25 * prec * rec / max(0.25 * prec + rec, 1e-12)
        if f > best + 1e-12:
            best, thr = f, float(t)
    return {
        "features": list(names),
        "fill": [float(v) for v in fill],
        "mean": [float(v) for v in mean],
        "scale": [float(v) for v in scale],
        "coef": [float(v) for v in lr.coef_[0]],
        "intercept": float(lr.intercept_[0]),
        "threshold": round(thr, 3),
    }


#: the value of a feature that cannot be measured: what a candidate without paint measures
FILL = {
    "contrast": 0.0,
    "side_ratio": 0.5,
    "width_m": 0.0,
    "foot_width_m": 1.0,
    "width_spread": 1.0,
    "height_step_m": 0.0,
    "line_height_m": 0.0,
    "step_beyond_m": 0.0,
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graph", default=str(ROOT / "graphs/paper.yaml"))
    ap.add_argument("--dataset", default=str(ROOT / "graphs/datasets/dev.yaml"))
    ap.add_argument("--kinds", default="bends,gore,shade,worn,parked,single,unpainted,verges")
    ap.add_argument("--frames", type=int, default=10, help="frames of each synthetic scene")
    ap.add_argument("--work", default="", help="folder for the rendered scenes (kept)")
    ap.add_argument("--corpus", default="", help="write the candidates to this CSV")
    ap.add_argument("--reuse", action="store_true", help="read --corpus instead of running")
    ap.add_argument("--write-model", default="", help="write the model trained on every group (JSON)")
    ap.add_argument("--fold-models", default="", help="write each fold's model to DIR/<group>.json")
    args = ap.parse_args(argv)
    paint = _features_mod()
    names = paint.FEATURES
    if args.reuse and args.corpus:
        rows = list(csv.DictReader(open(args.corpus)))
    else:
        rows = []
        ds = load_dataset(args.dataset)
        for seq in ds:
            print(f"running {seq.name} ...", file=sys.stderr, flush=True)
            rows += run_source(
                Path(args.graph), seq.name, "dev", seq.input, read_gt(seq, None) or [], seq.frames
            )
        work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="lanegraph-cand-"))
        kinds = [k for k in args.kinds.split(",") if k]
        for name, kind, folder in synthetic_sources(kinds, args.frames, work):
            print(f"running {name} ...", file=sys.stderr, flush=True)
            rows += run_source(Path(args.graph), name, kind, folder, read_jsonl(folder / "lanes_gt.jsonl"))
        if args.corpus:
            with open(args.corpus, "w", newline="") as fh:
                w = csv.DictWriter(fh, fieldnames=list(rows[0]))
                w.writeheader()
                w.writerows(rows)
    group = np.array([r["source"] if r["kind"] == "dev" else r["kind"] for r in rows])
    y = np.array([r["label"] == "paint" for r in rows])
    # the hand-set decision: the graph's check without the flatness rule, then the rule (at the graph's
    # 6 cm) on the measured features: the same decision for a corpus read back (--reuse)
    step = matrix(rows, ("height_step_m",))[:, 0]
    side = matrix(rows, ("side_ratio",))[:, 0]
    no_step = np.array([int(r.get("kept_no_step", r["kept"])) == 1 for r in rows])
    dark = np.nan_to_num(side, nan=1.0) < VERIFY_SIDE_RATIO

    # every lane's flatness (max_step_m): a kerb's height across it, no obstacle beyond
    beyond = (
        matrix(rows, ("step_beyond_m",))[:, 0] if "step_beyond_m" in rows[0] else np.full(len(rows), np.nan)
    )
    kerb = (np.nan_to_num(step, nan=0.0) > VERIFY_MAX_STEP) & ~(
        np.nan_to_num(beyond, nan=0.0) > VERIFY_OBSTACLE
    )
    no_step = no_step & ~kerb

    def decide(v):
        return no_step if v is None else no_step & ~(dark & (np.nan_to_num(step, nan=0.0) > v))

    kept = decide(0.06)
    x = matrix(rows, names)
    fill = np.array([FILL.get(n, 0.0) for n in names])
    learned = np.zeros(len(rows), bool)
    groups = list(dict.fromkeys(group))
    for g in groups:
        out = group == g
        if len(set(y[~out])) < 2:
            continue
        model = fit_model(x[~out], y[~out], names, fill)
        m = paint.PaintModel(model)
        learned[out] = [m.probability(dict(zip(names, v))) >= m.threshold for v in x[out]]
        if args.fold_models:
            Path(args.fold_models).mkdir(parents=True, exist_ok=True)
            (Path(args.fold_models) / f"{g}.json").write_text(json.dumps(model, indent=1) + "\n")
    print(f"{len(rows)} candidates ({int(y.sum())} paint) from {len(groups)} groups")
    print("\nthe paint decision per group (hand-set: thresholds set before; learned: left out)")
    print(
        "| group | candidates (paint / not) | hand-set precision | hand-set recall | learned precision | learned recall |"
    )
    print("|---|---|---|---|---|---|")
    for g in groups + ["all"]:
        sel = np.ones(len(rows), bool) if g == "all" else group == g
        hp, hr, npaint, nother = pr(kept[sel], y[sel])
        lp, lrc, _, _ = pr(learned[sel], y[sel])
        print(f"| {g} | {npaint} / {nother} | {_pct(hp)} | {_pct(hr)} | {_pct(lp)} | {_pct(lrc)} |")
    print("\nwhat the candidates that are not paint lie on: how many, and the share each check rejects")
    print("| what | candidates | hand-set rejects | learned rejects |")
    print("|---|---|---|---|")
    what = np.array([r["what"] for r in rows])
    for w in sorted(set(what) - {"paint"}):
        sel = what == w
        print(f"| {w} | {int(sel.sum())} | {_pct(1 - kept[sel].mean())} | {_pct(1 - learned[sel].mean())} |")
    print(
        "\nlanes.verify's max_dark_side_step_m chosen leave one group out (fewest false and missed candidates"
    )
    print(
        "on the other groups, a plateau's middle; the candidates' hand-set decision without the rule, then the rule)"
    )

    def errors(v, sel):
        d = decide(v)[sel]
        return int(np.sum(d & ~y[sel]) + np.sum(~d & y[sel]))

    print(
        "| group left out | chosen on the others | its errors there (false + missed) | at 0.06 | rule off |"
    )
    print("|---|---|---|---|---|")
    for g in groups:
        out = group == g
        scores = [-errors(v, ~out) for v in STEP_GRID]
        v = choose([str(x) for x in STEP_GRID], scores)
        chosen = None if v == "None" else float(v)
        print(f"| {g} | {v} | {errors(chosen, out)} | {errors(0.06, out)} | {errors(None, out)} |")
    if args.write_model:
        model = fit_model(x, y, names, fill)
        Path(args.write_model).write_text(json.dumps(model, indent=1) + "\n")
        print(f"\nmodel trained on every group -> {args.write_model}")
        print(
            "  "
            + ", ".join(f"{n} {c:+.2f}" for n, c in zip(names, model["coef"]))
            + f"; threshold {model['threshold']}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
