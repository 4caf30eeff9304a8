"""Synthetic stereo road scenes with exact ground truth (deterministic from a seed).

A planar road seen by a rectified stereo rig of known calibration, pitch, roll and height, with
painted lane markings (solid and dashed, straight, constant curvature or a clothoid), asphalt
texture, soft shadows, arrows and hatching, objects standing on the road (cars, poles, tree trunks,
walls), sky, sensor noise and over-exposed frames. Every pixel's ray is cast against the road plane
and every object, and the nearest hit is kept, so the two views, the disparity, the road and object
masks and the lane ground truth are exact and consistent with each other.

Frames
------
World frame (one per frame): ``x`` right, ``y`` down, ``z`` ahead and horizontal, origin at the left
camera centre; the road is the plane ``y = height``. Camera-to-world rotation ``R = Rx(pitch) @
Rz(roll)``: the camera looks down by ``pitch`` (radians, positive = nose down) and is rolled by
``roll`` (radians, positive = clockwise as seen by the camera) about its optical axis; the right
camera sits ``baseline`` metres along the rig's x axis. The same convention as ``lanegraph_road``.

Road coordinates: ``s`` metres along the road from the sequence start, ``lateral`` metres across it
from the reference line (right positive), which is where the ego vehicle drives at frame 0.

The road's reference line, seen from the vehicle at frame ``k`` (travelled ``s_k = k * speed /
fps``, lateral offset ``e_k``), is the clothoid (small-angle form)

    x(z) = c_k z**2 / 2 + r z**3 / 6,   c_k = curvature + r * s_k,   r = curvature_rate

and a marking at lateral offset ``o`` lies at ``x = o + x(z) - e_k`` (metres), ``z`` metres ahead.
The vehicle stays parallel to the road (it changes lanes by a lateral shift only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from lanegraph.types import Calibration

from .layout import LATERAL_HALF, PAINT_RES, SHADOW_RES, WEAR_RES, build_tile, side_road_paved
from .objects import Box, Placed, Pole, intersect, place

#: the KITTI colour pair's calibration (1242 x 375), the default rig
from .spec import KITTI_CALIB, PRESETS, Marking, SceneSpec, preset  # noqa: F401 - as they were here

FINE_TEXEL = 0.04  # metres per texel of the fine asphalt texture (512 x 512, repeating)


RIP_LEVELS = 7  # levels of the fine texture's rip-map: footprints of 1 .. 64 texels along the road


COARSE_TEXEL = 0.40  # metres per texel of the coarse (patchy) asphalt texture (256 x 256)


ASPHALT = 92.0  # grey level of the asphalt


REPAIR_DARKEN = 0.3  # repair asphalt is this much darker than the road's


PAINT = 210.0  # grey level of white paint


VERGE = 100.0  # grey level of the ground beyond the paved road


ASPHALT_TINT = np.array([1.03, 1.0, 0.97], np.float32)  # BGR


VERGE_TINT = np.array([0.62, 1.0, 0.85], np.float32)


def _rotation(pitch: float, roll: float) -> np.ndarray:
    """Camera-to-world rotation: roll about the optical axis, then pitch (nose down) about x."""
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    rx = np.array([[1, 0, 0], [0, cp, sp], [0, -sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return rx @ rz


@dataclass
class Frame:
    """One rendered frame.

    ``left``/``right``: H x W x 3 uint8 BGR. ``disparity``: H x W float32, the exact disparity of the
    left view in pixels (0 on the sky); ``disparity_right`` the same for the right view (right pixel
    ``(u, v)`` sees what left pixel ``(u + d, v)`` sees). ``road_mask``/``object_mask``: H x W bool,
    left-view pixels whose nearest hit is the road plane / an object; ``paved_mask`` the road-plane
    pixels on the paved road (between its edges, not the verge beyond). ``lanes_gt``: the data
    README's ground-truth record. ``pitch``, ``roll`` in radians, ``height`` in metres.
    """

    index: int
    frame: str
    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    disparity_right: np.ndarray
    road_mask: np.ndarray
    object_mask: np.ndarray
    lanes_gt: dict
    calib: Calibration
    pitch: float
    roll: float
    height: float
    overexposed: bool = False
    paved_mask: np.ndarray | None = None


@dataclass
class _View:
    """Per-camera constants: ray origin and directions, and the road hits of rows ``v0:``."""

    origin: np.ndarray  # (3,) world
    rays: np.ndarray  # (3, H, W) float32, world direction per unit of camera depth
    v0: int
    X: np.ndarray  # (H - v0, W) float32 road hit, world metres
    Z: np.ndarray
    depth: np.ndarray  # camera depth of the road hit (inf: no road)
    fp_lat: np.ndarray  # metres per pixel across / along the road at the hit
    fp_long: np.ndarray
    fine_amp: np.ndarray  # amplitude of the fine texture (fades where it would alias)
    blend_lo: np.ndarray  # weight of the low-resolution paint map
    level: np.ndarray  # rip-map level of the fine texture (log2 of the footprint along the road in texels)


@dataclass
class _State:
    """Per-frame ego pose and objects."""

    k: int
    s: float  # travelled, metres
    e: float  # lateral offset of the vehicle, metres (right positive)
    c: float  # curvature at the vehicle, 1/m
    r: float  # curvature rate, 1/m**2
    placed: list[Placed]


class SceneRenderer:
    """Renders the frames of a :class:`SceneSpec`: ``render(k)`` gives frame ``k`` (at ``k / fps`` s).

    Per-pixel rays and their road hits are computed once; a frame costs shading and the objects.
    """

    def __init__(self, spec: SceneSpec | None = None):
        self.spec = s = spec or SceneSpec()
        self.calib = c = s.calib
        self.R = _rotation(s.pitch, s.roll)
        rng = np.random.default_rng([s.seed, 7])
        fine = cv2.GaussianBlur(rng.normal(0.0, 1.0, (512, 512)).astype(np.float32), (0, 0), 1.0)
        coarse = cv2.GaussianBlur(rng.normal(0.0, 1.0, (256, 256)).astype(np.float32), (0, 0), 2.0)
        self.tex_fine = fine / fine.std()
        self.tex_levels = _rip_levels(self.tex_fine)
        self.tex_coarse = coarse / coarse.std()
        self.markings, lane_centres, self.edges = self._layout(rng)
        self.tile = build_tile(s, [m.offset for m in self.markings], lane_centres, self.edges, rng)
        self.paint_lo = cv2.resize(self.tile.paint, None, fx=1 / 8, fy=1 / 8, interpolation=cv2.INTER_AREA)
        self.objects: list[Box | Pole] = list(self.tile.objects) + list(s.objects)
        self.colours = np.array([(0, 0, 0)] + [o.colour for o in self.objects], np.float32).reshape(-1, 3)
        self.views = [self._view(0.0), self._view(c.baseline)]
        n_px = c.height * c.width * 3
        self.noise_bank = rng.standard_normal(n_px + max(n_px // 2, 4096), dtype=np.float32)
        v = np.arange(c.height, dtype=np.float32)[:, None, None] / max(c.height - 1, 1)
        top, bottom = np.array([215, 170, 140], np.float32), np.array([245, 225, 210], np.float32)
        self.sky = np.broadcast_to(top + (bottom - top) * v, (c.height, c.width, 3)).astype(np.float32)

    # ------------------------------------------------------------------ set-up
    def _layout(self, rng) -> tuple[list[Marking], list[float], tuple[float, float]]:
        s = self.spec
        ego = s.n_lanes // 2 if s.ego_lane < 0 else s.ego_lane
        left = -(ego + 0.5) * s.lane_width
        offsets = [left + i * s.lane_width for i in range(s.n_lanes + 1)]
        centres = [o + s.lane_width / 2 for o in offsets[:-1]]
        edges = (offsets[0] - s.shoulder - s.gore_width, offsets[-1] + s.shoulder)
        if s.markings is not None:
            return [replace(m) for m in s.markings], centres, edges
        period = s.dash_length + s.gap_length
        marks = []
        if s.gore_width > 0:  # the gore area's far border (the hatching is drawn in the tile)
            marks.append(Marking(offsets[0] - s.gore_width, "solid", s.marking_width))
        for i, o in enumerate(offsets):
            kind = s.outer_kind if i in (0, s.n_lanes) else s.inner_kind
            phase = float(rng.uniform(0, period))
            marks.append(Marking(o, kind, s.marking_width, s.dash_length, s.gap_length, phase))
        return marks, centres, edges

    def _view(self, offset_x: float) -> _View:
        """Rays of the camera at ``offset_x`` metres along the rig's x axis and their road hits."""
        s, c = self.spec, self.calib
        v, u = np.mgrid[0 : c.height, 0 : c.width].astype(np.float64)
        d_cam = np.stack([(u - c.cx) / c.f, (v - c.cy) / c.f_y, np.ones_like(u)])
        rays = np.tensordot(self.R, d_cam, axes=1)
        origin = self.R @ np.array([offset_x, 0.0, 0.0])
        down = rays[1] > 1e-9
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(down, (s.height - origin[1]) / np.where(down, rays[1], 1.0), np.inf)
        X = origin[0] + np.where(down, t, 0.0) * rays[0]
        Z = origin[2] + np.where(down, t, 0.0) * rays[2]
        valid = down & (t > 0) & (Z < s.z_far) & (Z > 0)
        rows = np.flatnonzero(valid.any(axis=1))
        v0 = int(rows[0]) if rows.size else c.height
        depth = np.where(valid, t, np.inf)[v0:]
        X, Z, valid = X[v0:], Z[v0:], valid[v0:]
        Zc = np.where(valid, Z, s.z_far)
        fp_long = np.clip(np.abs(np.gradient(Zc, axis=0)) if Zc.shape[0] > 1 else 1.0, 1e-3, 50.0)
        fp_lat = np.where(valid, depth, s.z_far) / c.f
        # the fine texture is pre-averaged along the road to the pixel's footprint (a rip-map level,
        # see _rip_levels): it fades along the road as a camera would average it but keeps its
        # detail across the road, which stereo matching needs; across, it fades only where the
        # footprint outgrows the texel
        fine_amp = 1.0 / (1.0 + (fp_lat / (2 * FINE_TEXEL)) ** 2)
        level = np.clip(np.log2(np.maximum(fp_long / FINE_TEXEL, 1.0)), 0.0, RIP_LEVELS - 1.0)
        blend_lo = np.clip((fp_long - 0.1) / 0.3, 0.0, 1.0)
        f32 = np.float32
        return _View(
            origin, rays.astype(f32), v0, X.astype(f32), Zc.astype(f32), depth.astype(f32),
            fp_lat.astype(f32), fp_long.astype(f32), fine_amp.astype(f32), blend_lo.astype(f32),
            level.astype(f32),
        )  # fmt: skip

    # ------------------------------------------------------------------ per frame
    def ego_offset(self, k: int) -> float:
        """Lateral offset of the vehicle from the reference line at frame ``k``, metres."""
        s = self.spec
        t = k / s.fps
        e = s.lateral_speed * t
        if s.lane_change:
            x = min(max((t - s.lane_change_start) / s.lane_change_duration, 0.0), 1.0)
            e += s.lane_change * s.lane_width * x * x * (3 - 2 * x)
        return e

    def _state(self, k: int) -> _State:
        s = self.spec
        t = k / s.fps
        sk = s.speed * t
        st = _State(k, sk, self.ego_offset(k), s.curvature + s.curvature_rate * sk, s.curvature_rate, [])
        L = s.tile_length
        for i, o in enumerate(self.objects):
            z = o.s + o.speed * t - sk
            z = math.fmod(z + 60.0, L)
            z = (z + L if z < 0 else z) - 60.0
            ext = o.length / 2 if isinstance(o, Box) else o.radius
            if z + ext < 0.3 or z - ext > s.z_far:
                continue
            x = o.lateral + self.centre_x(z, st) - st.e
            heading = math.atan(st.c * z + st.r * z * z / 2)
            st.placed.append(place(i + 1, o, z, x, heading, s.height))
        return st

    @staticmethod
    def centre_x(z, st: _State):
        """Lateral position (metres) of the reference line ``z`` metres ahead, before the ego offset."""
        return st.c * z * z / 2 + st.r * z * z * z / 6

    def marking_x(self, m: Marking, z, k: int):
        """World lateral ``x`` (metres, camera-centred) of marking ``m`` at ``z`` metres ahead, frame ``k``."""
        st = self._state_light(k)
        return m.offset + self.centre_x(np.asarray(z, float), st) - st.e

    def _state_light(self, k: int) -> _State:
        s = self.spec
        sk = s.speed * k / s.fps
        return _State(k, sk, self.ego_offset(k), s.curvature + s.curvature_rate * sk, s.curvature_rate, [])

    def _roi(self, view: _View, p: Placed) -> tuple[slice, slice] | None:
        """Image rows/cols that may see ``p``: its bounding box's edges clipped to the space in front
        of the camera, projected. None when it is out of view."""
        c = self.calib
        near = 0.05
        a, b = ((e - view.origin) @ self.R for e in p.edges())  # camera coordinates, (12, 3) each
        keep = (a[:, 2] > near) | (b[:, 2] > near)
        if not keep.any():
            return None
        a, b = a[keep], b[keep]
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.clip((near - a[:, 2]) / (b[:, 2] - a[:, 2]), 0.0, 1.0)[:, None]
        a = np.where(a[:, 2:] < near, a + w * (b - a), a)
        b = np.where(b[:, 2:] < near, b + (1 - w) * (a - b), b)
        q = np.concatenate([a, b])
        u = c.f * q[:, 0] / q[:, 2] + c.cx
        v = c.f_y * q[:, 1] / q[:, 2] + c.cy
        c0, c1 = max(int(math.floor(u.min())) - 1, 0), min(int(math.ceil(u.max())) + 2, c.width)
        r0, r1 = max(int(math.floor(v.min())) - 1, 0), min(int(math.ceil(v.max())) + 2, c.height)
        if c0 >= c1 or r0 >= r1:
            return None
        return slice(r0, r1), slice(c0, c1)

    def _cast(self, view: _View, st: _State):
        """Depth test of the road and all objects: (depth, label, shade, bbox); label -1 sky, 0 road,
        i > 0 object ``i - 1`` of ``self.objects``; bbox the rows/cols holding every object pixel."""
        c = self.calib
        depth = np.full((c.height, c.width), np.inf, np.float32)
        depth[view.v0 :] = view.depth
        label = np.where(np.isfinite(depth), 0, -1).astype(np.int16)
        shade = np.zeros((c.height, c.width), np.float32)
        box = [c.height, 0, c.width, 0]
        for p in st.placed:
            roi = self._roi(view, p)
            if roi is None:
                continue
            rs, cs = roi
            t, sh, ta, tb = intersect(view.origin, view.rays[:, rs, cs], p)
            cur = depth[rs, cs]
            win = t < cur
            if not win.any():
                continue
            tu = np.mod(ta * np.float32(1 / 0.03), 512).astype(np.float32)
            tv = np.mod(tb * np.float32(1 / 0.03), 512).astype(np.float32)
            tex = cv2.remap(self.tex_fine, tu, tv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
            np.copyto(cur, t, where=win)
            np.copyto(label[rs, cs], np.int16(p.index), where=win)
            np.copyto(shade[rs, cs], sh * (1.0 + np.float32(0.1) * tex), where=win)
            box = [min(box[0], rs.start), max(box[1], rs.stop), min(box[2], cs.start), max(box[3], cs.stop)]
        return depth, label, shade, box

    def _lateral(self, view: _View, st: _State) -> np.ndarray:
        """Lateral position of the road hits of rows ``v0:`` across the (curved) road, metres."""
        Z = view.Z
        return view.X - (np.float32(st.c / 2) * Z * Z + np.float32(st.r / 6) * Z * Z * Z) + np.float32(st.e)

    def _paved(self, lat: np.ndarray, Z: np.ndarray, st: _State) -> np.ndarray:
        """True where the road hits (``lat`` across, ``Z`` ahead, metres) are paved: between the
        road's edges or on a side road."""
        paved = (lat >= self.edges[0]) & (lat <= self.edges[1])
        if self.spec.side_roads or self.spec.side_roads_left:
            L = self.spec.tile_length
            s_tile = np.mod(Z + np.float32(math.fmod(st.s, L)), np.float32(L))
            paved |= side_road_paved(self.spec, lat, s_tile, self.edges)
        return paved

    def _shade_road(self, view: _View, st: _State) -> np.ndarray:
        """BGR float32 of the road plane for rows ``v0:`` (paint, texture, shadows)."""
        s = self.spec
        Z = view.Z
        lat = self._lateral(view, st)
        # asphalt: a fine texture (fading out where it would alias) and large patches
        per_f, per_c = 512 * FINE_TEXEL, 256 * COARSE_TEXEL
        tu = np.mod(lat, per_f) * np.float32(1 / FINE_TEXEL)
        tv = np.mod(Z + np.float32(math.fmod(st.s, per_f)), per_f) * np.float32(1 / FINE_TEXEL)
        fine = self._fine(tu, tv, view)
        tu = np.mod(lat, per_c) * np.float32(1 / COARSE_TEXEL)
        tv = np.mod(Z + np.float32(math.fmod(st.s, per_c)), per_c) * np.float32(1 / COARSE_TEXEL)
        coarse = cv2.remap(self.tex_coarse, tu, tv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        verge = ~self._paved(lat, Z, st)
        base = np.where(verge, np.float32(VERGE), np.float32(ASPHALT))
        tc = np.where(verge, np.float32(s.texture_contrast * s.verge_texture), np.float32(s.texture_contrast))
        lum = base + tc * (fine + np.float32(0.7) * coarse)
        # lane markings: exact coverage of the pixel footprint (a box filter) across and along
        paint = np.zeros_like(lum)
        L = s.tile_length
        s_tile_w = Z + np.float32(math.fmod(st.s, L))
        s_tile_w = np.where(s_tile_w >= L, s_tile_w - np.float32(L), s_tile_w)
        for i_m, m in enumerate(self.markings):
            cov = (
                np.float32(m.width / 2) + view.fp_lat / 2 - np.abs(lat - np.float32(m.offset))
            ) / view.fp_lat
            np.clip(cov, 0.0, 1.0, out=cov)
            if m.kind == "dashed":
                cov *= _dash_cover(Z, st.s - m.phase, m.dash, m.gap, view.fp_long)
            if self.tile.wear is not None:  # worn through: gaps along the marking
                gaps = self.tile.wear[min(i_m, self.tile.wear.shape[0] - 1)]
                cov *= gaps[np.clip((s_tile_w / np.float32(WEAR_RES)).astype(np.int32), 0, gaps.size - 1)]
            np.maximum(paint, cov, out=paint)
        # arrows and hatching from the tile's paint map, shadows from its shadow map
        L = s.tile_length
        s_tile = Z + np.float32(math.fmod(st.s, L))
        s_tile = np.where(s_tile >= L, s_tile - np.float32(L), s_tile)
        col = np.clip(
            (lat + np.float32(LATERAL_HALF)) / np.float32(PAINT_RES) - 0.5, -2, self.tile.paint.shape[1] + 1
        )
        row = s_tile / np.float32(PAINT_RES) - 0.5
        pm = cv2.remap(self.tile.paint, col, row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        pm_lo = cv2.remap(self.paint_lo, (col + 0.5) / 8 - 0.5, (row + 0.5) / 8 - 0.5, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT)  # fmt: skip
        pmf = (pm + view.blend_lo * (pm_lo.astype(np.float32) - pm)) * np.float32(1 / 255)
        np.maximum(paint, pmf, out=paint)
        r = PAINT_RES / SHADOW_RES
        if self.tile.repair is not None:  # darker repair asphalt, laid over the paint
            rep = cv2.remap(self.tile.repair, (col + 0.5) * r - 0.5, (row + 0.5) * r - 0.5, cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_CONSTANT) * np.float32(1 / 255)  # fmt: skip
            lum *= 1.0 - np.float32(REPAIR_DARKEN) * rep
            paint *= 1.0 - rep
        if s.paint_wear > 0:
            paint *= np.float32(1.0 - s.paint_wear)
        lum += paint * (np.float32(PAINT) + np.float32(0.4 * s.texture_contrast) * fine - lum)
        sh = cv2.remap(self.tile.shadow, (col + 0.5) * r - 0.5, (row + 0.5) * r - 0.5, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT)  # fmt: skip
        lum *= 1.0 - np.float32(s.shadow_strength / 255) * sh
        tint = np.where(verge[..., None], VERGE_TINT, ASPHALT_TINT)
        return lum[..., None] * tint

    def _fine(self, tu: np.ndarray, tv: np.ndarray, view: _View) -> np.ndarray:
        """The fine asphalt texture at texel coordinates, from the two rip-map levels around each
        pixel's level (rows are grouped by level, so each row is sampled at most twice)."""
        out = np.zeros(tu.shape, np.float32)
        lev = view.level
        lo = np.floor(lev).astype(np.int16)
        w = lev - lo
        row_min, row_max = lo.min(axis=1), lo.max(axis=1)
        for k in range(RIP_LEVELS):
            rows = np.flatnonzero((row_min <= k) & (row_max >= k - 1))
            if rows.size == 0:
                continue
            r0, r1 = int(rows[0]), int(rows[-1]) + 1
            sample = cv2.remap(
                self.tex_levels[k], tu[r0:r1], tv[r0:r1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP
            )
            lk, wk = lo[r0:r1], w[r0:r1]
            weight = np.where(lk == k, 1.0 - wk, 0.0) + np.where(lk == k - 1, wk, 0.0)
            out[r0:r1] += weight.astype(np.float32) * sample
        return out * view.fine_amp

    def _image(self, view: _View, st: _State, cast, noise_key: int) -> np.ndarray:
        s = self.spec
        depth, label, shade, box = cast
        img = self.sky.copy()
        road = (label[view.v0 :] == 0)[..., None]
        np.copyto(img[view.v0 :], self._shade_road(view, st), where=road)
        r0, r1, c0, c1 = box
        if r0 < r1:
            lab = label[r0:r1, c0:c1]
            col = self.colours[np.maximum(lab, 0)] * shade[r0:r1, c0:c1, None]
            np.copyto(img[r0:r1, c0:c1], col, where=(lab > 0)[..., None])
        if s.blur_sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), s.blur_sigma)
        gain, bias = (s.exposure_gain, 12.0) if s.is_overexposed(st.k) else (1.0, 0.0)
        if noise_key == 1:
            gain *= s.right_gain
        if gain != 1.0 or bias:
            img = cv2.addWeighted(img, gain, img, 0.0, bias)
        if s.noise_sigma > 0:
            # sensor noise: a window of a fixed bank of normal samples, chosen per frame and camera
            rng = np.random.default_rng([s.seed, st.k, noise_key])
            start = int(rng.integers(0, self.noise_bank.size - img.size + 1))
            img += self.noise_bank[start : start + img.size].reshape(img.shape) * np.float32(s.noise_sigma)
        return np.clip(img, 0, 255, out=img).astype(np.uint8)

    def render(self, k: int = 0) -> Frame:
        """Frame ``k`` of the sequence: both views, exact disparity, masks and lane ground truth."""
        s, c = self.spec, self.calib
        st = self._state(k)
        casts = [self._cast(v, st) for v in self.views]
        imgs = [
            self._image(v, st, cast, i) for i, (v, cast) in enumerate(zip(self.views, casts, strict=True))
        ]
        fb = np.float32(c.f * c.baseline)
        disp = [np.where(np.isfinite(cast[0]), fb / cast[0], 0.0).astype(np.float32) for cast in casts]
        label = casts[0][1]
        lat = self._lateral(self.views[0], st)
        paved = np.zeros_like(label, dtype=bool)
        paved[self.views[0].v0 :] = self._paved(lat, self.views[0].Z, st)
        return Frame(
            index=k,
            frame=f"{k:010d}",
            left=imgs[0],
            right=imgs[1],
            disparity=disp[0],
            disparity_right=disp[1],
            road_mask=label == 0,
            object_mask=label > 0,
            paved_mask=paved & (label == 0),
            lanes_gt=self._lanes_gt(st, casts[0]),
            calib=c,
            pitch=s.pitch,
            roll=s.roll,
            height=s.height,
            overexposed=s.is_overexposed(k),
        )

    # ------------------------------------------------------------------ ground truth
    def project(self, X: np.ndarray, Z: np.ndarray) -> np.ndarray:
        """Road points (world ``X``, ``Z`` metres, on ``y = height``) -> left-image pixels (x, y), N x 2."""
        return self._project(np.asarray(X, float), np.asarray(Z, float))[0]

    def _project(self, X: np.ndarray, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = self.calib
        P = np.stack([X, np.full_like(X, self.spec.height), Z])
        q = self.R.T @ P
        with np.errstate(divide="ignore", invalid="ignore"):
            pts = np.stack([c.f * q[0] / q[2] + c.cx, c.f_y * q[1] / q[2] + c.cy], axis=1)
        return pts, q[2]

    def lanes_gt(self, k: int = 0) -> dict:
        """The ground truth of frame ``k`` in the data README's format (see :meth:`render`)."""
        st = self._state(k)
        return self._lanes_gt(st, self._cast(self.views[0], st))

    def _lanes_gt(self, st: _State, cast) -> dict:
        """Markings' centre lines at rows multiple of 10, from the bottom of the image up to
        ``gt_max_distance``, where they are inside the image and not hidden by an object."""
        c, s = self.calib, self.spec
        depth, label = cast[0], cast[1]
        z = np.geomspace(0.5, s.gt_max_distance, 1500)
        cen = self.centre_x(z, st)
        markings, near_x = [], {}
        for i, m in enumerate(self.markings):
            X = m.offset + cen - st.e
            near_x[i] = m.offset - st.e
            pts, qz = self._project(X, z)
            inside = (qz > 0.1) & (pts[:, 0] >= 0) & (pts[:, 0] <= c.width - 1)
            inside &= (pts[:, 1] >= 0) & (pts[:, 1] <= c.height - 1)
            idx = np.flatnonzero(inside)
            if idx.size < 2:
                continue
            stop = np.flatnonzero(~inside[idx[0] :])
            run = slice(idx[0], idx[0] + (stop[0] if stop.size else inside.size))
            px, py, pd = pts[run, 0], pts[run, 1], qz[run]
            order = np.argsort(py)
            px, py, pd = px[order], py[order], pd[order]
            rows = np.arange(math.ceil(py[0] / 10) * 10, math.floor(py[-1]) + 1, 10)
            if rows.size == 0:
                continue
            xs = np.interp(rows, py, px)
            ds = np.interp(rows, py, pd)
            ci = np.clip(np.round(xs).astype(int), 0, c.width - 1)
            hidden = (label[rows, ci] > 0) & (depth[rows, ci] < ds - 0.05)
            points = [
                [round(float(x), 2), int(y)]
                for x, y, h in zip(xs[::-1], rows[::-1], hidden[::-1], strict=True)
                if not h
            ]
            if len(points) >= 2:
                markings.append({"id": i, "kind": m.kind, "points": points})
        shown = {m["id"] for m in markings}
        left = [i for i, x in near_x.items() if x < 0]
        right = [i for i, x in near_x.items() if x >= 0]
        ego_l = max(left, key=near_x.get) if left else None
        ego_r = min(right, key=near_x.get) if right else None
        ego = {"left": ego_l if ego_l in shown else None, "right": ego_r if ego_r in shown else None}
        return {"frame": f"{st.k:010d}", "image_size": [c.width, c.height], "markings": markings, "ego": ego}


def _rip_levels(tex: np.ndarray) -> list[np.ndarray]:
    """``tex`` box-averaged along its rows axis (the road's direction) over 1, 2, 4 ... texels,
    wrapping. Averaging lowers the contrast as a camera's footprint does, but only by the fourth
    root of the footprint (real asphalt has detail at every scale), not the square root of white
    noise."""
    levels = [tex]
    for k in range(1, RIP_LEVELS):
        n = 2**k
        c = np.cumsum(np.vstack([tex[-n:], tex]), axis=0, dtype=np.float64)  # a wrapping box sum
        avg = (c[n:] - c[:-n]) / n
        avg = avg / max(float(avg.std()), 1e-6) * (n**-0.25)
        levels.append(np.ascontiguousarray(avg, dtype=np.float32))  # RIP_LEVELS - 1 < log2(512)
    return levels


def _dash_cover(Z: np.ndarray, s0: float, dash: float, gap: float, fp: np.ndarray) -> np.ndarray:
    """Fraction of each pixel's footprint (``fp`` metres long, centred on ``s0 + Z``) that falls on
    the dashes ``[n (dash + gap), n (dash + gap) + dash]``."""
    period = dash + gap
    p = np.mod(Z + np.float32(math.fmod(s0, period)), np.float32(period))
    h = fp / 2
    cover = np.zeros_like(Z)
    for shift in (0.0, -period, period):
        q = p + np.float32(shift)
        cover += np.clip(np.minimum(q + h, np.float32(dash)) - np.maximum(q - h, 0.0), 0.0, None)
    cover /= fp
    return np.clip(cover, 0.0, 1.0, out=cover)
