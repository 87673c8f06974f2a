"""SE(3) exponential and logarithm with tangent ``ξ = [ω (rad), v (m)]`` (gtsam order).

Matches ``gtsam.Pose3.Expmap``/``Logmap``: ``Exp(ξ) = (exp(ω), V(ω)·v)``.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from .rotations import matrix_to_rotvec, rodrigues_coeffs, rotvec_to_matrix, skew


def _left_jacobian_coeffs(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    t2 = theta * theta
    b = np.where(small, 0.5 - t2 / 24, (1 - np.cos(safe)) / (safe * safe))
    c = np.where(small, 1.0 / 6 - t2 / 120, (safe - np.sin(safe)) / (safe**3))
    return b, c


def so3_left_jacobian(omega: np.ndarray) -> np.ndarray:
    """``V(ω) = I + b·[ω]× + c·[ω]×²`` for (..., 3) ω; maps v to the translation of ``Exp``."""
    omega = np.asarray(omega, dtype=np.float64)
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    b, c = _left_jacobian_coeffs(theta)
    W = skew(omega)
    return np.eye(3) + b * W + c * (W @ W)


def se3_exp(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., 6) tangent ``[ω, v]`` → rotation (..., 3, 3) and translation (..., 3) in metres."""
    xi = np.asarray(xi, dtype=np.float64)
    omega, v = xi[..., :3], xi[..., 3:]
    if xi.shape == (6,):
        return se3_exp_one(np.ascontiguousarray(xi))
    R = rotvec_to_matrix(omega)
    t = np.einsum("...ij,...j->...i", so3_left_jacobian(omega), v)
    return R, t


@numba.njit(cache=True, nogil=True)
def se3_exp_one(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`se3_exp` of one tangent vector ``xi`` (6,) float64 with scalar coefficients, compiled: the
    same series and closed forms as the batched path, at a fraction of its cost (it is every
    Gauss–Newton step of the trackers, and their compiled kernels call it)."""
    w0, w1, w2 = xi[0], xi[1], xi[2]
    t2 = w0 * w0 + w1 * w1 + w2 * w2
    a, b_rot = rodrigues_coeffs(t2)
    if t2 < 1e-8:
        b_left, c = 0.5 - t2 / 24, 1.0 / 6 - t2 / 120
    else:
        theta = math.sqrt(t2)
        b_left, c = b_rot, (theta - math.sin(theta)) / (t2 * theta)
    W = np.array([[0.0, -w2, w1], [w2, 0.0, -w0], [-w1, w0, 0.0]])
    W2 = W @ W
    return np.eye(3) + a * W + b_rot * W2, (np.eye(3) + b_left * W + c * W2) @ xi[3:]


def se3_log(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Inverse of :func:`se3_exp`: (..., 3, 3), (..., 3) → (..., 6) ``[ω, v]``."""
    omega = matrix_to_rotvec(R)
    V = so3_left_jacobian(omega)
    v = np.linalg.solve(V, np.asarray(t, dtype=np.float64)[..., None])[..., 0]
    return np.concatenate([omega, v], -1)


@numba.njit(cache=True, nogil=True)
def so3_log_one(R: np.ndarray) -> np.ndarray:
    """:func:`~hybridpose.geometry.matrix_to_rotvec` of one (3, 3) rotation, compiled (the filters take
    hundreds of logarithms per frame). Through the quaternion (Shepperd's branch choice), so it is
    well conditioned near π as well as near 0; angle in [0, π]."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > max(R[0, 0], R[1, 1], R[2, 2]):
        s = 2.0 * math.sqrt(1.0 + tr)
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] >= R[1, 1] and R[0, 0] >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-12:
        k = 2.0 / max(w, 1e-12)
    else:
        k = 2.0 * math.atan2(n, w) / n
    return np.array([x * k, y * k, z * k])


@numba.njit(cache=True, nogil=True)
def se3_log_one(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """:func:`se3_log` of one pose (R (3, 3), t (3,)), compiled: ``[ω, V(ω)⁻¹ t]``."""
    w = so3_log_one(R)
    t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    # V⁻¹ = I − ½[ω]× + c·[ω]×², c = (1 − θ sinθ / (2 (1 − cosθ))) / θ²
    if t2 < 1e-8:
        c = 1.0 / 12.0 + t2 / 720.0
    else:
        theta = math.sqrt(t2)
        c = (1.0 - theta * math.sin(theta) / (2.0 * (1.0 - math.cos(theta)))) / t2
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    v = (np.eye(3) - 0.5 * W + c * (W @ W)) @ t
    out = np.empty(6)
    out[:3] = w
    out[3:] = v
    return out
