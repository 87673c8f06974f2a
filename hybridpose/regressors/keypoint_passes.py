"""A keypoint network's passes on crops of an image, and PnP on their keypoints: the estimates a
keypoint regressor makes its measurement from (before any twin choice or edge fit).

One pass: the crop around a box (``geometry.crops``), the network, PnP (:mod:`.keypoint_pnp`) in the
twin its head believes most. Where PnP drops keypoints, the same crop turned in-plane by ±20°/±40°
too (``turns``); a second pass on the crop centred on the first pose where the twin head is unsure
(``passes``); an estimate whose projection does not fit the box it was found in, or that lies beyond
the depth gate, is no estimate.
"""
from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import cv2
import numpy as np
import torch

from ..geometry import Camera, Pose
from ..geometry.crops import crop_box, crop_image
from .calibration import PNP_THRESHOLD
from .detection import CROP_MARGIN
from .keypoint_pnp import PnPResult, solve_pnp
from .options import KeypointOptions
from .unlabelled import detections, solve_pnp_unlabelled

QUALITY_RMS = 0.02  # RMS reprojection error (fraction of the crop side) at which quality falls to 1/e
# passes="auto": the second, re-centred network pass only where the first pass's twin head is below
# this (≈ 15 % of views): it buys most of what two passes always would (docs/decisions.md)
# for ≈ 1 ms on average instead of 7.
SECOND_PASS_BELOW = 0.9
# PnP on near-collinear keypoints (edge-on views) can return the object several times too far away
# (13 m for a truss at 1 m in the seed-101 test set): a pose whose projected keypoints span more
# than this factor less (or more) than the box the network was shown is not a measurement
SIZE_RATIO_MAX = 3.0
# turns="auto": where the first pass's PnP keeps fewer than TURNS_BELOW_INLIERS of the keypoints, the
# network also sees its crop turned in-plane by TURNS_DEG (one batch) and the pass whose PnP keeps the
# most keypoints (then the lowest RMS) wins. The failures are keypoints in near edge-on views that a
# slightly turned crop gets right; larger turns (90°, 180°) move the sunlit side where the network
# never saw it and are worse alone (docs/decisions.md). 0.8 (≤ 9 of 12 kept: 19 %
# of the views) rather than 0.9 (≤ 10: 36 %) since PnP drops the worst keypoint: 3 ms less per view,
# and on 5000 fresh views 94 vs 97 > 30° off, 4.64° vs 4.76° mean (a test written before those views were rendered).
TURNS_DEG = (20.0, -20.0, 40.0, -40.0)
TURNS_BELOW_INLIERS = 0.8  # turned passes run where PnP keeps fewer than this share of keypoints


def size_ratio(pose: Pose, points_m: np.ndarray, camera: Camera, box) -> float:
    """How far the image extent of ``points_m`` under ``pose`` is from ``box``'s: ≥ 1, ∞ if behind the camera.

    Args:
        pose: T_cam_obj (metres). points_m: (N, 3) object points, metres. camera: the (undistorted)
            camera of the image. box: (x, y, w, h) pixels, the region the object was found in
            (detection or caller's ``roi``).
    Returns:
        max(d / d_box, d_box / d) for the diagonals d of the projected points' bounding box and
        d_box of ``box``.
    """
    try:
        uv = camera.project(points_m, pose)
    except ValueError:  # a point at or behind the camera plane: no pose of a visible object
        return float("inf")
    d = float(np.hypot(*(uv.max(0) - uv.min(0))))
    d_box = float(np.hypot(box[2], box[3]))
    if d <= 0 or d_box <= 0:
        return float("inf")
    return max(d / d_box, d_box / d)


def wants_turns(turns: str, res) -> bool:
    """Whether the first crop is also tried turned (``TURNS_DEG``) after a pass with PnP result ``res``
    (None: PnP failed), under the ``turns`` option (:class:`~hybridpose.regressors.options.KeypointOptions`)."""
    if turns == "auto":
        return res is None or res.inlier_ratio < TURNS_BELOW_INLIERS
    return turns == "always"


def wants_second_pass(passes, res, prob) -> bool:
    """Whether a second, re-centred network pass follows a first one with PnP result ``res`` (None:
    failed) and twin-head probabilities ``prob`` (None: no head), under the ``passes`` option."""
    if passes == "auto":
        return res is None or prob is None or float(prob.max()) < SECOND_PASS_BELOW
    return passes == 2


def _to_tensor(img: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1).float().div_(255.0)[None]


def _row(batch, i: int):
    """Row ``i`` of a batched network output, None where the network has no such output."""
    return None if batch is None else batch[i]


def image_batch(*images: np.ndarray) -> torch.Tensor:
    """(B, 3, H, W) float32 in [0, 1] on the CPU from B (H, W, 3) uint8 RGB images of one size."""
    return torch.cat([_to_tensor(img) for img in images]) if len(images) > 1 else _to_tensor(images[0])


