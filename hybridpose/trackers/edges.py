"""Moving-edge tracking on the model's visible sharp edges (RAPID / ViSP-style), and the refinement
the cv2.rapid backends run after their silhouette step.

Each visible edge sample is searched for along its image normal (``±search_px``) for the strongest
intensity step; the pose then minimises the point-to-*line* distances (only the normal component
is measured: the aperture problem) by Gauss–Newton with Tukey weights, re-searching from the new
pose a few times. ``cv2.rapid`` cannot do this part itself: its line search assumes an ordered
silhouette contour and its pose step uses point-to-point distances.

Quality = inliers (within ``inlier_px`` after the last iteration) / (matched samples + samples
whose search line is lit but shows no edge) × min(1, inliers / 40). Samples on dark search lines
with no edge are left out: edges between a face in shadow and black space have almost no
contrast, and counting them made the quality swing 0.2–0.6 with the lighting on a clean tumble.
When the arm covers the truss, its tool plate is a lit surface without the model's edges, and
its rim a single line: the quality collapses. Below ``lost_quality`` (default 0.5) → ``lost``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from ..core import Frame
from ..geometry import Pose
from ..objects import ObjectModel
from ..registry import register
from .base import Tracker
from ..geometry import line_jacobian, se3_exp
from .model_view import EdgeSamples, ModelView

TUKEY_C = 4.685
MIN_SUPPORT = 40  # inlier samples for full quality
LIT_GREY = 30.0  # mean grey level of a search line that is lit (not shadow on black space)


@dataclass(frozen=True)
class EdgeFit:
    """Result of :func:`fit_edges`: pose, covariance (6, 6) over ``[ω, v]``, inlier fraction, RMS px."""

    pose: Pose
    covariance: np.ndarray
    quality: float
    rms_px: float
    samples: int


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB → (H, W) float32 intensity."""
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)


