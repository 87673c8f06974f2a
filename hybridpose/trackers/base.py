"""The tracker contract: given the pose at the previous frame (or the caller's prior), follow the
object into the next frame and say how sure it is — or that it has lost the object.

Every built-in backend derives from :class:`Tracker` (which fulfils the role's contract,
:mod:`hybridpose.contracts`), which checks inputs, keeps the state machine
(``init`` → ``track``… → ``reset``) and guarantees that no NaN leaves a tracker: a backend whose
solver produces non-finite numbers reports ``lost`` instead.
"""
from __future__ import annotations

import copy
from abc import ABC, abstractmethod

import numpy as np

from ..core import LOST_COVARIANCE, Frame, Measurement
from ..edges import ModelView
from ..geometry import Camera, Pose
from ..objects import ObjectModel

MIN_DEPTH_M = 0.01  # a pose whose object comes nearer the camera than this is no pose
# how deep :meth:`Tracker.trial` looks through a tracker's members (its cues, their samples, lists of
# them) for what a trial shares with it instead of copying
SHARED_SEARCH_DEPTH = 4
# never changed by a fit, and frames are compared by identity (the frame a track started on): a trial
# shares these with the tracker it was copied from
SHARED_TYPES = (Frame, ObjectModel, ModelView, Camera, Pose)
# where the object is seen covered, a fit below this quality follows the occluder's edges, not the
# object: the next search keeps the previous pose (the truss wholly behind the arm, its edges left
# out of the honest quality: fits at 0.02–0.09; half behind it, right fits at 0.2 and more)
COVERED_ACCEPT = 0.15


