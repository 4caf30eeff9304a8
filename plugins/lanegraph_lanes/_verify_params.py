"""The params of ``lanes.verify`` (the paint check, the side check, the crossing check and the
optional texture check: see :mod:`._verify`), and the input ports it shares with
``lanes.verify_learned``."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from lanegraph import NodeParams, Port


class VerifyParams(NodeParams):
    """Params of ``lanes.verify``."""

    paint_check: bool = Field(
        True, description="drop a lane whose cross profile is not paint's (see the paint cues below)"
    )
    max_distance_m: float = Field(
        25.0,
        gt=0.0,
        le=500.0,
        description="paint check: the rows nearer than this are measured (where the BEV resolves paint), metres",
    )
    paint_band_m: float = Field(
        1.5, ge=0.1, le=10.0, description="paint check: the side bands reach this far from the lane, metres"
    )
    paint_gap_m: float = Field(
        0.25,
        ge=0.05,
        le=5.0,
        description="paint check: the side bands start this far from the lane (beyond the widest paint's half), metres",
    )
    align_m: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="paint check: each row's centre is the brightest pixel within this of the fitted lane, metres",
    )
    min_row_contrast: float = Field(
        0.15,
        ge=0.0,
        le=10.0,
        description="paint check: a row is painted when its centre is this much brighter than the brighter side band (relative: 0.15 = 15 %)",
    )
    min_painted_rows: int = Field(
        10, ge=1, le=100000, description="paint check: fewer painted rows than this and the lane is not paint"
    )
    min_paint_contrast: float = Field(
        0.3,
        ge=0.0,
        le=10.0,
        description="paint check: the painted rows' median contrast over the brighter side (relative): paint is "
        "bright against the road on both sides; the edge of a road beside a darker verge or a kerb's lit face barely is",
    )
    min_width_m: float = Field(
        0.09,
        ge=0.0,
        le=2.0,
        description="paint check: narrowest median profile at half height, metres (the narrowest marking is 10 cm; a kerb's lit edge is narrower)",
    )
    max_foot_width_m: float = Field(
        0.36,
        gt=0.0,
        le=5.0,
        description="paint check: widest median profile at a quarter of its height, metres (paint is at most 30 cm wide with "
        "sharp edges, blurred by about a BEV pixel; a concrete gutter is a wider band with soft edges)",
    )
    min_side_ratio: float = Field(
        0.75,
        ge=0.0,
        le=1.0,
        description="paint check: paint lies on road on both sides; a side whose level (the painted rows' median, over "
        "the brighter side's) is below this fraction is road only when it is smooth (max_dark_side_texture): a "
        "shadow cast along the line, not the gravel beyond a kerb (unitless; 0: not checked)",
    )
    max_dark_side_step_m: float | None = Field(
        0.06,
        gt=0.0,
        le=2.0,
        description="paint check, with the disparity, the road and the calibration wired: a side darker than "
        "step_side_ratio of the other must also be level with it: the road's median height above the fitted road "
        "plane 0.3-0.8 m left and right of the lane may differ by at most this (a kerb is a step of 10-15 cm and the "
        "gutter beside it dark; a shadow cast on the road is level), metres; null: not checked",
    )
    max_kerb_step_m: float | None = Field(
        None,
        gt=0.0,
        le=5.0,
        description="with max_dark_side_step_m: a step across the lane higher than this is no kerb (10-15 cm, at most "
        "20) but an obstacle's side standing beside the line (a parked car beside a parking strip's line, a wall): the "
        "step check keeps the lane, metres; None: every step above max_dark_side_step_m drops it",
    )
    max_step_m: float | None = Field(
        None,
        gt=0.0,
        le=2.0,
        description="paint check, with the disparity, the road and the calibration wired, on every lane: the road's "
        "median height above the fitted road plane 0.3-0.8 m left and right of the lane may differ by at most this "
        "(paint lies on the road plane; a kerb is a step of 10-15 cm, a kerb's lit top passes the paint check like "
        "paint), unless the higher side stands more than obstacle_height_m above the lower one 0.8-1.2 m out (a "
        "parked car or a wall beside a line, not a pavement), metres; null: not checked",
    )
    obstacle_height_m: float = Field(
        0.2,
        gt=0.0,
        le=5.0,
        description="with max_step_m: the higher side of a step across a lane, 0.8-1.2 m out, standing more than this "
        "above the lower side is an obstacle beside the line (a parked car: 34-38 cm), not a kerb's top and the "
        "pavement behind it (a kerb is at most 20 cm): the lane is kept, metres",
    )
    step_side_ratio: float = Field(
        0.45,
        ge=0.0,
        le=1.0,
        description="paint check: the flatness rule (max_dark_side_step_m) asks a side darker than this fraction "
        "of the other: a kerb's gutter in the kerb's own shade measures 0.23-0.38, the shadow of a car parked half a "
        "metre from a line 0.57-0.71 (the car's body raises that side as a kerb does) (unitless)",
    )
    max_dark_side_texture: float = Field(
        11.0,
        gt=0.0,
        le=255.0,
        description="paint check: the roughest a much darker side may be (the texture check's measure over gap_px .. "
        "band_px, in the grey levels of a road at reference_level): shadowed asphalt measures about 3-8, the gravel "
        "beside a kerb 15-17",
    )
    gap_px: int = Field(
        6, ge=0, le=200, description="texture check: start of the side bands, BEV pixels from the lane"
    )
    band_px: int = Field(
        30, ge=2, le=400, description="texture check: end of the side bands, BEV pixels from the lane"
    )
    max_texture: float | None = Field(
        None,
        gt=0.0,
        le=255.0,
        description="texture check: largest texture on either side, grey levels (see measure and brightness; 13.3 was "
        "the default before the paint check; about 12 suits 'diff', 18 'std'); null: no texture check",
    )
    crossing_check: bool = Field(
        True,
        description="drop a lane with parallel bars beside it that repeat its spacing (a pedestrian crossing's bar, not a lane line)",
    )
    crossing_band_px: int = Field(
        50,
        ge=4,
        le=400,
        description="crossing check: how far each side bars are looked for, BEV pixels (50: 2.5 m at 5 cm; a crossing's bars are about 1 m apart; a ridge cut off at the band's end counts as wide)",
    )
    crossing_min_offset_px: int = Field(
        12,
        ge=1,
        le=400,
        description="crossing check: nearer bright stripes are the lane's own paint or a double line's other line, BEV pixels",
    )
    max_bar_px: int = Field(
        16,
        ge=1,
        le=400,
        description="crossing check: widest bar, BEV pixels (wider bright regions, a pavement, do not count)",
    )
    min_contrast: float = Field(
        15.0,
        gt=0.0,
        le=255.0,
        description="crossing check: a painted row's centre is this much brighter than the row's road level, grey levels",
    )
    measure: Literal["std", "diff", "mdiff"] = Field(
        "mdiff",
        description="'std': lateral intensity std in the band; 'diff': mean absolute difference of "
        "neighbouring pixels (insensitive to shadow edges); 'mdiff': their median absolute difference "
        "(insensitive to any few sharp edges: a kerb's face, hatching bars)",
    )
    row_quantile: float = Field(
        0.75,
        ge=0.0,
        le=1.0,
        description="a side's texture is this quantile of its rows' textures (unitless; 0.5: the median; 0.75: "
        "the rougher quarter, where gravel beside a kerb is resolved, not far rows or shadows that smooth it)",
    )
    brightness: Literal["relative", "absolute"] = Field(
        "relative",
        description="'relative': textures and min_contrast are grey levels of a road whose level (the "
        "level_quantile of the BEV road's grey levels) is reference_level, so a frame exposed darker or "
        "brighter measures the same; 'absolute': grey levels of the image as it is",
    )
    reference_level: float = Field(
        170.0,
        ge=1.0,
        le=255.0,
        description="'relative': the road level the thresholds are stated for, grey levels",
    )
    level_quantile: float = Field(
        0.8,
        gt=0.0,
        lt=1.0,
        description="'relative': the road level is this quantile of the road's grey levels (unitless; 0.8: the "
        "sunlit asphalt, not its shadows, nor the paint)",
    )

    @model_validator(mode="after")
    def _band_not_empty(self) -> VerifyParams:
        if self.band_px < self.gap_px + 2:
            raise ValueError(
                f"band_px ({self.band_px}) must be at least gap_px + 2 ({self.gap_px + 2}): the side bands would be empty"
            )
        if self.crossing_band_px <= self.crossing_min_offset_px:
            raise ValueError(
                f"crossing_band_px ({self.crossing_band_px}) must exceed crossing_min_offset_px ({self.crossing_min_offset_px}): no offset would be searched"
            )
        return self


def verify_inputs(mask_doc: str, disparity_doc: str) -> dict[str, str | Port]:
    """The input ports of ``lanes.verify`` and ``lanes.verify_learned``: the lanes, the BEV they were
    found in and what a check may read beside it; ``mask_doc``, ``disparity_doc``: what the node
    reads from the road mask and the disparity map (the end of their ports' descriptions)."""
    return {
        "lanes": "lanes",
        "image": Port("bev_image", "the BEV image the lanes were found in"),
        "geometry": Port("bev_geometry", "the BEV grid: its resolution and distances"),
        "mask": Port("bev_mask", f"the BEV road mask: {mask_doc}", optional=True),
        "disparity": Port("disparity", f"the left disparity map: {disparity_doc}", optional=True),
        "road": Port("road_model", "the road profile and pose (road.profile)", optional=True),
        "calib": Port("calibration", "stereo calibration", optional=True, rate="constant"),
    }
