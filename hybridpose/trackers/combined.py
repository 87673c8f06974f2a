"""``combined``: one tracker, several cues in one fit, as ICG / M3T do — the model's edges, texture
points on its surface and the colours of its region against the background's
(:mod:`hybridpose.trackers.cues`), each a component that turns its correspondences into normal
equations weighted by its own uncertainty; one robust Gauss–Newton sums them.

Each frame:

1. the part's image patch in the previous frame is found again (±48 px, masked to the part): the
   start pose turns to follow it; then the texture cue follows its points with KLT from there (a
   search of its own, through the image pyramid) and a few Gauss–Newton steps on them alone bring the
   pose into the basin of the cues that search from the pose;
2. ``outer`` times: the edge and region cues search from the current pose (``search_px``, halving each
   time, never below 4), then ``inner`` Gauss–Newton steps over every active cue's equations;
3. covariance = ``covariance_scale`` × (Σ H)⁻¹ over ``[ω, v]``; quality = the mean of the cues'
   qualities that have a verdict (edges count half on a printed part: the print's edges pull them; a
   part that shows a print but none of its points here scores 0 for texture);
4. a plain part's trusted but mediocre fit gets a second look: fitted again from the pose turned about
   the image axes and from the other pose of the planar ambiguity (its largest face seen near head-on),
   and on the region cue alone from the frame's start, the best kept where all the cues agree with it
   clearly more — under blur a plain part's outline fits a pose 10–25° off almost as well, and the fit
   slides into it; an occluder coming in front (an arm, a hand) brings edges of its own beside the
   part's, which pull the edge cue, where the colours along the part's outline do not mislead.

Which cues speak follows what the part and the frame offer, not a flag: texture where the part shows a print
(corners inside its faces at the initial pose; a plain part's corners are corners of its shading and
outline, which slide as it turns), region where its colours differ from the
background's (not on black space with faces in shadow), edges always, with less weight on a printed
part (:func:`~hybridpose.edges.printed_faces`: the print's edges pull them). ``modalities``
restricts the set.

Quality below ``lost_quality`` (default 0.4) → ``lost``. No cue asks how much of the image the model
explains: a print on the part or clutter behind it is no evidence against a right pose.
"""
from __future__ import annotations

import math

import cv2
import numba
import numpy as np

from ..core import Frame, covariance_from_information
from ..edges import ModelView, printed_faces, to_gray, to_gray8
from ..edges.model_view import ID_SCALE
from ..geometry import Pose, mirrored_tilt, shifted_in_image, turned_about
from ..objects import ObjectModel
from ..registry import register
from .base import Tracker
from .cues import CUES, EdgeCue
from .cues.base import Sight
from .cues.solve import solve

