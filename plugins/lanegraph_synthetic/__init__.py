"""Synthetic stereo road scenes (``io.synthetic``).

Python API::

    from lanegraph_synthetic import preset, SceneRenderer, write_sequence

    spec = preset("urban", seed=3, pitch_deg=1.5)     # a SceneSpec
    frame = SceneRenderer(spec).render(0)              # left, right, disparity, masks, lanes_gt ...
    write_sequence(spec, "out/urban", n=20)            # an io.folder-readable folder + ground truth
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

from pydantic import Field

from lanegraph import NodeParams, Port, RunContext, hookimpl, node_type
from lanegraph.errors import InputError
from lanegraph.frames import select_frames, selection_text
from lanegraph.paths import create_new, inside
from lanegraph.types import calibration_problems

from .objects import Box, Pole, car
from .scene import KITTI_CALIB, PRESETS, Frame, Marking, SceneRenderer, SceneSpec, preset
from .sequence import disparity_to_png16, write_pairs, write_sequence

__all__ = [
    "KITTI_CALIB",
    "PRESETS",
    "Box",
    "Frame",
    "Marking",
    "Pole",
    "SceneRenderer",
    "SceneSpec",
    "SyntheticParams",
    "SyntheticSource",
    "car",
    "disparity_to_png16",
    "preset",
    "write_pairs",
    "write_sequence",
]

#: the ground truth a run of the synthetic scene writes into its output folder (what ``lanegraph
#: eval OUT`` and ``lanegraph report OUT`` score against)
GT_FILE = "lanes_gt.jsonl"

STEREO_OUTPUTS = {
    "frame": Port("frame_id", "left image file stem"),
    "left": Port("image", "left rectified image"),
    "right": Port("image", "right rectified image"),
    "calib": Port("calibration", "stereo calibration", rate="constant"),
}

#: params of io.synthetic that override the SceneSpec field of the same name when not None
_OVERRIDES = (
    "pitch_deg", "roll_deg", "height", "n_lanes", "lane_width", "curvature", "curvature_rate", "speed",
    "lateral_speed", "lane_change", "noise_sigma", "overexposed_every", "exposure_gain",
)  # fmt: skip


class SyntheticParams(NodeParams):
    """Params of ``io.synthetic``: a preset and overrides (``None`` keeps the preset's value)."""

    preset: Literal["straight", "curved", "clothoid", "urban", "no_markings", "overexposed"] = Field(
        "straight", description="scene preset: road shape, objects, shadows, paint, exposure"
    )
    frames: int = Field(10, ge=1, le=100000, description="number of frames in the sequence (10 Hz)")
    seed: int = Field(0, ge=0, description="random seed (texture, layout, dash phases, noise)")
    scale: float = Field(1.0, ge=0.1, le=2.0, description="image size relative to the 1242x375 KITTI rig")
    pitch_deg: float | None = Field(
        None, ge=-10, le=10, description="camera pitch, degrees (positive = nose down)"
    )
    roll_deg: float | None = Field(
        None, ge=-10, le=10, description="camera roll, degrees (positive = clockwise)"
    )
    height: float | None = Field(None, gt=0.3, le=5.0, description="camera height above the road, metres")
    n_lanes: int | None = Field(None, ge=1, le=6, description="number of lanes")
    lane_width: float | None = Field(None, ge=2.0, le=6.0, description="lane width, metres")
    curvature: float | None = Field(
        None, ge=-0.02, le=0.02, description="road curvature at the start, 1/metres (positive bends right)"
    )
    curvature_rate: float | None = Field(
        None, ge=-1e-3, le=1e-3, description="clothoid: curvature change per metre, 1/metres^2"
    )
    speed: float | None = Field(None, ge=0, le=60, description="ego speed, metres per second")
    lateral_speed: float | None = Field(
        None, ge=-3, le=3, description="lateral drift, metres per second (right positive)"
    )
    lane_change: int | None = Field(
        None, ge=-1, le=1, description="a lane change from t = 0.5 s over 3 s: -1 left, +1 right, 0 none"
    )
    noise_sigma: float | None = Field(None, ge=0, le=50, description="sensor noise, grey levels")
    overexposed_every: int | None = Field(
        None, ge=0, le=100000, description="every n-th frame is over-exposed (0: none)"
    )
    exposure_gain: float | None = Field(
        None, ge=1.0, le=10.0, description="gain of the over-exposed frames (then clipped at 255)"
    )


def spec_from_params(params: SyntheticParams) -> SceneSpec:
    """The :class:`SceneSpec` that ``io.synthetic`` renders for ``params``."""
    over = {name: getattr(params, name) for name in _OVERRIDES if getattr(params, name) is not None}
    if params.scale != 1.0:
        over["calib"] = KITTI_CALIB.scaled(params.scale)
    return preset(params.preset, seed=params.seed, **over)


@node_type(
    "io.synthetic",
    source=True,
    outputs={
        **STEREO_OUTPUTS,
        "gt_disparity": Port("disparity", "exact left disparity, pixels (0 on the sky)"),
        "gt_road_mask": Port("mask", "left-view pixels on the road plane"),
        "gt_object_mask": Port("mask", "left-view pixels on objects (cars, poles, walls)"),
    },
    implements=("constants", "identity", "frame_key", "len", "skip"),
)
class SyntheticSource:
    """A built-in synthetic stereo road sequence with exact ground truth (presets: straight, curved,
    clothoid, urban, no_markings, overexposed). In a run with an output folder its lane ground truth
    goes to OUT/lanes_gt.jsonl, one line per frame rendered, for lanegraph eval and report."""

    skipped: int  # frames of a resumed run left out (context.skip)

    def __init__(self, params: SyntheticParams, context: RunContext):
        self.params = params
        self.renderer = SceneRenderer(spec_from_params(params))
        problems = calibration_problems(self.renderer.calib)
        if problems:  # the params' bounds keep this from happening; checked like every source's
            raise InputError("implausible calibration: " + "; ".join(f"{k}: {m}" for k, m in problems))
        sel = context.frames if context is not None else None
        what = f"--frames {selection_text(sel)}"
        selected = select_frames(
            range(params.frames), [(what, sel)], f"io.synthetic ({params.frames} frames)"
        )
        self.skipped = min(max(int(getattr(context, "skip", 0)), 0), len(selected))
        self.indices = selected[self.skipped :]
        self.gt_path = None
        out_dir = context.out_dir if context is not None else None
        if out_dir is not None:
            # the exact answer beside the run's lanes: the frames a resumed run already did first
            self.gt_path = inside(Path(out_dir), GT_FILE, f"node '{context.node_id or '?'}' (io.synthetic)")
            self.gt_path.parent.mkdir(parents=True, exist_ok=True)
            with create_new(self.gt_path) as fh:
                for k in selected[: self.skipped]:
                    fh.write(_gt_line(self.renderer.lanes_gt(k)))

    def constants(self) -> dict:
        return {"calib": self.renderer.calib}

    def identity(self) -> str:
        """The rendered frames are determined by the params (for a resumed run's check)."""
        return f"synthetic:{self.params.model_dump_json()}"

    def frame_key(self, frame: str) -> str:
        """A rendered frame is determined by the params and the frame index (for result caches)."""
        return f"synthetic:{self.params.model_dump_json()}:{frame}"

    def __len__(self) -> int:
        return len(self.indices)

    def __iter__(self):
        for k in self.indices:
            fr = self.renderer.render(k)
            if self.gt_path is not None:
                with open(self.gt_path, "ab", buffering=0) as fh:  # one write: a whole line or none
                    fh.write(_gt_line(fr.lanes_gt))
            yield {
                "frame": fr.frame,
                "left": fr.left,
                "right": fr.right,
                "gt_disparity": fr.disparity,
                "gt_road_mask": fr.road_mask,
                "gt_object_mask": fr.object_mask,
            }


def _gt_line(record: dict) -> bytes:
    return (json.dumps(record, separators=(",", ":")) + "\n").encode("utf-8")


@hookimpl
def lanegraph_node_types():
    return [SyntheticSource]
