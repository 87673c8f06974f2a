"""Keypoints without identity, for objects with symmetries: one heatmap of all keypoints, the pose by
trying which keypoint each detection is.

A box looks the same after its half-turns, so no image says which corner is "corner 3": a network
asked for one heatmap per corner can only average the corners it cannot tell apart, and a 40-minute
CPU fit of a box left its keypoints piled on the visible corners (66° mean). Where a corner is
is a local question (two or three edges meet) that a small network learns in minutes; which
corner it is, is left to geometry: P3P on three detections for every labelling of them (the first
one only to a corner of each orbit of the symmetry group — the others are the same poses turned
by a symmetry), each pose scored by how well the object's corners visible from it land on the
detections. No library solves PnP without correspondences for a handful of points (OpenCV's
solvers all take matched pairs); this is that search, vectorised where numpy allows.

Visibility comes from the convex hull of the keypoints: a keypoint is seen where one of the hull's
faces around it faces the camera (exact for a box or any convex part; for a non-convex part the
hull's view of it).
"""
from __future__ import annotations

import itertools

import cv2
import numpy as np
import torch
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation

from ..geometry import Pose, projection_jacobian
from .keypoint_pnp import PnPResult

# a heatmap peak reaching this probability is a keypoint detection. Chosen on six tuning sequences of
# the box over two photos of circuit boards (not the benchmark's photo): 0.05 / 0.1 / 0.2 / 0.4 →
# CNN-only within a tracker's basin on 37 / 37 / 38 / 19 % of the frames (the network is less sure of
# corners on a real photo than on the procedural backgrounds it trained on, where 0.4 did best)
DETECTION_THRESHOLD = 0.2
TARGET_SIGMA_CELLS = 1.0   # the training target's Gaussian, heatmap cells
# P3P triples of detections tried, from the most confident ones (tuning sequences over photos: 1 / 2 / 4
# triples → CNN-only within a tracker's basin on 37 / 40 / 38 % of the frames at 31 / 37 / 57 ms a frame)
TRIPLES = 2
EARLY_STOP_RESIDUAL = 0.25  # mean residual (of the threshold) below which a pose ends the search
EARLY_STOP_DETECTIONS = 7  # …and at least this many detections agree with it
MAX_PLANES = 12            # hull faces kept per keypoint (a vertex of a fine hull touches more)


def hull_planes(keypoints_m: np.ndarray, max_planes: int = MAX_PLANES) -> np.ndarray:
    """(N, F, 4) float32 planes ``(n, d)`` (outward unit normal, offset: ``n·x = d`` on the face) of the
    convex-hull faces that touch each keypoint; unused rows are ``(0, 0, 0, 1)`` (never facing the
    camera), and a keypoint the hull cannot judge (coplanar keypoints) gets ``(0, 0, 0, −1)`` (always
    facing: it counts as visible).

    Args:
        keypoints_m: (N, 3) keypoints, metres, object frame.
    """
    pts = np.asarray(keypoints_m, dtype=np.float64)
    out = np.zeros((len(pts), max_planes, 4), np.float32)
    out[:, :, 3] = 1.0
    try:
        hull = ConvexHull(pts)
    except QhullError:  # flat or degenerate keypoints: no faces to hide anything behind
        out[:, 0, 3] = -1.0
        return out
    scale = float(np.ptp(pts, axis=0).max())
    count = np.zeros(len(pts), int)
    for eq in hull.equations:  # rows (n, −d), n outward, unit
        n, d = eq[:3], -eq[3]
        on = np.abs(pts @ n - d) < 1e-6 * scale
        for i in np.flatnonzero(on):
            # coplanar facets (the two triangles of a box face) give the same plane: keep one
            if count[i] < max_planes and not any(np.allclose(out[i, k, :3], n, atol=1e-6) for k in range(count[i])):
                out[i, count[i]] = (*n, d)
                count[i] += 1
    out[count == 0, 0, 3] = -1.0
    return out