MODALITIES = ("edges", "texture", "region")
TEXTURE_PREALIGN_STEPS = 5  # Gauss–Newton steps on texture points alone, before the searching cues
LEARN_CUE_QUALITY = 0.3  # every cue with a verdict at least this for the cues to learn from a frame
KEYFRAME_CUE_QUALITY = 0.5  # …and the other cues at least this for a new texture keyframe
PATCH_REACH_PX, PATCH_MIN_SCORE = 48, 0.5  # each frame's first, pose-free step: how far, how alike
# searched at quarter resolution, then ±1 px at half: a masked matchTemplate over the whole reach costs ≈ 0.6 ms
# at half resolution, 0.05 at quarter; the quarter's answer alone lost a few frames of the plain box (tuning seeds)
PATCH_SCALE = 0.5
# a second look at a plain part's trusted but mediocre fit (quality in [lost_quality, SECOND_LOOK_BELOW)) in a
# track held the frame before: fits again from SECOND_LOOK_TURN_DEG turns about the image axes and, where its
# largest face (≥ MIRROR_MIN_PIXELS at ID_SCALE) is seen MIRROR_TILT_DEG from head-on, from the mirrored tilt;
# the best is kept where its quality is SECOND_LOOK_MARGIN higher and at least SECOND_LOOK_FLOOR. It looks where
# the quality dropped SECOND_LOOK_DROP since the frame before, else after a wait that doubles, up to
# SECOND_LOOK_MAX_WAIT frames, while looks find nothing better (a plain part whose right fit scores 0.6-0.7
# would otherwise pay five fits a frame: ViSP's lego square 6.5 -> 22.6 ms). Chosen on the hand-held tuning
# scenes, plain box, frames trusted > 10 deg off of 1800: none 92; every frame 19 (margin 0.1: 52; below 0.8:
# 46; the mirrored tilt alone: 66-76; turns about the least-constrained axis instead of the image axes: 71);
# waits up to 4: 25, up to 16: 56; on the drop alone: 90
SECOND_LOOK_BELOW, SECOND_LOOK_MARGIN, SECOND_LOOK_FLOOR, SECOND_LOOK_TURN_DEG = 0.7, 0.05, 0.6, 12.0
SECOND_LOOK_DROP, SECOND_LOOK_MAX_WAIT = 0.1, 4  # when to look: the comment above
# under 4 deg the mirrored pose lies within the fit's own reach; with the mirror alone, tilts up to 20 deg
# only (not 40) left 73-81 frames > 10 deg off of 1800 where 40 left 66-76; a face under 100 px (ID_SCALE) is no plane to mirror
MIRROR_TILT_DEG, MIRROR_MIN_PIXELS = (4.0, 40.0), 100
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
    default_lost_quality = 0.4

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
        self._small = None  # the last frame at PATCH_SCALE and half that (float32 grey), for the patch step
        self._sight: Sight | None = None  # the frame being fitted, as the cues see it
        self._init_frame: Frame | None = None  # the frame of the last init
        self._deaf: set[str] = set()  # cues left out of this frame's fit and quality
        self._last_quality = 0.0  # the last fit's quality (0 after init or a failed fit): was the track held
        self._since_look = 0  # frames since the last second look
        self._look_wait = 1  # …and how many to wait before the next (doubles while looks find nothing better)

    def _cue(self, name: str):
        return next((c for c in self.cues if c.name == name), None)

    def _start(self, frame: Frame, gray: np.ndarray, pose: Pose, ids: np.ndarray) -> None:
        self.printed = printed_faces(self.view, frame, pose, gray, ids)
        for cue in self.cues:
            cue.start(frame, gray, pose, ids)
            if isinstance(cue, EdgeCue):
                cue.set_textured(self.printed)

    def _init(self, frame: Frame, pose: Pose) -> None:
        gray = to_gray(frame.image)
        ids = self.view.facet_ids(pose, frame.camera, scale=1.0)
        if int((ids > 0).sum()) < 50:
            raise ValueError(f"pose: {self.object.name!r} covers fewer than 50 pixels of the frame at the initial "
                             "pose — is the object in view and the pose right?")
        self._start(frame, gray, pose, ids)
        self._small = _shrunk(gray)
        self._init_frame = frame
        self._last_quality = 0.0
        self._since_look, self._look_wait = 0, 1  # a new track's second looks owe nothing to the fits before it

    def _track(self, frame: Frame, start: Pose, search_px: int | None = None):
        gray8 = to_gray8(frame.image)  # to_gray's, kept in uint8 for KLT and corners
        gray = gray8.astype(np.float32)
        ids = self.view.facet_ids(start, frame.camera)
        sight = Sight(frame, gray, gray8, start, ids, self.view.visible_index(start, frame.camera, margin_px=2, ids=ids))
        for cue in self.cues:
            cue.begin(sight)
        self._sight = sight
        # a fit of the very frame the tracker started on (the hybrid checking a CNN pose) must not hear
        # the texture cue: its points were lifted at that pose, so they agree with any pose, wrong too
        self._deaf = {"texture"} if frame is self._init_frame else set()
        pose = self._fit(frame, gray, start, search_px or self.search_px)
        if pose is None:
            for cue in self.cues:
                cue.finish(frame, gray, start, False, None)
            self._last_quality = 0.0
            return None, None, 0.0
        quality = self._quality(frame, gray, pose)
        pose, quality = self._second_look(sight, pose, start, quality, search_px or self.search_px)
        H = self._information
        edge_cue = self._cue("edges")
        self.last_sites = edge_cue.sites if edge_cue is not None and edge_cue.active else None
        # what the cues learn from this frame (keyframes, colours) must be the part's: only where every
        # cue with a verdict agrees (a mug passing in front of a printed cube, taken as its print at a
        # keyframe, was then followed as the cube)
        trusted = quality >= self.lost_quality and all(
            q >= LEARN_CUE_QUALITY for q in self.cue_qualities.values() if np.isfinite(q))
        texture = self._cue("texture")
        if texture is not None:
            # a keyframe fixes its pose's error into its points: only where the other cues vouch for it,
            # each of them; a cue starved by blur that still follows a few points (it votes low until it
            # lifts new ones) may also re-key where they vouch together. One that follows none (covered,
            # or the pose is elsewhere) waits for each of them.
            others = {n: q for n, q in self.cue_qualities.items() if n != "texture" and np.isfinite(q)}
            texture.may_keyframe = all(q >= KEYFRAME_CUE_QUALITY for q in others.values())
            texture.may_rekey_starved = texture.may_keyframe or (
                texture.active and self._vote(others) >= self.lost_quality)
        full_ids = _Once(lambda: self.view.facet_ids(pose, frame.camera, scale=1.0))
        for cue in self.cues:
            cue.finish(frame, gray, pose, trusted, full_ids)
        self._last_quality = quality
        return pose, covariance_from_information(H, self.covariance_scale), quality

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
        if not self._in_front(pose):
            return None
        pose = self._follow_patch(frame, gray, pose)
        texture = self._cue("texture")
        if texture is not None and texture.active and "texture" not in self._deaf:
            texture.correspond(frame, gray, pose, search_px)
            if len(texture.index) >= 6:
                pose = self._solve(pose, [texture], TEXTURE_PREALIGN_STEPS, frame.camera.K) or pose
        return self._search_fit(frame, gray, pose, start, search_px)

    def _search_fit(self, frame: Frame, gray: np.ndarray, pose: Pose, start: Pose, search_px: int) -> Pose | None:
        """``outer`` rounds: every active cue searches from ``pose``, then ``inner`` Gauss–Newton steps."""
        rng = search_px
        for _ in range(self.outer):
            active = [c for c in self.cues if c.active and c.name not in self._deaf]
            for cue in active:
                cue.correspond(frame, gray, pose, rng)
            pose = self._solve(pose, active, self.inner, frame.camera.K)
            if pose is None or np.linalg.norm(pose.t - start.t) > self.object.diameter or not self._in_front(pose):
                return None
            rng = max(4, rng // 2)
        return pose

    def _second_look(self, sight: Sight, pose: Pose, start: Pose, quality: float, search_px: int):
        """(pose, quality): a plain part's mediocre fit tried again from other starts (see
        ``SECOND_LOOK_BELOW``): the outline of a plain part under blur fits a pose turned 10–25° about an
        axis across the line of sight almost as well (seen near head-on, the two poses of the planar
        ambiguity: :func:`~hybridpose.geometry.mirrored_tilt`), and the Gauss–Newton fit slides into it.
        Where the region cue speaks, also its fit alone from ``start``: an occluder's edges beside the
        part's (an arm sliding over it) pull the edge cue and the fit of every cue with it, not the
        colours along the part's outline. Every fit is judged by all the cues.
        A printed part's texture points pin the pose; a track not held the frame before has no right
        pose to slide from. Else ``pose`` and its ``quality`` as they were."""
        texture = self._cue("texture")
        self._since_look += 1
        due = quality < self._last_quality - SECOND_LOOK_DROP or self._since_look >= self._look_wait
        held = self._last_quality >= self.lost_quality  # the frame before
        if ((texture is not None and texture.enabled) or not held or sight.frame is self._init_frame
                or not self.lost_quality <= quality < SECOND_LOOK_BELOW or not due):
            return pose, quality
        self._since_look = 0
        frame, camera, information = sight.frame, sight.frame.camera, self._information
        best = None
        # (start, the cues its fit leaves out); every fit is judged by all of them
        candidates = [(other_start, set()) for other_start in self._other_starts(pose, camera)]
        region = self._cue("region")
        if region is not None and region.active:
            candidates.append((start, {"edges", "texture"}))
        for other_start, left_out in candidates:
            other = sight  # the frame's own start: its raster and visible samples are those of the frame's sight
            if other_start is not sight.start:
                ids = self.view.facet_ids(other_start, camera)
                other = Sight(frame, sight.gray, sight.gray8, other_start, ids,
                              self.view.visible_index(other_start, camera, margin_px=2, ids=ids))
            for cue in self.cues:
                cue.begin(other)
            deaf, self._deaf = self._deaf, self._deaf | left_out
            fitted = self._search_fit(frame, sight.gray, other_start, start, search_px)
            self._deaf = deaf
            if fitted is not None:
                q = self._quality(frame, sight.gray, fitted)
                if best is None or q > best[1]:
                    best = (fitted, q, other, self._information)
        if best is not None and best[1] >= max(quality + SECOND_LOOK_MARGIN, SECOND_LOOK_FLOOR):
            pose, quality, kept, self._information = best
            self._look_wait = 1
        else:
            kept, self._information = sight, information
            self._look_wait = min(2 * self._look_wait, SECOND_LOOK_MAX_WAIT)
        for cue in self.cues:
            cue.begin(kept)
        self._sight = kept
        self._quality(frame, sight.gray, pose)  # the cues' verdicts (and the edge sites) of the pose kept
        return pose, quality

    def _other_starts(self, pose: Pose, camera) -> list[Pose]:
        """``pose`` turned ±``SECOND_LOOK_TURN_DEG`` about the camera's x and y axes through the part's
        centre and, where its largest face is seen near head-on, mirrored about the line of sight."""
        centre = self.object.bbox_corners.mean(0)
        centre_cam = pose.R @ centre + pose.t
        starts = [turned_about(pose, rotvec, centre)
                  for rotvec in np.radians(SECOND_LOOK_TURN_DEG) * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0.0]])]
        counts = np.bincount(self.view.facet_ids(pose, camera).ravel())
        counts[0] = 0
        face = int(np.argmax(counts))
        normal = self.view.plane_normal[face]
        tilt = np.degrees(np.arccos(np.clip(abs((pose.R @ normal) @ centre_cam) / np.linalg.norm(centre_cam), 0, 1)))
        if counts[face] >= MIRROR_MIN_PIXELS and MIRROR_TILT_DEG[0] <= tilt <= MIRROR_TILT_DEG[1]:
            starts.insert(0, mirrored_tilt(pose, normal, centre))
        return starts

    def _in_front(self, pose: Pose) -> bool:
        """Whether the whole part lies in front of the camera at ``pose`` (a fit that slid behind it is lost)."""
        return bool(((pose.R @ self.object.bbox_corners.T)[2] + pose.t[2]).min() > 1e-3)

    def _follow_patch(self, frame: Frame, gray: np.ndarray, start: Pose) -> Pose:
        """``start`` turned about the camera centre so that the part's projection lands where the image
        patch around it in the previous frame lies now (masked normalised cross-correlation ±``PATCH_REACH_PX``
        at half ``PATCH_SCALE``, refined at ``PATCH_SCALE``): a pose-free first step; the part's image may move further in a frame than
        the edge and region searches reach, and KLT, started closer, keeps more of its points."""
        small = _shrunk(gray)
        previous, self._small = self._small, small
        if previous is None or self.pose is None:
            return start
        box = frame.camera.image_box(self.object.bbox_corners, self.pose)
        if box is None:
            return start
        # the part alone, not its background: the previous pose's raster (the start's, when it starts there)
        ids = self._sight.ids if start is self.pose else self.view.facet_ids(self.pose, frame.camera, ID_SCALE)
        seen = [_nearest_mask(ids, im.shape) for im in small]
        box = np.asarray(box) * PATCH_SCALE
        coarse = patch_shift(previous[1], small[1], box * 0.5, int(PATCH_REACH_PX * PATCH_SCALE / 2), seen[1])
        if coarse is None:
            return start
        shift = refine_shift(previous[0], small[0], box, seen[0], 2.0 * coarse)
        moved = frame.camera.project(self.object.bbox_corners, self.pose).mean(0) + shift / PATCH_SCALE
        delta = moved - frame.camera.project(self.object.bbox_corners, start).mean(0)
        if np.hypot(*delta) < 1.0 or np.hypot(*delta) > 2 * PATCH_REACH_PX:
            return start  # no motion, or a start from elsewhere (a CNN pose): the patch says nothing of it
        return shifted_in_image(start, frame.camera, delta[0], delta[1])

    def _quality(self, frame: Frame, gray: np.ndarray, pose: Pose) -> float:
        self.cue_qualities = {c.name: c.quality(frame, gray, pose) for c in self.cues
                              if c.active and c.name not in self._deaf}
        texture = self._cue("texture")
        if (texture is not None and texture.enabled and "texture" not in self._deaf
                and not np.isfinite(self.cue_qualities.get("texture", np.nan))):
            # a part that shows a print but none of it here: covered, or the pose is elsewhere
            self.cue_qualities["texture"] = 0.0
        return self._vote(self.cue_qualities)

    def _vote(self, qualities: dict[str, float]) -> float:
        """The weighted mean of the cues' qualities that have a verdict (0 where none has)."""
        weights = {"edges": 0.5 if self.printed else 1.0}
        votes = [(weights.get(n, 1.0), q) for n, q in qualities.items() if np.isfinite(q)]
        if not votes:
            return 0.0
        return float(sum(w * q for w, q in votes) / sum(w for w, _ in votes))


