"""Pose error metrics (BOP / SPEED conventions). Poses are ``T_cam_obj``; distances in metres."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .geometry import Pose
from .geometry.checks import as_points3d


def _R(x, name: str) -> np.ndarray:
    if isinstance(x, Pose):
        return x.R
    R = np.asarray(x, dtype=np.float64)
    if R.shape != (3, 3):
        raise ValueError(f"{name}: expected a Pose or a (3, 3) rotation, got shape {R.shape}")
    return R


def _t(x, name: str) -> np.ndarray:
    if isinstance(x, Pose):
        return x.t
    t = np.asarray(x, dtype=np.float64)
    if t.shape != (3,):
        raise ValueError(f"{name}: expected a Pose or a (3,) translation in metres, got shape {t.shape}")
    return t


def rotation_error_rad(est, gt) -> float:
    """Geodesic angle between two rotations (Poses or (3, 3)), radians in [0, π]."""
    dR = _R(est, "est").T @ _R(gt, "gt")
    c = np.clip((np.trace(dR) - 1.0) / 2.0, -1.0, 1.0)
    # arccos is ill-conditioned near 0; use atan2 of the skew part's norm against the trace part
    s = 0.5 * np.linalg.norm([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
    return float(np.arctan2(s, c))


def rotation_error_deg(est, gt) -> float:
    """Geodesic angle between two rotations, degrees (BOP's ``re``)."""
    return float(np.degrees(rotation_error_rad(est, gt)))


def nearest_equivalent(est: Pose, gt: Pose, symmetries=()) -> Pose:
    """Of ``gt`` and the poses ``gt @ S`` that look the same (``S`` in the object's ``symmetries``),
    the one nearest ``est`` in rotation: what an estimate of a symmetric object is scored against
    (BOP's errors over ``symmetries_discrete``). ``gt`` itself for an asymmetric object."""
    if not symmetries:
        return gt
    return min((gt, *(gt @ S for S in symmetries)), key=lambda g: rotation_error_rad(est, g))


def translation_error_m(est, gt) -> float:
    """‖t_est − t_gt‖ in metres (BOP's ``te``)."""
    return float(np.linalg.norm(_t(est, "est") - _t(gt, "gt")))


def speed_score(est: Pose, gt: Pose) -> float:
    """SPEED score of one pose: rotation error (rad) + ‖Δt‖ / ‖t_gt‖ (dimensionless)."""
    n = np.linalg.norm(_t(gt, "gt"))
    if n <= 0:
        raise ValueError("gt: translation must be non-zero for the SPEED score")
    return rotation_error_rad(est, gt) + translation_error_m(est, gt) / float(n)


def add(est: Pose, gt: Pose, points_obj) -> float:
    """ADD: mean distance (m) between model points under the two poses, point to same point."""
    p = as_points3d(points_obj, "points_obj")
    return float(np.linalg.norm((est @ p) - (gt @ p), axis=1).mean())


def adds(est: Pose, gt: Pose, points_obj) -> float:
    """ADD-S: mean distance (m) from each ground-truth point to the closest estimated point
    (for symmetric objects)."""
    p = as_points3d(points_obj, "points_obj")
    dist, _ = cKDTree(est @ p).query(gt @ p, k=1)
    return float(np.mean(dist))


def pose_errors(est: Pose, gt: Pose, symmetries=(), points_obj=None, symmetric: bool = False) -> dict:
    """One estimate's errors, each to the nearest of ``gt``'s equivalent poses under ``symmetries``
    (:func:`nearest_equivalent`): ``rot_deg`` (°), ``trans_m`` (m), ``speed`` (SPEED score) and, with
    ``points_obj`` (N, 3) object points in metres, ``add_m``: ADD, or ADD-S for a ``symmetric`` object
    (against ``gt`` itself: ADD-S needs no equivalent). ``nearest``: the equivalent pose scored against."""
    near = nearest_equivalent(est, gt, symmetries)
    out = {"rot_deg": rotation_error_deg(est, near), "trans_m": translation_error_m(est, near),
           "speed": speed_score(est, near), "nearest": near}
    if points_obj is not None:
        out["add_m"] = (adds if symmetric else add)(est, gt, points_obj)
    return out


def add_recall(errors_m, diameter_m: float, fraction: float = 0.1) -> float:
    """Share of ADD(-S) errors below ``fraction · diameter`` (ADD-0.1d recall), 0..1."""
    e = np.asarray(errors_m, dtype=np.float64)
    if e.size == 0:
        raise ValueError("errors_m: empty")
    return float(np.mean(e < fraction * diameter_m))


def auc(errors, max_threshold: float) -> float:
    """Area under the accuracy–threshold curve for thresholds in [0, max_threshold], normalised
    to 0..1 (the ADD(-S) AUC of PoseCNN/YCB-Video with ``max_threshold`` = 0.1 m).

    Computed in closed form: the curve is the empirical CDF of the errors, whose integral over
    [0, m] is ``mean(max(0, m − e)) / m``.
    """
    e = np.asarray(errors, dtype=np.float64)
    if e.size == 0:
        raise ValueError("errors: empty")
    if max_threshold <= 0:
        raise ValueError(f"max_threshold: expected > 0, got {max_threshold}")
    return float(np.mean(np.clip(max_threshold - e, 0.0, None)) / max_threshold)
