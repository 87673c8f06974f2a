"""``ukf``: filterpy's Unscented Kalman filter on the pose manifold.

State ``x`` (12,) = ``[φ (3, rotation vector of R), t (3, m), ω (3, rad/s), v (3, m/s)]`` of
``T_cam_obj = (exp(φ), t)`` and its body twist; covariance ``P`` (12, 12) over the right
perturbation ``[δω, δv]`` of the pose and the twist's additive error. The rotation never leaves
SO(3): filterpy's hooks do every step on the manifold —

- sigma points: ``points.subtract(x, -u) = x ⊞ u`` with ``x ⊞ u = (T·Exp(u[:6]), ξ̇ + u[6:])``;
- ``state_add`` (the update step) is the same ``⊞``; ``residual_x(a, b) = (Log(T_b⁻¹ T_a), ξ̇_a − ξ̇_b)``;
- ``x_mean_fn`` / ``z_mean_fn``: the weighted Karcher mean on SE(3) (a few Gauss–Newton steps);
- ``fx``: ``T·Exp(ξ̇·dt)``, twist unchanged (constant velocity); ``hx``: the pose ``[φ, t]``;
- ``residual_z(a, b) = Log(T_b⁻¹ T_a)``, so the measurement covariance is the measurement's own
  right-perturbation covariance.

filterpy loops over the sigma points in Python, one SE(3) log or exp per call (≈ 12 ms a frame);
:class:`_ManifoldUKF` batches those loops through compiled ``⊞``/``⊟`` (same maths) and leaves the
weights, the gain and the update to filterpy.
"""
from __future__ import annotations

import numba
import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from ..geometry import Pose, matrix_to_rotvec, rotvec_to_matrix
from ..geometry.rotations import rotvec_to_matrix_one
from ..geometry.se3 import se3_exp_one, se3_log_one, so3_log_one
from ..registry import register
from .base import Fusion, process_noise, symmetrised

# the centre sigma point's negative covariance weight (alpha < 1) can leave P a hair indefinite after
# an unscented transform: eigenvalues are floored here (rad², m², (rad/s)², (m/s)²)
PSD_FLOOR = 1e-14
MEAN_ITERATIONS = 4  # Karcher mean Gauss–Newton steps (the sigma points sit within a few σ of each other)


