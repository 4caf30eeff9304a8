"""Synthetic stereo road scenes with exact ground truth (deterministic from a seed).

A planar road seen by a rectified stereo rig of known calibration, pitch, roll and height. Each
image pixel's ray is intersected with the road plane analytically, so the rendered pair, the
ground-truth disparity and the ground-truth lanes are exact.

World frame: x right, y down, z ahead, origin at the left camera centre; the road is the plane
``y = height``. The camera looks down by ``pitch`` (radians, positive = nose down) and is rolled
by ``roll`` (radians, positive = clockwise as seen by the camera) about its optical axis.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from lanegraph.types import Calibration


@dataclass
class Marking:
    """A longitudinal marking: lateral offset ``x0`` (m) at z=0, ``curvature`` (1/m), width (m),
    dashed or solid (dash length / gap in metres)."""

    x0: float
    kind: str = "solid"
    width: float = 0.15
    curvature: float = 0.0
    dash: float = 3.0
    gap: float = 6.0

    def x_at(self, z: np.ndarray) -> np.ndarray:
        return self.x0 + 0.5 * self.curvature * z * z


@dataclass
class SceneSpec:
    """Parameters of a synthetic scene."""

    calib: Calibration = field(
        default_factory=lambda: Calibration(f=721.5, cx=620.0, cy=180.0, baseline=0.54, width=1242, height=375)
    )
    pitch_deg: float = 1.0
    roll_deg: float = 0.0
    height: float = 1.65
    markings: list[Marking] = field(
        default_factory=lambda: [Marking(-5.4, "solid"), Marking(-1.8, "dashed"), Marking(1.8, "dashed"), Marking(5.4, "solid")]
    )
    speed: float = 10.0  # m/s, ego motion along z
    fps: float = 10.0
    noise_sigma: float = 3.0
    seed: int = 0


def _rotation(pitch: float, roll: float) -> np.ndarray:
    """Camera-to-world rotation: roll about the optical axis, then pitch (nose down) about x."""
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    rx = np.array([[1, 0, 0], [0, cp, sp], [0, -sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return rx @ rz


@dataclass
class Frame:
    """One rendered frame: BGR images, the exact disparity (0 off the road), lanes and calibration."""

    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    lanes_gt: dict
    calib: Calibration


class SceneRenderer:
    """Renders frames of a :class:`SceneSpec`; ``render(k)`` gives frame ``k`` of the sequence."""

    def __init__(self, spec: SceneSpec | None = None):
        self.spec = spec or SceneSpec()
        rng = np.random.default_rng(self.spec.seed)
        tex = rng.normal(0.0, 1.0, (512, 512)).astype(np.float32)
        tex = cv2.GaussianBlur(tex, (0, 0), 1.2)
        self.texture = (tex / (tex.std() + 1e-6)).astype(np.float32)
        self.R = _rotation(np.radians(self.spec.pitch_deg), np.radians(self.spec.roll_deg))

    def _road_hits(self, offset_x: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, Z, depth) of the road point seen by each pixel of a camera at ``offset_x`` (m, along the
        rig's x axis); depth is the camera-frame z (inf where the ray misses the road)."""
        c = self.spec.calib
        v, u = np.mgrid[0 : c.height, 0 : c.width].astype(np.float64)
        d_cam = np.stack([(u - c.cx) / c.f, (v - c.cy) / c.f_y, np.ones_like(u)])
        d_w = np.tensordot(self.R, d_cam, axes=1)
        origin = self.R @ np.array([offset_x, 0.0, 0.0])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.spec.height - origin[1]) / d_w[1]
        miss = (d_w[1] <= 1e-6) | ~(t > 0)
        t_hit = np.where(miss, 1e6, t)
        X = origin[0] + t_hit * d_w[0]
        Z = origin[2] + t_hit * d_w[2]
        t[miss] = np.inf
        return X, Z, t

    def _shade(self, X: np.ndarray, Z: np.ndarray, depth: np.ndarray, travelled: float) -> np.ndarray:
        s = self.spec
        road = np.isfinite(depth) & (Z < 150)
        Zw = Z + travelled
        img = np.full(X.shape, 95.0, dtype=np.float32)
        # asphalt texture, 4 cm per texel, tiled
        tu = np.where(road, np.mod(X / 0.04, 512), 0).astype(np.float32)
        tv = np.where(road, np.mod(Zw / 0.04, 512), 0).astype(np.float32)
        tex = cv2.remap(self.texture, tu, tv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        img += 10.0 * tex
        for m in s.markings:
            # pixel footprint for anti-aliasing: metres per pixel laterally at this depth
            fp = np.clip(np.where(road, depth, 1.0) / s.calib.f, 1e-3, 1e3)
            dist = np.abs(X - m.x_at(Z))
            cover = np.clip((m.width / 2 + fp / 2 - dist) / fp, 0.0, 1.0)
            if m.kind == "dashed":
                phase = np.mod(Zw, m.dash + m.gap)
                cover = cover * (phase < m.dash)
            img = img * (1 - cover) + 210.0 * cover
        sky_v = np.linspace(235, 170, X.shape[0], dtype=np.float32)[:, None]
        img = np.where(road, img, sky_v)
        return img

    def render(self, k: int = 0) -> Frame:
        s = self.spec
        c = s.calib
        travelled = k * s.speed / s.fps
        rng = np.random.default_rng(s.seed * 100003 + k)
        XL, ZL, tL = self._road_hits(0.0)
        XR, ZR, tR = self._road_hits(c.baseline)
        imgs = []
        for X, Z, t in ((XL, ZL, tL), (XR, ZR, tR)):
            g = self._shade(X, Z, t, travelled) + rng.normal(0, s.noise_sigma, X.shape)
            g8 = np.clip(g, 0, 255).astype(np.uint8)
            imgs.append(cv2.cvtColor(g8, cv2.COLOR_GRAY2BGR))
        disp = np.where(np.isfinite(tL) & (ZL < 150), c.f * c.baseline / tL, 0.0).astype(np.float32)
        return Frame(imgs[0], imgs[1], disp, self.lanes_gt(k), c)

    def project(self, X: np.ndarray, Z: np.ndarray) -> np.ndarray:
        """World road points (X, Z) -> left-image pixels (x, y), N x 2."""
        c = self.spec.calib
        P = np.stack([X, np.full_like(X, self.spec.height), Z])
        q = self.R.T @ P
        return np.stack([c.f * q[0] / q[2] + c.cx, c.f_y * q[1] / q[2] + c.cy], axis=1)

    def lanes_gt(self, k: int = 0) -> dict:
        """Ground truth in the data README's format (points at rows multiple of 10)."""
        c = self.spec.calib
        z = np.linspace(4.0, 60.0, 800)
        markings, xs_bottom = [], []
        for i, m in enumerate(self.spec.markings):
            pts = self.project(m.x_at(z), z)
            ok = (pts[:, 0] >= 0) & (pts[:, 0] < c.width) & (pts[:, 1] >= 0) & (pts[:, 1] < c.height)
            if ok.sum() < 2:
                continue
            px, py = pts[ok, 0], pts[ok, 1]
            order = np.argsort(py)
            px, py = px[order], py[order]
            rows = np.arange(np.ceil(py[0] / 10) * 10, py[-1] + 1e-9, 10)
            xs = np.interp(rows, py, px)
            points = [[round(float(x), 1), int(y)] for x, y in zip(xs[::-1], rows[::-1])]
            if len(points) >= 2:
                markings.append({"id": i, "kind": m.kind, "points": points})
                xs_bottom.append((i, m.x0))
        left = [i for i, x in xs_bottom if x < 0]
        right = [i for i, x in xs_bottom if x >= 0]
        ego = {
            "left": max(left, key=lambda i: self.spec.markings[i].x0) if left else None,
            "right": min(right, key=lambda i: self.spec.markings[i].x0) if right else None,
        }
        return {"frame": f"{k:010d}", "image_size": [c.width, c.height], "markings": markings, "ego": ego}
