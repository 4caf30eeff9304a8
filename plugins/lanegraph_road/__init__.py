"""Road stage: v-disparity, road profile and camera pose (``road.vdisparity``, ``road.profile``),
the drivable-area mask (``road.mask``) and the bird's-eye view (``bev.ipm``).

Geometry, conventions (sign of pitch and roll) and the derivations are in :mod:`.geometry`.
"""

from __future__ import annotations

from pathlib import Path

from lanegraph import hookimpl

from . import geometry
from .ipm import IpmParams, bev_ipm, warp_to_bev
from .mask import MaskParams, road_mask, road_mask_array
from .profile import ProfileParams, VDisparityParams, estimate_road, road_profile, road_vdisparity

__all__ = [
    "IpmParams",
    "MaskParams",
    "ProfileParams",
    "VDisparityParams",
    "bev_ipm",
    "estimate_road",
    "geometry",
    "warp_to_bev",
    "road_mask",
    "road_mask_array",
    "road_profile",
    "road_vdisparity",
]


@hookimpl
def lanegraph_node_types():
    return [road_vdisparity, road_profile, road_mask, bev_ipm]


@hookimpl
def lanegraph_kernels():
    """This plugin's kernel list, its kernels' machine code beside it (:mod:`lanegraph.kernels`)."""
    return Path(__file__).with_name("kernels.json")