def visible_keypoints(planes: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Which keypoints the camera sees: (..., N) bool for poses ``R`` (..., 3, 3), ``t`` (..., 3) (T_cam_obj)
    and the :func:`hull_planes` ``planes`` (N, F, 4)."""
    centre = -np.einsum("...ji,...j->...i", R, t)  # the camera centre in the object frame
    side = np.einsum("nfk,...k->...nf", planes[..., :3], centre) - planes[..., 3]
    return (side > 0).any(-1)


def heatmap_targets(kp_px: torch.Tensor, visible: torch.Tensor, size: int, stride: int,
                    sigma_cells: float = TARGET_SIGMA_CELLS) -> torch.Tensor:
    """The training target of one heatmap of all keypoints: (B, 1, size/stride, size/stride) in [0, 1],
    the maximum of a Gaussian at each visible keypoint (1 at the cell nearest to it).

    Args:
        kp_px: (B, N, 2) keypoints in input pixels (OpenCV: integer = pixel centre).
        visible: (B, N) bool. size: input side, pixels. stride: input pixels per heatmap cell.
    """
    h = size // stride
    cells = (kp_px - (stride - 1) / 2) / stride                      # cell-centre coordinates
    grid = torch.arange(h, dtype=kp_px.dtype, device=kp_px.device)
    gx = torch.exp(-(grid[None, None, :] - cells[..., 0:1]) ** 2 / (2 * sigma_cells ** 2))   # (B, N, w)
    gy = torch.exp(-(grid[None, None, :] - cells[..., 1:2]) ** 2 / (2 * sigma_cells ** 2))   # (B, N, h)
    g = gy[..., :, None] * gx[..., None, :] * visible[..., None, None].to(kp_px.dtype)      # (B, N, h, w)
    # the cell nearest each keypoint is the positive of the focal loss: make it exactly 1
    target = g.amax(1, keepdim=True)
    ix, iy = cells[..., 0].round().long(), cells[..., 1].round().long()
    inside = visible & (ix >= 0) & (ix < h) & (iy >= 0) & (iy < h)
    b, n = torch.nonzero(inside, as_tuple=True)
    target[b, 0, iy[b, n], ix[b, n]] = 1.0
    return target


def focal_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss (Zhou et al. 2019) per positive: ``logits`` and ``target``
    (B, 1, h, w); positives are the cells where ``target`` is 1."""
    p = torch.sigmoid(logits.float()).clamp(1e-4, 1 - 1e-4)
    pos = target.ge(1.0).float()
    pos_loss = -torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = -torch.log(1 - p) * p ** 2 * (1 - target) ** 4 * (1 - pos)
    return (pos_loss.sum() + neg_loss.sum()) / pos.sum().clamp_min(1.0)


def symmetry_gauge(keypoints_m: np.ndarray, symmetries, tolerance: float = 1e-3) -> list[int]:
    """One keypoint of each orbit of the symmetry group (first indices): the keypoints the first
    detection may be. Every other labelling is a symmetric copy of one of these.

    Args:
        keypoints_m: (N, 3) metres. symmetries: the object's symmetries (poses ``S``, object frame).
        tolerance: of the keypoints' extent: how close ``S·k`` must come to a keypoint to be it.
    """
    pts = np.asarray(keypoints_m, dtype=np.float64)
    tol = tolerance * float(np.ptp(pts, axis=0).max())
    orbit = np.arange(len(pts))
    for S in symmetries:
        moved = S @ pts
        d = np.linalg.norm(moved[:, None] - pts[None], axis=2)
        for i, j in enumerate(d.argmin(1)):
            if d[i, j] <= tol:  # i and j share an orbit: label both with the smaller label
                a, b = sorted((orbit[i], orbit[j]))
                orbit[orbit == b] = a
    return sorted(set(int(o) for o in orbit))


def detections(uv: np.ndarray, score: np.ndarray, threshold: float = DETECTION_THRESHOLD) -> np.ndarray:
    """(M, 2) the peaks of an :class:`~.keypoint_net.UnlabelledKeypointNet` (``uv`` (N, 2), ``score`` (N,),
    strongest first) whose probability reaches ``threshold``."""
    return np.asarray(uv, dtype=np.float64)[np.asarray(score) >= threshold]


def _pixels(cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(..., 2) pixels of camera-frame points (..., 3) in front of the camera (pinhole ``K``, no skew)."""
    return cam[..., :2] / cam[..., 2:] * K[[0, 1], [0, 1]] + K[:2, 2]


def _assignments(n_keypoints: int, gauge) -> np.ndarray:
    """(A, 3) ordered keypoint triples whose first entry is in ``gauge``."""
    return np.array([(a, b, c) for a in gauge for b in range(n_keypoints) for c in range(n_keypoints)
                     if len({a, b, c}) == 3], dtype=np.int64)


def solve_pnp_unlabelled(points_2d: np.ndarray, points_m: np.ndarray, planes: np.ndarray, gauge, K: np.ndarray,
                         threshold_px: float, min_inliers: int = 4, triples: int = TRIPLES) -> PnPResult | None:
    """The pose from unlabelled keypoint detections: None where no pose explains ``min_inliers`` of them.

    Args:
        points_2d: (M, 2) detections, pixels of the image of ``K``, most confident first.
        points_m: (N, 3) the object's keypoints, metres. planes: their :func:`hull_planes`.
        gauge: :func:`symmetry_gauge` of the keypoints (``range(N)`` for an asymmetric object).
        K: (3, 3) intrinsics. threshold_px: how near a visible keypoint's projection must come to a
            detection to explain it, pixels.
        min_inliers: fewer detections explained → None.
        triples: P3P triples of detections tried (from the most confident ones).
    Returns:
        a :class:`PnPResult` whose ``inliers`` mark the keypoints matched to a detection and whose
        ``visible`` marks those the hull shows at the pose (``inlier_ratio`` = matched / visible).
    """
    det = np.ascontiguousarray(points_2d, dtype=np.float64).reshape(-1, 2)
    pts = np.ascontiguousarray(points_m, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    if len(det) < max(4, min_inliers) or not np.all(np.isfinite(det)):
        return None
    labels = _assignments(len(pts), gauge)
    best = None
    for tri in list(itertools.combinations(range(min(len(det), triples + 2)), 3))[:triples]:
        found = _best_of_triple(det, tri, pts, planes, labels, K, threshold_px)
        if found is not None and (best is None or found[0] > best[0]):
            best = found
        # seven or more detections all explained closely, no visible keypoint left without one:
        # further triples only cost time. Fewer can fit a wrong labelling within a pixel or two: a
        # box's two faces seen under weak perspective fit their depth-reversed (Necker) pose too,
        # and only the residuals of every triple tell them apart.
        if (best is not None and best[0][0] == len(det) >= EARLY_STOP_DETECTIONS
                and -best[0][1] <= EARLY_STOP_RESIDUAL * threshold_px * best[0][0]):
            break
    if best is None or best[0][0] < min_inliers:
        return None
    return _refined(det, pts, planes, K, best[1], best[2], threshold_px, min_inliers)


def _best_of_triple(det, tri, pts, planes, labels, K, threshold_px):
    """The best pose of P3P on detections ``tri`` under every labelling in ``labels``: ((detections
    explained, −cost), R, t), or None where P3P has no pose in front of the camera."""
    image = det[list(tri)]
    rs, ts = [], []
    for abc in labels:
        try:
            _, rvecs, tvecs = cv2.solveP3P(pts[abc], image, K, None, flags=cv2.SOLVEPNP_P3P)
        except cv2.error:  # collinear detections
            return None
        rs += rvecs
        ts += tvecs
    if not rs:
        return None
    R = Rotation.from_rotvec(np.array(rs).reshape(-1, 3)).as_matrix()  # one call for all (cv2.Rodrigues: one each)
    t = np.array(ts).reshape(-1, 3)
    cam = pts @ R.transpose(0, 2, 1) + t[:, None]                               # (P, N, 3)
    ahead = (cam[..., 2] > 1e-6).all(1)
    if not ahead.any():
        return None
    R, t, cam = R[ahead], t[ahead], cam[ahead]
    uv = _pixels(cam, K)
    vis = visible_keypoints(planes, R, t)                                        # (P, N)
    dist = np.linalg.norm(det[None, :, None] - uv[:, None], axis=3)              # (P, M, N)
    dist[~np.broadcast_to(vis[:, None], dist.shape)] = np.inf
    near = dist.min(2)
    explained = (near < threshold_px).sum(1)
    # the most detections explained, then the least residual plus a threshold per visible keypoint
    # that no detection explains (a pose that shows corners the network did not see is less likely)
    cost = np.minimum(near, threshold_px).sum(1) + threshold_px * np.maximum(vis.sum(1) - explained, 0)
    i = np.lexsort((cost, -explained))[0]
    return (int(explained[i]), -float(cost[i])), R[i], t[i]


def _refined(det, pts, planes, K, R, t, threshold_px, min_inliers) -> PnPResult | None:
    """Match each detection to its nearest visible keypoint (one detection per keypoint), refine on
    the matches (Levenberg–Marquardt), match again at the refined pose."""
    rvec, tvec = cv2.Rodrigues(R)[0], t.reshape(3, 1).copy()
    pose = Pose(R, t)
    for _ in range(2):
        pairs, _ = _matches(det, pts, planes, K, pose, threshold_px)
        if len(pairs) < min_inliers:
            return None
        d, k = det[pairs[:, 0]], pts[pairs[:, 1]]
        rvec, tvec = cv2.solvePnPRefineLM(k, d, K, None, rvec, tvec)
        pose = Pose.from_rotvec_t(rvec.ravel(), tvec.ravel())
        if pose.t[2] <= 0:
            return None
    pairs, vis = _matches(det, pts, planes, K, pose, threshold_px)
    if len(pairs) < min_inliers:
        return None
    inliers = np.zeros(len(pts), bool)
    inliers[pairs[:, 1]] = True
    uv, J = projection_jacobian(pose, pts[pairs[:, 1]], K)
    rms = float(np.sqrt(np.mean(np.sum((uv - det[pairs[:, 0]]) ** 2, 1))))
    J = J.reshape(-1, 6)
    return PnPResult(pose=pose, inliers=inliers, rms_px=rms, information=J.T @ J, visible=vis | inliers)


def _matches(det, pts, planes, K, pose: Pose, threshold_px) -> tuple[np.ndarray, np.ndarray]:
    """((L, 2) int pairs (detection, keypoint), (N,) keypoints visible at ``pose``): each visible
    keypoint to its nearest detection within ``threshold_px``, nearest pairs first, each detection
    and keypoint used once."""
    cam = pts @ pose.R.T + pose.t
    vis = visible_keypoints(planes, pose.R, pose.t)
    if np.any(cam[:, 2] <= 1e-6):
        return np.zeros((0, 2), np.int64), vis
    uv = _pixels(cam, K)
    d = np.linalg.norm(det[:, None] - uv[None], axis=2)
    d[:, ~vis] = np.inf
    pairs, used_d, used_k = [], set(), set()
    for flat in np.argsort(d, axis=None):
        i, j = np.unravel_index(flat, d.shape)
        if d[i, j] >= threshold_px:
            break
        if i in used_d or j in used_k:
            continue
        pairs.append((i, j))
        used_d.add(i)
        used_k.add(j)
    return np.array(pairs, dtype=np.int64).reshape(-1, 2), vis
