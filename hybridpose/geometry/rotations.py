"""Quaternions and SO(3): pure functions, Hamilton convention, scalar first ``(w, x, y, z)``.

Written in NumPy rather than wrapping ``scipy.spatial.transform.Rotation`` because our order is
(w, x, y, z) everywhere and we need batched exp/log with well-behaved small-angle and near-π
branches; scipy is the independent oracle in the tests.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from .checks import as_unit_quat

_SMALL = 1e-8  # below this angle (rad) the series expansions replace sin θ / θ


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) → (..., 3, 3) cross-product matrix, ``skew(a) @ b == cross(a, b)``."""
    v = np.asarray(v, dtype=np.float64)
    # filled in place: three np.stack calls cost more than the math on the small arrays of the
    # trackers' inner loops
    W = np.zeros(v.shape + (3,))
    W[..., 0, 1], W[..., 0, 2] = -v[..., 2], v[..., 1]
    W[..., 1, 0], W[..., 1, 2] = v[..., 2], -v[..., 0]
    W[..., 2, 0], W[..., 2, 1] = -v[..., 1], v[..., 0]
    return W


def quat_canonical(q: np.ndarray) -> np.ndarray:
    """(..., 4) → same rotation with ``w ≥ 0`` (q and −q are the same rotation)."""
    q = np.asarray(q, dtype=np.float64)
    return np.where(q[..., :1] < 0, -q, q)


def quat_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternion (w, x, y, z) → (..., 3, 3) rotation matrix."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrix → (..., 4) canonical unit quaternion (w ≥ 0).

    Shepperd's method: picks the largest of w², x², y², z² as pivot, so it stays accurate near π.
    """
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    trace = m00 + m11 + m22
    cand = np.stack(
        [
            np.stack([1 + trace, R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1),
            np.stack([R[..., 2, 1] - R[..., 1, 2], 1 + m00 - m11 - m22, R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0]], -1),
            np.stack([R[..., 0, 2] - R[..., 2, 0], R[..., 0, 1] + R[..., 1, 0], 1 - m00 + m11 - m22, R[..., 1, 2] + R[..., 2, 1]], -1),
            np.stack([R[..., 1, 0] - R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1], 1 - m00 - m11 + m22], -1),
        ],
        -2,
    )  # (..., 4 pivots, 4 components); row k is 4·q_k·q
    pivot = np.argmax(np.stack([trace, m00, m11, m22], -1), axis=-1)
    q = np.take_along_axis(cand, pivot[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return quat_canonical(q)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of (..., 4) quaternions; the rotation of ``a`` after ``b``."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """(..., 4) → inverse rotation of a unit quaternion."""
    q = np.asarray(q, dtype=np.float64)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_angle_between(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Geodesic angle (rad, in [0, π]) between unit quaternions, the shorter way round.

    Uses ``2·atan2(‖vec(q1*⊗q2)‖, |w|)`` rather than ``2·acos(|⟨q1, q2⟩|)``: acos loses precision
    for small angles.
    """
    d = quat_multiply(quat_conjugate(q1), q2)
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))


def rotvec_to_matrix(omega: np.ndarray) -> np.ndarray:
    """SO(3) exponential: (..., 3) rotation vector (rad) → (..., 3, 3) (Rodrigues)."""
    omega = np.asarray(omega, dtype=np.float64)
    if omega.shape == (3,):
        return rotvec_to_matrix_one(np.ascontiguousarray(omega))
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    W = skew(omega)
    small = theta < 1e-4
    t2 = theta * theta
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(safe) / safe)
    b = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - np.cos(safe)) / (safe * safe))
    return np.eye(3) + a * W + b * (W @ W)


@numba.njit(cache=True, nogil=True)
def rodrigues_coeffs(t2: float) -> tuple[float, float]:
    """``(sin θ / θ, (1 − cos θ) / θ²)`` of the SO(3) exponential for ``t2 = θ²``, by their series
    below θ = 1e-4 (the batched :func:`rotvec_to_matrix`'s branches, compiled for the scalar paths)."""
    if t2 < 1e-8:
        return 1 - t2 / 6 + t2 * t2 / 120, 0.5 - t2 / 24 + t2 * t2 / 720
    theta = math.sqrt(t2)
    return math.sin(theta) / theta, (1 - math.cos(theta)) / t2


@numba.njit(cache=True, nogil=True)
def rotvec_to_matrix_one(omega: np.ndarray) -> np.ndarray:
    """:func:`rotvec_to_matrix` of one (3,) float64 rotation vector, compiled: the batched NumPy path
    costs ≈ 60 µs on one vector (a dozen array operations), and PnP makes a pose from one per call."""
    w0, w1, w2 = omega[0], omega[1], omega[2]
    a, b = rodrigues_coeffs(w0 * w0 + w1 * w1 + w2 * w2)
    W = np.array([[0.0, -w2, w1], [w2, 0.0, -w0], [-w1, w0, 0.0]])
    return np.eye(3) + a * W + b * (W @ W)


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """SO(3) logarithm: (..., 3, 3) → (..., 3) rotation vector with angle in [0, π].

    Goes through the quaternion, which is well conditioned everywhere including near π.
    """
    return quat_to_rotvec(matrix_to_quat_wxyz(R))


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternion → (..., 3) rotation vector (rad), angle in [0, π]."""
    q = quat_canonical(q)
    vec = q[..., 1:]
    s = np.linalg.norm(vec, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    small = s < _SMALL
    # angle / s → 2 / w for small s (w ≈ 1 there because w ≥ 0 after canonicalisation)
    scale = np.where(small, 2.0 / np.maximum(q[..., :1], _SMALL), angle / np.where(small, 1.0, s))
    return vec * scale


def rotvec_to_quat(omega: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vector (rad) → (..., 4) unit quaternion (w, x, y, z), not canonicalised."""
    omega = np.asarray(omega, dtype=np.float64)
    theta = np.linalg.norm(omega, axis=-1, keepdims=True)
    half = 0.5 * theta
    small = theta < 1e-4
    k = np.where(small, 0.5 - theta * theta / 48, np.sin(half) / np.where(small, 1.0, theta))
    return np.concatenate([np.cos(half), omega * k], -1)


def quat_slerp(q0: np.ndarray, q1: np.ndarray, alpha: float | np.ndarray) -> np.ndarray:
    """Spherical linear interpolation between unit quaternions along the shorter arc.

    Args:
        q0, q1: (..., 4) unit quaternions (w, x, y, z).
        alpha: 0 → q0, 1 → q1.
    """
    q0 = as_unit_quat(q0, "q0")
    q1 = as_unit_quat(q1, "q1")
    q1 = np.where(np.sum(q0 * q1, -1, keepdims=True) < 0, -q1, q1)
    delta = quat_to_rotvec(quat_multiply(quat_conjugate(q0), q1))
    alpha = np.asarray(alpha, dtype=np.float64)[..., None]
    return quat_multiply(q0, rotvec_to_quat(alpha * delta))


def random_quat(n: int | None = None, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """Uniformly distributed unit quaternions (normalised 4-D Gaussian), canonical (w ≥ 0).

    Returns (4,) when ``n`` is None, else (n, 4).
    """
    rng = np.random.default_rng(rng)
    q = rng.normal(size=(1 if n is None else n, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q = quat_canonical(q)
    return q[0] if n is None else q
