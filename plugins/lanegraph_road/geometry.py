"""Road-plane geometry shared by the road nodes: pose from the v-disparity profile, the road
plane's disparity, heights above the road and the image <-> road homography.

Conventions
-----------
Camera frame: ``X`` right, ``Y`` down, ``Z`` along the optical axis (OpenCV). World frame: ``x``
right, ``y`` down, ``z`` ahead and horizontal, origin at the left camera centre; the road is the
plane ``y = h`` (``h`` = camera height above the road, metres).

* **pitch** ``theta`` (radians): positive when the camera looks *down* (nose down); the horizon is
  then *above* the principal point, ``v_horizon = cy - fy * tan(theta)``.
* **roll** ``phi`` (radians): rotation about the optical axis, positive clockwise as seen by the
  camera (its right side down); the road then comes closer (larger disparity) on the right of the
  image and the horizon rises to the right.

Both together: the road's unit normal (pointing down, into the road) in camera coordinates is
``n = (cos(theta) sin(phi), cos(theta) cos(phi), sin(theta))`` and the road is ``n . P = h``
(the same convention as ``lanegraph_synthetic``: camera-to-world ``R = Rx(pitch) @ Rz(roll)``).

Disparity of the road plane
---------------------------
A pixel ``(u, v)`` with disparity ``d`` is the point ``P = (B/d) * ((u-cx) f/f, (v-cy) f/fy, f)``
(``Z = f B / d``). On the road ``n . P = h``, hence

    d_road(u, v) = (B / h) * (nx (u - cx) + ny (f/fy) (v - cy) + nz f).          (1)

Rotating the image about the principal point by the roll, i.e. using the *roll-corrected row*

    v' = cy + sin(phi) (fy/f) (u - cx) + cos(phi) (v - cy),                      (2)

removes the ``u`` term: ``d_road = (f B cos(theta) / (fy h)) * (v' - cy + fy tan(theta))``.
So the v-disparity road profile in ``v'`` is the line ``d = a0 + a1 v'`` with

    a1 = f B cos(theta) / (fy h),   v_horizon = -a0 / a1 = cy - fy tan(theta),

which gives (the paper's eq. 3 with the real principal point ``cy`` instead of ``(n-1)/2``)

    theta = arctan((cy + a0 / a1) / fy),    h = f B cos(theta) / (fy a1).         (3)

Height of a point above the road (along the road normal): ``height = h - n . P``; with (1),

    height(u, v, d) = h * (d - d_road(u, v)) / d       (metres, positive above the road).  (4)
"""

from __future__ import annotations

import math

import numpy as np

from lanegraph.types import Calibration, RoadModel


def pose_from_line(a0: float, a1: float, calib: Calibration) -> tuple[float, float]:
    """Pitch (radians) and camera height (metres) from the roll-corrected v-disparity line
    ``d = a0 + a1 * v'`` (eq. 3). ``a1`` must be > 0."""
    fy = calib.f_y
    pitch = math.atan((calib.cy + a0 / a1) / fy)
    height = calib.f * calib.baseline * math.cos(pitch) / (fy * a1)
    return pitch, height


def line_from_pose(pitch: float, height: float, calib: Calibration) -> tuple[float, float]:
    """Inverse of :func:`pose_from_line`: ``(a0, a1)`` of the road line in roll-corrected rows."""
    fy = calib.f_y
    a1 = calib.f * calib.baseline * math.cos(pitch) / (fy * height)
    a0 = a1 * (fy * math.tan(pitch) - calib.cy)
    return a0, a1


def roll_from_plane(b1: float, b2: float, calib: Calibration) -> float:
    """Roll (radians) from the road plane fitted in disparity space, ``d = b0 + b1 u + b2 v``:
    by (1), ``b1 = B nx / h`` and ``b2 = B ny f / (fy h)``, so ``tan(phi) = nx / ny = b1 fy / (b2 f)``."""
    return math.atan2(b1 * calib.f_y, b2 * calib.f)


def roll_row_coeffs(roll: float, calib: Calibration) -> tuple[float, float]:
    """``(s, c)`` of eq. (2): ``v' = cy + s (u - cx) + c (v - cy)``."""
    return math.sin(roll) * calib.f_y / calib.f, math.cos(roll)


def corrected_rows(u: np.ndarray, v: np.ndarray, roll: float, calib: Calibration) -> np.ndarray:
    """Roll-corrected row ``v'`` (eq. 2) of pixels ``(u, v)`` (column, row)."""
    s, c = roll_row_coeffs(roll, calib)
    return calib.cy + s * (np.asarray(u, float) - calib.cx) + c * (np.asarray(v, float) - calib.cy)


def road_normal(pitch: float, roll: float) -> np.ndarray:
    """Unit road normal (pointing into the road) in camera coordinates."""
    cp = math.cos(pitch)
    return np.array([cp * math.sin(roll), cp * math.cos(roll), math.sin(pitch)])


def road_disparity(road: RoadModel, calib: Calibration, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Disparity of the road model at pixels ``(u, v)`` (pixels; may be <= 0 above the horizon)."""
    return np.asarray(road.disparity_at(corrected_rows(u, v, road.roll, calib)), dtype=np.float64)


def height_above_road(
    road: RoadModel, calib: Calibration, u: np.ndarray, v: np.ndarray, d: np.ndarray
) -> np.ndarray:
    """Height (metres, positive above the road) of pixels ``(u, v)`` with disparity ``d > 0`` (eq. 4)."""
    d = np.asarray(d, dtype=np.float64)
    return road.height * (d - road_disparity(road, calib, u, v)) / d


def camera_rotation(pitch: float, roll: float) -> np.ndarray:
    """World-to-camera rotation ``R`` (``P_cam = R @ P_world``) for the conventions above."""
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    rz = np.array([[cr, sr, 0.0], [-sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return rz @ rx


def intrinsics(calib: Calibration) -> np.ndarray:
    """The 3x3 camera matrix ``K`` of the left camera."""
    return np.array([[calib.f, 0.0, calib.cx], [0.0, calib.f_y, calib.cy], [0.0, 0.0, 1.0]])


def homography_img_from_road(calib: Calibration, pitch: float, roll: float, height: float) -> np.ndarray:
    """3x3 homography mapping road-plane points ``(x, z, 1)`` (metres; x right, z ahead) to
    left-image pixels ``(u, v, 1)``: ``K R [e_x | e_z | h e_y]`` (the road is ``y = h``).

    This is the exact pinhole form of Bertozzi & Broggi's IPM (the paper's eqs. 1-2, yaw 0), which
    instead spreads the aperture angle linearly over the pixels; with roll 0 both agree up to that
    small-angle approximation.
    """
    R = camera_rotation(pitch, roll)
    plane = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, height], [0.0, 1.0, 0.0]])
    return intrinsics(calib) @ R @ plane
