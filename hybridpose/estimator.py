"""``HybridEstimator``: the policy that combines a model-based tracker, a CNN pose regressor and a
fusion filter — the only place where the three roles meet.

Status machine, one :meth:`HybridEstimator.step` per frame::

    init ──CNN pose──▶ tracking ──tracker lost / k gate rejections──▶ lost
                          ▲  │                                         │
                          │  └─CNN disagrees k checks in a row─▶ reinit│
                          └──────────────────── reinit ◀──two CNN answers agree

- **init**: no pose yet; the CNN runs on the full image until it finds the object and the tracker, started from the
  CNN pose (or from it slid along its viewing ray: the CNN's depth is its largest error; or from the network's other
  poses in the frame, ``start_alternatives``), confirms it (not lost; off black space, where it reports its cues,
  not by its edges alone unless the scene around is plain, ``plain_surround_quality``; its fit standing out from its
  own view slid across the image: clutter matches a wrong outline as well as its neighbours, ``start_contrast``; a
  plain part's in lit clutter, where another of the network's passes saw it too, ``start_sighting_iou``); the
  tracker's fit starts the fusion — or, where not convincing (``start_sure_quality``), a clearly better one from the
  start turned a few degrees; a plain part's in a lit scene, a clearly better one from the poses that cast its
  outline too, none where one of them (or, where the tracker sees colours, a pose another pass of the network saw
  there) fits about as well (``start_rival_margin``); a printed part's, moved up the print's score
  (``start_print_turn_deg``). Every start (init, reinit) does so.
- **tracking**: the fusion predicts; the tracker searches from the prediction; its measurement is gated
  (Mahalanobis) and fused (after ``keep_after`` frames, down to ``keep_covered_quality`` where the tracker sees the
  object covered, or, for a tracker that cannot tell, down to ``keep_quality``: an arm covering half the object
  lowers a right fit's quality under the tracker's own threshold). Every ``check_period`` frames the CNN runs on a
  crop around the predicted projection, and the tracker fits the edges from the CNN pose too (:class:`CnnCheck`).
  The check disagrees when the CNN pose is far from the fused one (``disagreement_chi2`` with both covariances;
  optionally ``disagreement_deg``) or when the fit from it lands elsewhere and matches the image better than the
  track (``switch_quality_margin``); ``confirm_checks`` disagreeing checks in a row (the next check follows at once)
  restart everything from that fit — the drift the tracker did not flag. A check whose CNN pose the edges cannot fit
  at all (typically its end-for-end twin) while the track fits better does not count, nor, for a printed part, one
  whose fit shows the print worse than the track (``print_prefers``). A CNN pose that agrees is fused. A tracker
  measurement the gate refuses calls a check at once; where the CNN and the edges from its pose vouch for it, the
  fusion (not the tracker) was wrong and starts over there. Where the tracker loses the object from the prediction,
  an established track (``retry_after``) tries once more from the tracker's previous pose and, found there, starts
  the fusion over from that fit: a hand-held camera stops where a constant-velocity model runs on.
- **lost**: the tracker said lost, or gating refused it ``lost_after_rejections`` frames in a row. The fusion keeps
  predicting (the estimate's covariance grows); the CNN runs on every frame until two consecutive answers agree
  (``reacquire_chi2``; optionally within ``reacquire_deg``) and the tracker, started from the latest, confirms it
  (under the arm the CNN can repeat a wrong answer; the edges do not match it); then everything restarts from the
  tracker's fit (**reinit**). Meanwhile the tracker also tries from the prediction each frame and takes up again
  when its fit is good, inside the gate and, for a printed part, the pose its print shows best (``print_backs``).

A start (init, reinit) may be put on probation (``confirm_frames``): not trusted until it has held. A printed part's
tracked pose where its print does not show (``track_print_floor``) is reported lost; so is, in a lit scene, a frame
that nothing measured (the tracker's fit refused by the gate, no CNN check to vouch): the fusion's prediction, the
guess of a hand's motion. The track goes on from either. In a lit scene, wherever the CNN would run, the part's
keypoint memory (``keypoint_memory``) answers first where it can: its print, where its model carries one, and its
look in this video, learned where the track was sure (``learn_after``); its answers are confirmed as the CNN's are.
Where neither finds a printed part at init, every few frames it is started from poses all round it where its print's
colours stand out (``colour_start_every``). There the fusion's motion model is a hand's (``handheld_accel_rad_s2``).

For a symmetric object (its ``symmetries``) each CNN answer is first restated as the equivalent pose nearest the
track (or, while lost, nearest the previous answer): the CNN may give any of the poses that look the same, and only
that one can be compared with the track or fused into it. A part that carries its print (``ObjectModel.texture``)
starts at the equivalent pose its print shows, so its track gives which face is which.

Every threshold is a field of :class:`HybridConfig`, its default chosen on the tuning seeds of the
suites (``hybridpose bench --split tuning``; evidence in ``docs/decisions.md``).
"""
from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from .contracts import check_backend
from .core import LOST_COVARIANCE, Estimate, Frame, Measurement, Status, check_next_frame
from .edges import ModelView, to_gray8
from .edges.silhouette import SPACE_DARK_SHARE, dark_share
from .fusion.base import measured_twist, nearest_equivalent_measurement, pose_mahalanobis2 as _mahalanobis2
from .geometry import Camera, Pose
from .geometry.crops import projection_roi
from .hybrid_config import DEFAULT_FUSION, HybridConfig, recommended_config
from .metrics import rotation_error_deg
from .objects import ObjectModel
from .regressors.colour_starts import SOURCE as COLOUR_SOURCE, ColourStarts
from .regressors.keypoint_memory import SOURCE as MEMORY_SOURCE, KeypointMemory
from .starts import (CnnCheck, confirmed_start, cues_vouch, edges_alone_in_clutter, image_test, plain_alternatives, print_backs,
                     print_climber, print_fails, print_prefers, print_view, rival_test, start_refused_in_light, unseen_in_clutter)
