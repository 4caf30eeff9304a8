"""Pictures to debug a pipeline by: every port type rendered as a BGR image, and a mosaic.

The drawing functions of the built-in port types (disparity colour map, v-disparity with the DP
path and the road model, road-mask overlay, bird's-eye view, features coloured by orientation,
the 1D Hough accumulator with its peaks, ROIs and fitted parabolas, the final overlay). Which one
draws a value is its port type's own ``render`` (:mod:`lanegraph.presentation.port_types`, where
:func:`~lanegraph.presentation.port_types.render_value` dispatches); a node type may draw its
outputs itself through the ``lanegraph_render`` hook, which is asked first.

The ``--debug-dir`` recorder that writes them: :mod:`lanegraph.presentation.debug`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import cv2
import numpy as np

from ..types import FeatureMap, Lane, Line, RoadModel

#: colours (BGR)
LEFT_COLOUR = (60, 60, 255)
RIGHT_COLOUR = (255, 120, 40)
OTHER_COLOUR = (0, 220, 255)
PATH_COLOUR = (0, 0, 255)
MODEL_COLOUR = (0, 255, 0)


def _colour(side: str) -> tuple[int, int, int]:
    return {"left": LEFT_COLOUR, "right": RIGHT_COLOUR}.get(side, OTHER_COLOUR)


# --------------------------------------------------------------------------- basic conversions
def to_bgr(image: np.ndarray) -> np.ndarray:
    """Any 2D/3D array as a BGR uint8 image (floats are scaled to their finite range)."""
    a = np.asarray(image)
    if a.dtype == bool:
        a = a.astype(np.uint8) * 255
    elif a.dtype != np.uint8:
        f = a.astype(np.float64)
        finite = np.isfinite(f)
        lo, hi = (float(f[finite].min()), float(f[finite].max())) if finite.any() else (0.0, 1.0)
        if hi <= lo:
            hi = lo + 1.0
        a = np.where(finite, (f - lo) * (255.0 / (hi - lo)), 0).clip(0, 255).astype(np.uint8)
    if a.ndim == 2:
        return cv2.cvtColor(a, cv2.COLOR_GRAY2BGR)
    if a.ndim == 3 and a.shape[2] == 3:
        return np.ascontiguousarray(a)
    if a.ndim == 3 and a.shape[2] == 4:
        return cv2.cvtColor(a, cv2.COLOR_BGRA2BGR)
    raise ValueError(f"cannot render an array of shape {a.shape} as an image")


def text_card(lines: Iterable[str], width: int = 360, title: str = "") -> np.ndarray:
    """A dark card with lines of text (for values that are not pictures)."""
    rows = ([title] if title else []) + [str(s) for s in lines]
    rows = rows[:14] or ["(empty)"]
    img = np.full((24 + 22 * len(rows), width, 3), 32, np.uint8)
    for i, s in enumerate(rows):
        cv2.putText(
            img, s[:48], (8, 22 + 22 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (230, 230, 230), 1, cv2.LINE_AA
        )
    return img


def render_disparity(disp: np.ndarray, max_disparity: float | None = None) -> np.ndarray:
    """Disparity as a TURBO colour map (near = red); invalid pixels (<= 0 or not finite) black."""
    d = np.asarray(disp, np.float32)
    valid = np.isfinite(d) & (d > 0)
    top = (
        float(max_disparity)
        if max_disparity
        else (float(np.percentile(d[valid], 99.5)) if valid.any() else 1.0)
    )
    u8 = np.zeros(d.shape, np.uint8)
    u8[valid] = np.clip(d[valid] * (255.0 / max(top, 1e-6)), 0, 255).astype(np.uint8)
    out = cv2.applyColorMap(u8, cv2.COLORMAP_TURBO)
    out[~valid] = 0
    return out


def render_mask(
    mask: np.ndarray, under: np.ndarray | None = None, colour: tuple[int, int, int] = (0, 200, 0)
) -> np.ndarray:
    """A mask blended in ``colour`` over ``under`` (an image of the same size) or white on black."""
    m = np.asarray(mask, bool)
    if under is None or np.asarray(under).shape[:2] != m.shape:
        return to_bgr(m)
    out = to_bgr(under).copy()
    tint = np.empty_like(out)
    tint[:] = colour
    out[m] = (0.55 * out[m] + 0.45 * tint[m]).astype(np.uint8)
    return out


def render_vdisparity(vdisp: np.ndarray, road: RoadModel | None = None) -> np.ndarray:
    """The v-disparity accumulator (log scale), with the DP path in red and the model d(v) in green."""
    acc = np.asarray(vdisp, np.float64)
    img = np.log1p(np.maximum(acc, 0))
    img = (255.0 * img / max(float(img.max()), 1e-9)).astype(np.uint8)
    out = cv2.applyColorMap(img, cv2.COLORMAP_BONE)
    if road is not None:
        _draw_road(out, road)
    return out


def _draw_road(out: np.ndarray, road: RoadModel) -> None:
    h, w = out.shape[:2]
    if road.profile is not None:
        prof = np.asarray(road.profile, np.float64)
        for v in np.flatnonzero(prof >= 0):
            if v < h:
                d = int(round(prof[v]))
                if 0 <= d < w:
                    out[v, max(d - 1, 0) : d + 2] = PATH_COLOUR
    if road.valid:
        v = np.arange(max(int(road.v_min), 0), h, dtype=np.float64)
        d = np.asarray(road.disparity_at(v), np.float64)
        ok = (d >= 0) & (d < w)
        pts = np.stack([d[ok], v[ok]], axis=1).round().astype(np.int32)
        if len(pts) > 1:
            cv2.polylines(out, [pts.reshape(-1, 1, 2)], False, MODEL_COLOUR, 1, cv2.LINE_AA)


def render_road_model(road: RoadModel, vdisp: np.ndarray | None = None) -> np.ndarray:
    """The road model over the v-disparity when known, with its pose as a caption."""
    if vdisp is not None:
        out = render_vdisparity(vdisp, road)
    else:
        h = int(len(road.profile)) if road.profile is not None else 256
        out = np.zeros((max(h, 64), 192, 3), np.uint8)
        _draw_road(out, road)
    if out.shape[1] < 200:  # v-disparity is narrow: widen it so the caption fits
        pad = np.zeros((out.shape[0], 200 - out.shape[1], 3), np.uint8)
        out = np.hstack([out, pad])
    caption = (
        f"pitch {math.degrees(road.pitch):+.2f} roll {math.degrees(road.roll):+.2f} h {road.height:.2f} m"
    )
    if not road.valid:
        caption = "road model: invalid"
    cv2.putText(out, caption, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def render_features(features: FeatureMap) -> np.ndarray:
    """Feature pixels coloured by orientation (hue over [0, pi)); white where it is unknown (SLT)."""
    m = np.asarray(features.mask, bool)
    out = np.zeros(m.shape + (3,), np.uint8)
    if features.orientation is None:
        out[m] = 255
        return out
    o = np.asarray(features.orientation, np.float64)
    known = m & (o >= 0)
    hsv = np.zeros(m.shape + (3,), np.uint8)
    hsv[..., 0] = (np.clip(o, 0, math.pi) * (179.0 / math.pi)).astype(np.uint8)
    hsv[..., 1] = 255
    hsv[..., 2] = 255
    col = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
    out[known] = col[known]
    out[m & ~known] = 255
    return out


def line_columns(line: Line, rows: int, y: np.ndarray) -> np.ndarray:
    """Columns of a BEV ``line`` at BEV rows ``y`` (rho = x - (H - y) / tan(theta))."""
    inv_tan = math.cos(line.theta) / max(math.sin(line.theta), 1e-6)
    return line.rho + (rows - np.asarray(y, np.float64)) * inv_tan


def hough_1d(features: FeatureMap, theta: float) -> np.ndarray:
    """The 1D Hough accumulator of ``features`` for orientation ``theta``; bin ``i`` is rho = i - 2W."""
    rows, cols = features.mask.shape
    r, c = features.points()
    inv_tan = math.cos(theta) / max(math.sin(theta), 1e-6)
    b = np.floor(c - (rows - r) * inv_tan + 0.5).astype(np.int64) + 2 * cols
    b = b[(b >= 0) & (b < 5 * cols)]
    return np.bincount(b, minlength=5 * cols).astype(np.float64)


def render_hough_1d(
    acc: np.ndarray, offset: int, width: int, peaks: Iterable[Line] = (), height: int = 120
) -> np.ndarray:
    """A bar plot of the 1D accumulator over the BEV's columns (rho in [0, width)), peaks marked."""
    acc = np.asarray(acc, np.float64)
    seg = acc[offset : offset + width] if offset + width <= acc.size else np.zeros(width)
    out = np.full((height, width, 3), 24, np.uint8)
    top = max(float(seg.max()), 1.0)
    for x, v in enumerate(seg):
        if v > 0:
            cv2.line(
                out,
                (x, height - 1),
                (x, height - 1 - int(round((height - 14) * v / top))),
                (200, 200, 200),
                1,
            )
    for line in peaks:
        x = int(round(line.rho))
        if 0 <= x < width:
            cv2.line(out, (x, 0), (x, height - 1), _colour(line.side), 1)
            cv2.putText(
                out,
                f"{line.votes:.0f}",
                (min(x + 2, width - 30), 11),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.35,
                _colour(line.side),
                1,
            )
    return out


