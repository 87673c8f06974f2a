"""Where a keypoint network finds its object in a whole frame, with no prior (``detection="network"``).

The network looks at the whole frame and at overlapping square tiles of it (one batch); each pass
whose PnP gives a pose proposes the box of that pose's projected keypoints. The regressor then
estimates in every distinct proposal and keeps the estimate PnP fits best
(:func:`~.keypoint_passes.pnp_quality`). Why tiles: on a cluttered photo the whole frame, shrunk to
the network's input, leaves a part a few dozen pixels across among corners of clutter; there the
whole-frame box missed the part (IoU < 0.5) on 38 % of the frames of the box's tuning sequences, and
a second look at a finer scale finds it (docs/decisions.md).
"""
from __future__ import annotations

import math

import numpy as np

from ..geometry import Camera
from ..geometry.crops import box_iou
from .detection import detect_bright_object
from .keypoint_net import HEATMAP_STRIDE
from .keypoint_passes import KeypointEstimate, pnp_quality

# tiles: squares this share of the frame's long side, overlapping by at least half a tile (640 × 480:
# two 480-px squares). Box tuning sequences, CNN-only in a tracker's basin with the frame alone 71 %;
# with 0.75: 1 × 1 86 %, 2 × 1 88 %, 3 × 1 89 %; 0.6 (2 × 2) 85 %, 0.5 (3 × 2) 84 %, 0.4 (3 × 2) 71 %:
# small tiles cut the part and find clutter that PnP fits well.
TILE_SIDE = 0.75
# fine_tiles (an option, off by default): where no estimate from those proposals reaches PnP quality
# FINE_BELOW, the network looks again at finer tiles (FINE_TILE_SIDE of the long side: twelve 256-px
# squares on 640 × 480), and an estimate found only there counts from quality FINE_ACCEPT: a part
# 20–35 px across in the whole frame's pass (ViSP's 84-mm cube at 0.5 m) is 50–70 px in these. Off by
# default: it doubles the CNN's call without a roi for a small gain (docs/decisions.md).
FINE_TILE_SIDE = 0.4
FINE_BELOW = 0.6  # see above: the whole frame's best PnP quality below which fine tiles run
FINE_ACCEPT = 0.7  # see above: 0.6 let fine tiles find clutter that PnP fits well
# proposals whose boxes overlap more than this (intersection over union) are one proposal
SAME_BOX_IOU = 0.7
# a whole-frame pass of an unlabelled network whose detections PnP cannot use (a part a few cells across)
# still says where the part is: the detections linked to the strongest one (each within CLUSTER_LINK of
# the crop side of another; clutter elsewhere stays out), boxed at least MIN_BOX_CELLS heatmap cells wide.
# Where PnP has a pose, its projection boxes the part better (tuning sequences over photos: CNN-only
# within a tracker's basin 38 vs 17 % of the frames; the procedural views favoured the linked box)
CLUSTER_LINK = 0.2  # procedural calibration views, whole path > 10° off: 0.12 / 0.2 / 0.3 → 47 / 27 / 30 %
MIN_BOX_CELLS = 4  # a proposal smaller than 4 × 4 heatmap cells is noise
# two estimates are one pose for a start where every projected keypoint of each lies within this share of
# the keypoints' image extent of a keypoint of the other (sets, not labels: a symmetric part's equivalent
# poses project the same keypoints and are one start)
SAME_POSE_SHARE = 0.05


def linked_cluster(points: np.ndarray, link: float) -> np.ndarray:
    """The points (M, 2) joined to the first one by a chain of steps shorter than ``link`` (single
    linkage), first one included."""
    inside = np.zeros(len(points), bool)
    inside[0] = True
    while True:
        near = (np.linalg.norm(points[:, None] - points[inside][None], axis=2) < link).any(1) & ~inside
        if not near.any():
            return points[inside]
        inside |= near


