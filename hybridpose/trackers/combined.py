"""``combined``: one tracker, several cues in one fit, as ICG / M3T do — the model's edges, texture
points on its surface and the colours of its region against the background's
(:mod:`hybridpose.trackers.cues`), each a component that turns its correspondences into normal
equations weighted by its own uncertainty; one robust Gauss–Newton sums them.

Each frame:

1. the texture cue follows its points with KLT (a search of its own, pose-free, reaching tens of
   pixels through the image pyramid) and a few Gauss–Newton steps on them alone bring the pose into
   the basin of the cues that search from the pose;
2. ``outer`` times: the edge and region cues search from the current pose (``search_px``, halving each
   time, never below 4), then ``inner`` Gauss–Newton steps over every active cue's equations;
3. covariance = ``covariance_scale`` × (Σ H)⁻¹ over ``[ω, v]``; quality = the mean of the cues'
   qualities that have a verdict (edges count half on a printed part: the print's edges pull them).

Which cues speak follows what the part and the frame offer, not a flag: texture where the part carries a print
(:func:`~hybridpose.edges.printed_faces` at the initial pose; a plain part's corners are corners of
its shading and outline, which slide as it turns), region where its colours differ from the
background's (not on black space with faces in shadow), edges always, with less weight on a printed
part. ``modalities``
restricts the set.

Quality below ``lost_quality`` (default 0.35) → ``lost``. No cue asks how much of the image the model
explains: a print on the part or clutter behind it is no evidence against a right pose.
"""
from __future__ import annotations

import numpy as np

from ..core import Frame
from ..edges import ModelView, printed_faces, to_gray
from ..geometry import Pose
from ..objects import ObjectModel
from ..registry import register
from .base import Tracker
from .cues import CUES, EdgeCue, TextureCue
from .cues.base import Sight
from .cues.solve import solve

MODALITIES = ("edges", "texture", "region")
TEXTURE_PREALIGN_STEPS = 5
LEARN_CUE_QUALITY = 0.3  # every cue with a verdict at least this for the cues to learn from a frame
MAX_STEP_RAD, MAX_STEP_M_SHARE = 0.5, 0.5  # a Gauss–Newton step beyond these (rad; × diameter) is refused


