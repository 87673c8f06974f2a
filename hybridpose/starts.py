"""How a CNN answer becomes the start of a track: the tracker fits the image from the CNN pose (or from
it slid along its viewing ray, or turned a few degrees) and the start is the fit the image and the
CNN's uncertainty both accept. Every start of :class:`~hybridpose.estimator.HybridEstimator` (init and
reinit) goes through :func:`confirmed_start`; the thresholds are :class:`~hybridpose.hybrid_config.HybridConfig`
fields.

``fit(start)`` is the caller's: the tracker started at ``start`` (a pose) and its fit of the frame from
there, or None where the tracker refuses that start (nothing of the model matches the image).
"""
from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .core import Frame, Measurement
from .edges import ModelView, coarse_to_fine, placement_contrast, projected_diagonal_px, to_gray
from .edges.fit import dark_surround
from .edges.print_match import PrintView, print_agreement
from .fusion.base import equivalent_measurement, pose_mahalanobis2
from .geometry import Pose, rotvec_to_matrix, turned_about
from .geometry.crops import box_iou
from .hybrid_config import HybridConfig
from .metrics import nearest_equivalent, rotation_error_deg

Fit = Callable[[Pose], "Measurement | None"]
# a printed part's start climbs the print's score (print_climb) while a turn gains this much, at most
# this many times: from starts 0-14° off on hand-held tuning scenes, fits > 6° off 19 -> 10 after the
# climb, fits < 3° off left within 3° (99 %)
PRINT_CLIMB_GAIN, PRINT_CLIMB_STEPS = 0.02, 6
WATCH_PIXELS = 1000  # pixels a tracked pose's print score compares (print_fails): a verdict, not a start's choice
# a start's image test: None where the image does not single the pose out; else the symmetry S of the
# object whose ``pose @ S`` the image shows (the identity but for a printed part, whose print tells
# which of the shape's equivalent poses is its own)
StandsOut = Callable[[Pose], "Pose | None"]
# a start's rivals (outline_rivals): its pose with the bounding box's axes carried onto each other (the 23 turns
# of a box onto itself, as 3 x 3 signed permutations of det +1), those closer than RIVAL_APART_DEG to the start
# or to each other (the object's symmetries included) counted once; each moved along the line of sight until
# its image box's diagonal is the start's, RIVAL_SIZE_STEPS times (the box's extent across the view changes)
AXIS_TURNS = tuple(P for P in (np.array([[s[i] * (p[i] == r) for i in range(3)] for r in range(3)], float)
                               for p in itertools.permutations(range(3)) for s in itertools.product((1, -1), repeat=3))
                   if np.linalg.det(P) > 0 and not np.array_equal(P, np.eye(3)))
RIVAL_APART_DEG, RIVAL_SIZE_STEPS = 30.0, 3  # the comment above: the same pose within 30°, three size steps
# a start's doubts (RivalTest.doubts): the network's other sightings at its place this far from it up to the symmetries
# or more — nearer, the tracker's own minima lie (a tuning fly-around's right start fitted 0.82 where a sighting 26° off,
# fitted, scored 0.93 at 35°; counted, that start waited and the track later went wrong)
DOUBT_APART_DEG = 60.0


