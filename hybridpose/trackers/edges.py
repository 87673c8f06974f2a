"""``edges``: the moving-edge tracker (RAPID / ViSP-style) on the model's visible sharp edges.

Each frame is one edge fit (:func:`hybridpose.edges.fit_edges`) from the caller's prior; the quality
is the fit's, capped by how much of the image's edges and, on a dark background, of its lit pixels
the model explains (:func:`hybridpose.edges.honest_quality`); under a known sun, the first fits after
an init and every start searched wider than frame to frame must also match the sunlit surface their
pose predicts, cast shadows included (``VERIFIED_FITS``). Below ``lost_quality`` (default 0.5) →
``lost``. Where something lit comes to stand beside the object after the track had dark space around
it — on black space, the arm passing in front — the tracker reports the object ``covered`` (a
caller may then accept a lower quality: ``track(..., covered_lost_quality=)``), and the quality
leaves the occluder's edges out (``quality_verdict(..., dark_surround=)``). A fit that comes out
lost on an object filling the view is tried again from edge fits on the shrunk frame
(:func:`hybridpose.edges.coarse_to_fine`).
"""
from __future__ import annotations

import numpy as np

from ..core import Frame
from ..edges import (
    ModelView,
    coarse_to_fine,
    fit_edges,
    printed_faces,
    projected_diagonal_px,
    quality_verdict,
    to_gray,
)
from ..edges.fit import TRACKING_POLISH, check_polish
from ..geometry import Pose
from ..objects import ObjectModel
from ..registry import register
from .base import Tracker

# objects whose projected box at a lost fit's start is this large (diagonal, px) get the
# coarse-to-fine retry: the truss overflowing a 640×480 view (0.3–0.6 m); chosen on the tuning seeds
COARSE_MIN_PX = 600.0
# a track's first fits after its init (a start from a CNN pose, or from a restart) have no history to
# vouch for them: they, and every start searched wider than frame to frame, must also match the
# sunlit surface their pose predicts under a known sun (edges.honest_quality's sunlit term; a shadow
# map costs 1–4 ms, so not on every frame)
VERIFIED_FITS = 4


