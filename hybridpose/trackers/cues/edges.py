"""The edge cue: the model's visible sharp edges searched for along their image normals (the
moving-edge search of :func:`~hybridpose.edges.search_edges`), point-to-line residuals with Tukey
weights — the edge tracker's fit as one cue among others.

On a printed part the print's own edges lie inside the faces, a few pixels from the model's, and pull
its samples off (fitted from the true pose on every frame of real hand-held footage of a printed cube,
edges alone landed 2.8° off, median): where the faces carry a print, the cue's standard deviation
grows to ``textured_sigma_px`` and the texture and region cues share the lead. Chosen on ViSP's cube
and MegaPose cube videos: 3 px left the grey cube 0.61 px from its edges (median), 1.5 px 0.48 px
with the MegaPose round trip as good (5.4° / 4.4 mm back at the start, none lost), 1 px 0.44 px but
202 frames of that round trip lost.

Quality = inliers within ``INLIER_PX`` / (matched samples + samples whose lit search line shows no
edge) × min(1, inliers / ``FULL_SUPPORT``), as :func:`~hybridpose.edges.fit_edges`.
"""
from __future__ import annotations

import numpy as np

from ...core import Frame
from ...edges import EdgeSites, ModelView, search_edges
from ...edges.fit import LIT_GREY, sun_shown
from ...geometry import Pose
from .base import Cue
from .solve import LineRows

INLIER_PX = 2.0
FULL_SUPPORT = 40
QUALITY_SEARCH_PX = 4  # quality reads edges this near the fitted pose's samples


class EdgeCue(Cue):
    """Moving-edge residuals of the model's visible sharp edges.

    Args:
        view: the model's :class:`~hybridpose.edges.ModelView`. max_samples: samples searched a frame.
        sigma_px: a residual's standard deviation on a plain part; textured_sigma_px: on a printed one.
    """

    name = "edges"

    def __init__(self, view: ModelView, max_samples: int = 400, sigma_px: float = 1.0,
                 textured_sigma_px: float = 1.5) -> None:
        super().__init__()
        self.view, self.max_samples = view, int(max_samples)
        self.plain_sigma_px, self.textured_sigma_px = float(sigma_px), float(textured_sigma_px)
        self.sigma_px = self.plain_sigma_px
        self.visible = np.zeros(0, np.int64)
        self.sites: EdgeSites | None = None  # the last quality search's moving-edge sites

    def set_textured(self, textured: bool) -> None:
        """Whether the part's faces carry a print (the tracker decides from the texture it sees)."""
        self.sigma_px = self.textured_sigma_px if textured else self.plain_sigma_px

    def start(self, frame: Frame, gray: np.ndarray, pose: Pose, ids: np.ndarray) -> None:
        pass

    def begin(self, sight) -> None:
        super().begin(sight)
        self.visible = self._visible(sight.frame, sight.gray, sight.start, sight.visible)

    def _visible(self, frame: Frame, gray: np.ndarray, pose: Pose, visible: np.ndarray) -> np.ndarray:
        # under a known sun, the edges it cannot show are left out (ModelView.sun_shows)
        visible = sun_shown(self.view, frame, gray, pose, visible)
        step = max(1, int(np.ceil(len(visible) / self.max_samples)))
        return visible[::step]

    def _search(self, frame: Frame, gray: np.ndarray, pose: Pose, search_px: int):
        s = self.view.samples_at(pose, frame.camera, self.visible, margin_px=2.0)
        offset, valid, brightness = search_edges(gray, s, int(search_px))
        return s, offset, valid, brightness

    def correspond(self, frame: Frame, gray: np.ndarray, pose: Pose, search_px: int) -> None:
        self.search_px = int(search_px)
        if len(self.visible) < 6:
            self.X = np.zeros((0, 3))
            return
        s, offset, valid, _ = self._search(frame, gray, pose, search_px)
        self.X, self.n = s.points_m[valid], s.normals[valid]
        self.m = s.uv[valid] + offset[valid, None] * s.normals[valid]

    def rows(self) -> LineRows | None:
        # scale capped by the search range: where clutter's edges outnumber the model's the MAD grows
        return LineRows(self.X, self.n, self.m, self.sigma_px, 0.5, max(1.0, self.search_px / 4)) if len(self.X) >= 6 else None

    def quality(self, frame: Frame, gray: np.ndarray, pose: Pose) -> float:
        """As the module doc says; also keeps the search's moving-edge sites (:attr:`sites`) for pictures."""
        self.sites = None
        if len(self.visible) < 6:
            return float("nan")
        s, offset, valid, brightness = self._search(frame, gray, pose, QUALITY_SEARCH_PX)
        near = np.abs(offset) < INLIER_PX
        self.sites = EdgeSites(s.points_m, pose, frame.camera.K, s.uv + offset[:, None] * s.normals, valid,
                               near[valid], brightness)
        inliers = int((valid & near).sum())
        contradicted = int((~valid & (brightness > LIT_GREY)).sum())
        return inliers / max(int(valid.sum()) + contradicted, 1) * min(1.0, inliers / FULL_SUPPORT)
