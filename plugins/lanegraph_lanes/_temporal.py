"""The previous-frame mask, and lanes from the BEV back to left-image pixels.

``lanes.temporal_mask`` (the paper's last step, against arrows and other transient markings):
features are accepted only within ``band_px`` of the lanes found in the previous frame (delivered
by a feedback edge). Re-acquisition, so that a wrong or lost lock does not persist:

- no previous lanes (first frame, a skipped frame, nothing found): the full mask;
- a side (left / right of the vehicle) with no previous lane, or whose previous lane scored below
  ``min_score``: that whole side stays open, so a lane there can be (re)found;
- a side with a previous lane accepts the bands of all previous lanes, so the band of a line the
  vehicle is crossing (a lane change) follows it past the vehicle's column;
- a side whose previous lane is that line, nearer than ``open_crossing_m`` to the vehicle, stays
  open: the far boundary of the lane the vehicle moves into appears there;
- ``reacquire``: when the current features inside the band are fewer than ``min_band_fraction`` of
  the features on that side, the side is opened again (the lock is not supported by this frame).
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field

from lanegraph import InputError, NodeParams, Port, jit, node_type
from lanegraph.types import BevGeometry, Calibration, FeatureMap, Lane


def lane_cols(lane: Lane, rows: int) -> np.ndarray:
    """The lane model's column at every BEV row (row 0 .. rows-1)."""
    t = rows - 1 - np.arange(rows, dtype=np.float64)
    c0, c1, c2 = lane.coeffs
    return c0 + c1 * t + c2 * t * t


@jit
def _side_band_kernel(lane_cols_rows, c_lo, c_hi, band_px, feat_rows, feat_cols, band):
    """The band of a side: sets ``band[r, c]`` for the columns ``c_lo <= c < c_hi`` within
    ``band_px`` of a lane (``|c - lane_cols_rows[i, r]| <= band_px`` for some lane ``i``); the other
    columns are not touched. Returns the number of features (BEV pixels ``(feat_rows[k],
    feat_cols[k])``) in the side's columns and, of those, in its band.

    Per row and lane the band is the run of columns ``ceil(x - band_px) .. floor(x + band_px)``:
    only those are written (the side's columns of ``band`` must come zeroed)."""
    n_lanes, rows = lane_cols_rows.shape
    for r in range(rows):
        for i in range(n_lanes):
            x = lane_cols_rows[i, r]
            if not (x - band_px < c_hi and x + band_px >= c_lo):  # also a NaN lane
                continue
            lo = max(int(math.ceil(x - band_px)), c_lo)
            hi = min(int(math.floor(x + band_px)) + 1, c_hi)
            for c in range(lo, hi):
                band[r, c] = True
    n_side = 0
    n_band = 0
    for k in range(feat_rows.shape[0]):
        c = feat_cols[k]
        if c_lo <= c < c_hi:
            n_side += 1
            n_band += band[feat_rows[k], c]
    return n_side, n_band


class TemporalParams(NodeParams):
    """Params of ``lanes.temporal_mask``."""

    band_px: float = Field(
        30.0,
        gt=0.0,
        le=1000.0,
        description="half width of the accepted band around a previous lane, BEV pixels",
    )
    min_score: float = Field(
        0.1, ge=0.0, le=1.0, description="previous lanes scoring below this do not restrict the search"
    )
    reacquire: bool = Field(
        True, description="open a side again when this frame's features do not support the previous lane"
    )
    min_band_fraction: float = Field(
        0.15,
        ge=0.0,
        le=1.0,
        description="reacquire when fewer than this fraction of a side's features lie in its band",
    )
    open_crossing_m: float = Field(
        0.6,
        ge=0.0,
        le=5.0,
        description="a side whose previous lane crossed the bottom row nearer than this to the vehicle (a lane change) stays open: "
        "the new lane's far boundary appears there; 0 = never, metres",
    )


