"""The road plane of the roll estimate (:mod:`.profile`, step 4): the road pixels within
``roll_tolerance_px`` of the profile are fitted with a plane ``d = b0 + b1 u + b2 v``, re-selecting
the pixels near the plane a few times (:func:`_plane_fit_kernel`, wrapped by
:func:`_fit_road_plane`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg.lapack import dgesv

from lanegraph import jit

if TYPE_CHECKING:
    from .profile import ProfileParams


@jit
def _plane_points(disp, step, v_top, min_disp):
    """The candidates of :func:`_plane_fit_kernel`, compacted in row-major order: ``(us, vs, ds, m)``
    (float64 columns, rows and disparities; the first ``m`` are set)."""
    H, W = disp.shape
    cap = ((H + step - 1) // step) * ((W + step - 1) // step)
    us = np.empty(cap, np.float64)
    vs = np.empty(cap, np.float64)
    ds = np.empty(cap, np.float64)
    m = 0
    for v in range(0, H, step):
        if v < v_top:
            continue
        for u in range(0, W, step):
            dd = np.float64(disp[v, u])
            if not (dd > min_disp and dd < math.inf):  # NaN, +-inf: invalid
                continue
            us[m] = u
            vs[m] = v
            ds[m] = dd
            m += 1
    return us, vs, ds, m


@jit
def _plane_sums(us, vs, ds, m, first, b0, b1, b2, first_tol, plane_tol, height, min_tol, uc, vc, M, rhs):
    """One round of :func:`_plane_fit_kernel`: selects the candidates within the round's tolerance
    of the plane ``b``, writes the normal equations into ``M`` (3 x 3) and ``rhs``; returns the
    number selected."""
    n = 0
    su = 0.0
    sv = 0.0
    suu = 0.0
    suv = 0.0
    svv = 0.0
    sd = 0.0
    sud = 0.0
    svd = 0.0
    for p in range(m):
        fu = us[p]
        fv = vs[p]
        dd = ds[p]
        if first:
            tol = first_tol
        else:
            tol = max(plane_tol * dd / height, min_tol)
        if abs(dd - (b0 + b1 * fu + b2 * fv)) < tol:
            x = fu - uc
            y = fv - vc
            n += 1
            su += x
            sv += y
            suu += x * x
            suv += x * y
            svv += y * y
            sd += dd
            sud += x * dd
            svd += y * dd
    M[0, 0] = n
    M[0, 1] = su
    M[0, 2] = sv
    M[1, 0] = su
    M[1, 1] = suu
    M[1, 2] = suv
    M[2, 0] = sv
    M[2, 1] = suv
    M[2, 2] = svv
    rhs[0] = sd
    rhs[1] = sud
    rhs[2] = svd
    return n


def _plane_fit_kernel(
    disp, step, v_top, min_disp, b0, b1, b2, first_tol, plane_tol, height, min_tol, uc, vc, rounds
):
    """The roll plane ``d = b0 + b1 u + b2 v`` (disparity space), ``rounds`` selection and
    least-squares rounds over every ``step``-th row and column from row 0 and column 0.

    The candidates (``d > min_disp``, ``v >= v_top``) are compacted once, in row-major order
    (:func:`_plane_points`). A round (:func:`_plane_sums`) selects those with ``|d - (b0 + b1 u + b2
    v)| < tol`` (the plane of the previous round, the first round the one given), ``tol =
    first_tol`` in the first round, then ``max(plane_tol * d / height, min_tol)``; sums the
    least-squares normal equations of ``d = a + c1 (u - uc) + c2 (v - vc)`` (centred coordinates)
    and solves them with LAPACK's ``dgesv`` (SciPy's, the one numba's ``np.linalg.solve`` calls:
    the solve stays out of the kernels, whose first compilation it made 4 s longer):
    ``b = (a - c1 uc - c2 vc, c1, c2)``. Returns ``(ok, b0, b1, b2)``; not ok when a round selects
    fewer than 50 pixels, its system is singular or not finite, a coefficient is not finite, or
    the final ``b2 <= 0``."""
    us, vs, ds, m = _plane_points(disp, int(step), int(v_top), float(min_disp))
    M = np.empty((3, 3), np.float64)
    rhs = np.empty(3, np.float64)
    b0, b1, b2 = float(b0), float(b1), float(b2)
    args = (float(first_tol), float(plane_tol), float(height), float(min_tol), float(uc), float(vc))
    for it in range(int(rounds)):
        n = _plane_sums(us, vs, ds, m, it == 0, b0, b1, b2, *args, M, rhs)
        if n < 50 or not (np.isfinite(M).all() and np.isfinite(rhs).all()):
            return False, 0.0, 0.0, 0.0
        _, _, sol, info = dgesv(M, rhs)
        if info != 0:  # singular (every selected pixel on one row or column)
            return False, 0.0, 0.0, 0.0
        c0, c1, c2 = float(sol[0]), float(sol[1]), float(sol[2])
        b0 = c0 - c1 * uc - c2 * vc
        b1 = c1
        b2 = c2
        if not (math.isfinite(b0) and math.isfinite(b1) and math.isfinite(b2)):
            return False, 0.0, 0.0, 0.0
    if not b2 > 0:
        return False, 0.0, 0.0, 0.0
    return True, b0, b1, b2


def _fit_road_plane(disp, line, height: float, v_top: int, params: ProfileParams) -> np.ndarray | None:
    """The road plane ``d = b0 + b1 u + b2 v`` (disparity space) fitted over the pixels within
    ``roll_tolerance_px`` of the profile line, then re-fitted ``roll_iterations`` times over the
    pixels within ``plane_tolerance_m`` (metric, eq. 4) of the plane: every round in one call of
    :func:`_plane_fit_kernel` (normal equations in coordinates centred on the image centre, a
    3 x 3 solve). None when a round has fewer than 50 pixels or no plane, or the plane is not
    a road (``b2 <= 0``). ``height``: the camera height of the line (metres)."""
    H, W = disp.shape
    ok, b0, b1, b2 = _plane_fit_kernel(
        disp,
        int(params.roll_subsample),
        int(v_top),
        float(params.min_fit_disparity_px),
        float(line[0]),
        0.0,
        float(line[1]),
        float(params.roll_tolerance_px),
        float(params.plane_tolerance_m),
        float(height),
        float(params.min_plane_tolerance_px),
        0.5 * (W - 1),
        0.5 * (H - 1),
        int(params.roll_iterations),  # at least one (the param's bound): b is then a fit
    )
    return np.array([b0, b1, b2]) if ok else None
