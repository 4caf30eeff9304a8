"""``lanes.verify_learned``: the paint decision of a small learned model over measured features.

Beside ``lanes.verify``'s hand-set check: each lane's physical features (:mod:`._paint`: paint
width and its constancy, contrast to the road on both sides, the rougher side's texture, flatness
on the road plane from the disparity, parallelism to the other lanes, dash runs) go into a logistic
regression whose weights are a JSON file (the packaged ``paint_model.json``, trained leave one
source out by ``benchmarks/paint_candidates.py``; or ``model``); a lane whose probability of paint
is below the model's threshold (or ``min_probability``) is dropped. The crossing check of
``lanes.verify`` (a lane among a pedestrian crossing's bars) stays, with its defaults.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from lanegraph import NodeParams, node_type
from lanegraph.types import BevGeometry, Calibration, Lane, RoadModel

from ._paint import PaintModel, paint_features
from ._verify import VerifyParams, _grey_bev, crossing_pattern, neighbour_bars, road_level
from ._verify_params import verify_inputs


class VerifyLearnedParams(NodeParams):
    """Params of ``lanes.verify_learned``."""

    model: str | None = Field(
        None,
        description="the model's JSON file (features, fill, mean, scale, coef, intercept, threshold); "
        "default: the packaged paint_model.json",
    )
    min_probability: float | None = Field(
        None,
        ge=0.0,
        le=1.0,
        description="least probability of paint a lane must have (unitless); default: the model's threshold",
    )
    max_distance_m: float = Field(
        25.0, gt=0.0, le=500.0, description="the lane's rows nearer than this are measured, metres"
    )
    crossing_check: bool = Field(
        True,
        description="drop a lane among a pedestrian crossing's bars (lanes.verify's check, its defaults)",
    )


@node_type(
    "lanes.verify_learned",
    inputs=verify_inputs("its pixels set the road level", "the road's height beside a lane"),
    outputs={"lanes": "lanes"},
)
def verify_learned(
    params: VerifyLearnedParams,
    lanes: list[Lane],
    image: np.ndarray,
    geometry: BevGeometry,
    mask: np.ndarray | None = None,
    disparity: np.ndarray | None = None,
    road: RoadModel | None = None,
    calib: Calibration | None = None,
) -> dict:
    """Keep the lanes that a learned model over their measured paint features calls paint."""
    if not lanes:
        return {"lanes": []}
    model = PaintModel.load(params.model)
    threshold = model.threshold if params.min_probability is None else params.min_probability
    image = _grey_bev(image)
    vp = VerifyParams()
    level = road_level(image, mask, vp.level_quantile)
    gain = vp.reference_level / level if level is not None and level > 0 else 1.0
    lanes = list(lanes)
    kept = []
    for ln in lanes:
        f = paint_features(
            image,
            ln,
            geometry,
            others=lanes,
            gain=gain,
            disparity=disparity,
            road=road,
            calib=calib,
            max_distance_m=params.max_distance_m,
        )
        p = model.probability(f)
        if p < threshold:
            continue
        if params.crossing_check and crossing_pattern(
            neighbour_bars(
                image,
                ln,
                vp.crossing_band_px,
                vp.crossing_min_offset_px,
                vp.max_bar_px,
                vp.min_contrast / gain,
            )
        ):
            continue
        extra = dict(ln.extra)
        extra["paint_probability"] = round(p, 3)
        kept.append(Lane(ln.coeffs, ln.bev_rows, ln.side, ln.score, ln.points, extra))
    return {"lanes": kept}
