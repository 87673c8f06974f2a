"""OpenCV contrib's ``cv2.rapid`` silhouette trackers as backends: ``rapid``, ``rapid-ols``, ``rapid-gos``.

What the OpenCV classes do (read from ``modules/rapid/src``): project the mesh, draw the wireframe
of its front faces, take the *outer contour* only (``RETR_EXTERNAL``), and use the mesh vertices
that fall on it as control points; search ±``len`` px along the contour normal (``Rapid``: the
strongest step; ``OLSTracker``/``GOSTracker``: foreground/background hue–saturation histograms,
GOS with a dynamic-programming path over neighbouring lines); then ``solvePnPRefineLM`` on
point-to-point matches. Consequences we handle here:

* control points exist only at vertices, so the mesh is subdivided (edges ≤ ``subdivide_m``);
  an 8-vertex box makes ``Rapid`` assert;
* only the silhouette constrains the pose — on a thin open truss that leaves rotation weak
  (≈ 6–10° median on our tumble, ``refine=False`` in the benchmark). By default (``refine=True``)
  the silhouette pose is therefore a *proposal*: the moving-edge fit on all visible model edges
  (:func:`~hybridpose.edges.fit_edges`) runs from the caller's start and, when that fit
  is poor (quality < 0.7), from the silhouette pose too; the fit more edge samples agree with wins; its inlier fraction × support, capped by the share of image edges the model explains (edges.honest_quality), is the quality (the cv2
  ratios are not comparable between variants: GOS always reports 1). The silhouette step helps
  when the start is far off (fast motion, re-acquisition), where its 20 px search reaches further;
* OLS/GOS histograms only count pixels with saturation > 25 and value > 50: a grey spacecraft on
  black space gives them nothing (OLS then returns ratio 0 and drifts), so they get a false-colour
  image (intensity → JET hue), which separates lit structure from dark space;
* ``GOSTracker.compute`` asserts (``cols.rows == pts3d.rows``) when asked for more than one
  iteration or an EPS criterion in OpenCV 5.0: we call it with one iteration at a time.
"""
from __future__ import annotations

import inspect

import cv2
import numpy as np
import trimesh

from ..core import Frame
from ..geometry import Pose
from ..objects import ObjectModel
from ..registry import register
from .base import Tracker
from ..edges import ModelView, fit_from_proposals, printed_faces, quality_verdict, to_gray
from ..edges.fit import TRACKING_POLISH, check_polish

_ONE_STEP = (cv2.TERM_CRITERIA_COUNT, 1, 0.0)
VARIANTS = {"rapid": "Rapid_create", "rapid-ols": "OLSTracker_create", "rapid-gos": "GOSTracker_create"}


# polish iterations of the refinement per variant, chosen on the standard suite's tuning seeds
# (docs/decisions.md): the polish helps rapid-gos and hurts rapid and rapid-ols there
POLISH = {"rapid": 0, "rapid-ols": 0, "rapid-gos": TRACKING_POLISH}


