"""Objects standing on the road (boxes and vertical cylinders) and their ray casting.

Objects are placed in *road coordinates*: ``s`` metres along the road (from the start of the
sequence) and ``lateral`` metres from the road's reference line (right positive). Each frame they
are moved into the camera-centred world frame of :mod:`lanegraph_synthetic.scene` (``x`` right,
``y`` down, ``z`` ahead, the road is ``y = height``) and turned with the road's heading.

The intersection kernels take a ray origin (3,) and per-pixel directions (3, h, w), scaled so that
the ray parameter ``t`` *is the camera depth* (the camera-frame z) of the hit; they return ``t``
(``inf`` where the ray misses) and a shading factor, so that the nearest hit among the road and all
objects can be kept by a plain depth test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: direction *towards* the light, in the world frame (x right, y down, z ahead): from above, left, behind
LIGHT = np.array([-0.45, -0.8, -0.4]) / np.linalg.norm([-0.45, -0.8, -0.4])


@dataclass
class Box:
    """A box standing on the road (a car's body, a wall segment, a thin pole).

    Attributes
    ----------
    s : float
        Position of the box centre along the road, metres from the sequence start.
    lateral : float
        Position of the box centre across the road, metres from the reference line (right positive).
    length, width, height : float
        Size along the road, across the road and up, metres.
    elevation : float
        Height of the box's bottom above the road, metres (0: standing on the road).
    colour : tuple of 3 floats
        BGR albedo, 0-255.
    speed : float
        Speed along the road, metres per second (0: parked).
    yaw : float
        Rotation about the vertical axis relative to the road heading, radians.
    """

    s: float
    lateral: float
    length: float = 4.2
    width: float = 1.8
    height: float = 1.5
    elevation: float = 0.0
    colour: tuple[float, float, float] = (70.0, 70.0, 170.0)
    speed: float = 0.0
    yaw: float = 0.0


@dataclass
class Pole:
    """A vertical cylinder standing on the road (a post, a lamp pole, a tree trunk).

    ``s``/``lateral``: position of its axis in road coordinates (metres); ``radius`` and ``height``
    in metres; ``colour`` BGR 0-255; ``speed`` along the road, metres per second.
    """

    s: float
    lateral: float
    radius: float = 0.08
    height: float = 4.0
    colour: tuple[float, float, float] = (150.0, 150.0, 150.0)
    speed: float = 0.0


def car(
    s: float, lateral: float, colour=(70.0, 70.0, 170.0), speed: float = 0.0, yaw: float = 0.0
) -> list[Box]:
    """A car as two boxes: a body 4.2 x 1.8 x 0.95 m and a darker cabin on top (windows)."""
    dark = tuple(0.35 * c + 15.0 for c in colour)
    body = Box(s, lateral, 4.2, 1.8, 0.95, 0.0, tuple(colour), speed, yaw)
    cabin = Box(s - 0.3, lateral, 2.3, 1.6, 0.55, 0.95, dark, speed, yaw)
    return [body, cabin]


@dataclass
class Placed:
    """An object in the camera-centred world frame of one frame (see :func:`place`)."""

    index: int
    kind: str  # "box" | "pole"
    centre: np.ndarray  # (3,) world metres; for a pole the axis point at mid height
    half: np.ndarray  # (3,) half sizes (x, y, z); pole: (radius, half height, radius)
    yaw: float
    colour: np.ndarray  # (3,) BGR

    def corners(self) -> np.ndarray:
        """The 8 corners of its bounding box, (8, 3) world metres (index bits: x, y, z sign)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        return (_UNIT_CORNERS * self.half) @ ry.T + self.centre

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """The 12 edges of its bounding box as (start, end) arrays, (12, 3) each."""
        p = self.corners()
        return p[_EDGES[:, 0]], p[_EDGES[:, 1]]


_UNIT_CORNERS = np.array([[(i >> 2) & 1, (i >> 1) & 1, i & 1] for i in range(8)], float) * 2 - 1
_EDGES = np.array([(i, i | b) for i in range(8) for b in (1, 2, 4) if not i & b])


def place(index: int, obj: Box | Pole, z: float, x: float, heading: float, road_y: float) -> Placed:
    """``obj`` with its centre (bottom centre for the road contact) at ahead distance ``z`` and lateral
    world ``x`` (metres), turned by the road ``heading`` (radians); the road is ``y = road_y``."""
    if isinstance(obj, Pole):
        half = np.array([obj.radius, obj.height / 2, obj.radius])
        centre = np.array([x, road_y - obj.height / 2, z])
        return Placed(index, "pole", centre, half, 0.0, np.asarray(obj.colour, np.float32))
    half = np.array([obj.width / 2, obj.height / 2, obj.length / 2])
    centre = np.array([x, road_y - obj.elevation - obj.height / 2, z])
    return Placed(index, "box", centre, half, heading + obj.yaw, np.asarray(obj.colour, np.float32))


def _hit_box(
    o: np.ndarray, d: np.ndarray, p: Placed
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Slab test of an oriented box. Returns (t, shade, tex_a, tex_b): ray parameter of the first hit
    (inf on a miss or when the origin is inside), a Lambert shading factor and face coordinates (m)."""
    c, s = math.cos(p.yaw), math.sin(p.yaw)
    ol = [float(v) for v in o - p.centre]  # python floats keep the float32 arrays float32
    ox, oy, oz = c * ol[0] - s * ol[2], ol[1], s * ol[0] + c * ol[2]
    dx = c * d[0] - s * d[2]
    dy = d[1]
    dz = s * d[0] + c * d[2]
    hx, hy, hz = (float(v) for v in p.half)
    with np.errstate(divide="ignore", invalid="ignore"):
        ix, iy, iz = 1.0 / dx, 1.0 / dy, 1.0 / dz
        ax, bx = (-hx - ox) * ix, (hx - ox) * ix
        ay, by = (-hy - oy) * iy, (hy - oy) * iy
        az, bz = (-hz - oz) * iz, (hz - oz) * iz
        nx, ny, nz = np.minimum(ax, bx), np.minimum(ay, by), np.minimum(az, bz)
        tnear = np.maximum(np.maximum(nx, ny), nz)
        tfar = np.minimum(np.minimum(np.maximum(ax, bx), np.maximum(ay, by)), np.maximum(az, bz))
        hit = (tnear <= tfar) & (tnear > 1e-3)
    t = np.where(hit, tnear, np.inf).astype(np.float32)
    fx = nx >= np.maximum(ny, nz)
    fy = ~fx & (ny >= nz)
    # world normal of the face hit: the local axis, signed against the ray, turned by the yaw
    sgn_x, sgn_y, sgn_z = -np.sign(dx), -np.sign(dy), -np.sign(dz)
    lx = np.where(fx, sgn_x * c, np.where(fy, 0.0, sgn_z * s))
    lz = np.where(fx, -sgn_x * s, np.where(fy, 0.0, sgn_z * c))
    ly = np.where(fy, sgn_y, 0.0)
    lam = lx * LIGHT[0] + ly * LIGHT[1] + lz * LIGHT[2]
    shade = (0.55 + 0.45 * np.clip(lam, 0.0, 1.0)).astype(np.float32)
    tn = np.where(hit, tnear, 0.0)
    px, py, pz = ox + tn * dx, oy + tn * dy, oz + tn * dz
    tex_a = np.where(fx, pz, px)
    tex_b = np.where(fy, pz, py)
    return t, shade, tex_a, tex_b


def _hit_pole(
    o: np.ndarray, d: np.ndarray, p: Placed
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """First hit of a vertical cylinder's side (its caps are not drawn). Same returns as :func:`_hit_box`."""
    r = float(p.half[0])
    ox, oz = float(o[0] - p.centre[0]), float(o[2] - p.centre[2])
    oy, cy, hy = float(o[1]), float(p.centre[1]), float(p.half[1])
    a = d[0] * d[0] + d[2] * d[2]
    b = 2.0 * (d[0] * ox + d[2] * oz)
    cc = ox * ox + oz * oz - r * r
    disc = b * b - 4.0 * a * cc
    with np.errstate(divide="ignore", invalid="ignore"):
        tt = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a)
    y = oy + tt * d[1]
    hit = (disc > 0) & (tt > 1e-3) & (np.abs(y - cy) <= hy)
    t = np.where(hit, tt, np.inf).astype(np.float32)
    tn = np.where(hit, tt, 0.0)
    nxw = (ox + tn * d[0]) / r
    nzw = (oz + tn * d[2]) / r
    lam = nxw * LIGHT[0] + nzw * LIGHT[2]
    shade = (0.5 + 0.5 * np.clip(lam, 0.0, 1.0)).astype(np.float32)
    tex_a = np.arctan2(nxw, nzw) * r
    return t, shade, tex_a, y


def intersect(o: np.ndarray, d: np.ndarray, p: Placed):
    """Ray cast ``p`` from origin ``o`` (3,) along directions ``d`` (3, h, w); see :func:`_hit_box`."""
    return _hit_pole(o, d, p) if p.kind == "pole" else _hit_box(o, d, p)
