"""The pictures of lanegraph's own port types, and drawing a value by its port type.

lanegraph's own port types (their checks and storage) are the core's
(:mod:`lanegraph.port_types`, registered by a built-in plugin through ``lanegraph_port_types``);
their pictures are drawn here (:data:`PICTURES`: ``render(value, context)``, a BGR ``uint8``
picture for ``--debug-dir`` and the report, or None). A plugin's port type carries its own
``render``. :func:`render_value` asks the port type, then these pictures; a value of a type that
draws nothing is drawn by what it is: an array as an image, a number or text as a small card,
metadata not at all.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ..port_types import PORT_TYPES
from ..types import BevGeometry, Calibration, FeatureMap, Line, PortType, RoadModel
from . import render as r

Context = Mapping[str, Any]


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


#: the pictures of lanegraph's own port types (:data:`lanegraph.port_types.PORT_TYPES`), by name
PICTURES: dict[str, Callable[[Any, Context], Any]] = {
    "image": lambda v, ctx: r.to_bgr(v),
    "gray": lambda v, ctx: r.to_bgr(v),
    "disparity": lambda v, ctx: r.render_disparity(v),
    "mask": lambda v, ctx: r.render_mask(v, ctx.get("image")),
    "vdisparity": lambda v, ctx: r.render_vdisparity(v, ctx.get("road_model")),
    "road_model": lambda v, ctx: (
        r.render_road_model(v, ctx.get("vdisparity")) if isinstance(v, RoadModel) else None
    ),
    "bev_image": lambda v, ctx: r.to_bgr(v),
    "bev_mask": lambda v, ctx: r.render_mask(v, ctx.get("bev_image")),
    "features": lambda v, ctx: r.render_features(v) if isinstance(v, FeatureMap) else None,
    "orientation": _orientation,
    "lines": _lines,
    "lanes": lambda v, ctx: r.render_lanes(v, ctx) if isinstance(v, list) else None,
}


def picture_of(pt: PortType) -> Callable[[Any, Context], Any] | None:
    """How a value of port type ``pt`` is drawn: its own ``render``, or, for lanegraph's own, its
    picture of :data:`PICTURES`."""
    if pt.render is not None:
        return pt.render
    return PICTURES.get(pt.name) if PORT_TYPES.get(pt.name) is pt else None


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
    render = picture_of(pt) if pt is not None else None
    if render is not None:
        img = render(value, dict(context or {}))
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
