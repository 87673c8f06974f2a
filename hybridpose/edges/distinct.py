"""Whether the image singles out a pose: the model's edges land on image edges at the pose clearly more
often than at the same view slid across the image beside it.

A tracker's fit in clutter always finds some edges: a small part's outline laid over a keyboard or a
cable crossing matches half of its edge samples, about what a right pose of a printed part over a busy
desk matches. What tells them apart is not the score at the pose but its contrast with the scores
around it (an *a-contrario* test, as LSD and other detectors validate a hypothesis against chance): a
right pose stands out from its own view slid a part's width away, which falls on the table or the
background; a wrong one sits in texture that every nearby placement matches as well. The edges at
the pose must beat their neighbours' by a margin, or the neighbours must hardly match at all (on black
space, where a sunlit sliver's few edges are all there is).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core import Frame
from ..geometry import Pose, shifted_in_image
from .fit import search_edges, to_gray
from .model_view import ModelView

MATCH_PX = 2.0  # an image edge within this of a model edge sample supports it
SEARCH_PX = 4  # edge search along each sample's normal, px
MAX_SAMPLES = 300  # evenly thinned: a share needs no more, and each placement costs one edge search
MIN_SAMPLES = 10  # a placement with fewer visible samples in the image has no score
# the view slid by these multiples of the projected size, in eight directions each (the outer ring turned
# by half a step): near enough to land on the part's surroundings, far enough to leave its outline
SLIDES = (0.75, 1.5)
NULL_PERCENTILE = 80  # the slid placements' support the pose must beat: one lucky slide does not veto it
NULL_SHARE = 0.2  # …or stay under this share of the pose's own support


def edge_support(view: ModelView, frame: Frame, pose: Pose, gray: np.ndarray | None = None) -> float:
    """Share of the model's visible edge samples at ``pose`` (object→camera, metres) with an image edge
    within ``MATCH_PX`` pixels along their normal; NaN where fewer than ``MIN_SAMPLES`` are in view.
    ``gray``: ``to_gray(frame.image)`` where the caller has it."""
    gray = to_gray(frame.image) if gray is None else gray
    samples = view.visible_samples(pose, frame.camera, margin_px=2, max_samples=MAX_SAMPLES)
    if len(samples.index) < MIN_SAMPLES:
        return float("nan")
    offset, valid, _ = search_edges(gray, samples, SEARCH_PX)
    return float(np.mean(valid & (np.abs(offset) <= MATCH_PX)))


@dataclass(frozen=True)
class PlacementContrast:
    """The edge support at a pose (``here``) and the ``NULL_PERCENTILE`` percentile of its slid
    placements' supports (``around``; NaN where none has a score), both shares of edge samples."""

    here: float
    around: float

    def stands_out(self, margin: float) -> bool:
        """Whether the pose beats its neighbours by ``margin``, or they match no more than
        ``NULL_SHARE`` of what it matches (on black space a sunlit sliver of the part is all the
        edges there are: its share is low and its neighbours' nil). True where there is nothing to
        compare (no score at the pose or around it): the test has no verdict and vetoes nothing."""
        if not np.isfinite(self.here) or not np.isfinite(self.around):
            return True
        return self.here - self.around >= margin or self.plain_around()

    def plain_around(self) -> bool:
        """Whether the placements around the pose match no more than ``NULL_SHARE`` of what it matches: the
        part stands on a plain table or wall, or on black space, where no clutter offers a wrong outline
        its edges (False where either has no score)."""
        return bool(np.isfinite(self.here) and np.isfinite(self.around) and self.here > 0
                    and self.around <= NULL_SHARE * self.here)


def placement_contrast(view: ModelView, frame: Frame, pose: Pose, gray: np.ndarray | None = None) -> PlacementContrast:
    """The edge support (:func:`edge_support`) at ``pose`` and around it: the same view slid by
    ``SLIDES`` × its projected size in eight directions (a right pose of a part on a table: about 0.8
    here, 0.2 around; an outline laid over clutter: 0.5 and 0.3)."""
    gray = to_gray(frame.image) if gray is None else gray
    here = edge_support(view, frame, pose, gray)
    box = frame.camera.image_box(view.object.bbox_corners, pose)
    if not np.isfinite(here) or box is None:
        return PlacementContrast(here, float("nan"))
    size = max(box[2] - box[0], box[3] - box[1])
    around = []
    for ring, reach in enumerate(SLIDES):
        for angle in (np.arange(8) + 0.5 * ring) * np.pi / 4:
            dx, dy = reach * size * np.cos(angle), reach * size * np.sin(angle)
            around.append(edge_support(view, frame, shifted_in_image(pose, frame.camera, dx, dy), gray))
    around = np.asarray(around)
    around = around[np.isfinite(around)]
    return PlacementContrast(here, float(np.percentile(around, NULL_PERCENTILE)) if len(around) else float("nan"))
