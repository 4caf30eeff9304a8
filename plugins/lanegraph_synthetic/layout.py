"""What is on and along the road in one *tile*: a stretch of ``tile_length`` metres that repeats.

Painted arrows and hatching (not lane markings: they are left out of the lane ground truth) and
soft shadows are rasterised into maps in road coordinates (``s`` along the road, ``lateral`` across
it), which the renderer samples per pixel. Parked cars, poles, tree trunks, walls and traffic are
drawn at random (from the scene's seed) as :mod:`~lanegraph_synthetic.objects`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from .objects import Box, Pole, car

#: the maps cover lateral offsets in [-LATERAL_HALF, LATERAL_HALF] metres
LATERAL_HALF = 20.0
PAINT_RES = 0.05  # metres per paint-map pixel
SHADOW_RES = 0.10  # metres per shadow-map pixel
WEAR_RES = 0.05  # metres per sample of a marking's worn-through gaps
SIDE_ROAD_LENGTH = 14.0  # how far a side road is paved (and kerbed) beyond its corners, metres

CAR_COLOURS = [(60, 60, 170), (170, 90, 40), (200, 200, 205), (40, 40, 45), (60, 130, 60), (30, 160, 200)]


@dataclass
class Tile:
    """Road-coordinate maps and objects of one repeating stretch of road.

    ``paint``: (rows = s / PAINT_RES, cols = (lateral + LATERAL_HALF) / PAINT_RES) uint8 paint
    coverage, 255 = full. ``shadow``: the same at SHADOW_RES, 255 = full shadow. ``objects``: boxes
    and poles in road coordinates.
    """

    length: float
    paint: np.ndarray
    shadow: np.ndarray
    objects: list = field(default_factory=list)
    #: (markings, length / WEAR_RES) float32, 0 where a marking is worn through; None: no gaps
    wear: np.ndarray | None = None
    #: darker repair asphalt (SHADOW_RES, 255 = repaired) or None
    repair: np.ndarray | None = None


def _to_px(lat, s, res):
    return np.stack([(np.asarray(lat) + LATERAL_HALF) / res, np.asarray(s) / res], axis=-1)


def _fill(img: np.ndarray, poly_m: np.ndarray, res: float, value: int = 255) -> None:
    """Fill a polygon given as (N, 2) (lateral, s) metres; 2 bits of sub-pixel precision."""
    pts = np.round(_to_px(poly_m[:, 0], poly_m[:, 1], res) * 4).astype(np.int32)
    cv2.fillPoly(img, [pts], value, lineType=cv2.LINE_AA, shift=2)


def _arrow(lat: float, s: float, straight: bool, turn: int) -> list[np.ndarray]:
    """Polygons (lateral, s metres) of a forward arrow 5 m long starting at ``s``, optionally with a
    turn arrow head to the side ``turn`` (-1 left, +1 right)."""
    polys = []
    w = 0.09
    polys.append(np.array([[lat - w, s], [lat + w, s], [lat + w, s + 3.4], [lat - w, s + 3.4]]))
    if straight:
        polys.append(np.array([[lat - 0.35, s + 3.3], [lat + 0.35, s + 3.3], [lat, s + 5.0]]))
    if turn:
        polys.append(
            np.array(
                [[lat, s + 2.3], [lat + turn * 0.45, s + 2.6], [lat + turn * 0.45, s + 2.8], [lat, s + 2.5]]
            )
        )
        polys.append(
            np.array([[lat + turn * 0.4, s + 2.0], [lat + turn * 0.4, s + 3.4], [lat + turn * 0.9, s + 2.7]])
        )
    return polys


def _hatch(
    paint: np.ndarray, lat0: float, lat1: float, s0: float, s1: float, spacing=1.6, width=0.35
) -> None:
    """Diagonal (45 degree) stripes filling the rectangle lateral [lat0, lat1] x s [s0, s1]."""
    c0, c1 = int((lat0 + LATERAL_HALF) / PAINT_RES), int(math.ceil((lat1 + LATERAL_HALF) / PAINT_RES))
    r0, r1 = int(s0 / PAINT_RES), int(math.ceil(s1 / PAINT_RES))
    r1 = min(r1, paint.shape[0])
    lat = (np.arange(c0, c1) + 0.5) * PAINT_RES - LATERAL_HALF
    s = (np.arange(r0, r1) + 0.5) * PAINT_RES
    phase = np.mod(s[:, None] + lat[None, :], spacing)
    on = phase < width * math.sqrt(2.0)
    block = paint[r0:r1, c0:c1]
    np.maximum(block, (on * 255).astype(np.uint8), out=block)


def _gore(
    paint: np.ndarray, lat0: float, lat1: float, L: float, pattern: str, step: float, width=0.45
) -> None:
    """Hatch the gore area lateral [lat0, lat1] over the whole tile: V-shaped bars at 45 degrees to
    the road ("chevron") or parallel diagonal ones ("stripes"), ``width`` metres wide, one every
    ``step`` metres along the road."""
    c0, c1 = int((lat0 + LATERAL_HALF) / PAINT_RES), int(math.ceil((lat1 + LATERAL_HALF) / PAINT_RES))
    lat = (np.arange(c0, c1) + 0.5) * PAINT_RES - LATERAL_HALF
    s = (np.arange(paint.shape[0]) + 0.5) * PAINT_RES
    across = np.abs(lat - 0.5 * (lat0 + lat1)) if pattern == "chevron" else lat - lat0
    on = np.mod(s[:, None] + across[None, :], step) < width * math.sqrt(2.0)
    block = paint[:, c0:c1]
    np.maximum(block, (on * 255).astype(np.uint8), out=block)


def side_road_spans(spec, side: int = 1) -> list[tuple[float, float]]:
    """(start, end) metres along a tile of the mouth of each side road joining on the right
    (``side`` 1: ``spec.side_roads``) or the left (-1: ``spec.side_roads_left``): from where its
    near corner's kerb leaves the edge to where its far corner's kerb rejoins it."""
    span = 2 * spec.side_road_radius + spec.side_road_width
    return [(float(s), float(s) + span) for s in (spec.side_roads if side > 0 else spec.side_roads_left)]


def side_road_paved(spec, lat: np.ndarray, s: np.ndarray, edges: tuple[float, float]) -> np.ndarray:
    """True where the road point (``lat`` metres across, ``s`` metres along a tile) lies on a side
    road: beyond the main road's edge (``edges``: left, right), outside the two corners' quarter
    circles (radius ``side_road_radius``, centred ``radius`` metres beyond the edge at each end of
    the mouth), and between the corners' straight kerbs for ``SIDE_ROAD_LENGTH`` metres beyond."""
    R = np.float32(spec.side_road_radius)
    out = np.zeros(np.shape(lat), bool)
    for side, edge in ((1, edges[1]), (-1, edges[0])):
        beyond = (lat - np.float32(edge)) * np.float32(side)  # metres beyond the edge, outwards
        dl = beyond - R
        for a, b in side_road_spans(spec, side):
            d1, d2 = s - np.float32(a), s - np.float32(b)
            outside = (d1 * d1 + dl * dl >= R * R) & (d2 * d2 + dl * dl >= R * R)
            corner = (s >= a) & (s <= b) & (dl <= 0) & outside
            straight = (d1 >= R) & (d2 <= -R) & (dl >= 0) & (dl <= SIDE_ROAD_LENGTH)
            out |= (beyond > 0) & (corner | straight)
    return out


