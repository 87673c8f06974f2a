"""How far to trust an edge fit: its own quality, capped by how much of the image around the object
the model explains (:func:`~hybridpose.edges.fit.explained_edge_share`; on black space also its lit
pixels, :func:`~hybridpose.edges.silhouette.lit_verdict`, and under a known sun the surface it lights,
:func:`~hybridpose.edges.shadows.sunlit_agreement`). The edge trackers' lost flag reads it.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..core import Frame
from .fit import EdgeFit, explained_edge_share
from .model_view import ModelView
from .shadows import sunlit_agreement
from .silhouette import lit_verdict

# the explained-edge term: 1 − slope · (1 − share), 0.5 at 75 % (slope 2): on the truss's tuning frames
# 0.99 median at the true pose, 0.69 at poses > 5° off the fit did not flag. A printed part around a lit
# background seen from the start (a desk, a photo) takes slope 1: clutter and shadows at its outline
# leave a quarter of a right pose's edges unexplained — ViSP's printed cube on its table 0.74–0.84, which
# slope 2 called lost — and the share tells its right poses from wrong ones no better than the print
# lets it (the realistic suite's printed cube, tuning seeds: 0.88 vs 0.86 median). A plain part keeps
# slope 2: with slope 1 `edges` on the own-object box's tuning sequences (an arm passing in front of a
# box over a photo) trusted frames > 5° off 18 → 66 of 1 800 (docs/decisions.md)
EXPLAINED_SLOPE_DARK, EXPLAINED_SLOPE_LIT = 2.0, 1.0
# the lit-share term of honest_quality: 1 − LIT_SLOPE · (1 − share), 0.5 at 98 % explained
LIT_SLOPE = 25.0
# its sunlit term: 1 − SUNLIT_SLOPE · (1 − precision), 0.5 at 98 %. On tuning frames fitted from the
# true pose the precision's 0.5th percentile was 0.997; fitted from starts that ended > 5° off, its
# median 0.75 and 90th percentile 0.93 (0.97 where the sun lights only slivers of the truss)
SUNLIT_SLOPE = 25.0
SUNLIT_FROM = 0.5  # a fit already lost (edge trackers' lost_quality) skips the term: it changes nothing there


class QualityVerdict(NamedTuple):
    """:func:`quality_verdict`'s answer: the honest ``quality`` (0..1) and whether something lit
    stood ``beside`` the object at the fitted pose (:func:`~hybridpose.edges.silhouette.lit_verdict`)."""

    quality: float
    beside: bool


def honest_quality(view: ModelView, frame: Frame, fit: EdgeFit, gray: np.ndarray | None = None,
                   sunlit: bool = False) -> float:
    """A tracker's quality from its final ``fit`` in ``frame``, never above the fit's own:
    ``min(fit quality, 1 − slope·(1 − edges), 1 − LIT_SLOPE·(1 − lit))`` with ``edges`` =
    :func:`explained_edge_share` and ``lit`` = :func:`~hybridpose.edges.silhouette.explained_lit_share`
    at the fitted pose; ``slope`` 2 (``EXPLAINED_SLOPE_DARK``; :func:`quality_verdict` gives a printed
    part around a lit background ``EXPLAINED_SLOPE_LIT``, 1). Either term alone brings the quality to
    0.5 (the edge trackers' ``lost_quality``): a quarter of the image's edges unexplained, or 2 % of the
    lit pixels around the silhouette outside it. With
    ``sunlit``, where the frame gives the sun's direction and the background is dark (the lit term has
    a verdict), also ``1 − SUNLIT_SLOPE·(1 − precision)``,
    ``precision`` the share of the surface the pose predicts sunlit that is lit in the image
    (:func:`~hybridpose.edges.shadows.sunlit_agreement`; 0.5 at 98 %), where the quality is at
    least ``SUNLIT_FROM`` before it. A term without a verdict (NaN) is left out."""
    return quality_verdict(view, frame, fit, gray, sunlit).quality


def quality_verdict(view: ModelView, frame: Frame, fit: EdgeFit, gray: np.ndarray | None = None,
                    sunlit: bool = False, dark_surround: bool = False, printed: bool = False,
                    dark_scene: bool = False) -> QualityVerdict:
    """:func:`honest_quality` (same arguments), with whether something lit stood beside the object
    (its lit term's ring: an arm in front on black space, or a lit background).

    ``dark_surround``: the caller saw the object on dark space before (a tracker's earlier fits). Then
    a broad lit thing beside it now is an occluder in front (:func:`~hybridpose.edges.silhouette.
    occluder_mask`), and both terms leave it out: it is no part of the object for any pose to explain.
    ``dark_scene``: the video showed the object on dark space before, if not in this track (a tracker
    re-initialised by the hybrid during an occlusion). Without either, a lit ring means a lit
    background, where the explained-edge term of a ``printed`` part (it carries a print:
    :func:`explained_edge_share`) takes its gentler slope."""
    quality = fit.quality
    ids = view.facet_ids(fit.pose, frame.camera)  # one raster of the fitted pose for every term
    lit, beside = lit_verdict(view, frame, fit.pose, gray, ids, dark_surround)
    explained = explained_edge_share(view, frame, fit.pose, gray, ids, occluder=beside and dark_surround,
                                     printed=printed)
    if np.isfinite(explained):
        lit_background = beside and not (dark_surround or dark_scene)
        slope = EXPLAINED_SLOPE_LIT if lit_background and printed else EXPLAINED_SLOPE_DARK
        quality = min(quality, 1.0 - slope * (1.0 - explained))
    if np.isfinite(lit):
        quality = min(quality, 1.0 - LIT_SLOPE * (1.0 - lit))
        if sunlit and frame.sun_direction_cam is not None and quality >= SUNLIT_FROM:
            precision = sunlit_agreement(view, frame, fit.pose, gray, ids)[0]
            if np.isfinite(precision):
                quality = min(quality, 1.0 - SUNLIT_SLOPE * (1.0 - precision))
    return QualityVerdict(float(max(0.0, quality)), beside)