from .threads import set_threads

MAX_TWIST_GAP_S = 0.2  # a twist measured from two tracker poses further apart than this is not worth keeping


@dataclass
class _Counters:
    since_check: int = 0
    since_start: int = 0
    disagreements: int = 0
    rejections: int = 0
    tracker_losses: int = 0
    last_cnn: Measurement | None = None


class HybridEstimator:
    """Track a known object in a monocular sequence with no initial pose.

    Args:
        tracker: a :class:`~hybridpose.trackers.base.Tracker`, or any object giving the members of
            :class:`~hybridpose.contracts.TrackerContract` (checked here: TypeError naming those missing).
        regressor: a :class:`~hybridpose.regressors.base.PoseRegressor`, or the same for
            :class:`~hybridpose.contracts.RegressorContract`.
        fusion: a :class:`~hybridpose.fusion.base.Fusion`, or the same for
            :class:`~hybridpose.contracts.FusionContract`.
        config: the policy's thresholds: a :class:`HybridConfig`, used as given; None (default): the
            defaults with the fields the regressor recommends (``regressor.hybrid_config``: a part's
            fitted network carries ``reacquire_deg=20``); a mapping of fields: those recommended
            values with these changed (``{"reacquire_deg": None}`` turns the recommendation off).
        threads: CPU threads for the per-frame work (:func:`hybridpose.threads.set_threads`, set for the process):
            None (default) takes ``HYBRIDPOSE_THREADS`` or 1, which holds up where other work keeps the cores busy.

    ``step(frame)`` returns an :class:`~hybridpose.core.Estimate` per frame: pose (``T_cam_obj``,
    metres; None until the CNN first finds the object), 6×6 covariance, body twist, status, the
    measurement sources fused and the milliseconds per component.
    """

    def __init__(self, tracker, regressor, fusion, config: HybridConfig | Mapping | None = None,
                 threads: int | None = None) -> None:
        for role, backend in (("tracker", tracker), ("regressor", regressor), ("fusion", fusion)):
            check_backend(role, backend)
        self.tracker, self.regressor, self.fusion = tracker, regressor, fusion
        self.threads = set_threads(threads)
        if config is None or isinstance(config, Mapping):
            config = recommended_config(regressor.hybrid_config, config, type(regressor).__name__)
        if not isinstance(config, HybridConfig):
            raise TypeError(f"config: expected a HybridConfig, a mapping of its fields or None, got {type(config).__name__}")
        self.config = config
        self.object: ObjectModel | None = tracker.object
        self.regressor_calls = 0  # since construction: the CNN's share of the work
        # the start's image test slides the model's edges across the frame (none without a CAD model: a user's backend)
        self._view = ModelView(self.object) if self.object is not None else None
        self._print = print_view(self._view)  # a printed part's print: checks its starts, seeds its memory
        self._own_motion_noise = getattr(fusion, "motion_noise", None)  # set off black space, back on it
        self.reset()

    @classmethod
    def from_names(cls, object: str | ObjectModel = "truss", tracker: str = "edges", regressor: str = "default",
                   fusion: str = DEFAULT_FUSION, config: HybridConfig | Mapping | None = None, scale: float = 1.0,
                   tracker_kw: dict | None = None, regressor_kw: dict | None = None,
                   fusion_kw: dict | None = None, threads: int | None = None) -> HybridEstimator:
        """Build every part from :mod:`hybridpose.registry` names.

        Args:
            object: a built-in object name (``"truss"``), a mesh file, or an :class:`ObjectModel`.
            tracker, fusion: registered names (``registry.available("tracker")`` ...).
            regressor: a registered name, or the path of a trained checkpoint (``runs/x/best.pt``).
            config: as for the constructor (None: the regressor's recommended policy).
            scale: mesh units → metres for a mesh file (0.001 for mm).
            tracker_kw, regressor_kw, fusion_kw: keyword arguments of each backend. threads: as for the constructor.
        """
        from .objects import load_object
        from .registry import create, create_regressor

        obj = object if isinstance(object, ObjectModel) else load_object(object, scale=scale)
        return cls(create("tracker", tracker, object=obj, **(tracker_kw or {})),
                   create_regressor(regressor, object=obj, **(regressor_kw or {})),
                   create("fusion", fusion, **(fusion_kw or {})), config=config, threads=threads)

    # --- public API --------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget everything: the next frame starts from the CNN again."""
        self.status = Status.INIT
        self._frames = 0  # frames stepped since reset (the one being stepped: not yet counted)
        self._restarts: list[int] = []  # frame counts at which fusion and tracker restarted
        self._first_start = False  # whether the last restart was the first start since reset
        self.best_start_fit = 0.0  # the best quality a start's fit reached since reset (why a run never started)
        self.camera: Camera | None = None
        self.last_timestamp: float | None = None
        self._n = _Counters()
        self.last_tracker: Measurement | None = None  # the tracker's last measurement (for plots and logs)
        self.memory: KeypointMemory | None = None  # the part's look, made at the first frame (none on black space)
        self.colour_starts: ColourStarts | None = None  # a printed part's last-resort starts (the same)
        self._lit = True  # whether the video's first frame is off black space (_meet_scene)
        self.tracker.reset()

    def step(self, frame: Frame) -> Estimate:
        """Estimate the pose in ``frame`` (frames in time order, one camera)."""
        self.camera = check_next_frame(frame, self.camera, self.last_timestamp)
        if self._frames == 0:
            self._meet_scene(frame)
        timings = {"tracker": 0.0, "regressor": 0.0, "fusion": 0.0}
        t_start = time.perf_counter()
        frame = frame.undistorted()  # once for the tracker and the CNN, which both model a pinhole
        state = {Status.INIT: self._initialise, Status.LOST: self._reacquire, Status.TRACKING: self._track}
        estimate = state[self.status](frame, timings)
        self._frames += 1
        unsettled = estimate.status in (Status.TRACKING, Status.REINIT) and self.config.unsettled(self._restarts, self._frames)
        if unsettled or (estimate.status == Status.TRACKING  # the track goes on, not trusted where its print does not show
                         and print_fails(self._print, frame, estimate.pose, self.config.track_print_floor)):
            estimate = replace(estimate, status=Status.LOST)
        estimate = self._on_probation(estimate, frame)
        if self._lit and estimate.status == Status.TRACKING and not estimate.sources:  # a hand's motion, guessed
            estimate = replace(estimate, status=Status.LOST)
        self.last_timestamp = frame.timestamp
        timings["total"] = 1000 * (time.perf_counter() - t_start)
        estimate.timings_ms.update(timings)
        return estimate

    def run(self, frames):
        """``step`` over an iterable of frames; yields (frame, estimate)."""
        for frame in frames:
            yield frame, self.step(frame)

    # --- the three states --------------------------------------------------------------------------
    def _initialise(self, frame: Frame, timings: dict) -> Estimate:
        fit = None
        for m, seen in self._start_candidates(frame, timings):
            if (fit := self._confirmed(frame, m, timings, depth_search=True, sightings=seen)) is not None:
                break
        if fit is None:
            return Estimate(pose=None, covariance=LOST_COVARIANCE, timestamp=frame.timestamp, status=Status.INIT)
        self._restart(frame, fit, timings)
        self.status = Status.TRACKING
        self._first_start = True
        return self._estimate(Status.INIT, (m.source, fit.source))

    def _track(self, frame: Frame, timings: dict) -> Estimate:
        prior = self._timed(timings, "fusion", self.fusion.predict, frame.timestamp)
        keep, keep_covered = self._keep_quality()
        m = self._track_from(frame, prior.pose, timings, lost_quality=keep, covered_lost_quality=keep_covered)
        previous, self.last_tracker = self.last_tracker, m
        if m.lost and self._retries(previous):
            retry = self._track_from(frame, previous.pose, timings, lost_quality=keep,
                                     covered_lost_quality=keep_covered)
            if not retry.lost:
                # the object is where the tracker last saw it, not where the motion model sent it (a
                # hand-held camera that stopped)
                self.last_tracker = retry
                return self._take_up(frame, retry, timings)
        sources = []
        rejected = False
        if m.lost:
            self._n.tracker_losses += 1
            if self._n.tracker_losses >= self.config.lost_after_tracker_losses:
                return self._declare_lost(frame, timings)
        elif self._timed(timings, "fusion", self.fusion.update, m):
            sources.append(m.source)
            self._n.rejections = self._n.tracker_losses = 0
            self._learn(frame, m, timings)
        else:
            self._n.rejections += 1
            rejected = True
            if self._n.rejections >= self.config.lost_after_rejections:
                return self._declare_lost(frame, timings)
        self._n.since_check += 1
        self._n.since_start += 1
        due = ((self.config.check_period > 0 and (self._n.since_check >= self.config.check_period
                                                  or self._n.disagreements > 0))
               or m.quality < self.config.check_below_quality or self._n.since_start <= self.config.probation_frames
               or (rejected and self.config.check_on_rejection))
        if due:
            self._n.since_check = 0
        check = self._check(frame, m, timings) if due else None
        if check is None:
            return self._estimate(Status.TRACKING, tuple(sources))
        if rejected and self.config.check_on_rejection and check.vouches_for(m, self.config.disagreement_chi2):
            # the edges from the CNN pose land on the refused measurement: the motion model was
            # wrong, not the tracker; start the fusion over from the tracker
            self._restart(frame, m, timings, measured_twist(previous, m, MAX_TWIST_GAP_S))
            return self._estimate(Status.TRACKING, (m.source, check.cnn.source))
        if check.disagrees and check.fit.lost and check.backed_by(m, self.config.switch_quality_margin):
            # the model's edges find nothing to hold at the CNN pose (typically its end-for-end twin)
            # while the track fits better: the image backs the track, the check is an outlier
            self._n.disagreements = 0
        elif check.disagrees:
            self._n.disagreements += 1
            if self._n.disagreements >= self.config.confirm_checks:
                if not check.stayed and not self.config.restart_unconfirmed:
                    return self._declare_lost(frame, timings)
                # restart from the edge fit where it stayed with the CNN, else from the CNN itself
                self._restart(frame, check.fit if check.stayed else check.cnn, timings)
                return self._estimate(Status.REINIT, (check.cnn.source, check.fit.source) if check.stayed
                                      else (check.cnn.source,))
        else:
            self._n.disagreements = 0
            if self._timed(timings, "fusion", self.fusion.update, check.cnn):
                sources.append(check.cnn.source)
        return self._estimate(Status.TRACKING, tuple(sources))

    def _check(self, frame: Frame, m: Measurement, timings: dict) -> CnnCheck | None:
        """The CNN on a crop around the fused pose, and the tracker's fit from its answer, held against
        the fused pose and the track's measurement ``m`` (None where the CNN found nothing)."""
        fused = self.fusion.estimate
        roi = None if self.object is None else projection_roi(self.object.bbox_corners, fused.pose, frame.camera,
                                                               self.config.check_roi_margin)
        c = self._cnn(frame, roi, timings, near=fused.pose)
        if c.pose is None:
            return None
        chi2 = self.config.disagreement_chi2
        fit = self._track_from(frame, c.pose, timings, self.config.cnn_search_px or None, from_cnn=True, trial=True)
        far = (_mahalanobis2(fused.pose, fused.covariance, c.pose, c.covariance) > chi2
               or (self.config.disagreement_deg is not None
                   and rotation_error_deg(fused.pose, c.pose) > self.config.disagreement_deg))
        better = (fit.pose is not None and fit.quality > m.quality + self.config.switch_quality_margin
                  and _mahalanobis2(fused.pose, fused.covariance, fit.pose, fit.covariance) > chi2)
        stayed = fit.pose is not None and _mahalanobis2(c.pose, c.covariance, fit.pose, fit.covariance) <= chi2
        return CnnCheck(c, fit, disagrees=(far or better) and print_prefers(self._print, frame, fit, m), stayed=stayed)

    def _reacquire(self, frame: Frame, timings: dict) -> Estimate:
        prior = self._timed(timings, "fusion", self.fusion.predict, frame.timestamp)
        if self.config.tracker_resumes:
            m = self._track_from(frame, prior.pose, timings)
            self.last_tracker = m
            vouched = cues_vouch(getattr(self.tracker, "cue_qualities", None), self.config.resume_cue_quality)
            if (not m.lost and vouched and not self._edges_alone(frame, m) and print_backs(self._print, frame, m.pose)
                    and self._timed(timings, "fusion", self.fusion.update, m)):
                # inside the gate: taken up, but the fusion starts over from the fit — the twist coasted through the
                # loss is a guess, and after one update its spread still lets the next CNN check pull the track off by cm
                return self._take_up(frame, m, timings)
        self._n.since_check += 1
        if self._n.since_check < self.config.lost_check_period:
            return self._estimate(Status.LOST, ())
        self._n.since_check = 0
        previous = self._n.last_cnn
        m = self._cnn(frame, None, timings, near=previous.pose if previous is not None else None)
        self._n.last_cnn = m
        if m.pose is not None and previous is not None and previous.pose is not None:
            dt = m.timestamp - previous.timestamp
            motion = self.fusion.initial_twist_covariance * dt**2
            cap = self.config.reacquire_deg
            if (_mahalanobis2(previous.pose, previous.covariance + motion, m.pose, m.covariance) <= self.config.reacquire_chi2
                    and (cap is None or rotation_error_deg(previous.pose, m.pose) <= cap)
                    and (fit := self._confirmed(frame, m, timings)) is not None):
                self._restart(frame, fit, timings)
                self.status = Status.TRACKING
                return self._estimate(Status.REINIT, (m.source, fit.source))
        return self._estimate(Status.LOST, ())

    # --- helpers -----------------------------------------------------------------------------------
    def _declare_lost(self, frame: Frame, timings: dict) -> Estimate:
        self.status, self._n = Status.LOST, _Counters()
        # the CNN starts looking at once; its answer here is the first of the two that must agree
        self._n.last_cnn = self._cnn(frame, None, timings, near=self.fusion.estimate.pose)
        return self._estimate(Status.LOST, ())

    def _confirmed(self, frame: Frame, m: Measurement, timings: dict, depth_search=False, sightings=None) -> Measurement | None:
        """The start the CNN measurement ``m`` gives in ``frame`` (:func:`~hybridpose.starts.confirmed_start`; ``sightings``:
        the network's other sightings of the part there, for a part with no print, :func:`~hybridpose.starts.unseen_in_clutter`)."""
        # the wide turns are for a plain part's minima in light (on the truss's tuning sequences none helped)
        c = self.config if self._lit else replace(self.config, start_wide_turn_deg=0.0)
        plain_bar = c.plain_start_quality if m.source != MEMORY_SOURCE and self._print is None else 0.0
        seen = sightings if self._print is None else None  # a printed part's start answers to its print

        def fit(start: Pose) -> Measurement | None:
            try:
                self._timed(timings, "tracker", self.tracker.init, frame, start)
            except ValueError:  # a tracker may refuse a start where nothing of the model matches the image
                return None
            f = self._track_from(frame, start, timings, c.cnn_search_px or None, from_cnn=True)
            self.best_start_fit = max(self.best_start_fit, f.quality if f.pose is not None else 0.0)
            cues = getattr(self.tracker, "cue_qualities", None)
            refused = self._view is not None and (
                start_refused_in_light(cues, frame, self._view, f, plain_bar, c.plain_surround_quality)
                or unseen_in_clutter(seen, frame, self._view, f, c.start_sighting_iou))
            return None if refused else f

        floor = c.colour_start_print if m.source == COLOUR_SOURCE else 0.0  # 32 blind tries: the print must show well
        stands_out = image_test(self._view, frame, c.start_contrast, self._print, c.start_print_margin, floor)
        climb = print_climber(fit, self._print, frame, self.object, c.start_print_turn_deg)
        # the network's other sightings doubt a start only where the tracker's colours speak too (docs/decisions.md)
        doubting = sightings if "region" in getattr(self.tracker, "modalities", ()) else None
        rivals = rival_test(self._view, frame, self._print is not None, c.start_rival_margin, doubting, c.start_sighting_iou)
        return confirmed_start(m, fit, c if m.source != MEMORY_SOURCE else replace(c, start_quality=c.memory_start_quality),
                               depth_search, stands_out, climb, rivals)

    def _edges_alone(self, frame: Frame, m: Measurement) -> bool:
        """Whether the fit ``m`` in ``frame`` stands on its edges alone in a lit scene: no start, nor a take-up (a start too)."""
        cues = getattr(self.tracker, "cue_qualities", None)
        return self._view is not None and not m.lost and edges_alone_in_clutter(cues, frame, self._view, m.pose)

    def _take_up(self, frame: Frame, m: Measurement, timings: dict) -> Estimate:
        """The track goes on from the tracker's own fit ``m`` (no CNN involved): the fusion starts over
        there with zero twist and its initial uncertainty, the counters of the track from zero."""
        self._timed(timings, "fusion", self.fusion.reset, m.pose, m.covariance, frame.timestamp)
        self.status = Status.TRACKING
        self._n = _Counters()
        return self._estimate(Status.TRACKING, (m.source,))

    def _retries(self, previous: Measurement | None) -> bool:
        """Whether a fit lost from the prediction is tried again from the tracker's ``previous`` pose: the track has run
        ``retry_after`` frames since its last (re)start (a younger one may be a wrong start a second chance keeps alive)."""
        after = self.config.retry_after
        return after is not None and previous is not None and previous.pose is not None and self._n.since_start >= after

    def _track_from(self, frame: Frame, start: Pose, timings: dict, search_px: float | None = None,
                    lost_quality: float | None = None, covered_lost_quality: float | None = None,
                    from_cnn: bool = False, trial: bool = False) -> Measurement:
        """The tracker's measurement searched from ``start`` (up to ``search_px`` pixels away where the
        tracker can widen its search; lost below ``lost_quality`` where given — below
        ``covered_lost_quality`` where given and the tracker sees the object covered — else below the
        tracker's own threshold; ``from_cnn``: ``start`` is a CNN pose, fitted without the frame's sun
        unless ``sun_in_cnn_fits``); lost where the tracker refuses that start (a prediction coasting
        while lost can leave the view or pass behind the camera). ``trial``: a second fit of the frame,
        on the tracker's throw-away copy where it offers one (``trial()``): the track goes on as before."""
        kw = {k: v for k, v in dict(search_px=search_px, lost_quality=lost_quality,
                                    covered_lost_quality=covered_lost_quality).items() if v is not None}
        if from_cnn and not self.config.sun_in_cnn_fits and frame.sun_direction_cam is not None:
            frame = replace(frame, sun_direction_cam=None)
        tracker = self.tracker.trial if trial and hasattr(self.tracker, "trial") else lambda: self.tracker
        try:
            return self._timed(timings, "tracker", lambda: tracker().track(frame, start, **kw))
        except ValueError:
            return Measurement(None, LOST_COVARIANCE, 0.0, "tracker:refused", frame.timestamp)

    def _keep_quality(self) -> tuple[float | None, float | None]:
        """The tracker's lost thresholds for the next frame-to-frame fit (in general, where it sees the object
        covered: :meth:`HybridConfig.keep_thresholds`), once the track has run ``keep_after`` frames since its
        start; else None (the tracker's own)."""
        if self._n.since_start < self.config.keep_after:
            return None, None
        return self.config.keep_thresholds(self.tracker.lost_quality, self.tracker.tells_covered)

    def _meet_scene(self, frame: Frame) -> None:
        """At a video's first frame, off black space: the part's keypoint memory (``keypoint_memory``), a printed
        part's colour starts (``colour_start_every``), a hand's motion model (``handheld_accel_rad_s2``) and the
        starts' wide turns (``start_wide_turn_deg``); on black space none."""
        own = self._own_motion_noise
        lit = self._lit = dark_share(to_gray8(frame.image)) < SPACE_DARK_SHARE
        if self.config.keypoint_memory and self._view is not None and lit:
            self.memory = KeypointMemory.for_part(self._view, frame.camera, self._print)
        if self.config.colour_start_every and self._print is not None and lit:
            self.colour_starts = ColourStarts(self.object)
        if own is not None and self.config.handheld_accel_rad_s2 is not None:  # a fusion that lets it be set
            c = self.config
            self.fusion.motion_noise = (c.handheld_accel_rad_s2, c.handheld_accel_m_s2) if lit else own

    def _restart(self, frame: Frame, m: Measurement, timings: dict, twist: np.ndarray | None = None) -> None:
        """Fusion and tracker start over from ``m`` (the tracker's fit), with body twist ``twist`` (6,) rad/s, m/s."""
        # by default the twist starts again from zero with the fusion's initial uncertainty: one
        # estimated through a drift or a loss is not worth keeping
        self._timed(timings, "fusion", self.fusion.reset, m.pose, m.covariance, frame.timestamp, twist)
        try:
            self._timed(timings, "tracker", self.tracker.init, frame, m.pose)
        except ValueError:  # a tracker may refuse a start; its last track (which gave m) left it there
            pass
        self._n = _Counters()
        self._restarts.append(self._frames)
        self._first_start = False  # (the first start says so after this)

    def _on_probation(self, estimate: Estimate, frame: Frame) -> Estimate:
        """``estimate`` as the start's probation has it (``confirm_frames``): within a start's first
        frames ``init`` without a pose (the first start) or ``lost`` (a restart); a first start lost
        within them sends the estimator back to ``init``."""
        n = self.config.confirm_frames
        if n == 0 or not self._restarts or self._frames - self._restarts[-1] > n:
            return estimate
        if estimate.status == Status.LOST and self._first_start:
            self.status = Status.INIT  # a wrong first start: look again from scratch
        if self._first_start:
            return Estimate(pose=None, covariance=LOST_COVARIANCE, timestamp=frame.timestamp, status=Status.INIT)
        return replace(estimate, status=Status.LOST)

    def _learn(self, frame: Frame, m: Measurement, timings: dict) -> None:
        """The memory learns the part's look from the tracker's fit ``m`` where the track is sure of it:
        ``learn_after`` frames since its start, ``start_sure_quality``, every cue vouching, not the edges alone."""
        if (self.memory is not None and self._n.since_start >= self.config.learn_after
                and m.quality >= self.config.start_sure_quality and self.memory.wants(m.pose)
                and cues_vouch(getattr(self.tracker, "cue_qualities", None), self.config.resume_cue_quality)
                and not self._edges_alone(frame, m)):
            self._timed(timings, "regressor", self.memory.learn, frame, m.pose)

    def _start_candidates(self, frame: Frame, timings: dict):
        """What a start tries in turn until one is confirmed, each with the network's sightings of the part in the frame
        (None: not said): the memory's answer, else the network's and its other poses (``start_alternatives``, plain
        surroundings only); every ``colour_start_every`` frames, a printed part's colour starts."""
        m = None if self.memory is None else self._timed(timings, "regressor", self.memory.find, frame, None)
        candidates = getattr(self.regressor, "candidates", None)
        self.regressor_calls += m is None
        found = ([m] if m is not None else self._timed(timings, "regressor", candidates, frame, None, self.config.start_alternatives)
                 if candidates else [self._timed(timings, "regressor", self.regressor.predict, frame, None)])
        yield from ((c, getattr(found, "sightings", None)) for c in plain_alternatives(found, frame, self._view))
        if self.colour_starts is not None and (every := self.config.colour_start_every) and self._frames % every == 0:
            yield from ((c, None) for c in self._timed(timings, "regressor", self.colour_starts.candidates, frame))

    def _cnn(self, frame: Frame, roi, timings: dict, near: Pose | None = None) -> Measurement:
        """The memory's answer in ``frame`` (:attr:`memory`), else the regressor's; for a symmetric
        object, as the equivalent pose nearest ``near`` (where given): its answer may be any of the
        poses that look the same, and only the one nearest the track can be compared with it or fused into it."""
        m = None if self.memory is None else self._timed(timings, "regressor", self.memory.find, frame, roi)
        if m is None:
            self.regressor_calls += 1
            m = self._timed(timings, "regressor", self.regressor.predict, frame, roi)
        symmetries = self.object.symmetries if self.object is not None else ()
        return m if near is None else nearest_equivalent_measurement(m, near, symmetries)

    def _estimate(self, status: str, sources: tuple[str, ...]) -> Estimate:
        return replace(self.fusion.estimate, status=status, sources=sources)

    @staticmethod
    def _timed(timings: dict, key: str, fn, *args):
        t0 = time.perf_counter()
        try:
            return fn(*args)
        finally:
            timings[key] += 1000 * (time.perf_counter() - t0)