def confirmed_start(m: Measurement, fit: Fit, config: HybridConfig, depth_search: bool = False,
                    stands_out: StandsOut | None = None,
                    climb: Callable[[Measurement], Measurement] | None = None,
                    rivals: RivalTest | None = None) -> Measurement | None:
    """The tracker's fit started from the CNN measurement ``m``, or None when the CNN found nothing,
    the fit does not reach ``start_quality`` (the model's edges do not match the image), it left
    the CNN pose's uncertainty (``disagreement_chi2``, both covariances: it found something else) or
    ``stands_out`` (the caller's test of a pose in this frame: :func:`~hybridpose.edges.distinct.
    placement_contrast` against ``start_contrast``) says the image does not single it out (clutter
    beside it matches the model as well). Where ``stands_out`` names another of the object's
    equivalent poses (a printed part's print shows which), the fit is restated there.

    With ``depth_search``, where the fit from ``m`` falls short, the fits from ``m`` slid along its
    viewing ray (:func:`slid_starts`, nearest first) are tried: the first one to reach
    ``start_quality`` and beat the fit from ``m`` by ``switch_quality_margin`` is taken (every extra
    try is another chance for a wrong pose to pass the threshold: the image must decide). The taken
    fit goes through :func:`best_turned`, then :func:`best_rival` where ``rivals`` is given (the
    poses whose outline may match the fit's: :func:`rival_test`; where the image does not single one
    of them out, that start is not confirmed), then ``climb`` where given (:func:`print_climb`)."""
    if m.pose is None:
        return None
    starts = slid_starts(m.pose, config.start_depth_step, config.start_depth_span) if depth_search else [m.pose]
    bar = config.start_quality
    for i, start in enumerate(starts):
        result = fit(start)
        found = result is not None and not result.lost
        if (found and result.quality >= bar
                and pose_mahalanobis2(m.pose, m.covariance, result.pose, result.covariance) <= config.disagreement_chi2):
            chosen = best_turned(m, start, result, fit, config)
            if rivals is not None:
                chosen = best_rival(chosen, rivals.poses(chosen.pose), fit, config, rivals.apart, rivals.doubts(chosen.pose), rivals.far)
            S = None if chosen is None else Pose.identity() if stands_out is None else stands_out(chosen.pose)
            if S is not None:
                chosen = chosen if _is_identity(S) else equivalent_measurement(chosen, S)
                return chosen if climb is None else climb(chosen)
        if i == 0:  # a slid start must beat the fit from the CNN pose itself
            bar = max(bar, (result.quality if found else 0.0) + config.switch_quality_margin)
    return None


def print_climb(first: Measurement, fit: Fit, print_view: PrintView, frame: Frame, centre: np.ndarray,
                turn_deg: float) -> Measurement:
    """``first`` (a confirmed start of a part whose print is known) moved up the print's score
    (:meth:`~hybridpose.edges.print_match.PrintView.score`): its pose turned ±``turn_deg`` about each
    camera axis through ``centre`` (the part's centre, object frame, metres), the best-scoring turn fitted
    again (``fit``) and taken where the fit's own score beats the current one; while the best turn
    gains ``PRINT_CLIMB_GAIN``, at most ``PRINT_CLIMB_STEPS`` times.

    Why: a start 6–14° off that the model's edges and colours fit almost as well as the truth is
    confirmed by them, and the texture cue's first keyframe, lifted there, then holds the track at that
    error (hand-held tuning scenes: a network's start 12° off held 6–12° off with every texture point
    agreeing). The print's score peaks at the truth: 0.85 at fits within 3°, 0.60 at fits over 6° off
    (median), and some 3° turn of a fit over 6° off raises it by more than 0.05 two times in three."""
    if turn_deg <= 0:
        return first
    gray = to_gray(frame.image)
    current, score = first, print_view.score(frame, first.pose, gray)
    if not np.isfinite(score):
        return first
    for _ in range(PRINT_CLIMB_STEPS):
        turns = [turned_about(current.pose, sign * np.radians(turn_deg) * axis, centre)
                 for axis in np.eye(3) for sign in (-1.0, 1.0)]
        scores = np.nan_to_num([print_view.score(frame, p, gray) for p in turns], nan=-1.0)
        if scores.max() < score + PRINT_CLIMB_GAIN:
            break
        other = fit(turns[int(np.argmax(scores))])
        other_score = -1.0 if other is None or other.lost else print_view.score(frame, other.pose, gray)
        if not np.isfinite(other_score) or other_score <= score:
            break
        current, score = other, other_score
    return current


def print_climber(fit: Fit, print_view: PrintView | None, frame: Frame, obj, turn_deg: float):
    """The ``climb`` of :func:`confirmed_start` for ``obj`` (an :class:`~hybridpose.objects.ObjectModel`)
    whose print is known (``print_view``): :func:`print_climb` about its centre; None otherwise."""
    if print_view is None or obj is None or turn_deg <= 0:
        return None
    centre = obj.bbox_corners.mean(0)
    return lambda first: print_climb(first, fit, print_view, frame, centre, turn_deg)