def render_lines(
    lines: list[Line],
    bev: np.ndarray | None,
    features: FeatureMap | None,
    shape: tuple[int, int] | None = None,
) -> np.ndarray:
    """The Hough lines over the BEV image, with the 1D accumulator and its peaks underneath."""
    if bev is not None:
        base = to_bgr(bev).copy()
    elif features is not None:
        base = render_features(features)
    else:
        h, w = shape or (400, 400)
        base = np.zeros((h, w, 3), np.uint8)
    rows, cols = base.shape[:2]
    y = np.array([0.0, rows - 1.0])
    for line in lines:
        x = line_columns(line, rows, y)
        cv2.line(
            base, (int(round(x[0])), 0), (int(round(x[1])), rows - 1), _colour(line.side), 2, cv2.LINE_AA
        )
    if features is None or features.mask.shape != (rows, cols):
        return base
    theta = lines[0].theta if lines else math.pi / 2
    plot = render_hough_1d(hough_1d(features, theta), 2 * cols, cols, lines)
    return np.vstack([base, plot])


def lane_columns(lane: Lane, rows: int, y: np.ndarray) -> np.ndarray:
    """Columns of a fitted lane at BEV rows ``y`` (``col = c0 + c1*t + c2*t**2``, ``t = rows - 1 - y``)."""
    t = rows - 1 - np.asarray(y, np.float64)
    c0, c1, c2 = lane.coeffs
    return c0 + c1 * t + c2 * t * t