class Tracker(ABC):
    """Frame-to-frame model-based tracker (role ``"tracker"`` in :mod:`hybridpose.registry`).

    Args:
        object: the tracked object's CAD model (metres).
        lost_quality: ``track`` reports ``lost`` when its quality falls below this (per-backend
            default, documented by each backend; measured by ``hybridpose bench --modes tracker``).

    Attributes:
        covered: whether the last ``track`` call saw the object partly covered — something lit came
            to stand beside it where the track had dark space around it (on black space, only an
            occluder such as the arm does that). A backend that cannot tell leaves it False.
        tells_covered: True for a backend (an instance, where its options decide) that sets ``covered``.
        printed: whether the part carried a print at the initial pose (an edge-refining backend's
            quality then leaves the print's edges inside the faces out of what the model must explain:
            :func:`~hybridpose.edges.printed_faces`); False for a backend that does not look.
        last_sites: the moving-edge sites of the last ``init`` or ``track`` call's edge fit
            (:class:`~hybridpose.edges.fit.EdgeSites`: samples, matches, inliers; what
            :func:`~hybridpose.viz.draw_edge_sites` draws), or None where it made none.

    Subclasses implement :meth:`_init` and :meth:`_track`; one that can tell what stands beside the
    object calls :meth:`_note_surround` from ``_track`` and sets ``tells_covered``.
    """

    name = "tracker"
    default_lost_quality = 0.3
    tells_covered = False

    def __init__(self, object: ObjectModel, lost_quality: float | None = None) -> None:
        if not isinstance(object, ObjectModel):
            raise TypeError(f"object: expected a hybridpose ObjectModel (load_object(...)), got {type(object).__name__}")
        self.object = object
        self.lost_quality = self.default_lost_quality if lost_quality is None else float(lost_quality)
        if not 0.0 <= self.lost_quality <= 1.0:
            raise ValueError(f"lost_quality: expected a value in [0, 1], got {lost_quality}")
        self.pose: Pose | None = None
        self.frame: Frame | None = None  # the last frame, undistorted
        self._camera = None  # the camera of init's frame, distortion and all
        self.covered = False
        self._dark_around = False  # whether this track has seen dark space around the object
        # …and whether this video has, before this track too: a re-init (the hybrid's restart) keeps it,
        # reset forgets it. Around a lit background never seen dark, a printed part's edge quality is gentler
        self._dark_scene = False
        self.last_sites = None
        self.printed = False

    # --- public API --------------------------------------------------------------------------------
    def init(self, frame: Frame, pose: Pose) -> None:
        """Start tracking at ``pose`` (``T_cam_obj``, metres) in ``frame``. Whether the video showed
        the object on black space before is kept (a restart within the same video); :meth:`reset` forgets it."""
        self._check_frame(frame)
        self._check_pose(pose, "pose")
        self.covered = self._dark_around = False
        self.last_sites = None
        self._camera = frame.camera  # as given: the next frames must come from it
        frame = frame.undistorted()  # the edge fits model a pinhole camera
        self._init(frame, pose)
        self.pose, self.frame = pose, frame

    def track(self, frame: Frame, prior: Pose | None = None, search_px: float | None = None,
              lost_quality: float | None = None, covered_lost_quality: float | None = None) -> Measurement:
        """Pose in ``frame``, searched around ``prior`` (default: the last pose).

        ``search_px``: how far (pixels) the object may lie from its projection at ``prior`` when that
        is further than the backend's own frame-to-frame range: a coarse prior such as a CNN pose. A
        backend with a fixed range ignores it.

        ``lost_quality``: this call's threshold in place of the backend's own (0..1): a caller that
        knows more, such as an estimator holding a long, consistent track through a partial
        occlusion, may accept a lower quality. ``covered_lost_quality``: the threshold instead where
        the backend sees the object partly covered (:attr:`covered`): an occluder hides model edges
        and adds edges the model does not explain, so a right fit scores lower.

        Returns a :class:`Measurement` with quality in 0..1. When quality falls below
        ``lost_quality`` or the solve fails, ``lost`` is True and ``pose`` is None (the contract of
        every backend of every role: ``lost == (pose is None)``); the next ``track`` without a prior
        still searches from the solver's last pose.
        """
        if self.pose is None or self.frame is None:
            raise RuntimeError(f"{self.name}: track() called before init(frame, pose)")
        self._check_frame(frame)
        if frame.camera != self._camera:
            raise ValueError(f"frame.camera: {frame.camera} differs from the camera given to init ({self._camera})")
        frame = frame.undistorted()
        start = self.pose if prior is None else prior
        if prior is not None:
            self._check_pose(prior, "prior")
        if search_px is not None and not (np.isfinite(search_px) and search_px > 0):
            raise ValueError(f"search_px: expected a positive number of pixels or None, got {search_px}")
        for name, value in (("lost_quality", lost_quality), ("covered_lost_quality", covered_lost_quality)):
            if value is not None and not 0.0 <= value <= 1.0:
                raise ValueError(f"{name}: expected a quality in [0, 1] or None, got {value}")
        threshold = self.lost_quality if lost_quality is None else float(lost_quality)
        self.covered = False
        self.last_sites = None
        try:
            if search_px is None:
                pose, cov, quality = self._track(frame, start)
            else:
                pose, cov, quality = self._track_wide(frame, start, float(search_px))
        except np.linalg.LinAlgError:
            pose, cov, quality = None, None, 0.0
        finite = pose is not None and np.all(np.isfinite(pose.matrix)) and cov is not None and np.all(np.isfinite(cov))
        if not finite or pose.t[2] <= MIN_DEPTH_M:
            pose, quality = None, 0.0
        quality = float(np.clip(quality, 0.0, 1.0))
        if covered_lost_quality is not None and self.covered:
            threshold = float(covered_lost_quality)
        if pose is None or quality < threshold:
            m = Measurement(pose=None, covariance=LOST_COVARIANCE, quality=quality, source=f"tracker:{self.name}",
                            timestamp=frame.timestamp, lost=True)
        else:
            m = Measurement(pose=pose, covariance=cov, quality=quality, source=f"tracker:{self.name}",
                            timestamp=frame.timestamp)
        self._accept(frame, pose, quality)
        return m

    def reset(self) -> None:
        """Forget the object (``track`` needs a new ``init``)."""
        self.pose, self.frame = None, None
        self.covered = self._dark_around = self._dark_scene = False

    def trial(self) -> Tracker:
        """A copy of this tracker for a fit that must leave its track as it is.

        A fit teaches a tracker what it saw (texture points kept and lifted, keyframes, colour
        statistics, the pose the next search starts from). A second fit of the same frame from another
        start — the hybrid checking a network's pose — would teach it that pose's view, wrong or
        right, and the next frame would follow it. The copy shares what no fit changes
        (:data:`SHARED_TYPES`: the model and its views, frames, cameras, poses) and is thrown away
        after its fit.
        """
        shared: dict[int, object] = {id(o): o for o in self._trial_shares()}
        _collect_shared(self, shared, SHARED_SEARCH_DEPTH, set())
        return copy.deepcopy(self, shared)

    def _trial_shares(self) -> tuple:
        """Members a :meth:`trial` shares with this tracker beyond :data:`SHARED_TYPES`: those a fit
        leaves as they are and that cannot be copied (an OpenCV object)."""
        return ()

    # --- for subclasses -------------------------------------------------------------------------
    @abstractmethod
    def _init(self, frame: Frame, pose: Pose) -> None:
        """Prepare for tracking from ``pose`` in ``frame`` (inputs already checked)."""

    @abstractmethod
    def _track(self, frame: Frame, start: Pose) -> tuple[Pose | None, np.ndarray | None, float]:
        """(pose, (6, 6) covariance over ``[ω, v]``, quality) in ``frame`` starting from ``start``."""

    def _note_surround(self, lit_beside: bool) -> None:
        """Record what the fit this ``_track`` call returns saw around the object: ``lit_beside``,
        something lit beside it (:func:`~hybridpose.edges.quality_verdict`). Something lit where the
        track saw dark space is an occluder that came in: ``covered``. A lit background (the Earth, a
        photo) is lit from the start and never counts."""
        self.covered = lit_beside and self._dark_around
        self._dark_around = self._dark_around or not lit_beside
        self._dark_scene = self._dark_scene or self._dark_around

    def _track_wide(self, frame: Frame, start: Pose, search_px: float) -> tuple[Pose | None, np.ndarray | None, float]:
        """:meth:`_track` with the search reaching ``search_px`` pixels (default: the backend's own range)."""
        return self._track(frame, start)

    def _accept(self, frame: Frame, pose: Pose | None, quality: float) -> None:
        """Remember the result: the next search starts from the solver's pose, even one below
        ``lost_quality`` (a caller with a better idea — the estimator — passes ``prior``); a failed
        solve, or one under ``COVERED_ACCEPT`` where the object is seen covered, keeps the previous
        pose."""
        if pose is not None and quality > (COVERED_ACCEPT if self.covered else 0.0):
            self.pose = pose
        self.frame = frame

    # --- checks ------------------------------------------------------------------------------------
    @staticmethod
    def _check_frame(frame: Frame) -> None:
        if not isinstance(frame, Frame):
            raise TypeError(f"frame: expected a hybridpose Frame, got {type(frame).__name__}")

    @staticmethod
    def _check_pose(pose: Pose, name: str) -> None:
        if not isinstance(pose, Pose):
            raise TypeError(f"{name}: expected a hybridpose Pose (T_cam_obj), got {type(pose).__name__}")
        if pose.t[2] <= MIN_DEPTH_M:
            raise ValueError(f"{name}: the object is behind the camera (t_z = {pose.t[2]:.3f} m; expected > {MIN_DEPTH_M} m)")


def _collect_shared(obj, shared: dict[int, object], depth: int, seen: set[int]) -> None:
    """Record in ``shared`` (id → object, a :func:`copy.deepcopy` memo) every member of ``obj`` down to
    ``depth`` levels that a trial shares (:data:`SHARED_TYPES`)."""
    if id(obj) in seen:
        return
    seen.add(id(obj))
    if isinstance(obj, SHARED_TYPES):
        shared[id(obj)] = obj
        return
    if depth == 0 or isinstance(obj, (np.ndarray, str, bytes, int, float)):
        return
    members = (obj if isinstance(obj, (list, tuple, set)) else obj.values() if isinstance(obj, dict)
               else vars(obj).values() if hasattr(obj, "__dict__") else ())
    for member in members:
        _collect_shared(member, shared, depth - 1, seen)