def best_turned(m: Measurement, start: Pose, first: Measurement, fit: Fit, config: HybridConfig) -> Measurement:
    """``first`` (the tracker's fit from ``start``, a start accepted for the CNN measurement ``m``), or,
    where it scores below ``start_sure_quality``, the best of the fits from ``start`` turned by
    ±``start_turn_deg`` about each camera axis through the object's origin that beats it by
    ``switch_quality_margin`` and stays within ``m``'s uncertainty (``disagreement_chi2``): a local
    minimum of the object's edges may lie a few degrees from the truth. Where none does, the same six
    turns by ``start_wide_turn_deg``: a plain cube's edges also hold a start 15° off."""
    if first.quality >= config.start_sure_quality:
        return first
    best, bar = first, first.quality + config.switch_quality_margin
    for deg in (config.start_turn_deg, config.start_wide_turn_deg):
        if deg <= 0 or best is not first:
            continue
        for axis in np.eye(3):
            for sign in (-1.0, 1.0):
                other = fit(Pose(rotvec_to_matrix(sign * np.radians(deg) * axis) @ start.R, start.t))
                if (other is not None and not other.lost and other.quality >= bar and other.quality > best.quality
                        and pose_mahalanobis2(m.pose, m.covariance, other.pose, other.covariance) <= config.disagreement_chi2):
                    best = other
    return best


def best_rival(first: Measurement, rivals: list[Pose], fit: Fit, config: HybridConfig,
               apart: Callable[[Pose, Pose], bool] | None = None, doubts: list[Pose] = (),
               far: Callable[[Pose, Pose], bool] | None = None) -> Measurement | None:
    """``first`` (a start's fit), or the best of the fits from ``rivals`` that reaches ``start_quality``
    and beats it by ``start_rival_margin``; None where the image does not single one pose out: another
    of these fits, elsewhere (``apart(a, b)``: whether two poses are different poses of the part; None:
    any two fits are), scores within the margin of the chosen one — or a fit from ``doubts`` (the
    network's other sightings of the part there: :meth:`RivalTest.doubts`), elsewhere by ``far`` (None:
    ``apart``), within the margin or above it. A doubt can only hold a start back, never be one: in
    clutter a pass's pose can fit a wrong outline best. Unlike :func:`best_turned`, a rival
    need not stay within the CNN pose's uncertainty: the network's answer is the very pose in doubt.

    Why: a plain box seen near end-on shows an outline that the box turned 90–120° also casts, nearer or
    farther; the network can give that pose, and the edges and colours confirm it (own-object tuning
    seeds: five starts 106–114° off, scoring 0.78–0.86 with ``combined``). Fitted from the rival poses,
    the truth scored 0.09–0.16 higher in four of them; of the 39 right starts none had a rival within 0.10
    of its own score. With another fit a fly-around's start 115° off scored 0.84 and the rival nearest the
    truth 0.86, 0.01–0.02 either side of it for six frames; taken, the wrong start was held 34 frames,
    while from the seventh frame the truth led by 0.05 (the view had turned). Where both lie within the
    margin, the start waits for the frame that tells them apart. A doubt: on a fly-around over a photo
    whose skin tones matched the box, the network's answer 102° off fitted at 0.89 and was held 59
    frames, while its tile pass had seen the part at the same place 4° off, fitted at 0.90 (no turn of the
    box's axes led there: the nearest rival lay 49° from the truth)."""
    margin = config.start_rival_margin
    if margin is None:
        return first
    others = [f for f in map(fit, rivals) if f is not None and not f.lost]
    best = first
    for other in others:
        if other.quality >= max(config.start_quality, first.quality + margin) and other.quality > best.quality:
            best = other
    close = [f for f in (first, *others) if f is not best and f.quality > best.quality - margin
             and (apart is None or apart(f.pose, best.pose))]
    far = far or apart
    close += [f for f in map(fit, doubts) if f is not None and not f.lost and f.quality > best.quality - margin
              and (far is None or far(f.pose, best.pose))]
    return None if close else best