def render_lanes_bev(
    lanes: list[Lane], bev: np.ndarray | None, roi_width: float = 40.0, shape: tuple[int, int] | None = None
) -> np.ndarray:
    """ROIs (``roi_width`` BEV pixels) and fitted parabolas over the BEV image."""
    if bev is not None:
        out = to_bgr(bev).copy()
    else:
        h, w = shape or (800, 400)
        out = np.zeros((h, w, 3), np.uint8)
    rows = out.shape[0]
    for lane in lanes:
        first, last = (int(v) for v in lane.bev_rows)
        lo, hi = sorted((max(first, 0), min(last, rows - 1)))
        y = np.arange(lo, hi + 1, dtype=np.float64)
        if y.size < 2:
            continue
        x = lane_columns(lane, rows, y)
        band = out.copy()
        poly = np.concatenate(
            [np.stack([x - roi_width / 2, y], 1), np.stack([x + roi_width / 2, y], 1)[::-1]]
        )
        cv2.fillPoly(band, [poly.round().astype(np.int32)], _colour(lane.side))
        out = cv2.addWeighted(band, 0.25, out, 0.75, 0)
        pts = np.stack([x, y], 1).round().astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(out, [pts], False, _colour(lane.side), 2, cv2.LINE_AA)
    return out