@numba.njit(cache=True, nogil=True)
def _boxplus_rows(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        R = rotvec_to_matrix_one(np.ascontiguousarray(x[i, :3]))
        dR, dt = se3_exp_one(np.ascontiguousarray(u[i, :6]))
        out[i, :3] = so3_log_one(R @ dR)
        out[i, 3:6] = R @ dt + x[i, 3:6]
        out[i, 6:] = x[i, 6:] + u[i, 6:]
    return out


@numba.njit(cache=True, nogil=True)
def _boxminus_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty_like(a)
    for i in range(a.shape[0]):
        Ra = rotvec_to_matrix_one(np.ascontiguousarray(a[i, :3]))
        RbT = rotvec_to_matrix_one(np.ascontiguousarray(b[i, :3])).T
        out[i, :6] = se3_log_one(RbT @ Ra, RbT @ (a[i, 3:6] - b[i, 3:6]))
        out[i, 6:] = a[i, 6:] - b[i, 6:]
    return out


def _rowwise(kernel, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``kernel`` over rows of (D,) or (N, D) arrays, a single row broadcast against N; (D,) in, (D,) out."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    n = max(a.shape[0] if a.ndim == 2 else 1, b.shape[0] if b.ndim == 2 else 1)
    rows = [np.ascontiguousarray(np.broadcast_to(x, (n, x.shape[-1])) if x.ndim == 1 else x) for x in (a, b)]
    out = kernel(*rows)
    return out[0] if a.ndim == 1 and b.ndim == 1 else out


def boxplus(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """State ⊞ tangent, ``(T·Exp(u[:6]), ξ̇ + u[6:])``, for (D,) or (N, D) arrays, D = 12 (state) or
    6 (pose only); a single row broadcasts against N."""
    return _rowwise(_boxplus_rows, x, u)


def boxminus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ⊟ b with ``b ⊞ (a ⊟ b) = a``: pose part ``Log(T_b⁻¹ T_a)``, the rest subtracted; shapes as
    :func:`boxplus`."""
    return _rowwise(_boxminus_rows, a, b)


def _pose_vector(pose: Pose) -> np.ndarray:
    """(6,) ``[φ, t]``: the pose part of the state and the measurement vector."""
    return np.r_[matrix_to_rotvec(pose.R), pose.t]


def manifold_mean(sigmas: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted Karcher mean of (N, 6 or 12) states/measurements: pose part on SE(3) (from the first
    sigma point, up to ``MEAN_ITERATIONS`` steps of ``mean ⊞ Σ w_i (σ_i ⊟ mean)``), the rest linear."""
    sigmas = np.ascontiguousarray(sigmas, dtype=np.float64)
    return _karcher_mean(sigmas, np.ascontiguousarray(weights, dtype=np.float64), MEAN_ITERATIONS)


@numba.njit(cache=True, nogil=True)
def _karcher_mean(sigmas: np.ndarray, weights: np.ndarray, iterations: int) -> np.ndarray:
    # compiled whole, on the same ⊞/⊟ kernels: the UKF takes two means a frame, and the Python loop
    # around the batched calls (a dozen of them) cost more than the maths
    n, d = sigmas.shape
    mean = sigmas[0].copy()
    around = np.empty_like(sigmas)
    for _ in range(iterations):
        for i in range(n):
            around[i] = mean
        diffs = _boxminus_rows(sigmas, around)
        step = np.zeros(d)
        for i in range(n):
            step[:6] += weights[i] * diffs[i, :6]
        mean = _boxplus_rows(mean.reshape(1, d), step.reshape(1, d))[0]
        if np.abs(step).max() < 1e-12:
            break
    mean[6:] = 0.0
    for i in range(n):
        mean[6:] += weights[i] * sigmas[i, 6:]
    return mean


def _transition(x: np.ndarray, dt: float) -> np.ndarray:
    """Constant body twist for ``dt`` s: (..., 12) → (..., 12)."""
    u = np.zeros_like(x)
    u[..., :6] = x[..., 6:] * dt
    return boxplus(x, u)


def _measure(x: np.ndarray) -> np.ndarray:
    return np.array(x[..., :6], copy=True)


def _unscented_transform(sigmas, Wm, Wc, noise_cov=None, mean_fn=None, residual_fn=None):
    """filterpy's ``unscented_transform`` with the residuals taken in one batch."""
    x = mean_fn(sigmas, Wm)
    y = residual_fn(sigmas, x)
    P = (y.T * Wc) @ y
    if noise_cov is not None:
        P = P + noise_cov
    return x, P


class _BatchedSigmaPoints(MerweScaledSigmaPoints):
    """Merwe's points, each ``x ⊞ ±column of √((n+λ)P)``, made in one batch (the same points as
    filterpy's loop with ``subtract(x, -u) = x ⊞ u``)."""

    def sigma_points(self, x, P):
        U = self.sqrt(self.alpha**2 * (self.n + self.kappa) * P)  # (λ + n) P
        return boxplus(x, np.vstack([np.zeros(self.n), U, -U]))


class _ManifoldUKF(UnscentedKalmanFilter):
    """filterpy's UKF with its per-sigma-point Python loops batched: propagation (``fx`` on every
    point at once), the unscented transform and the cross variance — the same maths, ~20× faster."""

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        self.sigmas_f = _transition(self.points_fn.sigma_points(self.x, self.P), dt)

    def predict(self, dt=None, UT=None, fx=None, **fx_args):
        super().predict(dt=dt, UT=_unscented_transform, fx=fx, **fx_args)

    def update(self, z, R=None, UT=None, hx=None, **hx_args):
        self.sigmas_h = _measure(self.sigmas_f)
        super().update(z, R=R, UT=_unscented_transform, hx=lambda x: x[:6], **hx_args)

    def cross_variance(self, x, z, sigmas_f, sigmas_h):
        dx = self.residual_x(sigmas_f, x)
        dz = self.residual_z(sigmas_h, z)
        return (dx.T * self.Wc) @ dz


def _sigma_subtract(x: np.ndarray, minus_u: np.ndarray) -> np.ndarray:
    # filterpy builds sigma points as subtract(x, -u); on the manifold that is x ⊞ u
    return boxplus(x, -minus_u)


@register("fusion", "ukf")
class UKFFusion(Fusion):
    """Unscented Kalman filter on SE(3) × twist (see the module docstring).

    Args:
        alpha, beta, kappa: Merwe scaled sigma-point parameters (alpha spreads the points; 0.3 keeps
            them within the range where ``Log`` is single-valued for covariances up to ~30°).
        **kw: :class:`~hybridpose.fusion.base.Fusion` noise and gating parameters.
    """

    name = "ukf"

    def __init__(self, alpha: float = 0.3, beta: float = 2.0, kappa: float = 0.0, **kw) -> None:
        super().__init__(**kw)
        points = _BatchedSigmaPoints(12, alpha=alpha, beta=beta, kappa=kappa, subtract=_sigma_subtract)
        self.ukf = _ManifoldUKF(dim_x=12, dim_z=6, dt=0.0, hx=_measure, fx=_transition, points=points,
                                x_mean_fn=manifold_mean, z_mean_fn=manifold_mean, residual_x=boxminus,
                                residual_z=boxminus, state_add=boxplus)

    def _reset(self, pose, covariance, timestamp, twist) -> None:
        self.ukf.x = np.r_[_pose_vector(pose), twist]
        P = np.zeros((12, 12))
        P[:6, :6] = covariance
        P[6:, 6:] = self.initial_twist_covariance
        self.ukf.P = P

    def _predict(self, dt: float, timestamp: float) -> None:
        self.ukf.Q = process_noise(dt, self.angular_accel_rad_s2, self.linear_accel_m_s2)
        self.ukf.predict(dt=dt)
        self.ukf.P = symmetrised(self.ukf.P, PSD_FLOOR)

    def _innovation(self, pose, covariance):
        x = self.ukf.x
        xi = boxminus(_pose_vector(pose), x[:6])
        return xi, self.ukf.P[:6, :6] + covariance

    def _update(self, pose, covariance) -> None:
        self.ukf.update(_pose_vector(pose), R=covariance)
        self.ukf.P = symmetrised(self.ukf.P, PSD_FLOOR)

    def _state(self):
        x = self.ukf.x
        return Pose(rotvec_to_matrix(x[:3]), x[3:6].copy()), self.ukf.P[:6, :6].copy(), x[6:].copy()