@register("tracker", "edges")
class EdgeTracker(Tracker):
    """Model-based moving-edge tracker on the visible sharp edges of the CAD model.

    Args:
        object: the CAD model (metres). search_px: search range along edge normals at the first
            iteration, pixels (covers the inter-frame motion the prior does not predict; 8: the
            wider 12 found the truss's neighbouring beams on far views, 0.4° median error where 8
            holds 0.14°). ``track(..., search_px=)`` widens it for one coarse start.
        max_samples: edge samples per iteration, evenly thinned from the visible ones (800: on the
            tuning sequences twice the 400 a far truss gives halved the spread of the fit from the
            true pose; see ``docs/decisions.md``). lost_quality: see module doc.
        covariance_scale: inflation of the Gauss–Newton covariance (neighbouring samples are
            correlated, so the covariance shrinks with their number faster than the error does: the
            scale grows with ``max_samples``); the default is measured by ``hybridpose bench`` (NEES
            coverage on rendered sequences, 0.89 of 0.90 on the tuning seeds).
        explain: the quality also asks how much of the image's edges and lit pixels around the
            object the model explains (:func:`honest_quality`); False: the fit's quality alone.
        polish: the fit's last iterations with each sample's search stopped halfway to the nearest
            other model edge (:func:`~hybridpose.edges.fit_edges`; 0: none).
        coarse_min_px: where a fit comes out lost and the object's projected box at its start is at
            least this large (diagonal, px), the fit is tried again from a coarse-to-fine pass over
            the shrunk frame (:func:`~hybridpose.edges.pyramid.coarse_to_fine`) and kept where its
            quality is higher (0: never): a CNN pose a few degrees off, or a prediction that coasted
            through an occlusion, close up.
    """

    name = "edges"
    default_lost_quality = 0.5
    reference_rate = 0.1

    def __init__(self, object: ObjectModel, search_px: int = 8, max_samples: int = 800,
                 lost_quality: float | None = None, covariance_scale: float = 8.0, explain: bool = True,
                 polish: int = TRACKING_POLISH, coarse_min_px: float = COARSE_MIN_PX) -> None:
        super().__init__(object, lost_quality)
        self.polish = check_polish(polish)
        if not (np.isfinite(coarse_min_px) and coarse_min_px >= 0):
            raise ValueError(f"coarse_min_px: expected a projected size ≥ 0 pixels (0: off), got {coarse_min_px!r}")
        self.coarse_min_px = float(coarse_min_px)
        if search_px < 1:
            raise ValueError(f"search_px: expected ≥ 1 pixel, got {search_px}")
        self.view = ModelView(object)
        self._unverified = 0  # fits left that must match the sunlit surface too (VERIFIED_FITS after init)
        self.explain = bool(explain)
        self.tells_covered = self.explain  # the quality's lit term sees what stands beside the object
        self.search_px, self.max_samples, self.covariance_scale = int(search_px), int(max_samples), float(covariance_scale)

    def _init(self, frame: Frame, pose: Pose) -> None:
        self._unverified = VERIFIED_FITS
        self.printed = printed_faces(self.view, frame, pose)
        fit = self._fit(frame, pose, outer=1)
        if fit is None:
            raise ValueError(
                f"pose: fewer than 6 model edges of {self.object.name!r} match image edges at the initial pose "
                "— is the object in view and the pose right?"
            )
        self.last_sites = fit.sites

    def _fit(self, frame: Frame, start: Pose, outer: int = 3, gray=None, search_px: int | None = None):
        return fit_edges(self.view, frame, start, gray=gray, search_px=search_px or self.search_px,
                         max_samples=self.max_samples, covariance_scale=self.covariance_scale, outer=outer,
                         polish=self.polish)

    def reset(self) -> None:
        super().reset()
        self._unverified = 0

    def _track(self, frame: Frame, start: Pose, search_px: int | None = None):
        gray = to_gray(frame.image)  # one conversion for the fits and their qualities
        verify = self._unverified > 0 or (search_px is not None and search_px > self.search_px)
        self._unverified = max(0, self._unverified - 1)
        pose, cov, quality, beside, sites = self._fit_once(frame, start, gray, search_px, verify)
        if (quality < self.lost_quality and self.coarse_min_px > 0
                and projected_diagonal_px(self.view, start, frame.camera) >= self.coarse_min_px):
            # an object this large may lie beyond any full-resolution search: fit the shrunk frames first
            coarse = self._fit_once(frame, coarse_to_fine(self.view, frame, start), gray, search_px, verify)
            if coarse[2] > quality:
                pose, cov, quality, beside, sites = coarse
        if pose is not None:
            self._note_surround(beside)
        self.last_sites = sites
        return pose, cov, quality

    def _fit_once(self, frame: Frame, start: Pose, gray: np.ndarray, search_px: int | None = None,
                  verify: bool = False):
        # the range halves at each outer iteration: a wider start takes as many more to reach the usual end
        extra = 0 if search_px is None else max(0, int(np.ceil(np.log2(search_px / self.search_px))))
        fit = self._fit(frame, start, outer=3 + extra, gray=gray, search_px=search_px)
        if fit is None:
            return None, None, 0.0, False, None
        if not self.explain:
            return fit.pose, fit.covariance, fit.quality, False, fit.sites
        verdict = quality_verdict(self.view, frame, fit, gray, sunlit=verify, dark_surround=self._dark_around,
                                  printed=self.printed, dark_scene=self._dark_scene)
        return fit.pose, fit.covariance, verdict.quality, verdict.beside, fit.sites

    def _track_wide(self, frame: Frame, start: Pose, search_px: float):
        return self._track(frame, start, search_px=max(self.search_px, int(np.ceil(search_px))))
