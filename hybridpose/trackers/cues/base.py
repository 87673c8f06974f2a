"""The contract of a cue of the combined tracker (:class:`~hybridpose.trackers.combined.CombinedTracker`):
one kind of evidence about the pose — model edges, texture points, the region's colours — that
finds its correspondences in a frame and turns them into the normal equations of one robust
Gauss–Newton step, as the modalities of ICG / M3T do (DLR-RM/3DObjectTracking).

A cue's life in one frame::

    cue.begin(sight)                               # the frame, seen from the fit's start pose
    cue.correspond(frame, gray, pose, search_px)   # once per outer iteration, from the current pose
    rows = cue.rows()                              # its residuals as point-to-line rows (LineRows)
    q = cue.quality(frame, gray, pose)             # after the fit: 0..1, NaN where it has no verdict
    cue.finish(frame, gray, pose, trusted)         # keyframes, colour statistics

Every cue's rows carry its own standard deviation (``sigma_px``) and robust scale bounds: the sum is a
maximum-likelihood step over all of them, with Tukey weights per cue.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from ...core import Frame
from ...geometry import Pose
from .solve import LineRows

@dataclass(frozen=True, eq=False)
class Sight:
    """One frame as every cue sees it at the fit's start pose (worked out once for all of them).

    Attributes:
        frame: the (undistorted) frame. gray: (H, W) float32 intensity. gray8: the same, uint8.
        start: the pose the fit starts from. ids: the facet-id raster of ``start`` at ``ID_SCALE``.
        visible: (S,) indices of the model's edge samples visible at ``start``.
    """

    frame: Frame
    gray: np.ndarray
    gray8: np.ndarray
    start: Pose
    ids: np.ndarray
    visible: np.ndarray


class Cue(ABC):
    """One cue of the combined tracker.

    Attributes:
        name: the cue's name in ``CombinedTracker(modalities=...)``.
        sigma_px: the standard deviation of one residual (px) its normal equations are divided by.
        active: whether it takes part in this frame's fit (a cue may find nothing to say: no texture
            on a plain part, no colour contrast between part and background).
    """

    name = "cue"
    sigma_px = 1.0

    def __init__(self) -> None:
        self.active = True
        self.sight: Sight | None = None  # the frame being fitted (begin)

    @abstractmethod
    def start(self, frame: Frame, gray: np.ndarray, pose: Pose, ids: np.ndarray) -> None:
        """Begin at a known ``pose`` in ``frame`` (``gray``: (H, W) float32; ``ids``: the full-resolution
        facet-id raster of ``pose``)."""

    def begin(self, sight: Sight) -> None:
        """A new frame (before its first :meth:`correspond`)."""
        self.sight = sight

    @abstractmethod
    def correspond(self, frame: Frame, gray: np.ndarray, pose: Pose, search_px: int) -> None:
        """Find this frame's correspondences from ``pose`` (searching ``±search_px`` where it searches)."""

    @abstractmethod
    def rows(self) -> LineRows | None:
        """This frame's correspondences as point-to-line rows (None: nothing to say)."""

    @abstractmethod
    def quality(self, frame: Frame, gray: np.ndarray, pose: Pose) -> float:
        """How well the fitted ``pose`` agrees with this cue, 0..1; NaN where it has no verdict."""

    def finish(self, frame: Frame, gray: np.ndarray, pose: Pose, trusted: bool, ids) -> None:
        """After the fit: ``trusted`` where the tracker reports the pose (keyframes, statistics);
        ``ids()``: the fitted pose's full-resolution facet-id raster (rendered on first call); None where
        the fit failed (nothing to learn from)."""