def tile_boxes(width: int, height: int, side_share: float = TILE_SIDE) -> list[tuple[float, float, float]]:
    """Square tiles (cx, cy, side) pixels covering a ``width`` × ``height`` frame: each ``side_share``
    of the long side (at most the short one), as few per axis as keep neighbours overlapping by at least
    half a tile, spread evenly from edge to edge."""
    side = min(side_share * max(width, height), float(min(width, height)))

    def centres(extent: int) -> np.ndarray:
        n = 1 + math.ceil(max(extent - side, 0.0) / (side / 2) - 1e-9)
        return np.linspace(side / 2, extent - side / 2, n) if n > 1 else np.array([extent / 2])

    return [(float(x), float(y), float(side)) for y in centres(height) for x in centres(width)]


def _clip(uv: np.ndarray, cam: Camera):
    """Box (x, y, w, h) of the points ``uv`` (N, 2) clipped to the frame, or None under 2 px."""
    (x0, y0), (x1, y1) = np.maximum(uv.min(0), 0.0), np.minimum(uv.max(0), [cam.width - 1.0, cam.height - 1.0])
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    return float(x0), float(y0), float(x1 - x0), float(y1 - y0)


def _pose_box(passes, pose, cam: Camera):
    """Box of the keypoints projected at ``pose`` (T_cam_obj), None for one behind or at the camera."""
    if np.any((pose @ passes.keypoints_m)[:, 2] <= 0.05):
        return None
    return _clip(cam.project(passes.keypoints_m, pose), cam)


def _cluster_box(passes, found: np.ndarray, K_crop: np.ndarray, cam: Camera):
    """Box around an unlabelled network's detections ``found`` (M, 2) crop pixels, strongest first, that
    link to the strongest one, at least ``MIN_BOX_CELLS`` heatmap cells wide; None without detections."""
    if len(found) == 0:
        return None
    A = cam.K @ np.linalg.inv(K_crop)
    uv = linked_cluster(found, CLUSTER_LINK * passes.image_size) @ A[:2, :2].T + A[:2, 2]
    centre, half = 0.5 * (uv.min(0) + uv.max(0)), 0.5 * (uv.max(0) - uv.min(0))
    half = np.maximum(half, MIN_BOX_CELLS * HEATMAP_STRIDE * A[0, 0] / 2)
    return _clip(np.stack([centre - half, centre + half]), cam)


def network_boxes(passes, image: np.ndarray, cam: Camera, tiles: bool = True, tile_side: float = TILE_SIDE,
                  whole_frame: bool = True, poses: list | None = None) -> list[tuple]:
    """Boxes (x, y, w, h) pixels where a keypoint network sees its object in the undistorted ``image``
    (camera ``cam``), the whole frame's first: the projected keypoints of each pass's PnP pose on the
    whole frame and (``tiles``) on :func:`tile_boxes`, one per place (``SAME_BOX_IOU``). Where the
    whole-frame pass of an unlabelled network gives no pose, the box of its linked detections takes its
    place. ``tile_side``: the tiles' share of the long side; ``whole_frame=False``: the tiles alone.
    ``passes``: the network's :class:`~.keypoint_passes.KeypointPasses`. [] where nothing is found.
    ``poses``: where given, each pass's own estimate is appended to it as (box, :class:`KeypointEstimate`)
    (within the depth gate)."""
    whole = ((cam.width - 1) / 2, (cam.height - 1) / 2, float(max(cam.width, cam.height)))
    views = [*([whole] if whole_frame else []), *(tile_boxes(cam.width, cam.height, tile_side) if tiles else [])]
    boxes = []
    for i, (res, found, K_crop, order, prob) in enumerate(passes.solve_boxes(image, cam.K, views)):
        if res is not None:
            box = _pose_box(passes, res.pose, cam)
            if (poses is not None and box is not None
                    and (passes.max_depth_m is None or res.pose.t[2] <= passes.max_depth_m)):
                poses.append((box, KeypointEstimate(res, order, prob, passes.image_size)))
        elif i == 0 and whole_frame and passes.unlabelled is not None:
            box = _cluster_box(passes, found, K_crop, cam)
        else:
            box = None
        if box is not None and all(box_iou(box, b) <= SAME_BOX_IOU for b in boxes):
            boxes.append(box)
    return boxes


