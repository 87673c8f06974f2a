"""The combined tracker's Gauss–Newton over the rows of every cue, compiled.

Every cue states its residuals as point-to-line rows — a model point whose projection should lie on
the line through a target pixel perpendicular to an image normal (an edge or a silhouette: one row;
a texture point: two rows, normals x and y) — so one kernel sums them all. Why our own kernel: a frame
runs some fifteen steps over about a thousand rows, where NumPy spent more time dispatching its small
array operations than computing (9–12 ms a frame in NumPy, most of it in the steps).

Conventions as in :mod:`hybridpose.geometry`: ``(R (3, 3), t (3,) metres)`` of ``T_cam_obj``,
right perturbation ``ξ = [ω, v]``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from ...geometry.camera import line_rows
from ...geometry.se3 import se3_exp_one

TUKEY_C = 4.685  # Tukey's biweight constant: 95 % efficiency under Gaussian noise
MAD_TO_SIGMA = 1.4826  # median absolute deviation → standard deviation of a Gaussian


@dataclass(frozen=True)
class LineRows:
    """One cue's residual rows.

    Attributes:
        points_m: (S, 3) model points, metres. normals: (S, 2) unit image normals. targets: (S, 2) px.
        sigma_px: one row's standard deviation. floor_px, cap_px: the bounds of the robust scale (MAD).
    """

    points_m: np.ndarray
    normals: np.ndarray
    targets: np.ndarray
    sigma_px: float
    floor_px: float
    cap_px: float


def solve(R: np.ndarray, t: np.ndarray, K: np.ndarray, rows: list[LineRows], steps: int, max_rot_rad: float,
          max_trans_m: float):
    """Up to ``steps`` robust Gauss–Newton steps over all ``rows`` from ``(R, t)``; Tukey weights at each
    cue's own scale, each cue's rows divided by its σ². Returns ``(R, t, H (6, 6) at the last step, rows
    with weight, ok)``; ``ok`` False where a step was not finite or beyond ``max_rot_rad`` / ``max_trans_m``."""
    rows = [r for r in rows if len(r.points_m)]
    if not rows:
        return R, t, np.zeros((6, 6)), 0, True
    X = np.ascontiguousarray(np.concatenate([r.points_m for r in rows]), np.float64)
    n = np.ascontiguousarray(np.concatenate([r.normals for r in rows]), np.float64)
    m = np.ascontiguousarray(np.concatenate([r.targets for r in rows]), np.float64)
    group = np.concatenate([np.full(len(r.points_m), k, np.int64) for k, r in enumerate(rows)])
    params = np.array([[r.sigma_px, r.floor_px, min(r.cap_px, 1e9)] for r in rows], np.float64)
    return _steps(np.ascontiguousarray(R, np.float64), np.ascontiguousarray(t, np.float64), X, n, m,
                  np.ascontiguousarray(K, np.float64), group, params, int(steps), float(max_rot_rad), float(max_trans_m))


@numba.njit(cache=True, nogil=True)
def _steps(R, t, X, n, m, K, group, params, steps, max_rot, max_trans):
    S, G = X.shape[0], params.shape[0]
    uv = np.empty((S, 2))
    J = np.empty((S, 6))
    r = np.empty(S)
    H = np.zeros((6, 6))
    used = 0
    for _ in range(steps):
        line_rows(R, t, X, K, n, uv, J)
        for s in range(S):
            r[s] = n[s, 0] * (uv[s, 0] - m[s, 0]) + n[s, 1] * (uv[s, 1] - m[s, 1])
        scale = np.empty(G)
        for k in range(G):
            a = np.abs(r[group == k])
            med = np.median(a) if a.size else 0.0
            scale[k] = min(max(MAD_TO_SIGMA * med, params[k, 1]), params[k, 2])
        H = np.zeros((6, 6))
        g = np.zeros(6)
        used = 0
        for s in range(S):
            k = group[s]
            u_t = r[s] / (TUKEY_C * scale[k])
            if abs(u_t) >= 1.0:
                continue
            w = (1.0 - u_t * u_t) ** 2 / (params[k, 0] * params[k, 0])
            used += 1
            for i in range(6):
                wj = w * J[s, i]
                g[i] += wj * r[s]
                for j in range(i + 1):
                    H[i, j] += wj * J[s, j]
        for i in range(6):
            for j in range(i):
                H[j, i] = H[i, j]
        if used < 6:
            return R, t, H, used, used > 0
        trace = 0.0
        for i in range(6):
            trace += H[i, i]
        A = H + (1e-6 * trace / 6 + 1e-12) * np.eye(6)
        delta = -np.linalg.solve(A, g)
        rot = np.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2)
        trans = np.sqrt(delta[3] ** 2 + delta[4] ** 2 + delta[5] ** 2)
        if not (np.isfinite(rot) and np.isfinite(trans)) or rot > max_rot or trans > max_trans:
            return R, t, H, used, False
        dR, dt = se3_exp_one(delta)
        t = R @ dt + t
        R = R @ dR
        if np.abs(delta).max() < 1e-5:  # 0.0006°, 10 µm
            break
    return R, t, H, used, True
