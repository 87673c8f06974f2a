"""``klt-pnp``: corners on the object, lifted onto the CAD model, followed with pyramidal KLT, pose
from RANSAC PnP + Levenberg–Marquardt.

* Features: ``cv2.goodFeaturesToTrack`` inside the object's projected region (eroded so that no
  corner sits on the silhouette, where the 3D point is ill-defined), lifted to 3D by intersecting
  the pixel's ray with the model facet the facet-id raster shows there (exact, no depth sensor).
* Tracking: forward–backward ``calcOpticalFlowPyrLK`` (a track whose round trip misses by more than
  ``fb_px`` is dropped); with a ``prior`` the flow starts from the prior's projections.
* Pose: ``solvePnPRansac`` (reprojection threshold ``ransac_px``, the prior as initial guess),
  ``solvePnPRefineLM`` on the inliers; covariance ``σ² (JᵀJ)⁻¹`` over ``[ω, v]``.
* Refinement (``edge_refine``, default): the moving-edge fit runs from the PnP pose (and, when
  that fit is poor, from the caller's start; the better-supported wins); it removes KLT's drift,
  and the surviving corners are re-lifted onto the model at the refined pose each frame (so no
  drift accumulates in their 3D points), new ones detected when too few remain. Without it, when fewer than ``min_features`` survive, new corners are
  detected away from the tracked ones (only on frames that were not lost).

Quality = inlier fraction of the tracks that entered the frame × min(1, inliers / 20) ×
exp(−rms / 2 px); with ``edge_refine`` the winning edge fit's quality (inlier fraction × support). Under the arm the tracks die or disagree and quality collapses; below
``lost_quality`` (default 0.3) the tracker reports ``lost``.
"""
from __future__ import annotations

import logging

import cv2
import numpy as np

from ..core import Frame, covariance_from_information
from ..geometry import Pose
from ..objects import ObjectModel
from ..registry import register
from .base import Tracker
from .surface_points import forward_backward_flow, surface_corners
from ..edges import ModelView, fit_from_proposals, printed_faces, quality_verdict
from ..edges.fit import TRACKING_POLISH, check_polish
from ..geometry import projection_jacobian

log = logging.getLogger(__name__)

MIN_INLIERS_FULL = 20  # PnP inliers for full quality
RMS_SCALE_PX = 2.0  # quality × exp(−RMS reprojection error / this), px