@register("tracker", "combined")
class CombinedTracker(Tracker):
    """Edges, texture and region cues of the CAD model in one robust Gauss–Newton fit.

    Args:
        object: the CAD model (metres).
        modalities: the cues that may take part, any of ``("edges", "texture", "region")``.
        search_px: the edge and region cues' first search range along their lines, px.
        outer, inner: search rounds, and Gauss–Newton steps per round.
        covariance_scale: inflation of (Σ H)⁻¹ (neighbouring samples are correlated).
        lost_quality: see the module doc.
    """

    name = "combined"
    default_lost_quality = 0.35

    def __init__(self, object: ObjectModel, modalities=MODALITIES, search_px: int = 12, outer: int = 3,
                 inner: int = 3, covariance_scale: float = 4.0, lost_quality: float | None = None) -> None:
        super().__init__(object, lost_quality)
        modalities = (modalities,) if isinstance(modalities, str) else tuple(modalities)
        unknown = [m for m in modalities if m not in CUES]
        if not modalities or unknown:
            raise ValueError(f"modalities: expected a non-empty subset of {MODALITIES}, got {modalities!r}")
        if search_px < 1 or outer < 1 or inner < 1:
            raise ValueError(f"search_px, outer, inner: expected ≥ 1, got {search_px}, {outer}, {inner}")
        if not (np.isfinite(covariance_scale) and covariance_scale > 0):
            raise ValueError(f"covariance_scale: expected a positive factor, got {covariance_scale!r}")
        self.view = ModelView(object)
        self.modalities = modalities
        self.cues = [CUES[m](self.view) for m in MODALITIES if m in modalities]
        self.search_px, self.outer, self.inner = int(search_px), int(outer), int(inner)
        self.covariance_scale = float(covariance_scale)
        self.cue_qualities: dict[str, float] = {}

    def _cue(self, name: str):
        return next((c for c in self.cues if c.name == name), None)

    def _start(self, frame: Frame, gray: np.ndarray, pose: Pose, ids: np.ndarray) -> None:
        self.printed = printed_faces(self.view, frame, pose, gray)
        for cue in self.cues:
            cue.start(frame, gray, pose, ids)
            if isinstance(cue, EdgeCue):
                cue.set_textured(self.printed)
            if isinstance(cue, TextureCue):
                # a plain part's corners are corners of its shading and outline, which slide as it turns
                # (the truss: 0.37° median with edges alone, 1.7° with its corners as texture points)
                cue.enabled = self.printed

    def _init(self, frame: Frame, pose: Pose) -> None:
        gray = to_gray(frame.image)
        ids = self.view.facet_ids(pose, frame.camera, scale=1.0)
        if int((ids > 0).sum()) < 50:
            raise ValueError(f"pose: {self.object.name!r} covers fewer than 50 pixels of the frame at the initial "
                             "pose — is the object in view and the pose right?")
        self._start(frame, gray, pose, ids)

    def _track(self, frame: Frame, start: Pose, search_px: int | None = None):
        gray = to_gray(frame.image)
        ids = self.view.facet_ids(start, frame.camera)
        sight = Sight(frame, gray, start, ids, self.view.visible_index(start, frame.camera, margin_px=2, ids=ids))
        for cue in self.cues:
            cue.begin(sight)
        pose = self._fit(frame, gray, start, search_px or self.search_px)
        if pose is None:
            for cue in self.cues:
                cue.finish(frame, gray, start, False, None)
            return None, None, 0.0
        H = self._information
        quality = self._quality(frame, gray, pose)
        # what the cues learn from this frame (keyframes, colours) must be the part's: only where every
        # cue with a verdict agrees (a mug passing in front of a printed cube, taken as its print at a
        # keyframe, was then followed as the cube)
        trusted = quality >= self.lost_quality and all(
            q >= LEARN_CUE_QUALITY for q in self.cue_qualities.values() if np.isfinite(q))
        full_ids = _Once(lambda: self.view.facet_ids(pose, frame.camera, scale=1.0))
        for cue in self.cues:
            cue.finish(frame, gray, pose, trusted, full_ids)
        cov = self.covariance_scale * np.linalg.pinv(H + 1e-9 * np.eye(6))
        return pose, 0.5 * (cov + cov.T), quality

    def _track_wide(self, frame: Frame, start: Pose, search_px: float):
        return self._track(frame, start, search_px=max(self.search_px, int(np.ceil(search_px))))

    # --- the fit -----------------------------------------------------------------------------------
    def _solve(self, pose: Pose, cues, steps: int, K: np.ndarray) -> Pose | None:
        rows = [r for r in (cue.rows() for cue in cues) if r is not None]
        R, t, H, used, ok = solve(pose.R, pose.t, K, rows, steps, MAX_STEP_RAD, MAX_STEP_M_SHARE * self.object.diameter)
        if not ok:
            return None
        self._information = H
        return Pose(R, t) if used >= 6 else pose

    def _fit(self, frame: Frame, gray: np.ndarray, start: Pose, search_px: int) -> Pose | None:
        pose = start
        self._information = np.zeros((6, 6))
        texture = self._cue("texture")
        if texture is not None and texture.active:
            texture.correspond(frame, gray, pose, search_px)
            if len(texture.index) >= 6:
                pose = self._solve(pose, [texture], TEXTURE_PREALIGN_STEPS, frame.camera.K) or pose
        rng = search_px
        for _ in range(self.outer):
            active = [c for c in self.cues if c.active]
            for cue in active:
                cue.correspond(frame, gray, pose, rng)
            pose = self._solve(pose, active, self.inner, frame.camera.K)
            if pose is None or np.linalg.norm(pose.t - start.t) > self.object.diameter:
                return None
            rng = max(4, rng // 2)
        return pose

    def _quality(self, frame: Frame, gray: np.ndarray, pose: Pose) -> float:
        self.cue_qualities = {c.name: c.quality(frame, gray, pose) for c in self.cues if c.active}
        weights = {"edges": 0.5 if self.printed else 1.0}
        votes = [(weights.get(n, 1.0), q) for n, q in self.cue_qualities.items() if np.isfinite(q)]
        if not votes:
            return 0.0
        return float(sum(w * q for w, q in votes) / sum(w for w, _ in votes))


class _Once:
    """A value worked out on the first call and kept (a raster only some cues need)."""

    def __init__(self, make) -> None:
        self.make, self.value = make, None

    def __call__(self):
        if self.value is None:
            self.value = self.make()
        return self.value
