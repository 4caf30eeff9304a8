"""``bev.ipm``: inverse perspective mapping of the left image (and the road mask) onto a metric
bird's-eye-view grid of the road plane.

The mapping is the road-plane homography of :func:`.geometry.homography_img_from_road` built from
the calibration and the estimated pitch, roll and height (the paper's eqs. 1-2, Bertozzi & Broggi,
yaw 0, written exactly for a pinhole camera), composed with the BEV grid: BEV pixel ``(c, r)`` is
the road point ``x = x_min + (c + 0.5) res``, ``z = z_max - (r + 0.5) res`` (row 0 is the far end).
Every BEV pixel is looked up in the image (``cv2.remap``); pixels that fall outside the image or
beyond the horizon are 0 in the image and False in the mask.
"""

from __future__ import annotations

import math
from typing import Literal

import cv2
import numpy as np
from pydantic import Field, model_validator

from lanegraph import NodeParams, Port, node_type
from lanegraph.types import BevGeometry, Calibration, RoadModel

from . import geometry
from .profile import RoadInputError

_INTERP = {"nearest": cv2.INTER_NEAREST, "linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}


#: the most pixels a BEV grid may have ((x range / resolution) x (z range / resolution))
MAX_BEV_PIXELS = 2_000_000


class IpmParams(NodeParams):
    """Params of ``bev.ipm``."""

    x_min: float = Field(-10.0, ge=-200.0, le=200.0, description="left edge of the BEV, metres (x right)")
    x_max: float = Field(10.0, ge=-200.0, le=200.0, description="right edge of the BEV, metres")
    z_min: float = Field(5.0, gt=0.0, le=500.0, description="nearest distance ahead (bottom row), metres")
    z_max: float = Field(45.0, gt=0.0, le=500.0, description="farthest distance ahead (top row), metres")
    resolution: float = Field(
        0.05,
        ge=0.005,
        le=10.0,
        description="BEV pixel size, metres per pixel (the grid has at most 2e6 pixels)",
    )
    interpolation: Literal["nearest", "linear", "cubic"] = Field("linear", description="image interpolation")
    color: Literal["gray", "keep"] = Field(
        "gray", description="BEV of a BGR input: gray (Hb x Wb, the bev_image type) or keep the 3 channels"
    )
    use_roll: bool = Field(True, description="use the estimated roll (False: roll 0)")
    fallback_pitch_deg: float = Field(
        0.0,
        ge=-30.0,
        le=30.0,
        description="pitch used when the road model is invalid, degrees (positive = nose down)",
    )
    fallback_height_m: float = Field(
        1.65, gt=0.05, le=20.0, description="camera height used when the road model is invalid, metres"
    )

    @model_validator(mode="after")
    def _check_ranges(self) -> IpmParams:
        if not self.x_max > self.x_min:
            raise ValueError(f"x_max ({self.x_max}) must be greater than x_min ({self.x_min})")
        if not self.z_max > self.z_min:
            raise ValueError(f"z_max ({self.z_max}) must be greater than z_min ({self.z_min})")
        cols = round((self.x_max - self.x_min) / self.resolution)
        rows = round((self.z_max - self.z_min) / self.resolution)
        if cols < 1 or rows < 1:
            raise ValueError(
                f"the BEV grid would be {cols} x {rows} pixels (x range / resolution x z range / resolution); "
                "lower the resolution"
            )
        cells = (self.x_max - self.x_min) / self.resolution * (self.z_max - self.z_min) / self.resolution
        if cells > MAX_BEV_PIXELS:  # memory and time grow with it: about 6x the default 400 x 800
            raise ValueError(
                f"the BEV grid would have {cells:.3g} pixels (more than {MAX_BEV_PIXELS:.0e}); raise the resolution or narrow the ranges"
            )
        return self


def bev_pose(params: IpmParams, road: RoadModel | None) -> tuple[float, float, float]:
    """``(pitch, roll, height)`` used for the BEV: the road model's, or the fallback when invalid."""
    if road is None or not road.valid or not road.height > 0:
        return math.radians(params.fallback_pitch_deg), 0.0, params.fallback_height_m
    return road.pitch, (road.roll if params.use_roll else 0.0), road.height


def bev_geometry(
    params: IpmParams, calib: Calibration, pitch: float, roll: float, height: float
) -> BevGeometry:
    """The BEV grid and its homography ``H_img_from_bev`` (BEV pixel (c, r, 1) -> image (x, y, 1))."""
    res = params.resolution
    grid = np.array(
        [[res, 0.0, params.x_min + 0.5 * res], [0.0, -res, params.z_max - 0.5 * res], [0.0, 0.0, 1.0]]
    )
    H = geometry.homography_img_from_road(calib, pitch, roll, height) @ grid
    return BevGeometry(params.x_min, params.x_max, params.z_min, params.z_max, res, H)


def bev_maps(geom: BevGeometry, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(map_x, map_y, inside)`` for ``cv2.remap``: the image pixel of every BEV pixel, and whether it
    lies inside the ``width x height`` image and in front of the camera (elsewhere the maps are -1)."""
    r, c = np.mgrid[0 : geom.rows, 0 : geom.cols].astype(np.float64)
    Hm = geom.H_img_from_bev
    w = Hm[2, 0] * c + Hm[2, 1] * r + Hm[2, 2]
    ahead = w > 1e-9
    safe_w = np.where(ahead, w, 1.0)
    x = (Hm[0, 0] * c + Hm[0, 1] * r + Hm[0, 2]) / safe_w
    y = (Hm[1, 0] * c + Hm[1, 1] * r + Hm[1, 2]) / safe_w
    inside = ahead & (x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1)
    map_x = np.where(inside, x, -1.0).astype(np.float32)
    map_y = np.where(inside, y, -1.0).astype(np.float32)
    return map_x, map_y, inside


def warp_to_bev(
    params: IpmParams,
    image: np.ndarray,
    road: RoadModel | None,
    calib: Calibration,
    mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, BevGeometry]:
    """The work of ``bev.ipm``: ``(bev image, bev mask, geometry)``."""
    image = np.asarray(image)
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3)) or image.size == 0:
        raise RoadInputError(
            f"bev.ipm: image: expected a non-empty HxW or HxWx3 image, got shape {image.shape}"
        )
    if image.dtype.kind not in "biuf":
        raise RoadInputError(f"bev.ipm: image: expected an image of numbers, got dtype {image.dtype}")
    if image.dtype not in (np.uint8, np.uint16, np.int16, np.float32, np.float64):
        image = image.astype(np.float32)  # the dtypes cv2.warpPerspective takes
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and params.color == "gray":
        if image.dtype not in (np.uint8, np.uint16, np.float32):
            image = image.astype(np.float32)  # the dtypes cv2.cvtColor takes
        image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2GRAY)
    h_img, w_img = image.shape[:2]
    if mask is not None and np.shape(mask) != (h_img, w_img):
        raise RoadInputError(
            f"bev.ipm: mask: expected shape {(h_img, w_img)} (the image's), got {np.shape(mask)}"
        )
    pitch, roll, height = bev_pose(params, road)
    geom = bev_geometry(params, calib, pitch, roll, height)
    # cv2 evaluates the homography per BEV pixel (the same mapping as bev_maps(), without building
    # float64 maps in NumPy every frame): one bilinear warp of the image, and one nearest warp of a
    # code image that is 0 outside the image (the border), 1 inside and 2 on the mask
    size = (geom.cols, geom.rows)
    flags = cv2.WARP_INVERSE_MAP
    Hm = geom.H_img_from_bev
    bev = cv2.warpPerspective(
        image, Hm, size, flags=_INTERP[params.interpolation] | flags, borderMode=cv2.BORDER_REPLICATE
    )
    if mask is None:
        code = np.ones((h_img, w_img), np.uint8)
    else:
        code = np.add(np.ascontiguousarray(mask, dtype=bool).view(np.uint8), 1, dtype=np.uint8)  # one pass
    code = cv2.warpPerspective(
        code, Hm, size, flags=cv2.INTER_NEAREST | flags, borderMode=cv2.BORDER_CONSTANT, borderValue=0
    )
    # outside: 0, never a replicated border (a masked AND: 10x cheaper than np.copyto with where=)
    bev = cv2.bitwise_and(bev, bev, mask=code)
    bev_mask = code > (0 if mask is None else 1)
    # keep only BEV pixels in front of the camera (w > 0), as bev_maps() does. w is linear in the
    # BEV pixel: when it is positive at the four corners it is positive everywhere.
    h20, h21, h22 = (float(x) for x in Hm[2])
    if not all(
        h20 * c + h21 * r + h22 > 1e-9 for c in (0.0, geom.cols - 1.0) for r in (0.0, geom.rows - 1.0)
    ):
        r = np.arange(geom.rows, dtype=np.float64)[:, None]
        c = np.arange(geom.cols, dtype=np.float64)[None, :]
        ahead = (Hm[2, 0] * c + Hm[2, 1] * r + Hm[2, 2]) > 1e-9
        bev[~ahead] = 0
        bev_mask &= ahead
    return bev, bev_mask, geom


@node_type(
    "bev.ipm",
    inputs={
        "image": Port("image", "left image (gray or BGR)"),
        "mask": Port("mask", "road mask in the left image (road.mask)", optional=True),
        "road": Port("road_model", "road model with pitch, roll and height (road.profile)"),
        "calib": Port("calibration", "stereo calibration", rate="constant"),
    },
    outputs={
        "image": Port("bev_image", "the bird's-eye view of the image"),
        "mask": Port("bev_mask", "BEV pixels inside the image (and on the road mask when given)"),
        "geometry": Port("bev_geometry", "the BEV grid and H_img_from_bev"),
    },
)
def bev_ipm(params: IpmParams, image: np.ndarray, road: RoadModel, calib: Calibration, mask=None) -> dict:
    """Inverse perspective mapping onto a metric road-plane grid using the estimated pitch, roll and
    camera height (fallback pitch / height when the road model is invalid)."""
    bev, bev_mask, geom = warp_to_bev(params, image, road, calib, mask)
    return {"image": bev, "mask": bev_mask, "geometry": geom}
