"""Whether a stereo pair is in the right order: left and right not swapped."""

from __future__ import annotations

import cv2
import numpy as np


def disparity_votes(left: np.ndarray, right: np.ndarray) -> tuple[int, int]:
    """How many confidently matched patches of a pair lie at a positive and at a negative disparity.

    Block matching by the sum of absolute differences on the lower 60 % of the (grey, halved) images,
    shifts of up to an eighth of the width either way; a patch counts when it is textured and its
    best shift, at least 2 px from 0, is clearly better than the best one of the other sign. A
    rectified pair in the right order has (nearly) only positive ones; swapped images, negative ones.
    """

    def grey(img: np.ndarray) -> np.ndarray:
        g = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        g = g[int(0.4 * g.shape[0]) :]
        while g.shape[1] > 700:
            g = cv2.pyrDown(g)
        return g.astype(np.float32)

    lg, rg = grey(left), grey(right)
    h, w = lg.shape
    s_max = min(64, w // 8)
    if h < 16 or s_max < 4:
        return 0, 0
    core = slice(s_max, w - s_max)
    costs = []
    for s in range(-s_max, s_max + 1):
        diff = np.abs(lg[:, core] - rg[:, s_max - s : w - s_max - s])  # left(x) against right(x - s)
        costs.append(cv2.boxFilter(diff, -1, (9, 9), normalize=True))
    c = np.stack(costs)
    shifts = np.arange(-s_max, s_max + 1)
    pos, neg = c[shifts >= 2].min(axis=0), c[shifts <= -2].min(axis=0)
    gx = cv2.boxFilter(np.abs(np.diff(lg, axis=1, append=lg[:, -1:]))[:, core], -1, (9, 9))
    textured = gx > 4.0
    n_pos = int((textured & (pos < 0.7 * neg) & (pos < 0.7 * c[s_max])).sum())
    n_neg = int((textured & (neg < 0.7 * pos) & (neg < 0.7 * c[s_max])).sum())
    return n_pos, n_neg