def outline_rivals(view: ModelView, camera, pose: Pose) -> list[Pose]:
    """The poses of ``view``'s object whose outline in ``camera`` may match its outline at ``pose``
    (``T_cam_obj``): its bounding box's axes carried onto each other about its centre (``AXIS_TURNS``),
    the centre kept on its line of sight, the image box's diagonal kept; none equivalent to ``pose`` or
    to each other under the object's symmetries (``RIVAL_APART_DEG``); none where the part reaches
    behind the camera."""
    obj = view.object
    centre = obj.bbox_corners.mean(0)
    centre_cam = pose.R @ centre + pose.t
    size = projected_diagonal_px(view, pose, camera)
    out: list[Pose] = []
    if not np.isfinite(size):
        return out
    for P in AXIS_TURNS:
        R = pose.R @ P
        rival = Pose(R, centre_cam - R @ centre)
        if not all(poses_apart(rival, other, obj.symmetries) for other in (pose, *out)):
            continue
        for _ in range(RIVAL_SIZE_STEPS):
            other_size = projected_diagonal_px(view, rival, camera)
            if not np.isfinite(other_size):
                break
            moved = (rival.R @ centre + rival.t) * (other_size / size)
            rival = Pose(rival.R, moved - rival.R @ centre)
        out.append(rival)
    return out


@dataclass(frozen=True)
class RivalTest:
    """A plain part's start rivals in ``frame`` (:func:`rival_test`): :meth:`poses` for :func:`best_rival`
    to fit, :meth:`apart` to tell a rival's fit from the start's; :meth:`doubts`, from the network's
    ``sightings`` in the frame (``T_cam_obj`` each) over the start's image box by ``min_iou``, for it to fit
    as doubts, :meth:`far` to tell a doubt's fit from the start's."""

    view: ModelView
    frame: Frame
    sightings: tuple = ()
    min_iou: float = 0.0

    def poses(self, pose: Pose) -> list[Pose]:
        """:func:`outline_rivals` of ``pose`` where the scene around it is lit (:func:`lit_around`), else none."""
        # a rival lies 10-25° from the pose it stands for (the network's answer is no exact turn of the box's
        # axes), beyond the tracker's reach at full resolution: each is brought in over the image pyramid first
        if not lit_around(self.frame, self.view, pose):
            return []
        return [coarse_to_fine(self.view, self.frame, rival) for rival in outline_rivals(self.view, self.frame.camera, pose)]

    def doubts(self, pose: Pose) -> list[Pose]:
        """The network's ``sightings`` of the part (``T_cam_obj`` each: its other passes' and proposals' poses in
        the frame) whose image box lies over ``pose``'s by ``min_iou`` (intersection over union; 0: none) and
        that are :meth:`far` from it, where the scene around ``pose`` is lit (:func:`lit_around`), else none;
        brought in over the image pyramid as :meth:`poses`."""
        if self.min_iou <= 0 or not self.sightings:
            return []
        box = _image_box(self.view, self.frame, pose)
        if box is None or not lit_around(self.frame, self.view, pose):
            return []
        return [coarse_to_fine(self.view, self.frame, other) for other in self.sightings if self.far(other, pose)
                and (other_box := _image_box(self.view, self.frame, other)) is not None and box_iou(box, other_box) >= self.min_iou]

    def far(self, a: Pose, b: Pose) -> bool:
        """Whether ``a`` and ``b`` are ``DOUBT_APART_DEG`` or more apart under the part's symmetries: another face
        arrangement, not a minimum of the tracker's beside the same one."""
        return poses_apart(a, b, self.view.object.symmetries, DOUBT_APART_DEG)

    def apart(self, a: Pose, b: Pose) -> bool:
        """Whether ``a`` and ``b`` are ``RIVAL_APART_DEG`` or more apart under the part's symmetries: two poses, not one
        (a rival's fit may come back to the start's own pose)."""
        return poses_apart(a, b, self.view.object.symmetries)


def poses_apart(a: Pose, b: Pose, symmetries=(), deg: float = RIVAL_APART_DEG) -> bool:
    """Whether ``a`` and ``b`` are ``deg`` or more apart in rotation, up to the object's ``symmetries``."""
    return rotation_error_deg(a, nearest_equivalent(a, b, symmetries)) >= deg


