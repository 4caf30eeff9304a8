"""A graph on synthetic scenes it was not tuned on: curves with hatching, no markings, noise, odd rigs, rough verges.

    python benchmarks/sweep_synthetic.py [GRAPH] [--frames 30] [--scenes noisy,narrow] [--kinds bends,gore]
                                         [--set NODE.PARAM=V ...]

The scenes of issue 28 come in kinds (``--kinds``; the table ends with each kind's frames pooled):
``bends`` (radius 30-250 m, entering a bend, S-bends), ``gore`` (a ramp beside a chevron- or
stripe-hatched gore area between two solid lines), ``shade`` (dappled tree shade; a shaded road
with saturated sun patches), ``worn`` (low contrast, gaps, repair strips), ``parked`` (a dashed line
partly hidden by parked cars), ``single`` (a folder of unrelated single pairs: nothing before
the first frame) and ``sideroad`` (issue 44: a residential street without paint where side roads
join on the right, their raised kerbs curving away; and the same street with edge lines).

Renders each scene (``lanegraph_synthetic``, exact lane ground truth) into ``--work`` (a temporary
folder by default), runs ``lanegraph run GRAPH`` on it and prints the lane metric of the data
README per scene: detection ratio, precision, ego recall, and the number of lanes reported (on the
scenes without markings and on the crossing without lines, any lane is a false one). Rendering
takes about a second per frame; the whole sweep at 30 frames about 4 minutes on the 2-core
reference machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from _sweep import (  # benchmarks/ (the script's folder)
    HEADER,
    lanes_file,
    lanes_reported,
    metric_row,
    run_graph,
)
from lanegraph_synthetic import Marking, preset, write_pairs, write_sequence

from lanegraph.evaluation.metrics import evaluate, read_jsonl

ROOT = Path(__file__).resolve().parents[1]

#: name -> (preset, overrides); none of these is a scene the defaults were tuned on
SCENES: dict[str, tuple[str, dict]] = {
    "highway_curve_hatching_right": (
        "straight",
        dict(curvature=1 / 400, n_lanes=3, lane_width=3.75, speed=25.0, hatching=10.0, traffic=2, seed=11),
    ),
    "highway_curve_hatching_left": (
        "straight",
        dict(curvature=-1 / 400, n_lanes=4, lane_width=3.75, speed=25.0, hatching=14.0, traffic=1, seed=12),
    ),
    "highway_clothoid_hatching": (
        "clothoid",
        dict(curvature=-0.001, curvature_rate=1e-4, n_lanes=3, speed=22.0, hatching=12.0, seed=13),
    ),
    "tight_curve_left": ("straight", dict(curvature=-1 / 250, n_lanes=2, speed=12.0, seed=14)),
    "kerbs_curve_left": ("kerbs", dict(curvature=-1 / 300, seed=26)),
    "no_markings_kerbs": (
        "no_markings",
        dict(kerb_height=0.12, parked_cars=10.0, shadows=10.0, trees=6.0, seed=15),
    ),
    "no_markings_walls": ("no_markings", dict(walls=True, poles=5.0, traffic=1, seed=16)),
    "no_markings_urban": ("urban", dict(markings=[], seed=44)),
    # a pedestrian crossing 22-26 m ahead: seven bars 0.5 m wide, 1 m apart (the ground truth has no lane)
    "no_lines_crossing": (
        "no_markings",
        dict(
            markings=[Marking(-3.0 + i, "dashed", 0.5, 4.0, 296.0, 22.0) for i in range(7)],
            speed=8.0,
            seed=81,
        ),
    ),
    "pitch_2.5_roll_1.5": ("straight", dict(pitch_deg=2.5, roll_deg=1.5, seed=17)),
    "narrow_lanes_2.8m": ("straight", dict(lane_width=2.8, n_lanes=2, seed=18)),
    "wide_lanes_4.3m": ("straight", dict(lane_width=4.3, seed=19)),
    "single_lane": ("straight", dict(n_lanes=1, shoulder=1.5, seed=20)),
    "solid_inner_lines": ("straight", dict(inner_kind="solid", seed=21)),
    "heavy_shadows": ("urban", dict(shadows=15.0, trees=10.0, shadow_strength=0.7, seed=22)),
    "noise_5": ("straight", dict(noise_sigma=5.0, seed=23)),
    "noise_8_right_gain_0.9": ("straight", dict(noise_sigma=8.0, right_gain=0.9, seed=23)),
    "wide_long_markings": ("straight", dict(marking_width=0.25, dash_length=6.0, gap_length=12.0, seed=24)),
    "tall_rig_2.2m": ("straight", dict(height=2.2, pitch_deg=0.0, seed=25)),
    # the car in the rightmost lane, its right boundary an edge line beside grass or gravel
    "rough_verge_0.5m": ("straight", dict(n_lanes=2, ego_lane=1, shoulder=0.5, verge_texture=3.0, seed=31)),
    "very_rough_verge_0.3m": (
        "straight",
        dict(n_lanes=2, ego_lane=1, shoulder=0.3, verge_texture=4.0, seed=33),
    ),
}

#: issue 28's kinds: name -> (kind, preset, overrides)
KIND_SCENES: dict[str, tuple[str, str, dict]] = {
    "bend_r30": ("bends", "straight", dict(curvature=1 / 30, n_lanes=2, speed=6.0, seed=101)),
    "bend_r60_left": ("bends", "straight", dict(curvature=-1 / 60, n_lanes=2, speed=8.0, seed=102)),
    "bend_r120": ("bends", "straight", dict(curvature=1 / 120, n_lanes=3, speed=12.0, seed=103)),
    "bend_r250_left": ("bends", "straight", dict(curvature=-1 / 250, n_lanes=3, speed=20.0, seed=104)),
    # entering a bend: straight at the car, 1/60 m^-1 50 m ahead (a clothoid), the car drives into it
    "entering_bend": (
        "bends",
        "clothoid",
        dict(curvature=0.0, curvature_rate=1 / 3000, n_lanes=2, speed=8.0, seed=105),
    ),
    # an S-bend: 1/80 m^-1 right at the car, straight 20 m ahead, then left
    "s_bend": (
        "bends",
        "straight",
        dict(curvature=1 / 80, curvature_rate=-1 / 1600, n_lanes=2, speed=8.0, seed=106),
    ),
    "ramp_gore_chevron": (
        "gore",
        "straight",
        dict(n_lanes=1, gore_width=3.0, curvature=1 / 100, speed=10.0, outer_kind="solid", seed=111),
    ),
    "ramp_gore_stripes": (
        "gore",
        "straight",
        dict(n_lanes=1, gore_width=2.5, gore_pattern="stripes", curvature=-1 / 150, speed=12.0, seed=112),
    ),
    "highway_gore_chevron": (
        "gore",
        "straight",
        dict(n_lanes=2, ego_lane=0, gore_width=4.0, gore_step=3.0, speed=20.0, seed=113),
    ),
    "dappled_shade": (
        "shade",
        "straight",
        dict(n_lanes=2, dappled=0.3, shadow_strength=0.6, speed=8.0, seed=121),
    ),
    "dappled_curve": (
        "shade",
        "straight",
        dict(n_lanes=2, dappled=0.4, shadow_strength=0.65, curvature=-1 / 150, speed=8.0, seed=122),
    ),
    "shade_saturated_sun": (
        "shade",
        "straight",
        dict(
            n_lanes=2,
            dappled=0.15,
            shadow_strength=0.8,
            overexposed_every=1,
            exposure_gain=1.7,
            speed=8.0,
            seed=123,
        ),
    ),
    "worn_paint": ("worn", "straight", dict(n_lanes=2, paint_wear=0.6, paint_gaps=0.3, seed=131)),
    "worn_repair_strips": ("worn", "straight", dict(n_lanes=2, paint_wear=0.4, repair_strips=15.0, seed=132)),
    "worn_curve_shade": (
        "worn",
        "straight",
        dict(n_lanes=2, paint_wear=0.5, paint_gaps=0.2, curvature=1 / 200, shadows=10.0, trees=6.0, seed=133),
    ),
    # a two-lane street, the right line dashed, cars parked on its right half a metre from it
    "dashed_behind_parked_cars": (
        "parked",
        "straight",
        dict(n_lanes=2, outer_kind="dashed", shoulder=2.3, parked_cars=14.0, speed=8.0, seed=141),
    ),
    # a residential street without paint, side roads joining on the right, their raised kerbs
    # curving away from the edge (12 m ahead at the first frame): any lane is a false one
    "residential_side_road": ("sideroad", "residential", dict(seed=161)),
    "residential_side_road_tight": (
        "sideroad",
        "residential",
        dict(side_road_radius=6.0, side_road_width=5.0, curvature=1 / 300, seed=162),
    ),
    # a side road joining on the left, its corner's kerb curving away through the image's left edge
    # near the car (where a road-guided disparity's bands have their borders)
    "residential_side_road_left": (
        "sideroad",
        "residential",
        dict(side_roads=(), side_roads_left=(9.0, 100.0), side_road_radius=8.0, seed=164),
    ),
    # the same street with solid edge lines 0.3 m inside both kerbs: they must still be found
    "residential_side_road_edge_lines": (
        "sideroad",
        "residential",
        dict(markings=[Marking(-4.9, "solid", 0.12), Marking(1.7, "solid", 0.12)], seed=163),
    ),
}

#: single pairs (kind ``single``): frame 0 of each, one folder
SINGLE_PAIRS: list[tuple[str, dict]] = [
    ("straight", dict(seed=151)),
    ("straight", dict(curvature=1 / 60, n_lanes=2, seed=152)),
    ("straight", dict(n_lanes=1, gore_width=3.0, curvature=1 / 100, seed=153)),
    ("straight", dict(n_lanes=2, dappled=0.3, shadow_strength=0.6, seed=154)),
    ("straight", dict(n_lanes=2, paint_wear=0.5, paint_gaps=0.2, seed=155)),
    ("straight", dict(n_lanes=2, outer_kind="dashed", shoulder=2.3, parked_cars=14.0, seed=156)),
    ("urban", dict(seed=157)),
    ("no_markings", dict(seed=158)),
]

for _name, (_kind, _base, _over) in KIND_SCENES.items():
    SCENES[_name] = (_base, _over)
SCENES["single_pairs"] = ("straight", {})  # rendered by write_pairs from SINGLE_PAIRS
KIND_OF = {name: kind for name, (kind, _b, _o) in KIND_SCENES.items()} | {"single_pairs": "single"}

#: scenes whose rendered ground truth lists the crossing's bars as markings (the README's metric
#: does not annotate crossings): only the number of lanes reported counts, and the right one is 0
LANE_COUNT_ONLY = {"no_lines_crossing"}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("graph", nargs="?", default=str(ROOT / "graphs" / "paper.yaml"))
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--scenes", default="", help="comma-separated subset of: " + ", ".join(SCENES))
    ap.add_argument(
        "--kinds",
        default="",
        help="comma-separated kinds: bends, gore, shade, worn, parked, single (issue 28), sideroad (issue 44)",
    )
    ap.add_argument(
        "--set", action="append", default=[], metavar="NODE.PARAM=VALUE", help="passed to lanegraph run"
    )
    ap.add_argument(
        "--work",
        default="",
        help="folder for the rendered scenes and the runs, kept (default: a temporary folder, removed at the end)",
    )
    args = ap.parse_args()
    kinds = [k for k in args.kinds.split(",") if k]
    names = [s for s in args.scenes.split(",") if s] + [n for n, k in KIND_OF.items() if k in kinds]
    names = names or list(SCENES)
    unknown = [s for s in names if s not in SCENES]
    if unknown:
        ap.error(f"--scenes: unknown scene(s) {unknown}; expected some of {list(SCENES)}")

    def sweep(work: Path) -> int:
        print(f"{args.graph} on {len(names)} synthetic scenes, {args.frames} frames each (work: {work})")
        print(f"{'scene':32s} {HEADER}")
        per_kind: dict[str, list[int]] = {}
        for name in names:
            base, over = SCENES[name]
            seq = work / "scenes" / name
            if not (seq / "lanes_gt.jsonl").is_file():
                if name == "single_pairs":
                    write_pairs([preset(b, **o) for b, o in SINGLE_PAIRS], seq)
                else:
                    write_sequence(preset(base, **over), seq, args.frames)
            out = work / "runs" / name
            failed = run_graph(args.graph, seq, out, args.set)
            if failed:
                print(f"{name:32s} {failed}")
                continue
            pred, gt = read_jsonl(lanes_file(out)), read_jsonl(seq / "lanes_gt.jsonl")
            n_lanes = lanes_reported(pred)
            if name in KIND_OF:
                res = evaluate(pred, gt)
                pooled = per_kind.setdefault(KIND_OF[name], [0, 0])
                pooled[0] += round(res["detection_ratio"] * len(gt))
                pooled[1] += len(gt)
            print(
                f"{name:32s} {metric_row(evaluate(pred, gt), n_lanes, blank=name in LANE_COUNT_ONLY)}",
                flush=True,
            )
        for kind, (ok, n) in per_kind.items():
            print(f"kind {kind:27s} {100 * ok / n:8.1f} % of {n} frames", flush=True)
        (work / "sweep.json").write_text(
            json.dumps({"graph": args.graph, "frames": args.frames, "set": args.set, "scenes": names})
        )
        return 0

    if args.work:
        return sweep(Path(args.work))
    # the data and the runs go to a temporary folder removed at the end (--work keeps them)
    with tempfile.TemporaryDirectory(prefix="lanegraph-sweep-") as tmp:
        return sweep(Path(tmp))


if __name__ == "__main__":
    sys.exit(main())
