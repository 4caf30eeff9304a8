"""The params of ``lanes.follow`` (see :mod:`._follow`)."""

from __future__ import annotations

from pydantic import Field

from lanegraph import NodeParams


class FollowParams(NodeParams):
    """Params of ``lanes.follow``."""

    seed_band_m: float = Field(
        2.0, gt=0.0, le=20.0, description="height of the near bands in which seeds are found, metres"
    )
    seed_bands: int = Field(4, ge=1, le=50, description="number of seed bands from the BEV's near end")
    min_seed_votes: int = Field(
        30, ge=1, le=100000, description="a seed needs this many features in one 25 cm column of its band"
    )
    step_m: float = Field(1.0, gt=0.0, le=10.0, description="length of a window along the line, metres")
    half_width_m: float = Field(
        0.25, gt=0.0, le=5.0, description="a window takes features this far across the predicted line, metres"
    )
    max_angle_deg: float = Field(
        25.0,
        gt=0.0,
        le=90.0,
        description="a window takes features whose orientation is within this of the line's heading, degrees",
    )
    max_gap_m: float = Field(
        14.0,
        ge=0.0,
        le=100.0,
        description="a line is followed over windows without features (dashes' gaps, occlusions) up to this, metres",
    )
    gap_heading_deg: float = Field(
        6.0,
        ge=0.0,
        le=45.0,
        description="after a gap a window widens by the lateral drift of a heading this far off over the gap's length "
        "(the uncertainty of a heading measured on a dash), degrees",
    )
    base_m: float = Field(
        10.0,
        gt=0.0,
        le=100.0,
        description="heading and curvature from a circle through the centres of the windows with features over the "
        "last this much of the line (three or more, dashes across their gaps), metres",
    )
    min_radius_m: float = Field(
        20.0,
        gt=0.0,
        le=1e6,
        description="tightest bend followed (the curvature is clamped to 1 / this; a window at the clamp guides no "
        "other line), metres",
    )
    guide_m: float = Field(
        4.5,
        ge=0.0,
        le=50.0,
        description="a line takes its heading and curvature from a long line followed before it within this across "
        "(the widest lane): markings are parallel, a dash's own curvature is noise, metres",
    )
    guide_min_m: float = Field(
        10.0,
        ge=0.0,
        le=500.0,
        description="a line followed over this much road guides the lines followed after it: longer than a hatching "
        "bar across a lane-wide gore area at 30 deg or more to the road (4.5 m / sin 30 deg), metres",
    )
    min_window_features: int = Field(
        12, ge=1, le=100000, description="a window with fewer features counts as a gap"
    )
    max_bar_m: float = Field(
        5.0,
        ge=0.0,
        le=100.0,
        description="a track with features over less than this (along the BEV rows) is short: a hatching bar when two "
        "short tracks run parallel beside it or it crosses the road's direction, metres",
    )
    max_heading_deg: float = Field(
        60.0,
        gt=0.0,
        le=89.0,
        description="the parabola is fitted where the line is within this of straight ahead, degrees",
    )
    near_fit_m: float | None = Field(
        20.0,
        gt=0.0,
        le=1000.0,
        description="a line seen over at least half of the BEV's near this many metres is fitted there only (as "
        "fit.irls's near_fit_m), metres; null: the whole line",
    )
    extend_px: float = Field(
        3.0,
        ge=0.0,
        le=100.0,
        description="a lane fitted on the near part reaches up to the farthest feature of its line within this of the "
        "parabola, BEV pixels (3: 15 cm, a marking's width)",
    )
    min_inlier_fraction: float = Field(
        0.8,
        ge=0.0,
        le=1.0,
        description="a track is a lane when its parabola keeps this fraction of its features (unitless)",
    )
    max_start_m: float = Field(
        12.0,
        ge=0.0,
        le=100.0,
        description="a lane's nearest feature lies at most this far beyond the BEV's near end (a lane boundary is seen "
        "near the car, after at most a dashed line's gap), metres",
    )
    min_inliers: int = Field(80, ge=3, le=1000000, description="a lane needs at least this many features")
    min_extent_m: float = Field(
        4.0, ge=0.0, le=500.0, description="its features must span this much road, metres"
    )
    min_offset_m: float = Field(
        0.6, ge=0.0, le=20.0, description="closest plausible lateral distance of a lane boundary, metres"
    )
    collect_along: bool = Field(
        True,
        description="a track under the car (straddle_offset_m..min_offset_m) whose windows took fewer than "
        "min_inliers features counts the free features within extend_px of its parabola over its span (a dash its "
        "windows missed after a gap)",
    )
    straddle_offset_m: float | None = Field(
        0.3,
        ge=0.0,
        le=20.0,
        description="a line this far or farther from the vehicle but nearer than min_offset_m is one the car straddles "
        "(a narrow street's centre line), reported on the straddled port when its features show a marking; "
        "null: none, metres",
    )
    straddle_min_extent_m: float = Field(
        8.0,
        ge=0.0,
        le=500.0,
        description="a straddled line's inliers must span this much road: more than an arrow (5 m) or a patch, metres",
    )
    max_offset_m: float = Field(
        5.0, gt=0.0, le=50.0, description="farthest plausible lateral distance of a lane boundary, metres"
    )
    max_curvature: float = Field(
        0.1,
        gt=0.0,
        le=1.0,
        description="largest curvature of a fitted line's path where it is seen nearest, 1/metres (else a straight refit)",
    )