def patch_shift(previous: np.ndarray, current: np.ndarray, box, reach_px: int,
                mask: np.ndarray | None = None) -> np.ndarray | None:
    """(2,) px: where the patch ``box`` (x0, y0, x1, y1) of the (H, W) float32 image ``previous`` lies
    in ``current``, searched ±``reach_px``, comparing only the pixels ``mask`` (H, W) bool marks (the
    part, not the background, which moves otherwise); None where the best normalised correlation is
    below ``PATCH_MIN_SCORE`` or the patch is too small. Sub-pixel: a parabola through the peak and its
    neighbours, along each axis."""
    h, w = previous.shape
    x0, y0 = max(int(box[0]), 0), max(int(box[1]), 0)
    x1, y1 = min(int(np.ceil(box[2])), w), min(int(np.ceil(box[3])), h)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    X0, Y0 = max(x0 - reach_px, 0), max(y0 - reach_px, 0)
    X1, Y1 = min(x1 + reach_px, w), min(y1 + reach_px, h)
    template = np.ascontiguousarray(previous[y0:y1, x0:x1])
    if mask is None:
        score = cv2.matchTemplate(np.ascontiguousarray(current[Y0:Y1, X0:X1]), template, cv2.TM_CCOEFF_NORMED)
    else:
        weights = np.ascontiguousarray(mask[y0:y1, x0:x1], np.float32)
        if weights.sum() < 32:
            return None
        score = cv2.matchTemplate(np.ascontiguousarray(current[Y0:Y1, X0:X1]), template, cv2.TM_CCOEFF_NORMED,
                                  mask=weights)
    score = np.nan_to_num(score, nan=-1.0, posinf=-1.0, neginf=-1.0)
    _, best, _, (bx, by) = cv2.minMaxLoc(score)
    if best < PATCH_MIN_SCORE:
        return None
    return np.array([X0 + bx + _vertex(score[by, bx - 1:bx + 2]) - x0,
                     Y0 + by + _vertex(score[by - 1:by + 2, bx]) - y0], np.float64)