def search_edges(gray: np.ndarray, samples: EdgeSamples, search_px: int, min_contrast: float = 4.0):
    """Strongest intensity step along each sample's normal within ``±search_px``.

    Returns (offset (S,) px along the normal, sub-pixel; valid (S,) bool: step ≥ ``min_contrast``
    grey levels per pixel; mean intensity (S,) along the search line). A mild Gaussian preference for nearer steps breaks ties as RAPID's
    nearest-maximum rule would. (Keeping each sample's contrast sign from frame to frame, as ViSP
    does, was tried and dropped: under a fixed sun, crease edges of a tumbling truss flip sign.)
    """
    k = np.arange(-search_px - 1, search_px + 2, dtype=np.float32)
    # u and v maps one at a time: the same float64 sums as one (S, 2L+3, 2) array, without its strided copies
    map_u = (samples.uv[:, :1] + k * samples.normals[:, :1]).astype(np.float32)
    map_v = (samples.uv[:, 1:] + k * samples.normals[:, 1:]).astype(np.float32)
    prof = cv2.remap(gray, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    g = np.abs(prof[:, 2:] - prof[:, :-2]) * 0.5               # step at k = −L … L
    ks = k[1:-1]
    score = g * np.exp(-0.5 * (ks / max(search_px, 1)) ** 2)
    j = np.argmax(score, axis=1)
    rows = np.arange(len(j))
    best = g[rows, j]
    # sub-pixel: parabola through the peak and its neighbours
    jl, jr = np.clip(j - 1, 0, len(ks) - 1), np.clip(j + 1, 0, len(ks) - 1)
    a, b, c = g[rows, jl], best, g[rows, jr]
    den = a - 2 * b + c
    sub = np.where((j > 0) & (j < len(ks) - 1) & (den < -1e-6), 0.5 * (a - c) / np.where(den == 0, 1, den), 0.0)
    return ks[j] + sub, best >= min_contrast, prof.mean(1)


class _RT(NamedTuple):
    R: np.ndarray
    t: np.ndarray


def _median(a: np.ndarray) -> float:
    """np.median of a 1-D array (the same value), without its generic-axis overhead (≈ 3× its
    cost on a few hundred samples, nine times per fit)."""
    n = len(a)
    if n % 2:
        return float(np.partition(a, n // 2)[n // 2])
    part = np.partition(a, (n // 2 - 1, n // 2))
    return float((part[n // 2 - 1] + part[n // 2]) / 2)


def _tukey(r: np.ndarray, scale: float) -> np.ndarray:
    u = r / (TUKEY_C * scale)
    return np.where(np.abs(u) < 1, (1 - u**2) ** 2, 0.0)


def fit_edges(view: ModelView, frame: Frame, start: Pose, gray: np.ndarray | None = None, search_px: int = 12,
              outer: int = 3, inner: int = 3, inlier_px: float = 2.0, max_samples: int = 400,
              covariance_scale: float = 1.0, max_step_m: float | None = None) -> EdgeFit | None:
    """Align the visible model edges with the image edges, starting from ``start``.

    ``search_px`` halves at each outer iteration (coarse to fine, never below 4). Quality =
    inliers / (matched samples + samples whose lit search line shows no edge) × min(1, inliers /
    MIN_SUPPORT). None when fewer than 6 samples are visible or matched, or
    when the pose moves more than ``max_step_m`` (default: the object's diameter) from ``start``.
    """
    cam = frame.camera
    K = cam.K
    gray = to_gray(frame.image) if gray is None else gray
    max_step_m = view.object.diameter if max_step_m is None else max_step_m
    # plain arrays through the iterations, one validated Pose at the end (a Pose checks and
    # re-orthonormalises its rotation on construction: a product of rotations needs neither)
    pose = _RT(start.R, start.t)
    rng_px = search_px
    visible = None
    for _ in range(outer):
        # visibility once per frame (at the start pose: the pose moves by a fraction of a degree)
        if visible is None:
            samples = view.visible_samples(pose, cam, margin_px=2, max_samples=max_samples)
            visible = samples.index
        else:
            samples = view.samples_at(pose, cam, visible, margin_px=2)
        if len(samples.index) < 6:
            return None
        offset, valid, brightness = search_edges(gray, samples, rng_px)
        if valid.sum() < 6:
            return None
        target = samples.uv + offset[:, None] * samples.normals   # matched edge points
        n, X, m = samples.normals[valid], samples.points_m[valid], target[valid]
        rt = pose
        for _ in range(inner):
            uv, Jn = line_jacobian(rt, X, K, n)                     # Jn: (S, 6)
            r = np.einsum("si,si->s", n, uv - m)                   # signed point-to-line distance, px
            # MAD scale, capped by the search range: when an occluder's edges outnumber the model's
            # the MAD would grow and let them in
            scale = min(max(1.4826 * _median(np.abs(r)), 0.5), max(1.0, rng_px / 4))
            w = _tukey(r, scale)
            if w.sum() < 6:
                return None
            H = (Jn * w[:, None]).T @ Jn
            delta = -np.linalg.solve(H + 1e-9 * np.eye(6), (Jn * w[:, None]).T @ r)
            dR, dt = se3_exp(delta)                                  # right perturbation, as Pose.retract
            rt = _RT(rt.R @ dR, rt.R @ dt + rt.t)
            if np.abs(delta).max() < 1e-6:
                break
        pose = rt
        if np.linalg.norm(pose.t - start.t) > max_step_m:
            return None
        rng_px = max(4, rng_px // 2)
    pose = Pose(pose.R, pose.t)
    uv, Jn = line_jacobian(pose, X, K, n)
    r = np.einsum("si,si->s", n, uv - m)
    inl = np.abs(r) < inlier_px
    if inl.sum() < 6:
        return None
    # a sample with no edge on a *lit* search line contradicts the model (a uniform occluder in
    # front, e.g. the arm's tool plate); on a dark line it says nothing (a face in shadow on black)
    contradicted = int((~valid & (brightness > LIT_GREY)).sum())
    ratio = float(inl.sum()) / (len(inl) + contradicted)
    dof = max(int(inl.sum()) - 6, 1)
    sigma2 = float((r[inl] ** 2).sum() / dof)
    # neighbouring samples on one edge are not independent: covariance_scale (≥ 1) accounts for it
    cov = covariance_scale * max(sigma2, 0.05) * np.linalg.pinv(Jn[inl].T @ Jn[inl])
    support = min(1.0, float(inl.sum()) / MIN_SUPPORT)
    return EdgeFit(pose=pose, covariance=0.5 * (cov + cov.T), quality=support * ratio,
                   rms_px=float(np.sqrt(np.mean(r[inl] ** 2))), samples=int(inl.sum()))


GOOD_FIT = 0.7  # a fit this good from the first proposal is kept without trying the next


def fit_from_proposals(view: ModelView, frame: Frame, starts, gray: np.ndarray | None = None,
                       good_fit: float = GOOD_FIT, **kwargs) -> EdgeFit | None:
    """Edge fits from ``starts`` in order, stopping at the first with quality ≥ ``good_fit``; the
    fit most samples agree with (inliers × quality) among those run, or None."""
    gray = to_gray(frame.image) if gray is None else gray
    fits = []
    for start in starts:
        fit = fit_edges(view, frame, start, gray=gray, **kwargs)
        if fit is not None:
            fits.append(fit)
            if fit.quality >= good_fit:
                break
    return max(fits, key=lambda f: f.samples * f.quality) if fits else None


@register("tracker", "edges")
class EdgeTracker(Tracker):
    """Model-based moving-edge tracker on the visible sharp edges of the CAD model.

    Args:
        object: the CAD model (metres). search_px: search range along edge normals at the first
            iteration, pixels (covers the inter-frame motion the prior does not predict).
        max_samples: edge samples per iteration (cost ∝ samples). lost_quality: see module doc.
        covariance_scale: inflation of the Gauss–Newton covariance (correlated samples); the
            default is measured in ``benchmarks/tracker_accuracy.py`` (NEES on rendered sequences).
    """

    name = "edges"
    default_lost_quality = 0.5
    reference_rate = 0.1

    def __init__(self, object: ObjectModel, search_px: int = 12, max_samples: int = 400,
                 lost_quality: float | None = None, covariance_scale: float = 4.0) -> None:
        super().__init__(object, lost_quality)
        if search_px < 1:
            raise ValueError(f"search_px: expected ≥ 1 pixel, got {search_px}")
        self.view = ModelView(object)
        self.search_px, self.max_samples, self.covariance_scale = int(search_px), int(max_samples), float(covariance_scale)

    def _init(self, frame: Frame, pose: Pose) -> None:
        if self._fit(frame, pose, outer=1) is None:
            raise ValueError(
                f"pose: fewer than 6 model edges of {self.object.name!r} match image edges at the initial pose "
                "— is the object in view and the pose right?"
            )

    def _fit(self, frame: Frame, start: Pose, outer: int = 3) -> EdgeFit | None:
        return fit_edges(self.view, frame, start, search_px=self.search_px, max_samples=self.max_samples,
                         covariance_scale=self.covariance_scale, outer=outer)

    def _track(self, frame: Frame, start: Pose):
        fit = self._fit(frame, start)
        if fit is None:
            return None, None, 0.0
        return fit.pose, fit.covariance, fit.quality
