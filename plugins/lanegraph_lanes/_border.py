"""Which parts of the road mask's border are an obstacle's footprint rather than a kerb.

``features.mask`` erodes the BEV road mask so that its border is no feature: where the road meets
a kerb, the kerb's lit edge or the light gutter beside it lies on the mask's last pixels (the
kerb's 10-15 cm step fades into the disparity noise, so the mask reaches onto it) and passes
SLT/ESLT like paint. Where the road meets a parked car, a wall or a pole, the free-space scan ends
the road at the obstacle's foot (an obstacle's disparity spreads onto the road beside it, never
the other way), and a line painted along it -- a parking strip's line beside the parked cars --
lies on those last pixels too. The two are told apart by what stands beyond the border, from the
disparity: a kerb's top (the pavement behind it) is a step of at most ``max_kerb_height_m`` above
the road; an obstacle's side rises higher within the band beyond its foot.
"""

from __future__ import annotations

import cv2
import numpy as np

from lanegraph.types import BevGeometry, Calibration, RoadModel

from ._heights import heights_at


def obstacle_border(
    mask: np.ndarray,
    geometry: BevGeometry,
    disparity: np.ndarray,
    road: RoadModel,
    calib: Calibration,
    band_px: int,
    max_kerb_height_m: float,
    reach_px: int | None = None,
) -> np.ndarray:
    """A bool BEV map, True on the mask's pixels within ``band_px`` of a border that is an
    obstacle's footprint: most of the pixels with a disparity beyond the border within the
    ``2 band_px + 1`` square around the pixel stand more than ``max_kerb_height_m`` above the road
    (a kerb's top, the pavement behind it, does not; neither do pixels without a disparity, which
    count for nothing). All False without a valid road model or with a disparity of another size
    than the calibration's image."""
    keep = np.ascontiguousarray(mask, dtype=bool)
    none = np.zeros(keep.shape, bool)
    if band_px <= 0 or not keep.any() or not road.valid or not road.height > 0:
        return none
    disparity = np.asarray(disparity)
    h, w = disparity.shape[:2]
    if (calib.width and w != calib.width) or (calib.height and h != calib.height):
        return none  # a reduced disparity map: the road model is not its
    k = 2 * band_px + 1
    reach = band_px if reach_px is None else max(int(reach_px), band_px)
    kw = 2 * reach + 1
    m8 = keep.view(np.uint8)
    beyond = cv2.dilate(m8, cv2.getStructuringElement(cv2.MORPH_RECT, (kw, kw))).view(bool) & ~keep
    ring = keep & ~cv2.erode(m8, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)), borderValue=0).view(bool)
    r, c = np.nonzero(beyond)
    hgt = heights_at(geometry, disparity, road, calib, r, c)
    valid = np.zeros(keep.shape, np.float32)
    tall = np.zeros(keep.shape, np.float32)
    fin = np.isfinite(hgt)
    valid[r[fin], c[fin]] = 1.0
    tall[r[fin], c[fin]] = (hgt[fin] > max_kerb_height_m).astype(np.float32)
    n_valid = cv2.boxFilter(valid, -1, (kw, kw), normalize=False, borderType=cv2.BORDER_CONSTANT)
    n_tall = cv2.boxFilter(tall, -1, (kw, kw), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return ring & (n_valid > 0.5) & (n_tall > 0.5 * n_valid)
