"""``HybridConfig``: every threshold of the hybrid policy (:mod:`hybridpose.estimator`), each default
chosen on the tuning seeds of the suites (``hybridpose bench --split tuning``; evidence in
``docs/decisions.md``)."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace

from .fusion.base import DEFAULT_GATE_CHI2

# the hybrid's fusion backend unless named: the fixed-lag smoother beat the UKF on the tuning seeds
# (docs/decisions.md, "isam2 is the default fusion")
DEFAULT_FUSION = "isam2"


@dataclass(frozen=True)
class HybridConfig:
    """The hybrid policy's parameters.

    Attributes:
        check_period: frames between CNN checks while tracking (0: never check).
        disagreement_chi2: squared Mahalanobis distance (fused pose vs CNN pose, both covariances)
            above which a CNN check disagrees.
        disagreement_deg: a CNN check whose rotation is further than this from the fused pose (°)
            disagrees too, whatever the covariances say (e.g. 20: twice a tracker's basin is another
            pose, not noise). A regressor whose calibration had to cover gross errors (a part's
            60-minute fit puts a quarter of its held-out views outside a tracker's basin) reports
            covariances no track lies outside, so its checks never switch a wrong start; but its
            gross errors then switch right tracks too. None (default): the Mahalanobis test alone.
        confirm_checks: consecutive disagreeing checks that re-initialise from the CNN (1: trust
            every check; 2 or more: a single CNN outlier is ignored).
        lost_after_rejections: consecutive tracker measurements refused by the fusion's gate that
            declare the object lost.
        unstable_window, settle_frames: a restart within ``unstable_window`` frames of the previous
            one marks the next ``settle_frames`` frames ``lost`` (pose given, not to be trusted): the CNN
            and the edges keep agreeing on poses that do not hold, a view both get wrong (0: off).
        confirm_frames: every (re)start is on probation for its first this-many frames (its own
            included): they say ``init`` without a pose (the first start) or ``lost`` with the pose (a
            restart), and a start the tracker loses within them was wrong — a first start begins again
            from the CNN (0, the default: a start is trusted at once). For a part where one frame
            cannot vouch for a CNN pose (a printed, symmetric part in clutter: a wrong start there
            dies within a few frames as the view turns), a choice of fewer wrong poses for fewer
            poses: on the hand-held tuning scenes 8 frames cut the trusted frames > 5° off from 472
            to 200 of 5 400, and flagged 35 % of the frames at a right pose (0.8 % without).
        tracker_resumes: while lost, the tracker also tries every frame from the fusion's
            prediction and takes up again by itself when its fit is not lost and passes the gate
            (the honest quality keeps it from taking up on the arm), and the fusion starts over from
            that fit with zero twist; False: only the CNN restarts it.
        resume_cue_quality: such a take-up also needs every cue with a verdict to reach this
            (:func:`~hybridpose.starts.cues_vouch`, for a tracker that reports its cues' verdicts):
            the coasted prediction is where the track was lost, often under an occluder, and a fit
            from there can lay the part's outline on what still shows of it (ViSP's MegaPose cube
            half behind a mug: taken up 32° off with edges 0.79, texture 0.61 and region 0.48). 0:
            the tracker's own lost threshold alone decides.
        retry_after: where the tracker loses the object from the fusion's prediction, a track that
            has run this many frames since its last (re)start tries once more from the tracker's
            previous pose; a fit there (not lost) starts the fusion over from it with zero twist. A
            constant-velocity prediction runs on when a hand-held camera stops (ViSP's cube: 13 mm
            ahead after 53 frames, the track lost); wrong starts on the truss's tuning seeds were
            retried 1–2 frames after they began. None: never.
        lost_after_tracker_losses: consecutive frames the tracker reports lost that declare the
            object lost (before that the estimate coasts on the fusion's prediction).
        reacquire_chi2: squared Mahalanobis distance below which two consecutive CNN answers agree
            while lost (both covariances, plus the motion possible in between).
        reacquire_deg: two consecutive CNN answers further apart than this in rotation (°) never agree,
            whatever the covariances say: a regressor whose covariance covers its gross errors (a
            part's fit) lets two answers 65° apart agree. None (default): the Mahalanobis test alone
            (on the truss, whose edges reject wrong poses, 20 only delays recoveries by a frame); a
            part's fitted checkpoint recommends 20 (:func:`recommended_config`; evidence in
            ``docs/decisions.md``).
        lost_check_period: frames between CNN answers while lost (1: every frame). Under a long
            occlusion the CNN finds nothing frame after frame; asking it less often is most of the
            hybrid's saving over CNN-only, at up to that many frames' delay in recovering.
        check_roi_margin: the CNN check's crop is the box of the object's projection at the
            predicted pose, grown by this fraction on each side.
        probation_frames: after every (re)initialisation the CNN checks each of the next this-many
            frames: a fresh start is the least certain moment (an end-for-end twin that the edges fit
            as well as the truth, a start as the object comes out from behind the arm).
        check_below_quality: a tracker measurement of lower quality calls a CNN check at once,
            whatever ``check_period`` says (0: never). A tracker that slid onto a wrong pose still
            reports 0.6–0.75 where a right one reports 0.8 and more: the check it calls lets the
            edges started from the CNN pose show the better fit.
        switch_quality_margin: at a check, the tracker also fits the model edges from the CNN pose;
            when that fit lands elsewhere (``disagreement_chi2``) and its quality beats the current
            track's by this margin, the check disagrees even where the CNN's own covariance is too
            wide to tell (the image's edges decide between the two poses).
        start_quality: a CNN pose starts (or restarts) the track only where the tracker's fit from
            it reaches this quality: the fits from wrong CNN poses that the edges still hold land at
            0.4–0.6, right ones mostly above 0.65 (chosen on the tuning seeds: docs/decisions.md).
        start_depth_step, start_depth_span: a CNN pose's largest error in the image is its depth (a few
            % of the distance: at 0.35 m, 40 px where the edge search reaches 12; the edge fit
            converges from about ±2 %). Where the fit from the CNN pose falls short of
            ``start_quality`` at initialisation, the CNN pose slid along its viewing ray by whole steps
            of ``start_depth_step`` (relative distance), up to ``start_depth_span`` either way and
            nearest first, is tried; the first fit to reach ``start_quality`` and beat the fit from
            the CNN pose by ``switch_quality_margin`` starts the track (0: the CNN pose only).
        start_turn_deg, start_sure_quality: a start's fit that scores below ``start_sure_quality``
            may sit in a local minimum a few degrees from the truth (the truss's parallel beams: a
            CNN pose 6° off fits at 0.66 and holds there for frames). Fits from its start turned by
            ±``start_turn_deg`` about each camera axis through the object's origin are tried as
            well; one that beats it by ``switch_quality_margin`` and stays within the CNN pose's
            uncertainty (``disagreement_chi2``) starts the track instead (0: off). Right starts
            mostly score 0.8 and more: on the tuning seeds a third of the starts tried the six extra
            fits, about 0.2 ms a frame amortised.
        start_wide_turn_deg: where none of those turns fits better, the same six turns by this much
            are tried (0: off), off black space only: a plain cube's edges held a start 15° off at 0.8
            where the truth fits at 0.96 (hand-held tuning scenes); on the truss's 140 tuning sequences
            they changed no frame and cost 29 ms a start (docs/decisions.md).
        start_rival_margin: a start of a part with no print in a lit scene is also fitted from the poses
            whose outline may match its own (:func:`~hybridpose.starts.outline_rivals`: its box's axes
            carried onto each other, seen the same size); one whose fit reaches ``start_quality`` and
            beats the start's by this much starts the track instead, wherever the CNN put it; where a
            fit elsewhere comes within this much of the chosen one, the image does not tell them apart
            and the start waits for a frame that does (None: off). A plain box seen near end-on casts
            the outline of the box turned 90–120° (own-object tuning seeds: docs/decisions.md). With a
            tracker that sees colours (a ``region`` cue), the start also waits where one of the
            network's other sightings of the part at its place (``start_sighting_iou``), another face
            arrangement (60° or more away), fits within this much of it or better; a sighting never
            starts the track itself.
        start_print_turn_deg: a start of a part whose print is known climbs the print's score
            (:func:`~hybridpose.starts.print_climb`): its pose turned by this much about each camera axis
            through the part's centre, the best turn by the print fitted again while the print scores
            it higher (0: off). Hand-held tuning scenes: see docs/decisions.md.
        start_contrast: a start's fit must also stand out from its own view slid across the image
            (:class:`~hybridpose.edges.distinct.PlacementContrast`): the share of the model's edges
            that land on image edges at the fit must beat the share at the same view slid a part's
            width away in eight directions (their 80th percentile) by this much — unless those match
            next to nothing (black space). A small part's outline laid on a keyboard or a cable
            crossing matches as many edges as a right pose of a printed part, but so do the
            placements beside it (0: off).
        start_print_margin: for a part that carries its print (:attr:`~hybridpose.objects.ObjectModel.
            texture`), a start's fit must also show it: among the fit's pose and its equivalents under
            the shape's symmetries, the print's correlation with the image must single out one by
            this much (:func:`~hybridpose.edges.print_match.print_agreement`). On ViSP's MegaPose cube
            video a fit's network put the printed cube on a bottle's label 1 m away and inside one of
            its own faces, where the edges and region cues confirmed it (0: off). The start is then
            the pose the print singles out: a printed part's pose is its own, not any of its shape's
            look-alikes (which face is which).
        track_print_floor: for a part that carries its print, a tracked pose whose print correlates
            with the image (:meth:`~hybridpose.edges.print_match.PrintView.score`) less than this is
            reported ``lost``, not trusted; the track goes on, and is trusted again where the print
            shows (0: off). A print without corners gives the texture cue nothing to hold: where the
            hand turns, the outline and colours slide onto the print's own strong edges, 10-20° off,
            at the quality of a right fit, while the print at that pose correlates near 0 (right
            fits: 0.3-0.95). Hand-held tuning scenes: see docs/decisions.md.
        cnn_search_px: how far (px) a tracker fit started from a CNN pose (a start, a check) searches
            for the model's edges, where the tracker can widen its search (``track(..., search_px=)``;
            0: the tracker's own frame-to-frame range). A CNN pose lies further from the truth than
            the previous frame's pose does.
        sun_in_cnn_fits: whether a tracker fit started from a CNN pose (a start, a check) gets the
            frame's sun direction (:attr:`Frame.sun_direction_cam <hybridpose.core.Frame>`) too, as
            the frame-to-frame fits do. On: its edges in shadow are left out, and a tracker that can
            (``edges``) asks the fit to match the sunlit surface its pose predicts — without that
            check, where the sun lights only slivers of the object, a pose 15° off explained them as
            well as the right one and starts settled on it.
        keep_covered_quality, keep_after: once a track has run ``keep_after`` frames since its
            (re)start, a tracker that tells when the object is covered (``tells_covered``: on black
            space, something lit came in beside the object — the arm; ``track(...,
            covered_lost_quality=)``) counts its frame-to-frame fit lost only below
            ``keep_covered_quality`` where it sees the object covered, and below its own threshold
            elsewhere. With 40–50 % of the truss behind the arm a right fit's honest quality is
            0.4–0.5 (the arm's own edges left out of it), under the edge trackers' 0.5; starts,
            checks and resumes keep the tracker's own threshold (a young track may be a wrong
            start). Never above the tracker's own; None: off.
        keep_quality: the same for a tracker that takes a threshold per call (``track(...,
            lost_quality=)``) but cannot tell when the object is covered: its fits count as lost only
            below this, covered or not (never above its own threshold; None: off).
        restart_unconfirmed: when checks disagree with the track and the tracker started from the
            CNN pose does not stay there, restart from the CNN pose alone (True) or declare the object
            lost until the CNN and the edges agree again (False: such restarts were wrong in every
            case on the tuning seeds).
        keypoint_memory: keep a memory of the part's look (:class:`~hybridpose.regressors.keypoint_memory.
            KeypointMemory`: image keypoints on the part with the model points under them), asked before
            the CNN wherever the CNN would run: it holds the part's print where the object carries one
            (found from the first frame) and learns from the track (found again after a loss, by this
            camera's view of the part, not by a network's guess). Its answers are confirmed as a
            CNN's are. Never on black space (the first frame at least ``SPACE_DARK_SHARE`` dark, as
            ``track`` tells it): a plain part's keypoints there are its shading, which the sun moves
            (the space suite's hybrid as accurate without it, and a third faster). False: the CNN alone.
        start_alternatives: at ``init``, where the tracker refuses the network's answer, up to this many
            other distinct poses its passes found in the same frame are tried in turn through the same
            start checks (:meth:`~hybridpose.regressors.base.PoseRegressor.candidates`; a close crop of
            a printed part can take corners of its print for the part's where the whole frame's coarser
            pass does not) — those whose surroundings are plain (:func:`~hybridpose.starts.plain_alternatives`:
            in clutter each is one more chance for a wrong outline); the first accepted is taken. 0: the
            network's answer alone.
        colour_start_every: while the hybrid has no pose (``init``) and neither the memory nor the CNN
            gives a start, every this many frames a part that carries its print is also started from
            poses all around it placed where its print's colours stand out (:class:`~hybridpose.
            regressors.colour_starts.ColourStarts`, 32 for a cube), each through the start checks, the
            first accepted taken: a dark or smooth print the memory's keypoints miss. Seconds of fits
            each time on a CPU core, hence not every frame. Off black space only, as the memory; 0: never.
        colour_start_print: a colour start must also show the print at least this well (its
            :func:`~hybridpose.edges.print_match.print_agreement`'s best score; the other starts need
            only single one pose out, ``start_print_margin``): 32 tries give a wrong pose more chances
            to pass. Hand-held tuning scenes: the 18 right colour starts scored 0.68–0.98, the one
            wrong (102° off, a brick print seen near head-on) 0.32; right starts on ViSP's MegaPose
            cube video score 0.5–0.7.
        learn_after: frames a track must have run since its (re)start before the memory learns from
            it, at fits reaching ``start_sure_quality`` whose cues all vouch (``resume_cue_quality``).
        memory_start_quality: ``start_quality`` for a start from the memory's answer: the pose its
            keypoints gave already agrees with dozens of points on the part, so the tracker need only
            hold it as an established track holds a frame (``keep_quality``'s 0.4) — under a hand
            holding the part, a right fit scores 0.5–0.6. ViSP's MegaPose cube with its print: within
            5° / 2 cm 257 → 289 of 376 frames, trusted > 10° off 10 → 2 (0.45: the same); the
            detection cube 218 → 219, none > 10° off either way.
        plain_start_quality: ``start_quality`` for a start of a part with no print to check it against
            (a plain CAD model), fitted by a tracker that reports its cues (``combined``) in a lit scene
            (not black space): a network's pose at the wrong distance (×0.65–4) fits a smaller cube inside
            a face of the real one, on a square of its print or in the clutter, at 0.6–0.82, where right
            starts on renders mostly fit at 0.8 and more. Hand-held printed cube, the shape alone, tuning
            seeds (frames trusted > 10° off / held within 5° and 2 cm, of 1800, photos and behind a hand):
            without it 241 / 251 and 205 / 343; at 0.75: 86 / 301 and 55 / 438; at 0.8: 17 / 301 and
            17 / 328. Not 0.8: on real footage right starts fit lower (ViSP's detection cube: 0.63–0.8;
            its first right start, at 0.76, never came at 0.8 and the hybrid held 0 of 261 frames
            instead of 233). A start from the memory keeps ``memory_start_quality``; on black space, or
            with ``edges``, ``start_quality`` decides.
        plain_surround_quality: in a lit scene a start the edges alone vouch for (the region cue without
            a verdict, as on a white box on a white table) is refused, unless the scene around it is
            plain — its view slid beside it matches at most a fifth of its edges
            (:meth:`~hybridpose.edges.distinct.PlacementContrast.plain_around`) — and its fit reaches this
            (0: refused everywhere; 0.75: ViSP's mono tea box, docs/decisions.md).
        start_sighting_iou: a start of a part with no print to check it, from the network's answer at
            ``init``, in a lit scene whose surroundings are not plain, is refused where none of the
            network's other looks at the frame (its whole-frame and tile passes, its other proposals:
            :attr:`~hybridpose.regressors.base.Candidates.sightings`) saw the part at the start's place
            — its image box over the start's by at least this intersection over union
            (:func:`~hybridpose.starts.unseen_in_clutter`; 0: off; a regressor that does not say: no
            verdict). A close look alone took a box or a bottle's label in the clutter for a far, small
            part (docs/decisions.md). The sightings over the start's place by this much are also the
            doubts a plain part's start answers to (``start_rival_margin``).
        handheld_accel_rad_s2, handheld_accel_m_s2: the fusion's motion model off black space (the
            first frame less than ``SPACE_DARK_SHARE`` dark, as for ``keypoint_memory``): white-
            acceleration densities (rad/s², m/s² per √Hz; :attr:`Fusion.motion_noise`) for a camera or
            a part moved by hand, which stops and turns within a few frames where a spacecraft drifts.
            With the fusion's space defaults (0.5, 0.5) its gate refuses the tracker's right fit after a
            stop, and the track coasts off on the old motion; at 10 rad/s² it let a fit jump 25° to a
            wrong pose after one refused frame (ViSP's detection cube). None: the fusion's own everywhere.
        check_on_rejection: a tracker measurement refused by the gate calls a CNN check at once; when
            the CNN pose and the edge fit started from it both agree with the refused measurement
            (``disagreement_chi2``), the motion model was wrong, not the tracker (a sudden change
            of motion): the fusion starts over from the tracker's pose, with the twist between its
            last two poses, and tracking goes on.
    """

    check_period: int = 10
    disagreement_chi2: float = DEFAULT_GATE_CHI2  # the 99.9 % point of χ²₆
    confirm_checks: int = 2
    lost_after_rejections: int = 3
    lost_after_tracker_losses: int = 1
    tracker_resumes: bool = True
    resume_cue_quality: float = 0.5
    retry_after: int | None = 3
    unstable_window: int = 20
    settle_frames: int = 0
    confirm_frames: int = 0
    reacquire_chi2: float = DEFAULT_GATE_CHI2
    lost_check_period: int = 1
    check_roi_margin: float = 0.15
    switch_quality_margin: float = 0.05
    check_below_quality: float = 0.7
    probation_frames: int = 1
    check_on_rejection: bool = True
    start_quality: float = 0.62
    start_depth_step: float = 0.03
    start_depth_span: float = 0.12
    restart_unconfirmed: bool = False
    start_turn_deg: float = 4.0
    start_sure_quality: float = 0.8
    start_wide_turn_deg: float = 10.0
    start_print_turn_deg: float = 3.0
    start_rival_margin: float | None = 0.05
    start_contrast: float = 0.3
    start_print_margin: float = 0.2
    track_print_floor: float = 0.15
    cnn_search_px: float = 12.0
    sun_in_cnn_fits: bool = True
    keep_quality: float | None = 0.4
    keep_covered_quality: float | None = 0.3
    keep_after: int = 5
    disagreement_deg: float | None = None
    reacquire_deg: float | None = None
    keypoint_memory: bool = True
    colour_start_every: int = 4
    colour_start_print: float = 0.45
    learn_after: int = 10
    memory_start_quality: float = 0.4
    plain_start_quality: float = 0.75
    plain_surround_quality: float = 0.75
    start_alternatives: int = 4
    start_sighting_iou: float = 0.25
    handheld_accel_rad_s2: float | None = 3.0
    handheld_accel_m_s2: float = 3.0

    def __post_init__(self) -> None:
        for name in ("check_period", "probation_frames", "unstable_window", "settle_frames", "confirm_frames",
                     "keep_after", "learn_after", "colour_start_every"):
            v = getattr(self, name)
            if int(v) != v or v < 0:
                raise ValueError(f"{name}: expected a whole number of frames ≥ 0, got {v}")
        if int(self.start_alternatives) != self.start_alternatives or self.start_alternatives < 0:
            raise ValueError(f"start_alternatives: expected a whole number of poses ≥ 0, got {self.start_alternatives}")
        if self.retry_after is not None and (int(self.retry_after) != self.retry_after or self.retry_after < 0):
            raise ValueError(f"retry_after: expected a whole number of frames ≥ 0 or None, got {self.retry_after}")
        for name in ("confirm_checks", "lost_after_rejections", "lost_check_period", "lost_after_tracker_losses"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name}: expected a whole number ≥ 1, got {v}")
        for name in ("disagreement_chi2", "reacquire_chi2"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected a positive squared Mahalanobis distance, got {getattr(self, name)}")
        for name in ("disagreement_deg", "reacquire_deg"):
            v = getattr(self, name)
            if v is not None and not 0 < v <= 180:
                raise ValueError(f"{name}: expected an angle in (0, 180] degrees or None, got {v}")
        for name in ("keep_quality", "keep_covered_quality"):
            v = getattr(self, name)
            if v is not None and not 0 <= v <= 1:
                raise ValueError(f"{name}: expected a tracker quality in [0, 1] or None, got {v}")
        for name in ("start_quality", "memory_start_quality", "plain_start_quality", "plain_surround_quality"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name}: expected a tracker quality in [0, 1], got {getattr(self, name)}")
        if not 0 <= self.start_sighting_iou <= 1:
            raise ValueError(f"start_sighting_iou: expected an intersection over union in [0, 1] (0: off), got {self.start_sighting_iou}")
        if self.start_rival_margin is not None and not 0 <= self.start_rival_margin <= 1:
            raise ValueError(f"start_rival_margin: expected a quality difference in [0, 1] or None, got {self.start_rival_margin}")
        if not 0 <= self.switch_quality_margin <= 1:
            raise ValueError(f"switch_quality_margin: expected a quality difference in [0, 1], got {self.switch_quality_margin}")
        if not 0 <= self.start_depth_step < 1 or not 0 <= self.start_depth_span < 1:
            raise ValueError(f"start_depth_step, start_depth_span: expected relative distances in [0, 1), got "
                             f"{self.start_depth_step}, {self.start_depth_span}")
        for name in ("start_turn_deg", "start_wide_turn_deg", "start_print_turn_deg"):
            if not 0 <= getattr(self, name) <= 45:
                raise ValueError(f"{name}: expected degrees in [0, 45] (0: off), got {getattr(self, name)}")
        if not 0 <= self.resume_cue_quality <= 1:
            raise ValueError(f"resume_cue_quality: expected a cue quality in [0, 1] (0: off), got {self.resume_cue_quality}")
        if not 0 <= self.start_print_margin <= 2:
            raise ValueError(f"start_print_margin: expected a correlation difference in [0, 2] (0: off), got {self.start_print_margin}")
        for name in ("track_print_floor", "colour_start_print"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name}: expected a correlation in [0, 1] (0: off), got {getattr(self, name)}")
        if not 0 <= self.start_contrast <= 1:
            raise ValueError(f"start_contrast: expected a share of edge samples in [0, 1] (0: off), got {self.start_contrast}")
        if not 0 <= self.start_sure_quality <= 1:
            raise ValueError(f"start_sure_quality: expected a tracker quality in [0, 1], got {self.start_sure_quality}")
        if self.handheld_accel_rad_s2 is not None and not (self.handheld_accel_rad_s2 > 0 and self.handheld_accel_m_s2 > 0):
            raise ValueError(f"handheld_accel_rad_s2, handheld_accel_m_s2: expected positive densities (or None for the "
                             f"first), got {self.handheld_accel_rad_s2}, {self.handheld_accel_m_s2}")
        if not self.cnn_search_px >= 0:
            raise ValueError(f"cnn_search_px: expected ≥ 0 pixels, got {self.cnn_search_px}")
        if not 0 <= self.check_roi_margin <= 2:
            raise ValueError(f"check_roi_margin: expected a fraction in [0, 2], got {self.check_roi_margin}")

    def keep_thresholds(self, own: float | None, tells_covered: bool) -> tuple[float | None, float | None]:
        """An established track's lost thresholds (in general, where the tracker sees the object covered)
        for a tracker whose own is ``own`` (its ``lost_quality``; None: it takes none per call): one that
        tells when the object is covered (``tells_covered``) keeps its own in general and gets
        ``keep_covered_quality`` where covered; any other ``keep_quality``; neither above ``own``."""
        def capped(q: float | None) -> float | None:
            return q if q is None or own is None else min(q, float(own))

        if tells_covered:
            return None, capped(self.keep_covered_quality)
        return capped(self.keep_quality), None

    def unsettled(self, restarts: list[int], frames: int) -> bool:
        """Whether a hybrid that restarted at the frame counts ``restarts`` and has stepped ``frames`` frames
        restarted twice within ``unstable_window`` frames, not yet ``settle_frames`` frames ago: the CNN and
        the edges keep agreeing on poses that do not hold (a view both get wrong)."""
        r = restarts
        return (self.settle_frames > 0 and len(r) >= 2 and r[-1] - r[-2] <= self.unstable_window
                and frames - r[-1] <= self.settle_frames)


def recommended_config(recommended: Mapping | None, overrides: Mapping | None = None,
                       source: str = "regressor") -> HybridConfig:
    """The policy for a hybrid whose regressor recommends ``recommended`` (its ``hybrid_config``, a
    mapping of :class:`HybridConfig` fields; a part's ``hybridpose fit`` records ``reacquire_deg`` in
    its checkpoint): the defaults with those fields, then the caller's ``overrides`` applied.
    TypeError naming the unknown fields and where they came from (``source``: the regressor)."""
    config = HybridConfig()
    known = {f.name for f in fields(HybridConfig)}
    for origin, changes in ((f"{source}.hybrid_config (its maker's recommended policy)", recommended or {}),
                            ("config", overrides or {})):
        if not isinstance(changes, Mapping):
            raise TypeError(f"{origin}: expected a mapping of HybridConfig fields, got {type(changes).__name__}")
        unknown = sorted(set(changes) - known)
        if unknown:
            raise TypeError(f"{origin}: {', '.join(map(str, unknown))} not a field of HybridConfig "
                            f"(fields: {', '.join(sorted(known))})")
        config = replace(config, **changes)
    return config


def changes_text(config: HybridConfig) -> str:
    """The fields of ``config`` that differ from the defaults, as ``"name=value, ..."`` (``none`` for
    None; ``""`` for the defaults): how results and logs name a policy."""
    base = HybridConfig()
    return ", ".join(f"{f.name}={_value_text(getattr(config, f.name))}" for f in fields(HybridConfig)
                     if getattr(config, f.name) != getattr(base, f.name))


def _value_text(value) -> str:
    return "none" if value is None else str(value).lower() if isinstance(value, bool) else format(value, "g")
