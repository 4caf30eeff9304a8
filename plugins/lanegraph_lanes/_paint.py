"""The paint decision's measured features, and the learned decision over them (``lanes.verify_learned``).

:func:`paint_features` measures, of one lane candidate, what tells paint from what else makes a
bright line in the BEV (a kerb's lit edge, the asphalt's border against a verge, a gutter, a crack, a
shadow's edge, a rail). Every measure is physical and relative to the road beside the lane, on its
rows nearer than ``max_distance_m`` (where the BEV resolves paint):

- ``contrast``: the painted rows' median centre over the brighter side band, less 1 (paint is
  bright against the road on both sides);
- ``side_ratio``: their median darker side over the brighter one (a kerb's gravel, a verge, a
  shadow darken one side);
- ``width_m``, ``foot_width_m``: the median profile's width at half and a quarter of its height
  (paint is 10-30 cm wide with sharp edges);
- ``width_spread``: the interquartile range of the painted rows' own widths at half height over
  their median (paint keeps its width; a crack, a shadow's edge or a kerb's lit face does not);
- ``painted_fraction``, ``saturated_fraction``: the share of the near rows that are painted, and of
  the painted rows clipped at the image's largest grey level;
- ``dark_texture``: the rougher side band's texture (the median absolute difference of neighbouring
  pixels, its rows' 75th percentile) in grey levels of a road at ``gain`` times the image's
  level (gravel and grass are rough, asphalt and shadow smooth);
- ``height_step_m``, ``line_height_m``: from the disparity, the difference of the road's height
  above the fitted road plane 0.3-0.8 m left and right of the lane, and the lane's own height
  there (a kerb is a step of 10-15 cm; paint lies flat on the road plane); 0 without a disparity;
- ``step_beyond_m`` (measured beside :data:`FEATURES`, not a model input): how high the higher of
  those sides stands 0.8-1.2 m out above the lower one (a kerb's pavement stays at the kerb's
  height, a parked car's body rises higher);
- ``parallel_spread_m``: how much the lane's distance to the most parallel other candidate (1 m
  away or more) changes over the rows both cover (markings are parallel); ``unparallel_m`` when
  there is none;
- ``dash_runs``, ``longest_run_m``: the painted rows' runs (gaps under 0.5 m bridged) at least
  0.5 m long, and the longest (a solid line is one long run, a dashed line runs of 1.5-6 m at a
  period, cracks and cobbles short irregular ones).

The learned decision is a logistic regression over these features (standardised, each with a
fill value where it cannot be measured), trained by ``benchmarks/paint_candidates.py`` leave one
source out with scikit-learn; its weights are a small JSON file (``paint_model.json`` beside this
module; no pickles), read here with NumPy alone.
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np

from lanegraph import InputError
from lanegraph.types import BevGeometry, Calibration, Lane, RoadModel

from ._heights import lane_heights, step_across
from ._verify import (
    _column_medians,
    _crossing_width,
    _grey_bev,
    painted_rows,
    side_texture,
)

#: the features, in the order of the model's weights
FEATURES = (
    "contrast",
    "side_ratio",
    "width_m",
    "foot_width_m",
    "width_spread",
    "painted_fraction",
    "saturated_fraction",
    "dark_texture",
    "height_step_m",
    "line_height_m",
    "parallel_spread_m",
    "dash_runs",
    "longest_run_m",
)

#: a parallel spread for a lane with no other candidate beside it, metres
UNPARALLEL_M = 2.0

MODEL_FILE = Path(__file__).with_name("paint_model.json")


def row_widths(strips: np.ndarray, band: int) -> np.ndarray:
    """Each row's width at half its height, pixels: the run of pixels around the centre column
    ``band`` of ``strips`` (rows divided by their brighter side's level, so 1 is that level) at or
    above ``1 + (centre - 1) / 2``."""
    half = 1.0 + 0.5 * (strips[:, band] - 1.0)
    above = strips >= half[:, None]
    left = np.cumprod(above[:, band - 1 :: -1], axis=1).sum(axis=1)
    right = np.cumprod(above[:, band + 1 :], axis=1).sum(axis=1)
    return 1.0 + left + right


def runs_of(rows: np.ndarray, max_gap: int, min_len: int) -> np.ndarray:
    """The lengths (rows) of the runs of the sorted ``rows``, gaps of up to ``max_gap`` rows
    bridged, at least ``min_len`` rows long."""
    if rows.size == 0:
        return np.empty(0, np.int64)
    breaks = np.flatnonzero(np.diff(rows) > max_gap + 1)
    first = np.concatenate(([0], breaks + 1))
    last = np.concatenate((breaks, [rows.size - 1]))
    length = rows[last] - rows[first] + 1
    return length[length >= min_len]


def parallel_spread(lane: Lane, others: list[Lane], geometry: BevGeometry, min_gap_m: float = 1.0) -> float:
    """The smallest change (metres) of the signed distance between ``lane`` and another candidate
    at least ``min_gap_m`` from it on average, over the BEV rows both cover (at least 2 m of them);
    at most :data:`UNPARALLEL_M`, which it is when there is none."""
    res = float(geometry.resolution)
    best = UNPARALLEL_M
    for o in others:
        lo = max(lane.bev_rows[0], o.bev_rows[0])
        hi = min(lane.bev_rows[1], o.bev_rows[1])
        if (hi - lo) * res < 2.0:
            continue
        t = geometry.rows - 1 - np.arange(lo, hi + 1, dtype=np.float64)
        d = (np.polyval(lane.coeffs[::-1], t) - np.polyval(o.coeffs[::-1], t)) * res
        if abs(float(d.mean())) < min_gap_m:
            continue
        best = min(best, float(d.max() - d.min()))
    return best


def paint_features(
    image: np.ndarray,
    lane: Lane,
    geometry: BevGeometry,
    *,
    others: list[Lane] = (),
    gain: float = 1.0,
    disparity: np.ndarray | None = None,
    road: RoadModel | None = None,
    calib: Calibration | None = None,
    max_distance_m: float = 25.0,
    band_m: float = 1.5,
    gap_m: float = 0.25,
    align_m: float = 0.1,
    min_row_contrast: float = 0.15,
    texture_gap_px: int = 6,
    texture_band_px: int = 30,
) -> dict[str, float]:
    """The features of :data:`FEATURES` for ``lane`` in the grey BEV ``image`` (see the module
    docstring); NaN where one cannot be measured (fewer than 3 painted rows; no disparity)."""
    img = _grey_bev(image)
    res = float(geometry.resolution)
    inside, row, start, inv_level, measures, saturated, band, gap = painted_rows(
        img, lane, geometry, max_distance_m, band_m, gap_m, align_m, min_row_contrast
    )
    painted = row.size
    f = dict.fromkeys((*FEATURES, "step_beyond_m"), math.nan)
    f["painted_fraction"] = painted / inside if inside else 0.0
    f["saturated_fraction"] = saturated / painted if painted else 0.0
    runs = runs_of(np.sort(row), int(round(0.5 / res)), int(round(0.5 / res)))
    f["dash_runs"] = float(runs.size)
    f["longest_run_m"] = float(runs.max()) * res if runs.size else 0.0
    if painted >= 3:
        strips = img[row[:, None], start[:, None] + np.arange(2 * band + 1)] * inv_level[:, None]
        widths = row_widths(strips, band) * res
        q1, med, q3 = np.percentile(widths, [25, 50, 75])
        f["width_spread"] = float((q3 - q1) / med) if med > 0 else math.nan
        k = slice(0, painted, max(1, painted // 64))
        sub = np.ascontiguousarray(strips[k])
        profile = np.empty(2 * band + 1)
        _column_medians(sub, sub.shape[0], profile)
        base = max(float(np.median(profile[: band - gap + 1])), float(np.median(profile[band + gap :])))
        height = profile[band] - base
        meds = np.median(measures, axis=0)
        f["contrast"], f["side_ratio"] = float(meds[0]), float(meds[1])
        if height > 0:
            f["width_m"] = _crossing_width(profile, band, base + 0.5 * height) * res
            f["foot_width_m"] = _crossing_width(profile, band, base + 0.25 * height) * res
    f["dark_texture"] = max(side_texture(img, lane, texture_gap_px, texture_band_px, "mdiff", 0.75)) * gain
    if disparity is not None and road is not None and calib is not None:
        left, line, right = lane_heights(lane, geometry, np.asarray(disparity), road, calib, max_distance_m)
        f["height_step_m"] = abs(left - right)
        f["line_height_m"] = line
        f["step_beyond_m"] = step_across(lane, geometry, disparity, road, calib, max_distance_m)[1]
    f["parallel_spread_m"] = parallel_spread(lane, [o for o in others if o is not lane], geometry)
    return f


class PaintModel:
    """A logistic regression over :data:`FEATURES`, from its JSON file: ``features`` (names),
    ``fill`` (the value of a feature that could not be measured), ``mean`` and ``scale`` (the
    standardisation), ``coef``, ``intercept`` and ``threshold`` (the least probability of paint)."""

    def __init__(self, spec: dict, where: str = "paint model") -> None:
        try:
            self.features = [str(n) for n in spec["features"]]
            n = len(self.features)
            self.fill = np.asarray(spec["fill"], np.float64).reshape(n)
            self.mean = np.asarray(spec["mean"], np.float64).reshape(n)
            self.scale = np.asarray(spec["scale"], np.float64).reshape(n)
            self.coef = np.asarray(spec["coef"], np.float64).reshape(n)
            self.intercept = float(spec["intercept"])
            self.threshold = float(spec.get("threshold", 0.5))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(
                f"{where}: expected features, fill, mean, scale, coef, intercept: {exc}"
            ) from None
        unknown = sorted(set(self.features) - set(FEATURES))
        if unknown:
            raise InputError(f"{where}: unknown features {unknown}; expected some of {list(FEATURES)}")
        if not (np.isfinite(self.scale).all() and (self.scale > 0).all()):
            raise InputError(f"{where}: scale: expected positive numbers")
        self.spec = spec

    @classmethod
    def load(cls, path: str | Path | None = None) -> PaintModel:
        """The model of the JSON file ``path`` (the packaged ``paint_model.json`` when None)."""
        return _load(str(path or MODEL_FILE))

    def vector(self, features: dict[str, float]) -> np.ndarray:
        """The model's input: the features in its order, NaN replaced by their fill values."""
        x = np.array([features.get(n, math.nan) for n in self.features], np.float64)
        return np.where(np.isfinite(x), x, self.fill)

    def probability(self, features: dict[str, float]) -> float:
        """The probability that a lane with these features is paint."""
        z = float(((self.vector(features) - self.mean) / self.scale) @ self.coef) + self.intercept
        return 1.0 / (1.0 + math.exp(-max(min(z, 50.0), -50.0)))


@functools.cache
def _load(path: str) -> PaintModel:
    p = Path(path)
    try:
        spec = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"lanes.verify_learned: model: cannot read {p}: {exc}") from None
    if not isinstance(spec, dict):
        raise InputError(f"lanes.verify_learned: model: {p}: expected a JSON object")
    return PaintModel(spec, str(p))