@node_type(
    "lanes.temporal_mask",
    inputs={
        "previous": Port("lanes", "the previous frame's lanes (a feedback edge)", optional=True),
        "geometry": Port("bev_geometry"),
        "features": Port("features", "this frame's features, for re-acquisition", optional=True),
    },
    outputs={"mask": "bev_mask"},
)
def temporal_mask(
    params: TemporalParams,
    geometry: BevGeometry,
    previous: list[Lane] | None = None,
    features: FeatureMap | None = None,
) -> dict:
    """Previous-frame mask: bands around the previous frame's lanes; re-acquires sides that are lost or unsupported."""
    rows, cols = geometry.rows, geometry.cols
    good = [ln for ln in (previous or []) if ln.score >= params.min_score]
    if not good:
        return {"mask": np.ones((rows, cols), bool)}
    x0 = geometry.vehicle_col
    # the left side is the columns c < x0, the right side c >= x0
    split = min(max(math.ceil(x0), 0), cols)
    use_feat = params.reacquire and features is not None
    if use_feat:
        if features.shape != (rows, cols):
            raise InputError(
                f"lanes.temporal_mask: features: expected a map of the BEV's shape {(rows, cols)}, got {features.shape}"
            )
        fr, fc = features.points()
    else:
        fr = fc = np.zeros(0, np.int64)
    mask = np.zeros((rows, cols), bool)  # each side's band is written straight into its columns
    lcols = np.stack([lane_cols(ln, rows) for ln in good])
    for side, c_lo, c_hi in (("left", 0, split), ("right", split, cols)):
        mine = [ln for ln in good if ln.side == side]
        if not mine or any(abs(geometry.lateral_m(ln.coeffs[0])) < params.open_crossing_m for ln in mine):
            mask[:, c_lo:c_hi] = True
            continue
        # the bands of every previous lane, also one of the other side that reaches across the
        # vehicle's column: in a lane change the line being crossed moves from one side to the other
        n_side, n_band = _side_band_kernel(lcols, c_lo, c_hi, float(params.band_px), fr, fc, mask)
        if use_feat and n_side > 0 and n_band < params.min_band_fraction * n_side:
            mask[:, c_lo:c_hi] = True
    return {"mask": mask}


def image_points(
    lane: Lane, geometry: BevGeometry, width: int | None = None, height: int | None = None
) -> np.ndarray:
    """The lane's BEV rows ``bev_rows[0] .. bev_rows[1]`` projected into left-image pixels, ``N x 2``
    (x, y) in BEV row order; points that are not finite or fall outside the ``width`` x ``height``
    image (when given) are left out."""
    r = np.arange(lane.bev_rows[0], lane.bev_rows[1] + 1, dtype=np.float64)
    t = geometry.rows - 1 - r
    c0, c1, c2 = lane.coeffs
    pts = geometry.bev_to_image(c0 + c1 * t + c2 * t * t, r)
    ok = np.isfinite(pts).all(axis=1)
    if height is not None:
        ok &= (pts[:, 1] >= 0) & (pts[:, 1] <= height - 1)
    if width is not None:
        ok &= (pts[:, 0] >= 0) & (pts[:, 0] <= width - 1)
    return pts[ok]


class ToImageParams(NodeParams):
    """Params of ``lanes.to_image``."""

    row_step: float = Field(
        5.0, ge=0.1, le=10.0, description="spacing of the output points, image rows (0.1 to 10)"
    )


@node_type(
    "lanes.to_image",
    inputs={
        "lanes": "lanes",
        "geometry": Port("bev_geometry"),
        "calib": Port("calibration", "image size for clipping", optional=True, rate="constant"),
    },
    outputs={"lanes": "lanes"},
)
def to_image(
    params: ToImageParams, lanes: list[Lane], geometry: BevGeometry, calib: Calibration | None = None
) -> dict:
    """Lanes as points in left-image pixels (x, y), covering the detected extent, at most 10 rows apart."""
    out = []
    w = calib.width if calib is not None and calib.width else None
    h = calib.height if calib is not None and calib.height else None
    for ln in lanes or []:
        pts = image_points(ln, geometry, w, h)
        if len(pts) < 2:
            continue
        x, y = pts[:, 0], pts[:, 1]
        dy = np.diff(y)
        if (dy > 0).all():  # the usual case: y grows with the BEV row (nearer is lower)
            y_uniq, x_uniq = y, x
        elif (dy < 0).all():
            y_uniq, x_uniq = y[::-1], x[::-1]
        else:  # not monotonic (a strong roll, a lane across the image): sort, drop repeated rows
            order = np.argsort(-y)  # bottom (near) first
            x, y = x[order], y[order]
            y_uniq, idx = np.unique(y, return_index=True)
            x_uniq = x[idx]
        ys = np.arange(y_uniq[-1], y_uniq[0], -params.row_step)
        ys = np.append(ys, y_uniq[0])
        xs = np.interp(ys, y_uniq, x_uniq)
        new = Lane(ln.coeffs, ln.bev_rows, ln.side, ln.score, np.stack([xs, ys], axis=1), dict(ln.extra))
        out.append(new)
    return {"lanes": out}