def rival_test(view: ModelView | None, frame: Frame, printed: bool, margin: float | None,
               sightings=None, min_iou: float = 0.0) -> RivalTest | None:
    """The ``rivals`` of :func:`confirmed_start` in ``frame``: those of a part with no print (``printed``:
    its print tells its faces apart), with the network's ``sightings`` in the frame (None: it does not
    say) over the start's place by ``min_iou``; None without a ``view`` or with ``margin``
    (``start_rival_margin``) None. On black space (:func:`lit_around`) there are none: the space suites
    measured the hybrid without them."""
    if view is None or printed or margin is None:
        return None
    return RivalTest(view, frame, tuple(sightings or ()), min_iou)


def print_fails(print_view: PrintView | None, frame: Frame, pose: Pose | None, floor: float) -> bool:
    """Whether ``pose`` (a tracked part's) shows too little of the part's print (``print_view``;
    None: no print, never): its :meth:`~hybridpose.edges.print_match.PrintView.score`, on
    ``WATCH_PIXELS`` pixels, below ``floor`` (0: off). A score of too few pixels is no verdict."""
    if print_view is None or floor <= 0 or pose is None:
        return False
    score = print_view.score(frame, pose, max_pixels=WATCH_PIXELS)
    return bool(np.isfinite(score) and score < floor)


def print_backs(print_view: PrintView | None, frame: Frame, pose: Pose) -> bool:
    """Whether the part's print (``print_view``; None: no print, always) shows ``pose`` itself best among
    the poses its shape cannot tell apart (:func:`~hybridpose.edges.print_match.print_agreement`; no
    verdict where none scores). A track taken up again after a loss carries on which face is which: a
    fit whose print another face arrangement explains better slid onto the part's outline elsewhere
    (hand-held tuning scenes: the one wrong take-up, 71° off after a hand passed, scored 0.20 at its own
    pose and 0.48 at another; the nine right ones scored best at their own, 0.37–0.95)."""
    if print_view is None:
        return True
    agreement = print_agreement(print_view, frame, pose)
    return agreement.branch is None or _is_identity(agreement.branch)


def print_prefers(print_view: PrintView | None, frame: Frame, candidate: Measurement, track: Measurement) -> bool:
    """Whether the part's print (``print_view``; None: no print, always) shows the ``candidate`` fit (a
    CNN check's) at least as well as the ``track``'s measurement (:meth:`~hybridpose.edges.print_match.
    PrintView.score`; no verdict where either has no pose or no score). A check that would move a printed
    part's track elsewhere must not move it off its print: on a hand-held tuning scene the memory's
    answer 24° off, fitted by the edges better than a track 3.6° off after a hand passed, restarted the
    track there (its print 0.00, the track's 0.7) and it stayed off for 27 frames."""
    if print_view is None or candidate.pose is None or track.pose is None:
        return True
    gray = to_gray(frame.image)
    ours, theirs = print_view.score(frame, candidate.pose, gray), print_view.score(frame, track.pose, gray)
    return not (np.isfinite(ours) and np.isfinite(theirs)) or ours >= theirs


def print_view(view: ModelView | None) -> PrintView | None:
    """The :class:`~hybridpose.edges.print_match.PrintView` of ``view``'s object where it carries a print
    that maps onto its facets; None otherwise (no print check)."""
    if view is None or view.object.texture is None:
        return None
    try:
        return PrintView(view)
    except ValueError:  # no facet maps affinely onto the print (a curved unwrap)
        return None


def image_test(view: ModelView | None, frame: Frame, margin: float, part_print: PrintView | None = None,
               print_margin: float = 0.0, print_floor: float = 0.0) -> StandsOut | None:
    """The ``stands_out`` test of :func:`confirmed_start` in ``frame``: a pose's
    :func:`~hybridpose.edges.placement_contrast` with ``margin`` (``start_contrast``) and, for a
    printed part (``part_print``: its :func:`print_view`),
    :func:`~hybridpose.edges.print_match.print_agreement` singling out one of its equivalent poses by
    ``print_margin`` (``start_print_margin``) — the one the test then names — with a score of at least
    ``print_floor``; None (no test) without a model view or with both margins 0."""
    contrast = view is not None and margin > 0
    printed = part_print is not None and print_margin > 0
    if not contrast and not printed:
        return None

    grey: list[np.ndarray] = []  # the frame in grey, converted once, for the first candidate that gets here

    def stands_out(pose: Pose) -> Pose | None:
        if not grey:
            grey.append(to_gray(frame.image))
        if contrast and not placement_contrast(view, frame, pose, grey[0]).stands_out(margin):
            return None
        if not printed:
            return Pose.identity()
        agreement = print_agreement(part_print, frame, pose, grey[0])
        return agreement.branch if agreement.singles_out(print_margin) and agreement.best >= print_floor else None

    return stands_out


