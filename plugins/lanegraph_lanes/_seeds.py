"""Where ``lanes.follow`` starts its lines: the seeds in the BEV's near bands (each feature moved
along its orientation to its band's lower edge, the columns histogrammed), and the BEV rows where
one image row covers more than two BEV rows."""

from __future__ import annotations

import math

import numpy as np

from lanegraph.types import BevGeometry

from ._follow_params import FollowParams


def _steep_rows(geometry: BevGeometry) -> np.ndarray:
    """Per BEV row (uint8): 1 where one image row covers more than two BEV rows on the vehicle's
    column (the BEV repeats it: a slanted line's features read steeper there)."""
    h = geometry.H_img_from_bev
    r = np.arange(geometry.rows, dtype=np.float64)
    c = geometry.vehicle_col
    num = h[1, 0] * c + h[1, 1] * r + h[1, 2]  # the image row y = num / den
    den = h[2, 0] * c + h[2, 1] * r + h[2, 2]
    per_row = np.abs(h[1, 1] * den - num * h[2, 1]) / (den * den)  # |dy / dr|: image rows per BEV row
    return (per_row < 0.5).astype(np.uint8)


def _seeds(t, c, theta, row_start, rows, cols, p: FollowParams, res: float):
    """(t, column, orientation, votes) of the seeds, nearest band first.

    Every band in one pass over the features of the near bands (each feature's band is its ``t``
    over the band's height): each band's counts are those of its features, taken in the same order,
    as a pass over that band alone would make them."""
    band = max(1, int(round(p.seed_band_m / res)))
    bin_px = max(1, int(round(0.25 / res)))
    n_bins = cols // bin_px + 2
    n_bands = min(p.seed_bands, -(-rows // band))  # the bands that start inside the BEV
    # the features of the bands' BEV rows: (rows - n_bands band, rows - 1]
    i0, i1 = row_start[max(0, rows - n_bands * band)], row_start[rows]
    tt, cc, th = t[i0:i1], c[i0:i1], theta[i0:i1]
    j = (tt // band).astype(np.int64)  # the band of each feature (t: whole rows above the bottom one)
    n_band = np.bincount(j, minlength=n_bands)
    ok = th > math.radians(20.0)
    ok &= th < math.radians(160.0)
    tt, cc, th, j = tt[ok], cc[ok], th[ok], j[ok]
    t_b = j * band  # each feature's band's lower edge
    col_b = cc - (tt - t_b) * np.cos(th) / np.sin(th)
    b = np.floor(col_b / bin_px).astype(np.int64)
    keep = (b >= 0) & (b < n_bins)
    b, th, j = b[keep], th[keep], j[keep]
    n_kept = np.bincount(j, minlength=n_bands)
    cell = j * n_bins + b
    hist = np.bincount(cell, minlength=n_bands * n_bins).astype(np.float64).reshape(n_bands, n_bins)
    s2 = np.bincount(cell, weights=np.sin(2 * th), minlength=n_bands * n_bins).reshape(n_bands, n_bins)
    c2 = np.bincount(cell, weights=np.cos(2 * th), minlength=n_bands * n_bins).reshape(n_bands, n_bins)
    h3 = hist.copy()
    h3[:, 1:] += hist[:, :-1]
    h3[:, :-1] += hist[:, 1:]
    # the peaks: enough votes, no fewer than either neighbour, and more than the left one (a
    # plateau: its first bin); a band with fewer features than a seed's votes has none
    peak = h3 >= p.min_seed_votes
    peak[:, :-1] &= h3[:, :-1] >= h3[:, 1:]
    peak[:, 1:] &= h3[:, 1:] > h3[:, :-1]
    peak[(n_band < p.min_seed_votes) | (n_kept < p.min_seed_votes)] = False
    # the orientation of a peak: its bin's and its neighbours' doubled angles, each sum as NumPy sums
    # the (two or three) bins, from 0.0 in their order (a 0.0 beyond either end adds nothing)
    s3 = _window_sums(s2)[peak].tolist()
    c3 = _window_sums(c2)[peak].tolist()
    out = []
    jj, kk = np.nonzero(peak)  # nearest band first, then by column
    for jb, k, s, co, votes in zip(jj.tolist(), kk.tolist(), s3, c3, h3[peak].tolist()):
        psi = 0.5 * math.atan2(s, co)
        if psi < 0:
            psi += math.pi
        out.append((float(jb * band), (k + 0.5) * bin_px, psi, votes))
    return out


def _window_sums(a: np.ndarray) -> np.ndarray:
    """Per row of ``a``, each value plus its left and right neighbours (two at the ends), added as
    ``a[j, k - 1 : k + 2].sum()`` adds them: from 0.0, left to right."""
    pad = np.zeros((a.shape[0], a.shape[1] + 2))
    pad[:, 1:-1] = a
    out = 0.0 + pad[:, :-2]
    out += pad[:, 1:-1]
    out += pad[:, 2:]
    return out