class RapidTracker(Tracker):
    """A ``cv2.rapid`` tracker (silhouette step) + optional moving-edge refinement.

    Args:
        object: the CAD model (metres).
        variant: ``"rapid"``, ``"rapid-ols"`` or ``"rapid-gos"``.
        refine: finish with the moving-edge fit on all visible model edges (quality from it).
            False gives OpenCV's result alone (quality = its match ratio; benchmarks only).
        control_points: cv2's ``num``; search_px: cv2's ``len``; iterations: cv2 steps per frame.
        subdivide_m: longest mesh edge after subdivision (control points live on vertices).
        lost_quality: below it ``lost`` (default 0.5 with refinement: the inlier fraction of
            matched edge samples × support; 0.3 for OpenCV's ratio).
        polish: the refinement's polish iterations (:func:`~hybridpose.edges.fit_edges`); None: the
            variant's default (``POLISH``).
    """

    def __init__(self, object: ObjectModel, variant: str = "rapid", refine: bool = True, control_points: int = 200,
                 search_px: int = 20, iterations: int = 2, subdivide_m: float = 0.04,
                 lost_quality: float | None = None, polish: int | None = None) -> None:
        if variant not in VARIANTS:
            raise ValueError(f"variant: expected one of {sorted(VARIANTS)}, got {variant!r}")
        self.polish = check_polish(POLISH[variant] if polish is None else polish)
        self.default_lost_quality = 0.5 if refine else 0.3
        self.tells_covered = bool(refine)  # the edge fit's quality sees what stands beside the object
        super().__init__(object, lost_quality)
        if control_points < 3 or search_px < 1 or iterations < 1 or subdivide_m <= 0:
            raise ValueError("control_points ≥ 3, search_px ≥ 1, iterations ≥ 1 and subdivide_m > 0 expected, got "
                             f"{control_points}, {search_px}, {iterations}, {subdivide_m}")
        self.name, self.variant, self.refine = variant, variant, bool(refine)
        self.control_points, self.search_px, self.iterations = int(control_points), int(search_px), int(iterations)
        v, f = trimesh.remesh.subdivide_to_size(object.vertices, object.faces, max_edge=float(subdivide_m))
        self._vertices = np.ascontiguousarray(v, np.float32)
        self._tris = np.ascontiguousarray(f, np.int32)
        self.view = ModelView(object) if refine else None
        self._cv = None

    def _init(self, frame: Frame, pose: Pose) -> None:
        # a fresh cv2 object: OLS/GOS learn their colour histograms on the first compute()
        self._cv = getattr(cv2.rapid, VARIANTS[self.variant])(self._vertices, self._tris)
        self.printed = self.view is not None and printed_faces(self.view, frame, pose)

    def _trial_shares(self) -> tuple:
        # OpenCV's trackers cannot be copied; OLS and GOS learn their colour histograms on a track's
        # first compute() only, so a trial's fits leave them as they were
        return (self._cv,)

    def _image(self, frame: Frame) -> np.ndarray:
        gray = cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY)
        if self.variant == "rapid":
            return gray
        return cv2.applyColorMap(gray, cv2.COLORMAP_JET)

    def _track(self, frame: Frame, start: Pose):
        K = frame.camera.K
        rvec = cv2.Rodrigues(start.R)[0]
        tvec = start.t.reshape(3, 1).copy()
        img = self._image(frame)
        ratio = 0.0
        try:
            for _ in range(self.iterations):
                ratio, rvec, tvec = self._cv.compute(img, self.control_points, self.search_px, K, rvec, tvec, _ONE_STEP)
        except cv2.error:
            ratio = 0.0  # e.g. the silhouette left the image: no control points
        pose = start
        if ratio > 0 and np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec)):
            candidate = Pose.from_rotvec_t(np.ravel(rvec), np.ravel(tvec))
            if candidate.t[2] > 0 and np.linalg.norm(candidate.t - start.t) < self.object.diameter:
                pose = candidate
        if not self.refine:
            if pose is start:
                return None, None, 0.0
            return pose, np.diag([0.05**2] * 3 + [0.01**2] * 3), float(ratio)
        # the silhouette pose is a proposal: the edge fit from the caller's start is kept when good,
        # else the fit from the silhouette pose competes (more agreeing model edges win)
        gray = to_gray(frame.image)
        best = fit_from_proposals(self.view, frame, (start,) if pose is start else (start, pose), gray=gray,
                                  polish=self.polish)
        if best is None:
            return None, None, 0.0
        self.last_sites = best.sites
        verdict = quality_verdict(self.view, frame, best, gray, dark_surround=self._dark_around, printed=self.printed,
                                  dark_scene=self._dark_scene)
        self._note_surround(verdict.beside)
        return best.pose, best.covariance, verdict.quality


def _factory(variant: str):
    def make(object: ObjectModel, **kwargs) -> RapidTracker:
        return RapidTracker(object, variant=variant, **kwargs)

    make.__name__ = f"make_{variant.replace('-', '_')}"
    make.__doc__ = f"``cv2.rapid`` backend {variant!r}; see :class:`RapidTracker`."
    # the keywords it takes are RapidTracker's (what `track --tracker-option` lists and checks)
    signature = inspect.signature(RapidTracker)
    make.__signature__ = signature.replace(parameters=[p for p in signature.parameters.values() if p.name != "variant"])
    return make


for _variant in VARIANTS:
    register("tracker", _variant, baseline=True)(_factory(_variant))
