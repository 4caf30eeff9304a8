"""lanegraph's own port types, registered by a built-in plugin through ``lanegraph_port_types``
exactly as a third party registers its own (as datasette registers its default column types
through its own hook): each with its ``check`` (what is wrong with a value of it) and, for the
value types of :mod:`lanegraph.types`, its storage (``stores``, ``encode``, ``decode``:
:mod:`lanegraph.storage`). Their pictures are the presentation layer's
(:mod:`lanegraph.presentation.port_types`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .hookspecs import hookimpl
from .storage import MAX_DIM, StorageError, dataclass_storage
from .types import BevGeometry, Calibration, FeatureMap, Lane, Line, PortType, RoadModel

MAX_FEATURE_MAP_PIXELS = 1 << 24  #: a stored FeatureMap's grid (8x the largest BEV grid bev.ipm allows)


# --------------------------------------------------------------------------- checks
def _array(dtypes: tuple[type, ...], ndims: tuple[int, ...], what: str) -> Callable[[Any], str | None]:
    def check(value: Any) -> str | None:
        if not isinstance(value, np.ndarray) or value.dtype.type not in dtypes or value.ndim not in ndims:
            got = (
                f"{value.dtype} array of shape {value.shape}"
                if isinstance(value, np.ndarray)
                else type(value).__name__
            )
            return f"expected {what}, got {got}"
        return None

    return check


def _instance(cls: type | tuple[type, ...], what: str) -> Callable[[Any], str | None]:
    def check(value: Any) -> str | None:
        return None if isinstance(value, cls) else f"expected {what}, got {type(value).__name__}"

    return check


def _list_of(cls: type, what: str) -> Callable[[Any], str | None]:
    def check(value: Any) -> str | None:
        if isinstance(value, list) and all(isinstance(v, cls) for v in value):
            return None
        return f"expected {what}, got {type(value).__name__}"

    return check


def _number(value: Any) -> str | None:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    return None if ok else f"expected a number, got {type(value).__name__}"


_IMAGE = _array((np.uint8,), (2, 3), "an HxW or HxWx3 uint8 image")


# --------------------------------------------------------------------------- storage
def _encode_feature_map(value: FeatureMap) -> dict[str, Any]:
    rows, cols = value.points()
    return {"shape": list(value.shape), "rows": rows, "cols": cols, "values": value.point_orientations()}


def _decode_feature_map(data: Any) -> FeatureMap:
    """A :class:`FeatureMap` from its points, its grid and points checked first."""
    if not isinstance(data, dict) or set(data) != {"shape", "rows", "cols", "values"}:
        raise StorageError("a FeatureMap has the fields ['cols', 'rows', 'shape', 'values']")
    shape, rows, cols = data["shape"], data["rows"], data["cols"]
    if not (
        isinstance(shape, list)
        and len(shape) == 2
        and all(isinstance(n, int) and not isinstance(n, bool) and 0 <= n <= MAX_DIM for n in shape)
        and shape[0] * shape[1] <= MAX_FEATURE_MAP_PIXELS
    ):
        raise StorageError(
            f"shape: expected [rows, cols] of at most {MAX_FEATURE_MAP_PIXELS} pixels, got {str(shape)[:60]}"
        )
    if not (
        isinstance(rows, np.ndarray)
        and isinstance(cols, np.ndarray)
        and rows.shape == cols.shape
        and rows.ndim == 1
    ):
        raise StorageError("rows, cols: expected two 1-D arrays of one length")
    if rows.size and (rows.min() < 0 or cols.min() < 0 or rows.max() >= shape[0] or cols.max() >= shape[1]):
        raise StorageError(f"feature points outside the {shape[0]}x{shape[1]} map")
    return FeatureMap.from_points(tuple(shape), rows, cols, data["values"])


#: lanegraph's own port types, by name (what the built-in plugin registers)
PORT_TYPES: dict[str, PortType] = {
    t.name: t
    for t in (
        PortType("any", "any value"),
        PortType(
            "frame_id", "frame identifier: the left image's file stem (str)", check=_instance(str, "a str")
        ),
        PortType("image", "image, HxW or HxWx3 uint8 (BGR)", check=_IMAGE),
        PortType(
            "gray",
            "gray image, HxW uint8 or float32",
            "image",
            check=_array((np.uint8, np.float32), (2,), "an HxW uint8 or float32 image"),
        ),
        PortType(
            "disparity",
            "disparity map, HxW float32 pixels; invalid pixels <= 0",
            check=_array((np.float32,), (2,), "an HxW float32 disparity map"),
        ),
        PortType(
            "mask",
            "binary mask in image pixels, HxW bool",
            check=_array((np.bool_,), (2,), "an HxW bool mask"),
        ),
        PortType(
            "calibration",
            "rectified stereo calibration (lanegraph.types.Calibration)",
            check=_instance(Calibration, "a lanegraph.types.Calibration"),
            **dataclass_storage(Calibration),
        ),
        PortType(
            "vdisparity",
            "v-disparity accumulator, H x D float32",
            check=_array((np.float32,), (2,), "an H x D float32 accumulator"),
        ),
        PortType(
            "road_model",
            "road profile d(v), roll, pitch, height (lanegraph.types.RoadModel)",
            check=_instance(RoadModel, "a lanegraph.types.RoadModel"),
            **dataclass_storage(RoadModel),
        ),
        PortType(
            "bev_geometry",
            "bird's-eye-view grid and its mapping (lanegraph.types.BevGeometry)",
            check=_instance(BevGeometry, "a lanegraph.types.BevGeometry"),
            **dataclass_storage(BevGeometry),
        ),
        PortType("bev_image", "bird's-eye-view image, Hb x Wb uint8", check=_IMAGE),
        PortType(
            "bev_mask",
            "bird's-eye-view binary mask, Hb x Wb bool",
            check=_array((np.bool_,), (2,), "an Hb x Wb bool mask"),
        ),
        PortType(
            "features",
            "lane feature map with orientation (lanegraph.types.FeatureMap)",
            check=_instance(FeatureMap, "a lanegraph.types.FeatureMap"),
            stores=FeatureMap,
            encode=_encode_feature_map,
            decode=_decode_feature_map,
        ),
        PortType("orientation", "global lane orientation in the BEV, radians (float)", check=_number),
        PortType(
            "lines",
            "straight BEV lines (list of lanegraph.types.Line)",
            check=_list_of(Line, "a list of lanegraph.types.Line"),
            **dataclass_storage(Line),
        ),
        PortType(
            "lanes",
            "fitted lanes (list of lanegraph.types.Lane)",
            check=_list_of(Lane, "a list of lanegraph.types.Lane"),
            **dataclass_storage(Lane),
        ),
        PortType("number", "a scalar", check=_number),
    )
}


class _BuiltinPortTypes:
    """The plugin that registers :data:`PORT_TYPES` (the plugin manager registers it first, as
    ``lanegraph``)."""

    @hookimpl
    def lanegraph_port_types(self) -> list[PortType]:
        return list(PORT_TYPES.values())


BUILTIN_PORT_TYPES = _BuiltinPortTypes()