def _vertex(three: np.ndarray) -> float:
    """Offset (−0.5 … 0.5) of the vertex of the parabola through three scores around a peak; 0 at an edge."""
    if len(three) != 3:
        return 0.0
    den = three[0] - 2 * three[1] + three[2]
    return float(np.clip(0.5 * (three[0] - three[2]) / den, -0.5, 0.5)) if den < -1e-9 else 0.0


def refine_shift(previous: np.ndarray, current: np.ndarray, box, mask: np.ndarray, guess) -> np.ndarray:
    """(2,) px: ``guess`` (a shift of the patch ``box`` of ``previous`` into ``current``, as
    :func:`patch_shift` gives it at half this resolution) refined over the integer shifts ±1 px around it
    by the masked normalised correlation, with a parabola through the peak. The guess where the patch
    leaves the image."""
    h, w = previous.shape
    x0, y0 = max(int(box[0]), 0), max(int(box[1]), 0)
    x1, y1 = min(int(np.ceil(box[2])), w), min(int(np.ceil(box[3])), h)
    gx, gy = int(round(guess[0])), int(round(guess[1]))
    score = masked_correlations(previous, current, mask, x0, y0, x1, y1, gx, gy)
    by, bx = np.unravel_index(int(np.argmax(score)), score.shape)
    if score[by, bx] <= -1.0:
        return np.asarray(guess, np.float64)
    return np.array([gx + bx - 1 + _vertex(score[by, bx - 1:bx + 2]),
                     gy + by - 1 + _vertex(score[by - 1:by + 2, bx])], np.float64)


