"""The contract of a cue of the combined tracker (:class:`~hybridpose.trackers.combined.CombinedTracker`):
one kind of evidence about the pose — model edges, texture points, the region's colours — that
finds its correspondences in a frame and turns them into the normal equations of one robust
Gauss–Newton step, as the modalities of ICG / M3T do (DLR-RM/3DObjectTracking).

A cue's life in one frame::

    cue.begin(sight)                               # the frame, seen from the fit's start pose
    cue.correspond(frame, gray, pose, search_px)   # once per outer iteration, from the current pose
    H, g, n = cue.normal_equations(pose)           # every inner iteration; summed over the cues
    q = cue.quality(frame, gray, pose)             # after the fit: 0..1, NaN where it has no verdict
    cue.finish(frame, gray, pose, trusted)         # keyframes, colour statistics

Every cue weights its residuals by its own standard deviation (``sigma_px``) and a Tukey M-estimator,
so the sum is a maximum-likelihood step over all of them.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from ...core import Frame
from ...geometry import Pose, line_jacobian

TUKEY_C = 4.685
MAD_TO_SIGMA = 1.4826


def tukey_weights(residuals: np.ndarray, scale_px: float) -> np.ndarray:
    """(N,) Tukey biweights of scalar ``residuals`` (N,) px at ``scale_px`` (0 beyond 4.685 scales)."""
    u = residuals / (TUKEY_C * scale_px)
    return np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)


def robust_scale(residuals: np.ndarray, floor_px: float, cap_px: float = np.inf) -> float:
    """The residuals' spread (MAD × 1.4826, px) kept within [``floor_px``, ``cap_px``]."""
    if len(residuals) == 0:
        return floor_px
    return float(min(max(MAD_TO_SIGMA * np.median(np.abs(residuals)), floor_px), cap_px))


def normal_equations(J: np.ndarray, r: np.ndarray, w: np.ndarray, sigma_px: float) -> tuple[np.ndarray, np.ndarray]:
    """``(JᵀWJ, JᵀWr) / σ²`` of rows ``J`` (N, 6), residuals ``r`` (N,) px and weights ``w`` (N,)."""
    Jw = J * (w / sigma_px**2)[:, None]
    return Jw.T @ J, Jw.T @ r


@dataclass(frozen=True, eq=False)
class Sight:
    """One frame as every cue sees it at the fit's start pose (worked out once for all of them).

    Attributes:
        frame: the (undistorted) frame. gray: (H, W) float32 intensity.
        start: the pose the fit starts from. ids: the facet-id raster of ``start`` at ``ID_SCALE``.
        visible: (S,) indices of the model's edge samples visible at ``start``.
    """

    frame: Frame
    gray: np.ndarray
    start: Pose
    ids: np.ndarray
    visible: np.ndarray


def line_equations(pose: Pose, points_m: np.ndarray, normals: np.ndarray, targets: np.ndarray, K: np.ndarray,
                   floor_px: float, cap_px: float, sigma_px: float) -> tuple[np.ndarray, np.ndarray, int]:
    """(H, g, rows used) of point-to-line residuals: model ``points_m`` (S, 3) whose projections at
    ``pose`` should lie on the lines through ``targets`` (S, 2) px perpendicular to ``normals`` (S, 2);
    Tukey weights at the residuals' spread within [``floor_px``, ``cap_px``]. Too few (< 6): zeros."""
    if len(points_m) < 6:
        return np.zeros((6, 6)), np.zeros(6), 0
    uv, J = line_jacobian(pose, points_m, K, normals)
    r = np.einsum("si,si->s", normals, uv - targets)
    w = tukey_weights(r, robust_scale(r, floor_px, cap_px))
    H, g = normal_equations(J, r, w, sigma_px)
    return H, g, int((w > 0).sum())


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
    def normal_equations(self, pose: Pose) -> tuple[np.ndarray, np.ndarray, int]:
        """(H (6, 6), g (6,), rows used) at ``pose`` over ``[ω, v]`` (right perturbation), σ-weighted."""

    @abstractmethod
    def quality(self, frame: Frame, gray: np.ndarray, pose: Pose) -> float:
        """How well the fitted ``pose`` agrees with this cue, 0..1; NaN where it has no verdict."""

    def finish(self, frame: Frame, gray: np.ndarray, pose: Pose, trusted: bool, ids) -> None:
        """After the fit: ``trusted`` where the tracker reports the pose (keyframes, statistics);
        ``ids()``: the fitted pose's full-resolution facet-id raster (rendered on first call)."""
