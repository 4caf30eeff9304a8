"""Disparity backends (family ``disparity``): a rectified pair in, a float32 disparity map out.

=======================  =======================================================
``disparity.sgbm``       OpenCV StereoSGBM
``disparity.road_sgbm``  OpenCV StereoSGBM over row bands, ranges from the road profile
``disparity.bm``         OpenCV StereoBM
``disparity.sgm``        census + semi-global matching, own numba kernels
``disparity.file``       precomputed maps (KITTI 16-bit PNG or .npy), e.g. PSMNet
``disparity.onnx``       a stereo network exported to ONNX (PSMNet ...), ONNX Runtime
=======================  =======================================================

Every map is HxW float32 at the input resolution, in pixels; invalid pixels are 0.
The computing backends share :class:`DisparityParams` (``scale``, ``lr_check`` ...).
"""

from pathlib import Path

from lanegraph import hookimpl

from ._common import DisparityParams
from ._file import FileParams, file
from ._onnx import OnnxDisparity, OnnxParams
from ._opencv import BmParams, OpenCVDisparityParams, SgbmParams, bm, sgbm
from ._road import RoadSgbmParams, road_sgbm
from ._sgm import SgmParams, sgm

__all__ = [
    "BmParams",
    "DisparityParams",
    "FileParams",
    "OnnxDisparity",
    "OnnxParams",
    "OpenCVDisparityParams",
    "RoadSgbmParams",
    "SgbmParams",
    "SgmParams",
    "bm",
    "file",
    "road_sgbm",
    "sgbm",
    "sgm",
]


@hookimpl
def lanegraph_node_types():
    return [sgbm, road_sgbm, bm, sgm, file, OnnxDisparity]


@hookimpl
def lanegraph_kernels():
    """This plugin's kernel list, its kernels' machine code beside it (:mod:`lanegraph.kernels`)."""
    return Path(__file__).with_name("kernels.json")