def _kerbed(length: float, mouths: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The stretches of [0, ``length``] metres outside the side roads' ``mouths`` (sorted)."""
    runs, start = [], 0.0
    for a, b in sorted(mouths):
        if a > start:
            runs.append((start, a))
        start = max(start, b)
    return runs + ([(start, length)] if start < length else [])


def _side_road_kerbs(spec, edges: tuple[float, float]) -> list[Box]:
    """Kerb segments (``kerb_height``, 0.2 m wide, bright concrete) of each side road: two quarter
    circles leaving the edge (chords of about 0.8 m, turned with the circle) and the straight
    kerbs along the side road beyond them."""
    R, h, col = spec.side_road_radius, spec.kerb_height, (185.0, 190.0, 195.0)
    n = max(4, int(math.ceil(0.5 * math.pi * R / 0.8)))
    chord = 2 * (R - 0.1) * math.sin(0.25 * math.pi / n) + 0.02
    boxes = []
    for side, edge in ((1, edges[1]), (-1, edges[0])):
        for a, b in side_road_spans(spec, side):
            for i in range(n):
                th = (i + 0.5) * 0.5 * math.pi / n  # 0 at the edge, pi/2 along the side road
                ds, dl = (R - 0.1) * math.sin(th), R - (R - 0.1) * math.cos(th)  # 0.1 m into the corner
                boxes.append(Box(a + ds, edge + side * dl, chord, 0.2, h, 0.0, col, yaw=side * th))
                boxes.append(Box(b - ds, edge + side * dl, chord, 0.2, h, 0.0, col, yaw=-side * th))
            for lat in np.arange(1.0, SIDE_ROAD_LENGTH, 2.0):
                for s in (a + R - 0.1, b - R + 0.1):
                    lat_c = edge + side * (R + float(lat))
                    boxes.append(Box(s, lat_c, 1.98, 0.2, h, 0.0, col, yaw=0.5 * math.pi))
    return boxes


def build_tile(
    spec, offsets: list[float], lane_centres: list[float], edges: tuple[float, float], rng
) -> Tile:
    """Draw the paint, shadows and objects of one tile of ``spec`` (a :class:`~.scene.SceneSpec`).

    ``offsets``: lateral positions of the painted lane markings (metres); ``lane_centres``: of
    every lane; ``edges``: lateral (left, right) limits of the paved road.
    """
    L = float(spec.tile_length)
    n_lat = int(round(2 * LATERAL_HALF / PAINT_RES))
    paint = np.zeros((int(round(L / PAINT_RES)), n_lat), np.uint8)
    shadow = np.zeros((int(round(L / SHADOW_RES)), int(round(2 * LATERAL_HALF / SHADOW_RES))), np.uint8)
    objects: list = []
    left_edge, right_edge = edges
    per_tile = L / 100.0

    def count(density: float) -> int:
        return int(rng.poisson(density * per_tile)) if density > 0 else 0

    # ---- painted arrows in the lanes, hatching on the right shoulder
    for _ in range(count(spec.arrows)):
        lat = float(rng.choice(lane_centres))
        s = float(rng.uniform(10.0, L - 10.0))
        turn = int(rng.choice([0, 0, -1, 1]))
        for poly in _arrow(lat, s, straight=(turn == 0 or rng.random() < 0.5), turn=turn):
            _fill(paint, poly, PAINT_RES)
    hatched: list[tuple[float, float]] = []
    for _ in range(count(spec.hatching)):
        s0 = float(rng.uniform(5.0, L - 40.0))
        s1 = s0 + float(rng.uniform(15.0, 30.0))
        right = max(offsets) if offsets else right_edge
        _hatch(paint, right + 0.35, right + min(2.2, max(right_edge - right - 0.2, 0.6)), s0, s1)
        hatched.append((s0, s1))

    # ---- parked cars on the right shoulder (or just off the road), avoiding the hatched areas
    n_parked = count(spec.parked_cars)
    on_shoulder = right_edge - (max(offsets) if offsets else 0.0) > 2.2
    side_gap = 0.7 if (on_shoulder or not n_parked) else 2.6  # poles beside the parked cars
    if n_parked:
        slots = np.arange(0.0, L - 6.0, 6.5)
        blocked = hatched + side_road_spans(spec)  # parked on the right
        slots = [s for s in slots if not any(a - 4 < s < b + 4 for a, b in blocked)]
        pick = rng.choice(len(slots), size=min(n_parked, len(slots)), replace=False) if slots else []
        lat = right_edge - 1.1 if on_shoulder else right_edge + 1.1
        for i in sorted(pick):
            col = CAR_COLOURS[int(rng.integers(len(CAR_COLOURS)))]
            objects += car(
                float(slots[i] + 3.0),
                lat + float(rng.uniform(-0.15, 0.15)),
                col,
                yaw=float(rng.uniform(-0.03, 0.03)),
            )

    # ---- traffic: moving cars in the lanes, ahead of the ego vehicle
    for j in range(int(spec.traffic)):
        if len(lane_centres) > 1 and j % 2 == 0:
            others = [c for c in lane_centres if abs(c) > 0.5]
            lat = float(rng.choice(others)) if others else lane_centres[0]
            speed = spec.speed + float(rng.uniform(-4.0, 4.0))
        else:
            lat = min(lane_centres, key=abs)
            speed = spec.speed
        s = float(rng.uniform(18.0, 60.0)) + 45.0 * j
        col = CAR_COLOURS[int(rng.integers(len(CAR_COLOURS)))]
        objects += car(s, lat, col, speed=max(speed, 0.0))

    # ---- poles along both sides, with their shadows
    sun = np.array([-0.75, -0.55])  # shadow direction in (lateral, s)
    sun /= np.linalg.norm(sun)
    for _ in range(count(spec.poles)):
        side = 1.0 if rng.random() < 0.7 else -1.0
        lat = (right_edge + side_gap) if side > 0 else (left_edge - 0.7)
        s = float(rng.uniform(0.0, L))
        h = float(rng.uniform(4.0, 8.0))
        objects.append(Pole(s, lat, radius=0.09, height=h, colour=(165.0, 165.0, 160.0)))
        tip = np.array([lat, s]) + sun * h * 1.3
        nrm = np.array([-sun[1], sun[0]]) * 0.12
        base = np.array([lat, s])
        _fill(shadow, np.array([base - nrm, base + nrm, tip + nrm, tip - nrm]), SHADOW_RES)

    # ---- trees: a trunk beside the road, a soft canopy shadow reaching onto the road
    for _ in range(count(spec.trees)):
        side = 1.0 if rng.random() < 0.75 else -1.0  # mostly on the right: the sun throws shadows left
        lat = (right_edge + rng.uniform(2.9, 4.4)) if side > 0 else (left_edge - rng.uniform(1.5, 4.4))
        s = float(rng.uniform(0.0, L))
        objects.append(Pole(s, float(lat), radius=0.18, height=3.5, colour=(45.0, 65.0, 85.0)))
        centre = np.array([lat, s]) + sun * rng.uniform(4.0, 7.0)
        r = rng.uniform(2.5, 5.0)
        ang = np.sort(rng.uniform(0, 2 * np.pi, 11))
        rad = r * rng.uniform(0.65, 1.25, ang.size)
        poly = centre + np.stack([np.cos(ang) * rad, np.sin(ang) * rad * 1.2], axis=1)
        _fill(shadow, poly, SHADOW_RES)

    # ---- canopy shadows of trees out of view, anywhere across the road
    for _ in range(count(spec.shadows)):
        centre = np.array([rng.uniform(left_edge - 2.0, right_edge + 2.0), rng.uniform(0.0, L)])
        r = rng.uniform(1.5, 4.0)
        ang = np.sort(rng.uniform(0, 2 * np.pi, 9))
        rad = r * rng.uniform(0.6, 1.3, ang.size)
        _fill(
            shadow, centre + np.stack([np.cos(ang) * rad * 0.8, np.sin(ang) * rad * 1.5], axis=1), SHADOW_RES
        )

    # ---- a wall along the right side (20 m segments, so that they follow a curved road)
    if spec.walls:
        lat = right_edge + 5.5
        for s in np.arange(10.0, L, 20.0):
            objects.append(Box(float(s), lat, 19.8, 0.3, 2.6, 0.0, (120.0, 135.0, 150.0)))

    # ---- kerbs: low concrete steps along both road edges (5 m segments, so they follow a curve);
    # a bright, straight, parallel-bordered ridge that passes SLT like paint
    # (none across a side road's mouth: its own kerbs curve away there)
    if spec.kerb_height > 0:
        for lat, runs in (
            (left_edge - 0.1, _kerbed(L, side_road_spans(spec, -1))),
            (right_edge + 0.1, _kerbed(L, side_road_spans(spec))),
        ):
            for a, b in runs:
                n = max(1, int(math.ceil((b - a) / 5.0)))
                for i in range(n):
                    s, ln = a + (i + 0.5) * (b - a) / n, (b - a) / n - 0.02
                    objects.append(Box(float(s), lat, ln, 0.2, spec.kerb_height, 0.0, (185.0, 190.0, 195.0)))
        objects += _side_road_kerbs(spec, edges)

    # ---- a ramp's gore area: hatched between the two leftmost markings (the gore's far border
    # and the ego lane's left line)
    if spec.gore_width > 0 and len(offsets) >= 2:
        a, b = sorted(offsets)[:2]
        _gore(paint, a + 0.3, b - 0.3, L, spec.gore_pattern, spec.gore_step)

    # ---- dappled shade: a canopy over the road, sun patches (0.2-1.2 m, hard-edged) through it
    if spec.dappled > 0:
        c0 = int((left_edge - 2.0 + LATERAL_HALF) / SHADOW_RES)
        c1 = int((right_edge + 2.0 + LATERAL_HALF) / SHADOW_RES)
        shadow[:, max(c0, 0) : c1] = 255
        area = (right_edge - left_edge + 4.0) * L * spec.dappled
        n = int(area / (math.pi * 0.55**2))
        cs = rng.uniform(left_edge - 2.0, right_edge + 2.0, n)
        ss = rng.uniform(0.0, L, n)
        ra = rng.uniform(0.2, 0.9, n)
        rb = ra * rng.uniform(0.5, 1.0, n)
        ang = rng.uniform(0.0, 180.0, n)
        for x, s_, a_, b_, g in zip(cs, ss, ra, rb, ang, strict=True):
            centre = (int(round((x + LATERAL_HALF) / SHADOW_RES * 4)), int(round(s_ / SHADOW_RES * 4)))
            axes = (max(1, int(a_ / SHADOW_RES * 4)), max(1, int(b_ / SHADOW_RES * 4)))
            cv2.ellipse(shadow, centre, axes, float(g), 0, 360, 0, -1, cv2.LINE_AA, 2)

    # ---- worn paint: gaps along each marking; repair strips of darker asphalt across the road
    wear = None
    if spec.paint_gaps > 0:
        n_s = int(round(L / WEAR_RES))
        wear = np.ones((max(len(offsets), 1), n_s), np.float32)
        for row in wear:
            done = 0.0
            while done < spec.paint_gaps * L:
                g = float(rng.uniform(0.2, 1.5))
                s0 = float(rng.uniform(0.0, L - g))
                row[int(s0 / WEAR_RES) : int((s0 + g) / WEAR_RES)] = 0.0
                done += g
    repair = None
    if spec.repair_strips > 0:
        repair = np.zeros_like(shadow)
        for _ in range(count(spec.repair_strips)):
            s0 = float(rng.uniform(0.0, L - 4.0))
            length = float(rng.uniform(1.0, 3.0))
            skew = float(rng.uniform(-0.5, 0.5))
            poly = np.array(
                [
                    [left_edge, s0],
                    [right_edge, s0 + skew],
                    [right_edge, s0 + skew + length],
                    [left_edge, s0 + length],
                ]
            )
            _fill(repair, poly, SHADOW_RES)

    paint = cv2.GaussianBlur(paint, (0, 0), 0.7)
    # canopy shade is hard-edged (sun patches through leaves); soft shadows of trees out of view
    shadow = cv2.GaussianBlur(shadow, (0, 0), 0.6 if spec.dappled > 0 else 2.5)
    return Tile(L, paint, shadow, objects, wear, repair)