@register("tracker", "klt-pnp", baseline=True)
class KltPnpTracker(Tracker):
    """Keypoint tracker: KLT on model-lifted corners + PnP.

    Args:
        object: the CAD model (metres). max_features: corners kept; min_features: below this
            many tracks new corners are detected. fb_px: forward–backward KLT tolerance, pixels.
        ransac_px: PnP RANSAC inlier threshold, pixels. lost_quality: see the module doc.
        edge_refine: finish each frame with the moving-edge fit from the PnP pose (as ViSP's
            hybrid KLT+edge tracker) and re-detect the corners at the refined pose. Without it
            KLT corners on a flat-shaded truss slide ≈ 0.3 px per frame and the pose drifts
            (≈ 1.5° after 10 frames, 4–5° after 30, measured on the tumble sequence).
        polish: the edge fit's polish iterations (:func:`~hybridpose.edges.fit_edges`).
    """

    name = "klt-pnp"
    default_lost_quality = 0.3

    def __init__(self, object: ObjectModel, max_features: int = 150, min_features: int = 40, fb_px: float = 1.0,
                 ransac_px: float = 2.0, edge_refine: bool = True, lost_quality: float | None = None,
                 polish: int = TRACKING_POLISH) -> None:
        super().__init__(object, lost_quality)
        self.polish = check_polish(polish)
        if not 6 <= min_features <= max_features:
            raise ValueError(f"min_features, max_features: expected 6 ≤ min ≤ max, got {min_features}, {max_features}")
        self.view = ModelView(object)
        self.max_features, self.min_features = int(max_features), int(min_features)
        self.fb_px, self.ransac_px, self.edge_refine = float(fb_px), float(ransac_px), bool(edge_refine)
        self.tells_covered = self.edge_refine  # the edge fit's quality sees what stands beside the object
        self._lk = dict(winSize=(15, 15), maxLevel=2, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))

    # --- features -----------------------------------------------------------------------------------
    def _detect(self, gray: np.ndarray, pose: Pose, frame: Frame, existing: np.ndarray, count: int, ids=None):
        if ids is None:
            ids = self.view.facet_ids(pose, frame.camera, scale=1.0)
        return surface_corners(self.view, gray, pose, frame.camera, ids, count, existing)

    def _init(self, frame: Frame, pose: Pose) -> None:
        gray = cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY)
        self.printed = printed_faces(self.view, frame, pose, gray.astype(np.float32))
        self.uv, self.X = self._detect(gray, pose, frame, np.zeros((0, 2)), self.max_features)
        self.gray = gray
        if len(self.uv) >= 6:
            return
        if not self.edge_refine:
            raise ValueError(
                f"pose: only {len(self.uv)} trackable corners on {self.object.name!r} at the initial pose "
                "(need 6) — is the object in view, lit and the pose right?"
            )
        # far away or in shadow: the edge fit carries the first frames, corners come as they appear
        log.info("klt-pnp: only %d corners at init; edges only until more appear", len(self.uv))

    # --- tracking ------------------------------------------------------------------------------------
    def _klt_pnp(self, gray: np.ndarray, K: np.ndarray, start: Pose):
        """KLT from the previous frame + RANSAC PnP: (pose, cov, quality, surviving mask, new uv) or None."""
        prev = self.uv.reshape(-1, 1, 2).astype(np.float32)
        if len(prev) < 6:
            return None
        guess = (start @ self.X) @ K.T
        init = (guess[:, :2] / guess[:, 2:3]).reshape(-1, 1, 2).astype(np.float32)
        uv, good = forward_backward_flow(self.gray, gray, prev, init, self._lk, self.fb_px)
        if good.sum() < 6:
            return None
        rvec0, tvec0 = cv2.Rodrigues(start.R)[0], start.t.reshape(3, 1).copy()
        ok, rvec, tvec, inl = cv2.solvePnPRansac(self.X[good], uv[good].astype(np.float64), K, None, rvec0, tvec0,
                                                 useExtrinsicGuess=True, iterationsCount=100,
                                                 reprojectionError=self.ransac_px, confidence=0.999,
                                                 flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok or inl is None or len(inl) < 6:
            return None
        idx = np.flatnonzero(good)[inl.ravel()]
        rvec, tvec = cv2.solvePnPRefineLM(self.X[idx], uv[idx].astype(np.float64), K, None, rvec, tvec)
        pose = Pose.from_rotvec_t(rvec.ravel(), tvec.ravel())
        proj, J = projection_jacobian(pose, self.X[idx], K)
        res = (proj - uv[idx]).ravel()
        keep = np.zeros(len(prev), bool)
        keep[idx] = True
        sigma2 = max(float(res @ res) / max(res.size - 6, 1), 0.01)
        Jf = J.reshape(-1, 6)
        cov = covariance_from_information(Jf.T @ Jf, sigma2)
        rms = float(np.sqrt(np.mean(res**2) * 2))
        quality = len(idx) / len(prev) * min(1.0, len(idx) / MIN_INLIERS_FULL) * float(np.exp(-rms / RMS_SCALE_PX))
        return pose, cov, quality, keep, uv

    def _track(self, frame: Frame, start: Pose):
        gray = cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY)
        klt = self._klt_pnp(gray, frame.camera.K, start)
        if not self.edge_refine:
            if klt is None:
                self._carry(gray, np.zeros(len(self.uv), bool), None)
                return None, None, 0.0
            pose, cov, quality, keep, uv = klt
            self._carry(gray, keep, uv, pose if quality >= self.lost_quality else None, frame)
            return pose, cov, quality
        # the KLT pose is a proposal next to the caller's start; the edge fit from it is kept unless
        # it is poor and the fit from the start is better (KLT reaches further under fast motion,
        # the edges remove its drift)
        best = fit_from_proposals(self.view, frame, (start,) if klt is None else (klt[0], start),
                                  gray=gray.astype(np.float32), polish=self.polish)
        if best is None:
            self._carry(gray, np.zeros(len(self.uv), bool), None)
            return None, None, 0.0
        self.last_sites = best.sites
        quality, beside = quality_verdict(self.view, frame, best, gray.astype(np.float32),
                                          dark_surround=self._dark_around, printed=self.printed,
                                          dark_scene=self._dark_scene)
        self._note_surround(beside)
        if quality >= self.lost_quality:
            self._refresh(gray, best.pose, frame, klt)
        else:
            self.gray = gray
        return best.pose, best.covariance, quality

    def _refresh(self, gray, pose: Pose, frame: Frame, klt) -> None:
        """Drift-free corners for the next frame: the surviving tracks re-lifted onto the model at
        the refined pose (a corner that slid along an edge moves its 3D point with it), topped up
        with new corners when fewer than ``min_features`` remain."""
        ids = self.view.facet_ids(pose, frame.camera, scale=1.0)
        uv = np.zeros((0, 2), np.float32) if klt is None else klt[4][klt[3]]
        if len(uv):
            X, ok = self.view.lift(pose, frame.camera, uv, ids=ids)
            ok &= self.view.surface_fixed(pose, frame.camera, uv, ids)
            uv, X = uv[ok].astype(np.float32), X[ok]
        else:
            X = np.zeros((0, 3))
        if len(uv) < self.min_features:
            new_uv, new_X = self._detect(gray, pose, frame, uv, self.max_features - len(uv), ids=ids)
            uv = np.concatenate([uv.reshape(-1, 2), new_uv]).astype(np.float32)
            X = np.concatenate([X.reshape(-1, 3), new_X])
        self.uv, self.X, self.gray = uv, X, gray

    def _carry(self, gray, keep, uv, pose: Pose | None = None, frame: Frame | None = None) -> None:
        """Keep the surviving tracks; top up with new lifted corners when a trusted pose allows."""
        self.uv = (self.uv if uv is None else uv)[keep].astype(np.float32)
        self.X = self.X[keep]
        if pose is not None and len(self.uv) < self.min_features:
            new_uv, new_X = self._detect(gray, pose, frame, self.uv, self.max_features - len(self.uv))
            self.uv = np.concatenate([self.uv.reshape(-1, 2), new_uv]).astype(np.float32)
            self.X = np.concatenate([self.X.reshape(-1, 3), new_X])
        self.gray = gray