def _is_identity(S: Pose) -> bool:
    return bool(np.array_equal(S.matrix, np.eye(4)))


def edges_alone_in_clutter(cue_qualities: dict | None, frame: Frame, view: ModelView, pose: Pose) -> bool:
    """Whether a start's fit at ``pose`` in ``frame`` was confirmed by the model's edges alone in a lit
    scene, for a tracker that reports its cues' verdicts (``cue_qualities``: cue name → quality, NaN
    for none; ``combined``'s): a small outline laid on a keyboard's edge or a cable crossing fits the
    edges as a right pose does, so off black space another cue must speak too (the texture cue cannot
    on the frame a start is checked on; the region cue where the part's colours stand out). On black
    space the edges alone decide; a tracker without cues is not judged here."""
    return _edges_alone(cue_qualities) and lit_around(frame, view, pose)


def start_refused_in_light(cue_qualities: dict | None, frame: Frame, view: ModelView, fit: Measurement,
                           plain_bar: float, plain_surround_bar: float = 0.0) -> bool:
    """Whether a start's ``fit`` in ``frame``, by a tracker that reports its cues' verdicts
    (``cue_qualities``), is refused for what a lit scene asks more than black space: it scores below
    ``plain_bar`` — a plain part's start there needs :attr:`~hybridpose.hybrid_config.HybridConfig.plain_start_quality`
    (a network's pose at the wrong distance fits a smaller cube inside a face of the real one, or in the
    clutter, almost as well) — or the edges alone vouch for it (:func:`edges_alone_in_clutter`), unless
    the scene around it is plain (:meth:`~hybridpose.edges.distinct.PlacementContrast.plain_around`: a
    white box on a white table, where the region cue has no verdict and no clutter lends a wrong outline
    its edges) and the fit reaches ``plain_surround_bar`` (0: never)."""
    if not cue_qualities or fit.lost or not lit_around(frame, view, fit.pose):
        return False
    if fit.quality < plain_bar:
        return True
    if not _edges_alone(cue_qualities):
        return False
    return not (0 < plain_surround_bar <= fit.quality and placement_contrast(view, frame, fit.pose).plain_around())


def _edges_alone(cue_qualities: dict | None) -> bool:
    """Whether the edges are the only cue with a verdict (NaN: none) among ``cue_qualities``."""
    return bool(cue_qualities) and {name for name, q in cue_qualities.items() if np.isfinite(q)} == {"edges"}


def lit_around(frame: Frame, view: ModelView, pose: Pose) -> bool:
    """Whether the scene around the part's outline at ``pose`` in ``frame`` is lit (a desk, a photo, the
    Earth), not black space (:func:`~hybridpose.edges.fit.dark_surround`); False where none of the
    model shows."""
    samples = view.visible_samples(pose, frame.camera, margin_px=2)
    return len(samples.index) > 0 and not dark_surround(to_gray(frame.image), samples.uv)


def plain_alternatives(found: list[Measurement], frame: Frame, view: ModelView | None) -> list[Measurement]:
    """Of a network's answers ``found`` (its answer first, then its other poses in ``frame``), the first and
    those of the others whose surroundings are lit (:func:`lit_around`: not black space, where the space
    suites measured the hybrid without them) and plain (:meth:`~hybridpose.edges.distinct.PlacementContrast.
    plain_around`); none without a ``view``. Why: in clutter each extra guess is one more chance for a wrong
    outline to pass a start's checks (hand-held tuning scenes over photos: a tile's pose 90° off confirmed
    by edges and region at 0.81 and held for 90 frames), where on a plain table only the part has edges."""
    return found[:1] + [m for m in found[1:] if view is not None and m.pose is not None and lit_around(frame, view, m.pose)
                        and placement_contrast(view, frame, m.pose).plain_around()]


