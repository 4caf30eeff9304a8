"""From the BEV image to lanes: SLT/ESLT features, road and previous-frame masks, orientation
histogram, 1D/2D Hough, IRLS/RANSAC parabolas, and the projection back to image pixels."""

from __future__ import annotations

from pathlib import Path

from lanegraph import hookimpl

from ._features import eslt, mask_features, slt
from ._fit import fit_irls, fit_ransac, irls_fit, ransac_fit
from ._follow import follow
from ._hough import line1d, line2d, orientation
from ._merge import merge_node
from ._near import near_paint
from ._temporal import temporal_mask, to_image
from ._verify import verify
from ._verify_learned import verify_learned

__all__ = ["irls_fit", "ransac_fit"]


@hookimpl
def lanegraph_node_types():
    return [
        slt,
        eslt,
        mask_features,
        orientation,
        line1d,
        line2d,
        fit_irls,
        fit_ransac,
        follow,
        merge_node,
        near_paint,
        temporal_mask,
        verify,
        verify_learned,
        to_image,
    ]


@hookimpl
def lanegraph_kernels():
    """This plugin's kernel list, its kernels' machine code beside it (:mod:`lanegraph.kernels`)."""
    return Path(__file__).with_name("kernels.json")
