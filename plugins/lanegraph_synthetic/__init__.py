"""Synthetic stereo road scenes (``io.synthetic``) and the input-path dispatcher ``io.auto``."""

from __future__ import annotations

from pydantic import Field

from lanegraph import NodeParams, Port, RunContext, hookimpl, node_type

from .scene import Frame, Marking, SceneRenderer, SceneSpec

__all__ = ["Frame", "Marking", "SceneRenderer", "SceneSpec"]

STEREO_OUTPUTS = {
    "frame": Port("frame_id", "left image file stem"),
    "left": Port("image", "left rectified image"),
    "right": Port("image", "right rectified image"),
    "calib": Port("calibration", "stereo calibration", rate="constant"),
}


class SyntheticParams(NodeParams):
    """Params of ``io.synthetic``."""

    frames: int = Field(10, ge=1, le=100000, description="number of frames in the sequence")
    seed: int = Field(0, ge=0, description="random seed (texture, noise)")
    pitch_deg: float = Field(1.0, ge=-10, le=10, description="camera pitch, degrees (positive = nose down)")
    roll_deg: float = Field(0.0, ge=-10, le=10, description="camera roll, degrees")
    height: float = Field(1.65, gt=0.3, le=5.0, description="camera height above the road, metres")
    curvature: float = Field(0.0, ge=-0.02, le=0.02, description="lane curvature, 1/metres")
    speed: float = Field(10.0, ge=0, le=60, description="ego speed, metres per second (10 fps)")
    noise_sigma: float = Field(3.0, ge=0, le=50, description="sensor noise, grey levels")


@node_type(
    "io.synthetic",
    source=True,
    outputs={**STEREO_OUTPUTS, "gt_disparity": Port("disparity", "exact disparity (0 off the road)")},
)
class SyntheticSource:
    """A built-in synthetic stereo road sequence (4 lanes, dashed and solid) with exact ground truth."""

    def __init__(self, params: SyntheticParams, context: RunContext):
        self.params = params
        marks = [Marking(x, kind, curvature=params.curvature) for x, kind in
                 ((-5.4, "solid"), (-1.8, "dashed"), (1.8, "dashed"), (5.4, "solid"))]
        spec = SceneSpec(
            pitch_deg=params.pitch_deg,
            roll_deg=params.roll_deg,
            height=params.height,
            markings=marks,
            speed=params.speed,
            noise_sigma=params.noise_sigma,
            seed=params.seed,
        )
        self.renderer = SceneRenderer(spec)
        sel = context.frames or slice(None)
        self.indices = list(range(params.frames))[sel]

    def constants(self) -> dict:
        return {"calib": self.renderer.spec.calib}

    def __len__(self) -> int:
        return len(self.indices)

    def __iter__(self):
        for k in self.indices:
            fr = self.renderer.render(k)
            yield {"frame": f"{k:010d}", "left": fr.left, "right": fr.right, "gt_disparity": fr.disparity}


class AutoParams(NodeParams):
    """Params of ``io.auto``."""

    default: str = Field("io.synthetic", description="source node type used when no --input is given")


@node_type("io.auto", source=True, outputs=STEREO_OUTPUTS)
class AutoSource:
    """Chooses the source from the --input path (KITTI raw, KITTI odometry, a folder of pairs);
    the built-in synthetic scene when there is none. Resolved by the executor before the run."""

    def __init__(self, params: AutoParams, context: RunContext):  # pragma: no cover - replaced at compile time
        raise RuntimeError("io.auto is resolved by the executor and never instantiated")


@hookimpl
def lanegraph_node_types():
    return [SyntheticSource, AutoSource]
