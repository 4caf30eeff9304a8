"""lanegraph's own port types, registered by a built-in plugin through ``lanegraph_port_types``
exactly as a third party registers its own (as datasette registers its default column types
through its own hook).

Each :class:`~lanegraph.types.PortType` carries what is particular to its values: ``render(value,
context)`` (a BGR ``uint8`` picture for ``--debug-dir`` and the report, or None) and
``check(value)`` (what is wrong with a value of this type, or None). :func:`render_value` asks the
port type; a value of a type that draws nothing (or of a type without a ``render``) is drawn by
what it is: an array as an image, a number or text as a small card, metadata not at all.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ..hookspecs import hookimpl
from ..types import BevGeometry, Calibration, FeatureMap, Lane, Line, PortType, RoadModel
from . import render as r

Context = Mapping[str, Any]


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


# --------------------------------------------------------------------------- renderings
def _orientation(value: Any, ctx: Context) -> np.ndarray:
    shape = ctx["features"].mask.shape if isinstance(ctx.get("features"), FeatureMap) else (200, 200)
    line = Line(
        rho=shape[1] / 2 + (shape[0] / 2) * math.cos(value) / max(math.sin(value), 1e-6),
        theta=float(value),
    )
    img = r.render_lines([line], ctx.get("bev_image"), None, shape)
    r.cv2.putText(
        img,
        f"theta {math.degrees(value):.1f} deg",
        (4, 16),
        r.cv2.FONT_HERSHEY_SIMPLEX,
        0.5,
        r.OTHER_COLOUR,
        1,
        r.cv2.LINE_AA,
    )
    return img


def _lines(value: Any, ctx: Context) -> np.ndarray | None:
    if not isinstance(value, list):
        return None
    feats = ctx.get("features")
    return r.render_lines(value, ctx.get("bev_image"), feats if isinstance(feats, FeatureMap) else None)


_IMAGE = _array((np.uint8,), (2, 3), "an HxW or HxWx3 uint8 image")

#: lanegraph's own port types, by name (what the built-in plugin registers)
PORT_TYPES: dict[str, PortType] = {
    t.name: t
    for t in (
        PortType("any", "any value"),
        PortType(
            "frame_id", "frame identifier: the left image's file stem (str)", check=_instance(str, "a str")
        ),
        PortType("image", "image, HxW or HxWx3 uint8 (BGR)", render=lambda v, ctx: r.to_bgr(v), check=_IMAGE),
        PortType(
            "gray",
            "gray image, HxW uint8 or float32",
            "image",
            render=lambda v, ctx: r.to_bgr(v),
            check=_array((np.uint8, np.float32), (2,), "an HxW uint8 or float32 image"),
        ),
        PortType(
            "disparity",
            "disparity map, HxW float32 pixels; invalid pixels <= 0",
            render=lambda v, ctx: r.render_disparity(v),
            check=_array((np.float32,), (2,), "an HxW float32 disparity map"),
        ),
        PortType(
            "mask",
            "binary mask in image pixels, HxW bool",
            render=lambda v, ctx: r.render_mask(v, ctx.get("image")),
            check=_array((np.bool_,), (2,), "an HxW bool mask"),
        ),
        PortType(
            "calibration",
            "rectified stereo calibration (lanegraph.types.Calibration)",
            check=_instance(Calibration, "a lanegraph.types.Calibration"),
        ),
        PortType(
            "vdisparity",
            "v-disparity accumulator, H x D float32",
            render=lambda v, ctx: r.render_vdisparity(v, ctx.get("road_model")),
            check=_array((np.float32,), (2,), "an H x D float32 accumulator"),
        ),
        PortType(
            "road_model",
            "road profile d(v), roll, pitch, height (lanegraph.types.RoadModel)",
            render=lambda v, ctx: (
                r.render_road_model(v, ctx.get("vdisparity")) if isinstance(v, RoadModel) else None
            ),
            check=_instance(RoadModel, "a lanegraph.types.RoadModel"),
        ),
        PortType(
            "bev_geometry",
            "bird's-eye-view grid and its mapping (lanegraph.types.BevGeometry)",
            check=_instance(BevGeometry, "a lanegraph.types.BevGeometry"),
        ),
        PortType(
            "bev_image",
            "bird's-eye-view image, Hb x Wb uint8",
            render=lambda v, ctx: r.to_bgr(v),
            check=_IMAGE,
        ),
        PortType(
            "bev_mask",
            "bird's-eye-view binary mask, Hb x Wb bool",
            render=lambda v, ctx: r.render_mask(v, ctx.get("bev_image")),
            check=_array((np.bool_,), (2,), "an Hb x Wb bool mask"),
        ),
        PortType(
            "features",
            "lane feature map with orientation (lanegraph.types.FeatureMap)",
            render=lambda v, ctx: r.render_features(v) if isinstance(v, FeatureMap) else None,
            check=_instance(FeatureMap, "a lanegraph.types.FeatureMap"),
        ),
        PortType(
            "orientation",
            "global lane orientation in the BEV, radians (float)",
            render=_orientation,
            check=_number,
        ),
        PortType(
            "lines",
            "straight BEV lines (list of lanegraph.types.Line)",
            render=_lines,
            check=_list_of(Line, "a list of lanegraph.types.Line"),
        ),
        PortType(
            "lanes",
            "fitted lanes (list of lanegraph.types.Lane)",
            render=lambda v, ctx: r.render_lanes(v, ctx) if isinstance(v, list) else None,
            check=_list_of(Lane, "a list of lanegraph.types.Lane"),
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


# --------------------------------------------------------------------------- by port type
def render_value(
    port_type: str, value: Any, context: Context | None = None, types: Mapping[str, PortType] | None = None
) -> np.ndarray | None:
    """Render a value of ``port_type`` as a BGR uint8 image; ``None`` when it is not renderable.

    The port type's own ``render`` draws it (``types``: the registered port types, default
    lanegraph's own); ``context`` maps port types to other values of the same frame (the left
    image, the BEV image, the v-disparity, the features ...), used to draw a value over what it
    belongs to. A value its type does not draw is drawn by what it is.
    """
    if value is None:
        return None
    pt = (PORT_TYPES if types is None else types).get(port_type)
    if pt is not None and pt.render is not None:
        img = pt.render(value, dict(context or {}))
        if img is not None:
            return img
    if isinstance(value, (Calibration, BevGeometry)):
        return None  # metadata, not a picture
    if isinstance(value, np.ndarray) and value.ndim in (2, 3) and value.size:
        try:
            return r.to_bgr(value)
        except ValueError:
            return None
    if isinstance(value, (str, int, float)):
        return r.text_card([str(value)], title=port_type)
    return None


def check_value(port_type: str, value: Any, types: Mapping[str, PortType] | None = None) -> str | None:
    """What is wrong with ``value`` as a value of ``port_type`` (its ``check``), or None."""
    pt = (PORT_TYPES if types is None else types).get(port_type)
    return pt.check(value) if pt is not None and pt.check is not None else None
