"""An unrectified stereo calibration (both cameras' intrinsics and distortion, the pose between them,
or the rectification a calibration tool already worked out) and the rectification it implies.

``StereoCalibration`` is what the calibration readers of :mod:`lanegraph_io._calibfiles` return and
what travels on a ``stereo_calibration`` port; :class:`Rectifier` holds the two cameras' remap
tables, computed once (``cv2.stereoRectify`` when the file gives only ``R``, ``T``; the file's own
``R1``/``P1``, ``R2``/``P2`` otherwise) and the rectified :class:`~lanegraph.types.Calibration` that
the rectified images have.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from lanegraph.errors import InputError
from lanegraph.types import BASELINE_RANGE_M, Calibration

from ._calib import calibration_from_projections, check_calibration


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """Two cameras of a stereo rig as a calibration tool gives them.

    Attributes
    ----------
    K1, K2 : ndarray, shape (3, 3)
        Camera matrices of the left and right camera, pixels.
    D1, D2 : ndarray, shape (N,)
        Distortion coefficients (OpenCV's order: k1, k2, p1, p2[, k3[, k4, k5, k6]]); empty: none.
    R, T : ndarray, shape (3, 3) and (3,), or None
        The right camera's pose: ``x_right = R x_left + T``, ``T`` in metres.
    R1, R2 : ndarray, shape (3, 3), or None
        Rectification rotations, when the file gives them (``stereoRectify``, ROS ``R``).
    P1, P2 : ndarray, shape (3, 4), or None
        Rectified projection matrices, when the file gives them.
    width, height : int
        Image size in pixels (0 when the file does not say; the frames then tell).
    path : str
        The file(s) it was read from, for messages.
    names : dict
        Field -> the key in the file that holds it, for messages.
    """

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray | None = None
    T: np.ndarray | None = None
    R1: np.ndarray | None = None
    R2: np.ndarray | None = None
    P1: np.ndarray | None = None
    P2: np.ndarray | None = None
    width: int = 0
    height: int = 0
    path: str = ""
    names: dict[str, str] = field(default_factory=dict)

    def name(self, key: str) -> str:
        return self.names.get(key, key)

    def with_size(self, width: int, height: int) -> StereoCalibration:
        return replace(self, width=int(width), height=int(height))

    def is_rectified(self) -> bool:
        """Whether the images are rectified as they are: no distortion, no rectification rotation,
        both cameras' matrices equal to the rectified projection's."""
        if np.any(self.D1 != 0) or np.any(self.D2 != 0):
            return False
        eye = np.eye(3)
        if self.P1 is not None and self.P2 is not None:
            rots = [r for r in (self.R1, self.R2) if r is not None]
            return (
                all(np.allclose(r, eye, atol=1e-9) for r in rots)
                and np.allclose(self.K1, self.P1[:, :3], rtol=1e-9, atol=1e-9)
                and np.allclose(self.K2, self.P2[:, :3], rtol=1e-9, atol=1e-9)
            )
        if self.R is None or self.T is None:
            return False
        t = np.asarray(self.T, dtype=np.float64)
        return (
            np.allclose(self.R, eye, atol=1e-9)
            and abs(t[1]) < 1e-9
            and abs(t[2]) < 1e-9
            and np.allclose(self.K1, self.K2, rtol=1e-9, atol=1e-9)
        )

    def check(
        self, frame_size: tuple[int, int] | None, baseline_range_m: tuple[float, float] = BASELINE_RANGE_M
    ) -> StereoCalibration:
        """Refuse what cannot be a stereo rig (each problem named with the file and key): a focal
        length <= 0, a non-finite value, a baseline outside ``baseline_range_m``, an image size that
        disagrees with ``frame_size`` (``(width, height)`` of the frames). Returns the calibration
        with the frames' size when the file gives none."""
        problems = []
        for key in ("K1", "K2"):
            k = getattr(self, key)
            if not np.isfinite(k).all():
                problems.append(f"{self.name(key)}: must hold finite numbers")
                continue
            for i, axis in ((0, "fx"), (1, "fy")):
                if k[i, i] <= 0:
                    problems.append(
                        f"{self.name(key)}: focal length {axis} ({key}[{i},{i}]) must be > 0 pixels, got {k[i, i]:g}"
                    )
        for key in ("D1", "D2", "R", "T", "R1", "R2", "P1", "P2"):
            v = getattr(self, key)
            if v is not None and not np.isfinite(v).all():
                problems.append(f"{self.name(key)}: must hold finite numbers")
        lo, hi = baseline_range_m
        if self.T is not None and np.isfinite(self.T).all():
            b = float(np.linalg.norm(self.T))
            if not (lo <= b <= hi):
                what = "zero" if b == 0 else f"{b:.4g} m"
                hint = (
                    f" (millimetres? T is in metres: {b / 1000:g})"
                    if lo <= b / 1000 <= hi
                    else "; a source's min_baseline_m / max_baseline_m widen the range"
                )
                problems.append(
                    f"{self.name('T')}: the baseline (|T|) is {what}, expected a plausible {lo}-{hi} m{hint}"
                )
        if self.T is None and (self.P1 is None or self.P2 is None):
            problems.append(
                f"{self.name('T')}: missing: expected the right camera's pose (R, T) or the rectified projections (P1, P2)"
            )
        size = (self.width, self.height)
        if frame_size is not None and self.width and size != tuple(frame_size):
            problems.append(
                f"{self.name('width')}: the calibration is for {self.width}x{self.height} images, "
                f"the frames are {frame_size[0]}x{frame_size[1]}"
            )
        if problems:
            raise InputError(f"implausible calibration: {'; '.join(problems)}", path=self.path)
        if not self.width and frame_size is not None:
            return self.with_size(*frame_size)
        return self


class Rectifier:
    """The remap tables of a :class:`StereoCalibration` (computed once) and the rectified
    :class:`~lanegraph.types.Calibration` of the images it makes.

    ``identity`` is true when the images are rectified already: they then pass unchanged.
    """

    def __init__(
        self, stereo: StereoCalibration, baseline_range_m: tuple[float, float] = BASELINE_RANGE_M
    ) -> None:
        if not (stereo.width and stereo.height):
            raise InputError("the calibration's image size is unknown (check() it with the frames' size)")
        self.stereo = stereo
        size = (stereo.width, stereo.height)
        self.identity = stereo.is_rectified()
        if stereo.P1 is not None and stereo.P2 is not None:
            r1 = stereo.R1 if stereo.R1 is not None else np.eye(3)
            r2 = stereo.R2 if stereo.R2 is not None else np.eye(3)
            p1, p2 = stereo.P1, stereo.P2
        else:
            r1, r2, p1, p2, *_ = cv2.stereoRectify(
                stereo.K1, stereo.D1, stereo.K2, stereo.D2, size, stereo.R,
                np.asarray(stereo.T, np.float64).reshape(3, 1),
                flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0,
            )  # fmt: skip
        names = (stereo.name("P1"), stereo.name("P2"))
        try:
            calib = calibration_from_projections(
                np.asarray(p1, np.float64), np.asarray(p2, np.float64), Path(stereo.path),
                width=stereo.width, height=stereo.height, keys=names,
            )  # fmt: skip
        except InputError as exc:
            raise InputError(f"the rectified projections: {exc}") from None
        check_calibration(calib, stereo.path, {"baseline": names[1]}, baseline_range_m)
        self.calib: Calibration = calib
        self.maps = None
        if not self.identity:
            self.maps = [
                cv2.initUndistortRectifyMap(k, d, r, p, size, cv2.CV_16SC2)
                for k, d, r, p in ((stereo.K1, stereo.D1, r1, p1), (stereo.K2, stereo.D2, r2, p2))
            ]

    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rectified pair (the same arrays when the input is rectified already)."""
        if self.maps is None:
            return left, right
        want = (self.stereo.height, self.stereo.width)
        for side, img in (("left", left), ("right", right)):
            if img.shape[:2] != want:
                raise InputError(
                    f"the {side} image is {img.shape[1]}x{img.shape[0]}, the calibration expects "
                    f"{want[1]}x{want[0]}",
                    path=self.stereo.path,
                )
        (a1, b1), (a2, b2) = self.maps
        return (
            cv2.remap(left, a1, b1, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT),
            cv2.remap(right, a2, b2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT),
        )


def unrectify(
    stereo: StereoCalibration, rectified: Calibration, left: np.ndarray, right: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The raw pair that the cameras of ``stereo`` would have seen of the rectified pair ``left``,
    ``right`` (made with ``rectified``): each raw pixel looks up the rectified pixel its ray goes
    through (``cv2.undistortPoints`` with the rectification ``R1``/``P1``, ``R2``/``P2``). The
    inverse of :class:`Rectifier`, up to interpolation: test data and the docs' recordings."""
    h, w = left.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1).reshape(-1, 1, 2)
    out = []
    for img, k, d, r, p in (
        (left, stereo.K1, stereo.D1, stereo.R1, stereo.P1),
        (right, stereo.K2, stereo.D2, stereo.R2, stereo.P2),
    ):
        if p is None:
            raise ValueError("unrectify: the calibration must give the rectified projections P1, P2")
        rect = cv2.undistortPoints(pts, k, d, R=r if r is not None else np.eye(3), P=p)
        mx = rect[:, 0, 0].reshape(h, w).astype(np.float32)
        my = rect[:, 0, 1].reshape(h, w).astype(np.float32)
        out.append(cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
    return out[0], out[1]


def example_rig(
    rectified: Calibration, *, distortion: float = -0.12, angle_deg: float = 0.6
) -> StereoCalibration:
    """A plausible unrectified rig whose rectification gives ``rectified`` exactly: both cameras
    with radial and tangential distortion, camera matrices a few per cent off the rectified one,
    and each camera turned by ``angle_deg`` about a different axis (the rectification rotations
    ``R1``, ``R2``). Test data and the docs' example recordings."""
    f, cx, cy, b = rectified.f, rectified.cx, rectified.cy, rectified.baseline
    p1 = np.array([[f, 0, cx, 0], [0, rectified.f_y, cy, 0], [0, 0, 1, 0]], np.float64)
    p2 = p1.copy()
    p2[0, 3] = -f * b
    a = np.deg2rad(angle_deg)
    r1, _ = cv2.Rodrigues(np.array([a, -0.5 * a, 0.3 * a]))
    r2, _ = cv2.Rodrigues(np.array([-0.4 * a, a, -0.6 * a]))
    k1 = np.array([[f * 1.03, 0, cx + 6.0], [0, rectified.f_y * 1.03, cy - 4.0], [0, 0, 1]])
    k2 = np.array([[f * 0.98, 0, cx - 5.0], [0, rectified.f_y * 0.98, cy + 3.0], [0, 0, 1]])
    d1 = np.array([distortion, 0.05, 0.001, -0.0008, 0.0])
    d2 = np.array([0.8 * distortion, 0.03, -0.0006, 0.0009, 0.0])
    # the pose between the raw cameras that these rectifications imply: x_r = R x_l + T
    r = r2.T @ r1
    t = r2.T @ np.array([-b, 0.0, 0.0])
    return StereoCalibration(
        K1=k1, D1=d1, K2=k2, D2=d2, R=r, T=t, R1=r1, R2=r2, P1=p1, P2=p2,
        width=rectified.width, height=rectified.height,
    )  # fmt: skip