class KeypointEstimate(NamedTuple):
    """One estimate of a keypoint network's passes, before any twin choice or edge fit.

    ``result``: the PnP result, its pose T_cam_obj already turned to the twin head's most likely twin;
    ``order``: the symmetry indices (0 = the keypoints' own pose, k = ``twins[k-1]``), most likely first
    by the twin head (0, 1, 2, … without one); ``prob``: (T,) the head's softmax indexed like the
    symmetries (None without a head); ``crop_px``: the side of the crop the network saw, pixels.
    """

    result: PnPResult
    order: list
    prob: np.ndarray | None
    crop_px: int


def pnp_quality(est: KeypointEstimate) -> float:
    """The PnP part of an estimate's quality: inlier share × exp(−RMS / ``QUALITY_RMS`` of its own crop
    side, so estimates at different crop sizes compare)."""
    res, _, _, crop_px = est
    return res.inlier_ratio * float(np.exp(-res.rms_px / (QUALITY_RMS * crop_px)))


def _pass_rank(candidate) -> tuple:
    """Sort key of a network pass (:meth:`KeypointPasses.solve_turned`): a PnP pose first, then the most
    keypoints kept, then the lowest RMS reprojection error."""
    res = candidate[0]
    return (1, 0.0, 0.0) if res is None else (0, -res.inlier_ratio, res.rms_px)