@numba.njit(cache=True, nogil=True)
def masked_correlations(previous, current, mask, x0, y0, x1, y1, gx, gy):
    """(3, 3) normalised correlations (``cv2.TM_CCOEFF_NORMED`` with a binary mask) of the patch
    ``previous[y0:y1, x0:x1]``, where ``mask`` holds, against ``current`` shifted by (gx + dx, gy + dy),
    dx, dy ∈ {−1, 0, 1}; −1 where the shifted patch leaves the image or either side is flat.

    Compiled, one pass over the patch for all nine shifts: nine positions only, where
    ``cv2.matchTemplate`` pays for its whole-image transforms."""
    h, w = current.shape
    out = np.full((3, 3), -1.0)
    n = t_sum = tt_sum = 0.0
    s_i = np.zeros((3, 3))
    s_ii = np.zeros((3, 3))
    s_ti = np.zeros((3, 3))
    inside = np.zeros((3, 3), np.bool_)
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            sx, sy = gx + dx, gy + dy
            inside[dy + 1, dx + 1] = x0 + sx >= 0 and y0 + sy >= 0 and x1 + sx <= w and y1 + sy <= h
    for y in range(y0, y1):
        for x in range(x0, x1):
            if not mask[y, x]:
                continue
            t = previous[y, x]
            n += 1.0
            t_sum += t
            tt_sum += t * t
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    if inside[dy + 1, dx + 1]:
                        i = current[y + gy + dy, x + gx + dx]
                        s_i[dy + 1, dx + 1] += i
                        s_ii[dy + 1, dx + 1] += i * i
                        s_ti[dy + 1, dx + 1] += t * i
    if n < 32:
        return out
    tt = tt_sum - t_sum * t_sum / n
    for r in range(3):
        for c in range(3):
            if not inside[r, c]:
                continue
            ii = s_ii[r, c] - s_i[r, c] * s_i[r, c] / n
            ti = s_ti[r, c] - t_sum * s_i[r, c] / n
            if tt > 1e-6 * n and ii > 1e-6 * n:
                out[r, c] = ti / math.sqrt(tt * ii)
    return out


def _nearest_mask(ids: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) bool: where the facet-id raster ``ids`` shows the part, resampled to ``shape`` (h, w) by
    nearest neighbour (``cv2.INTER_NEAREST``'s pixels); a plain stride where ``ids`` is a whole multiple of
    it, which picks the same pixels without a full-size copy."""
    h, w = shape
    sy, sx = ids.shape[0] // h, ids.shape[1] // w
    if sy >= 1 and sx >= 1 and ids.shape == (h * sy, w * sx):
        return ids[::sy, ::sx] > 0
    return cv2.resize((ids > 0).astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0


def _shrunk(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``gray`` at ``PATCH_SCALE`` and at half that."""
    small = cv2.resize(gray, None, fx=PATCH_SCALE, fy=PATCH_SCALE, interpolation=cv2.INTER_AREA)
    return small, cv2.resize(small, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)


class _Once:
    """A value worked out on the first call and kept (a raster only some cues need)."""

    def __init__(self, make) -> None:
        self.make, self.value = make, None

    def __call__(self):
        if self.value is None:
            self.value = self.make()
        return self.value