def fine_boxes(passes, image: np.ndarray, cam: Camera, coarse: list[tuple]) -> list[tuple]:
    """Boxes (x, y, w, h) px the network finds in the ``FINE_TILE_SIDE`` tiles of ``image`` (camera
    ``cam``) that are not already among the ``coarse`` proposals (``SAME_BOX_IOU``)."""
    return [b for b in network_boxes(passes, image, cam, tile_side=FINE_TILE_SIDE, whole_frame=False)
            if all(box_iou(b, c) <= SAME_BOX_IOU for c in coarse)]


def find_object(passes, image: np.ndarray, cam: Camera, sun_turn: float, network: bool = True,
                fine_tiles: bool = True, others: list | None = None) -> tuple:
    """(box (x, y, w, h) px where the object is, its estimate or None) with no prior; (None, None)
    where nothing is found. With the network's proposals (``network``: :func:`network_boxes`) the
    estimate PnP fits best (``passes.estimate_in``), the first proposal's box where none gives an
    estimate; with ``fine_tiles``, where none reaches PnP quality ``FINE_BELOW``, finer tiles'
    proposals too (:func:`fine_boxes`), their estimates from ``FINE_ACCEPT``. Without proposals, the
    sunlit pixels (:func:`~.detection.detect_bright_object`). ``others``: where given, every other
    estimate found on the way — the other proposals', and each whole-frame and tile pass's own (a close
    crop of a printed part can take corners of its print for the part's where the coarser pass does
    not) — is appended to it, best PnP fit first."""
    passes_found = [] if others is not None else None
    proposals = network_boxes(passes, image, cam, poses=passes_found) if network else []
    if not proposals:
        seen = detect_bright_object(image)
        return seen, None if seen is None else passes.estimate_in(image, cam, seen, sun_turn)
    found = [(box, passes.estimate_in(image, cam, box, sun_turn)) for box in proposals]
    found = [(box, est) for box, est in found if est is not None]
    if fine_tiles and (not found or max(pnp_quality(est) for _, est in found) < FINE_BELOW):
        fine = [(box, passes.estimate_in(image, cam, box, sun_turn))
                for box in fine_boxes(passes, image, cam, proposals)]
        found += [(box, est) for box, est in fine if est is not None and pnp_quality(est) >= FINE_ACCEPT]
    if not found:
        best = (proposals[0], None)
    else:
        best = max(found, key=lambda box_est: pnp_quality(box_est[1]))  # the first of equals: the whole frame's
    if others is not None:
        rest = [be for be in found + passes_found if be is not best]
        others.extend(sorted(rest, key=lambda box_est: -pnp_quality(box_est[1])))
    return best


def distinct_estimates(estimates, first, keypoints_m: np.ndarray, cam: Camera, limit: int) -> list[KeypointEstimate]:
    """Up to ``limit`` of ``estimates`` ([(box, :class:`KeypointEstimate`)], in order) whose poses differ
    from the pose ``first`` (``T_cam_obj``; None: none) and from each other: their keypoints
    (``keypoints_m`` (N, 3) metres) projected by ``cam`` do not all lie within ``SAME_POSE_SHARE`` of their
    image extent of the other's."""
    kept = [cam.project(keypoints_m, first)] if first is not None and np.all((first @ keypoints_m)[:, 2] > 0) else []
    out = []
    for _, est in estimates:
        if len(out) >= limit:
            break
        if np.any((est.result.pose @ keypoints_m)[:, 2] <= 0):
            continue
        uv = cam.project(keypoints_m, est.result.pose)
        if not np.isfinite(uv).all() or any(_same_points(uv, k) for k in kept):
            continue
        kept.append(uv)
        out.append(est)
    return out


def _same_points(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the point sets ``a`` (N, 2) and ``b`` (N, 2) px each lie within ``SAME_POSE_SHARE`` of their
    extent of the other (nearest neighbours both ways)."""
    extent = max(float(np.ptp(a, 0).max()), float(np.ptp(b, 0).max()), 1.0)
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    return bool(max(d.min(1).max(), d.min(0).max()) <= SAME_POSE_SHARE * extent)