def draw_lane_points(
    img: np.ndarray,
    lanes: Iterable[Lane],
    colours: Mapping[str, tuple[int, int, int]] | None = None,
    thickness: int = 3,
    captions: bool = False,
) -> None:
    """Draw the lanes' image points into ``img`` (BGR, in place), coloured by side (``colours``
    maps ``"left"``, ``"right"`` and ``""`` to BGR; the debug palette by default); with
    ``captions``, side and score at each lane's far end."""
    for lane in lanes:
        if lane.points is None or len(lane.points) < 2:
            continue
        colour = (
            _colour(lane.side) if colours is None else colours.get(lane.side, colours.get("", OTHER_COLOUR))
        )
        pts = np.asarray(lane.points, np.float64).round().astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(img, [pts], False, colour, thickness, cv2.LINE_AA)
        if captions:
            x, y = pts[-1, 0]
            cv2.putText(
                img,
                f"{lane.side} {lane.score:.2f}",
                (int(x) + 4, int(y)),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.5,
                colour,
                1,
                cv2.LINE_AA,
            )


def render_lanes_image(lanes: list[Lane], image: np.ndarray) -> np.ndarray:
    """The final overlay: lanes' image points over the left image, with side and score."""
    out = to_bgr(image).copy()
    draw_lane_points(out, lanes, captions=True)
    return out


def render_lanes(lanes: list[Lane], context: Mapping[str, Any]) -> np.ndarray:
    """Lanes with image points over the left image (final overlay); otherwise in the BEV."""
    image = context.get("image")
    if image is not None and any(lane.points is not None and len(lane.points) > 1 for lane in lanes):
        return render_lanes_image(lanes, image)
    return render_lanes_bev(lanes, context.get("bev_image"))


# --------------------------------------------------------------------------- mosaic
def caption(img: np.ndarray, text: str) -> np.ndarray:
    """``img`` with a caption bar on top."""
    bar = np.full((20, img.shape[1], 3), 48, np.uint8)
    cv2.putText(
        bar,
        text[: max(img.shape[1] // 7, 8)],
        (4, 14),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.45,
        (255, 255, 255),
        1,
        cv2.LINE_AA,
    )
    return np.vstack([bar, img])


def mosaic(
    tiles: Iterable[tuple[str, np.ndarray]],
    tile_height: int = 240,
    max_row_width: int = 1920,
    max_tile_width: int = 640,
    min_tile_width: int = 160,
) -> np.ndarray:
    """Captioned tiles scaled to ``tile_height`` (at most ``max_tile_width`` wide), packed in rows
    of at most ``max_row_width`` pixels, in the order given. A tall, narrow picture (a v-disparity:
    one column per disparity bin) is stretched to ``min_tile_width``; a tile narrower than its
    caption is widened (black on the right) so that the caption is never cut."""
    scaled = []
    for name, img in tiles:
        h, w = img.shape[:2]
        s = min(tile_height / max(h, 1), max_tile_width / max(w, 1))
        size = (max(int(round(w * s)), 1, min(min_tile_width, max_tile_width)), max(int(round(h * s)), 1))
        interp = cv2.INTER_AREA if s < 1 and size[0] <= w else cv2.INTER_NEAREST
        tile = cv2.resize(to_bgr(img), size, interpolation=interp)
        (text_w, _), _ = cv2.getTextSize(name, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
        if text_w + 8 > tile.shape[1]:
            tile = np.pad(tile, ((0, 0), (0, text_w + 8 - tile.shape[1]), (0, 0)))
        scaled.append(caption(tile, name))
    if not scaled:
        return text_card(["nothing to show"])
    rows: list[list[np.ndarray]] = [[]]
    width = 0
    for t in scaled:
        if rows[-1] and width + t.shape[1] + 4 > max_row_width:
            rows.append([])
            width = 0
        rows[-1].append(t)
        width += t.shape[1] + 4
    lines = []
    for row in rows:
        height = max(t.shape[0] for t in row)
        lines.append(np.hstack([np.pad(t, ((0, height - t.shape[0]), (0, 4), (0, 0))) for t in row]))
    full = max(line.shape[1] for line in lines)
    return np.vstack([np.pad(line, ((0, 4), (0, full - line.shape[1]), (0, 0))) for line in lines])