class KeypointPasses:
    """A keypoint network's passes and PnP on an undistorted image.

    Args:
        engine: runs the network (:mod:`.engines`): ``engine(x)`` → (uv, spread, twin logits).
        keypoints_m: (N, 3) float64, the keypoints in the object frame, metres.
        twins: the object's box twins the twin head names (list of :class:`Pose`, symmetry k = ``twins[k-1]``).
        has_twin_head: whether the network has a twin head.
        image_size: side of the network's square input, pixels.
        options: the :class:`KeypointOptions` whose ``passes``, ``turns``, ``pnp_outliers`` and
            ``turn_pnp_outliers`` apply (the regressor replaces it when it is reconfigured).
        max_depth_m: the depth gate, metres (None: none).
        unlabelled: for an :class:`~.keypoint_net.UnlabelledKeypointNet` (the engine then gives its
            peaks and their scores): the keypoints' hull planes and symmetry gauge
            (:mod:`.unlabelled`); None for a network that names its keypoints.
    """

    def __init__(self, engine, keypoints_m: np.ndarray, twins: list, has_twin_head: bool, image_size: int,
                 options: KeypointOptions, max_depth_m: float | None = None, unlabelled=None) -> None:
        self.engine, self.keypoints_m, self.twins = engine, keypoints_m, twins
        self.has_twin_head, self.image_size = has_twin_head, image_size
        self.options, self.max_depth_m = options, max_depth_m
        self.unlabelled = unlabelled

    def network_pass(self, image: np.ndarray, K: np.ndarray, box, turns: bool = False, sun_turn: float = 0.0):
        """One network pass on ``box`` (cx, cy, side) in ``image`` with intrinsics ``K`` (3, 3): (PnP
        result in the head's most likely twin or None, keypoints (N, 2) in crop pixels (an unlabelled
        network's detections, (M, 2), strongest first), crop K, twin
        order, twin probabilities), order and probabilities as in :class:`KeypointEstimate`. With
        ``turns`` the crop turned by ``TURNS_DEG`` is tried too where :func:`wants_turns` says so, and
        the pass whose PnP keeps the most keypoints (then the lowest RMS) is returned. Every turn
        starts from ``sun_turn`` (°, OpenCV's counter-clockwise sense)."""
        crop, K_crop = crop_image(image, K, *box, (self.image_size, self.image_size))
        best = self.solve_turned(crop, K_crop, (sun_turn,))[0]
        # an unlabelled network's corners look alike at any in-plane angle: turned crops find nothing
        # new, at twice the cost (tuning sequences over photos)
        if turns and self.unlabelled is None and wants_turns(self.options.turns, best[0]):
            turned = self.solve_turned(crop, K_crop, [sun_turn + a for a in TURNS_DEG], self.options.turn_pnp_outliers)
            best = min([best, *turned], key=_pass_rank)
        res, uv, order, prob = best
        return res, uv, K_crop, order, prob

    def solve_turned(self, crop: np.ndarray, K_crop: np.ndarray, angles_deg, outliers: str | None = None) -> list:
        """Network passes on ``crop`` (S, S, 3) uint8 turned in-plane by each of ``angles_deg`` (about its
        centre, one batch), keypoints mapped back to the unturned crop, then PnP (``outliers``:
        :func:`solve_pnp`'s, default ``pnp_outliers``): [(result or None, keypoints (N, 2) in crop
        pixels, twin order, twin probabilities)] per angle."""
        outliers = self.options.pnp_outliers if outliers is None else outliers
        centre = ((self.image_size - 1) / 2.0,) * 2
        turns = [np.vstack([cv2.getRotationMatrix2D(centre, float(a), 1.0), [0.0, 0.0, 1.0]]) for a in angles_deg]
        crops = [crop if a == 0 else cv2.warpAffine(crop, A[:2], crop.shape[1::-1], flags=cv2.INTER_LINEAR,
                                                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                 for a, A in zip(angles_deg, turns)]
        uv_all, score_all, twin = self.engine(image_batch(*crops))
        out = []
        for i, A in enumerate(turns):
            back = np.linalg.inv(A)
            uv = uv_all[i].float().cpu().numpy().astype(np.float64) @ back[:2, :2].T + back[:2, 2]
            out.append(self._solve(uv, _row(score_all, i), _row(twin, i), K_crop, outliers))
        return out

    def solve_boxes(self, image: np.ndarray, K: np.ndarray, boxes) -> list:
        """One network pass on each of ``boxes`` [(cx, cy, side), …] pixels of ``image`` (intrinsics ``K``
        (3, 3)), all in one batch, then PnP: [(result or None, keypoints (N, 2) in crop pixels, crop K
        (3, 3), twin order, twin probabilities)] per box."""
        crops, Ks = zip(*(crop_image(image, K, *box, (self.image_size, self.image_size)) for box in boxes))
        uv_all, score_all, twin = self.engine(image_batch(*crops))
        out = []
        for i, K_crop in enumerate(Ks):
            uv = uv_all[i].float().cpu().numpy().astype(np.float64)
            res, uv, order, prob = self._solve(uv, _row(score_all, i), _row(twin, i), K_crop, self.options.pnp_outliers)
            out.append((res, uv, K_crop, order, prob))
        return out

    def _solve(self, uv: np.ndarray, score, twin_logits, K_crop: np.ndarray, outliers: str) -> tuple:
        """PnP on one pass's keypoints ``uv`` (N, 2) crop pixels (an unlabelled network's peaks, scored by
        ``score``): (result in the twin head's most likely twin or None, keypoints or detections,
        twin order, twin probabilities)."""
        if self.unlabelled is not None:
            planes, gauge = self.unlabelled
            uv = detections(uv, score.float().cpu().numpy())
            res = solve_pnp_unlabelled(uv, self.keypoints_m, planes, gauge, K_crop, PNP_THRESHOLD * self.image_size)
        else:
            res = solve_pnp(uv, self.keypoints_m, K_crop, threshold_px=PNP_THRESHOLD * self.image_size,
                            outliers=outliers)
        order, prob = list(range(len(self.twins) + 1)), None
        if self.has_twin_head:
            prob = torch.softmax(twin_logits.float(), 0).cpu().numpy()
            order = [int(k) for k in np.argsort(-prob, kind="stable")]
            if res is not None and order[0] > 0:  # undo the twin the keypoints follow (half-turns are their own inverses)
                res = replace(res, pose=res.pose @ self.twins[order[0] - 1])
        return res, uv, order, prob

    def estimate_in(self, image: np.ndarray, cam: Camera, seen, sun_turn: float = 0.0) -> KeypointEstimate | None:
        """The estimate from the box ``seen`` (x, y, w, h, pixels) where the object was found in the
        undistorted ``image`` (camera ``cam``): the first pass (with turns), a second one where
        :func:`wants_second_pass` says so; None where PnP gives no plausible pose."""
        K = cam.K
        box = crop_box(seen, CROP_MARGIN)
        res, uv, K_crop, order, prob = self.network_pass(image, K, box, turns=True, sun_turn=sun_turn)
        # second pass on the crop centred on the first pose (the crop the network knows best)
        again = (self._box_around(res.pose if res is not None else None, uv, K_crop, K)
                 if wants_second_pass(self.options.passes, res, prob) else None)
        if again is not None:
            res2, _, _, order2, prob2 = self.network_pass(image, K, again, sun_turn=sun_turn)
            if res2 is not None and (res is None or res2.inlier_ratio >= res.inlier_ratio):
                res, order, prob = res2, order2, prob2
        if res is None or size_ratio(res.pose, self.keypoints_m, cam, seen) > SIZE_RATIO_MAX:
            return None
        if self.max_depth_m is not None and res.pose.t[2] > self.max_depth_m:
            return None
        return KeypointEstimate(res, order, prob, self.image_size)

    def _box_around(self, pose: Pose | None, uv, K_crop, K) -> tuple[float, float, float] | None:
        """Crop box (cx, cy, side) in frame pixels around the projected keypoints."""
        if pose is not None:
            p = (pose @ self.keypoints_m) @ K.T
            pts = p[:, :2] / p[:, 2:3]
        else:  # PnP failed: the raw coarse keypoints, mapped back to the frame
            A = K @ np.linalg.inv(K_crop)
            pts = uv @ A[:2, :2].T + A[:2, 2]
        if len(pts) == 0:
            return None
        lo, hi = pts.min(0), pts.max(0)
        if not np.all(np.isfinite(lo)) or np.any(hi - lo < 1):
            return None
        return crop_box((lo[0], lo[1], hi[0] - lo[0] + 1, hi[1] - lo[1] + 1), CROP_MARGIN)