def unseen_in_clutter(sightings, frame: Frame, view: ModelView, fit: Measurement, min_iou: float) -> bool:
    """Whether a start's ``fit`` in ``frame`` lies where none of the network's other looks at the frame saw
    the part — no pose of ``sightings`` (``T_cam_obj`` each: :attr:`~hybridpose.regressors.base.Candidates.
    sightings` of the answer it started from) puts the part's image box over the fit's by ``min_iou``
    (intersection over union) — in a lit scene whose surroundings are not plain (:func:`lit_around`,
    :meth:`~hybridpose.edges.distinct.PlacementContrast.plain_around`). False where ``sightings`` is None
    (the regressor does not say), with ``min_iou`` 0, or for a lost fit.

    Why: a network's close look can take a box, a bottle's label or a panel in the clutter for a far,
    small part that the edges and the region cue then confirm (hand-held tuning scenes over photos and
    ViSP's MegaPose cube: four such starts, each 48–57° off and held 5–33 frames); there the network's
    whole-frame and tile passes saw the part elsewhere, twice to seven times as large, or nowhere. A
    right start has a pass at its place (overlap 0.3–1 on those scenes)."""
    if sightings is None or min_iou <= 0 or fit.lost:
        return False
    box = _image_box(view, frame, fit.pose)
    if box is None or any(box_iou(box, other) >= min_iou for other in
                          (_image_box(view, frame, pose) for pose in sightings) if other is not None):
        return False
    return lit_around(frame, view, fit.pose) and not placement_contrast(view, frame, fit.pose).plain_around()


def _image_box(view: ModelView, frame: Frame, pose: Pose):
    """Box (x, y, w, h) px of the part's bounding box projected at ``pose``; None where it reaches behind the camera."""
    box = frame.camera.image_box(view.object.bbox_corners, pose)
    return None if box is None else (box[0], box[1], box[2] - box[0], box[3] - box[1])


def cues_vouch(cue_qualities: dict | None, bar: float) -> bool:
    """Whether every cue with a verdict (``cue_qualities``: cue name → quality, NaN for none) reaches
    ``bar``; True for a tracker that reports no cues, or with ``bar`` 0."""
    if not cue_qualities or bar <= 0:
        return True
    return all(q >= bar for q in cue_qualities.values() if np.isfinite(q))


def slid_starts(pose: Pose, step: float, span: float) -> list[Pose]:
    """``pose``, then ``pose`` with its distance scaled by 1 ± k·``step`` (k = 1, 2, …, up to
    ``span``), nearest first: a CNN pose's largest error is its depth."""
    k_max = int(span / step + 1e-9) if step > 0 else 0
    factors = [1.0] + [1.0 + sign * k * step for k in range(1, k_max + 1) for sign in (-1, 1)]
    return [pose if f == 1.0 else Pose(pose.R, pose.t * f) for f in factors]


@dataclass(frozen=True)
class CnnCheck:
    """A CNN check of a track: the CNN's answer, the tracker's fit from it, whether they disagree with
    the fused pose (the CNN's pose beyond the gate or ``disagreement_deg``, or the fit from it landing
    elsewhere and matching the image better than the track) and whether the fit stayed with the CNN."""

    cnn: Measurement
    fit: Measurement
    disagrees: bool
    stayed: bool

    def backed_by(self, track: Measurement, margin: float) -> bool:
        """Whether the ``track`` measurement fits the image better than the fit from the CNN by ``margin``."""
        return not track.lost and track.quality >= self.fit.quality + margin

    def vouches_for(self, track: Measurement, chi2: float) -> bool:
        """Whether the CNN's pose and the fit from it both lie within ``chi2`` (squared Mahalanobis) of ``track``."""
        return (self.fit.pose is not None and pose_mahalanobis2(track.pose, track.covariance, self.fit.pose, self.fit.covariance) <= chi2
                and pose_mahalanobis2(track.pose, track.covariance, self.cnn.pose, self.cnn.covariance) <= chi2)
