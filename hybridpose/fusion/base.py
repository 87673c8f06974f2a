"""The fusion contract: one pose belief over time, predicted to each frame and updated with
measurements from any tracker or regressor.

Every built-in backend derives from :class:`Fusion` (which fulfils the role's contract,
:mod:`hybridpose.contracts`), which checks inputs (timestamps that go forward, a
measurement at the predicted time, finite poses and covariances), holds the gating rule and turns
the backend's state into an immutable :class:`~hybridpose.core.Estimate`. Backends implement
:meth:`Fusion._reset`, :meth:`Fusion._predict`, :meth:`Fusion._innovation`, :meth:`Fusion._update` and
:meth:`Fusion._state`.

Motion model (all backends): the object moves with a constant body-frame twist
``ξ̇ = [ω (rad/s), v (m/s)]``, ``T(t + dt) = T(t) · Exp(ξ̇ · dt)``, driven by white angular and linear
acceleration of spectral densities ``angular_accel_rad_s2² · s`` and ``linear_accel_m_s2² · s``.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import replace

import numpy as np

from ..core import Estimate, Measurement, as_covariance6
from ..geometry import Pose, skew
from ..metrics import rotation_error_rad

# 99.9 % of a correct 6-dof Gaussian innovation lies inside this squared Mahalanobis distance
# (scipy.stats.chi2.ppf(0.999, 6); a constant, so that `import hybridpose` does not load scipy.stats)
DEFAULT_GATE_CHI2 = 22.457744484825323


def process_noise(dt: float, angular_accel_rad_s2: float, linear_accel_m_s2: float) -> np.ndarray:
    """(12, 12) discrete process noise of the constant-velocity model over ``dt`` seconds, state
    ``[pose tangent ω, v (6); twist ω̇, v̇ (6)]``: the white-acceleration model's
    ``[[dt³/3, dt²/2], [dt²/2, dt]] ⊗ diag(q)`` with q = (σ_α², σ_α², σ_α², σ_a², σ_a², σ_a²)."""
    q = np.r_[[angular_accel_rad_s2**2] * 3, [linear_accel_m_s2**2] * 3]
    Q = np.zeros((12, 12))
    Q[:6, :6] = np.diag(q) * dt**3 / 3
    Q[:6, 6:] = Q[6:, :6] = np.diag(q) * dt**2 / 2
    Q[6:, 6:] = np.diag(q) * dt
    return Q


def symmetrised(P: np.ndarray, floor: float = 1e-15) -> np.ndarray:
    """``P`` made exactly symmetric with eigenvalues ≥ ``floor`` (round-off in long runs can push a
    covariance a hair outside the positive-definite cone)."""
    P = 0.5 * (P + P.T)
    w, V = np.linalg.eigh(P)
    if w.min() >= floor:
        return P
    return (V * np.maximum(w, floor)) @ V.T


class DegenerateBelief(ArithmeticError):
    """A backend's belief has lost its information: a filter's covariance went indefinite, a smoother's
    linear system became indeterminate (a coast of seconds with no measurement). Backends raise it from
    their ``_predict`` where their library reports so; :meth:`Fusion.predict` starts the belief over."""


class Fusion(ABC):
    """Pose + twist filter/smoother (role ``"fusion"`` in :mod:`hybridpose.registry`).

    Args:
        angular_accel_rad_s2: spectral density (as a standard deviation) of the angular acceleration
            that drives the twist, rad/s² per √Hz.
        linear_accel_m_s2: the same for the linear acceleration, m/s² per √Hz (the default follows
            an approach braking at a few m/s² without refusing a 0.2-mm-accurate tracker).
        initial_twist_sigma: (2,) standard deviations of the twist at ``reset``: rad/s, m/s.
        gate_chi2: a measurement whose squared Mahalanobis distance from the prediction (with both
            covariances) exceeds this is rejected (default: the 99.9 % point of χ²₆, 22.5);
            ``inf`` turns gating off.
    """

    name = "fusion"

    def __init__(self, angular_accel_rad_s2: float = 0.5, linear_accel_m_s2: float = 0.5,
                 initial_twist_sigma: tuple[float, float] = (0.3, 0.1), gate_chi2: float = DEFAULT_GATE_CHI2) -> None:
        for name, value in (("angular_accel_rad_s2", angular_accel_rad_s2), ("linear_accel_m_s2", linear_accel_m_s2),
                            ("gate_chi2", gate_chi2)):
            if not value > 0:
                raise ValueError(f"{name}: expected a positive number, got {value}")
        sig = np.asarray(initial_twist_sigma, dtype=np.float64)
        if sig.shape != (2,) or not np.all(np.isfinite(sig)) or np.any(sig <= 0):
            raise ValueError(f"initial_twist_sigma: expected (rad/s, m/s) positive, got {initial_twist_sigma!r}")
        self.angular_accel_rad_s2 = float(angular_accel_rad_s2)
        self.linear_accel_m_s2 = float(linear_accel_m_s2)
        self.initial_twist_covariance = np.diag(np.r_[[sig[0] ** 2] * 3, [sig[1] ** 2] * 3])
        self.gate_chi2 = float(gate_chi2)
        self.timestamp: float | None = None
        self.last_mahalanobis2: float = float("nan")

    # --- public API --------------------------------------------------------------------------------
    @property
    def motion_noise(self) -> tuple[float, float]:
        """(``angular_accel_rad_s2``, ``linear_accel_m_s2``): the white-acceleration densities of the
        motion model; set it to change them from the next prediction on (ValueError unless both positive)."""
        return self.angular_accel_rad_s2, self.linear_accel_m_s2

    @motion_noise.setter
    def motion_noise(self, value: tuple[float, float]) -> None:
        angular, linear = (float(v) for v in value)
        if not (angular > 0 and linear > 0 and np.isfinite(angular) and np.isfinite(linear)):
            raise ValueError(f"motion_noise: expected (rad/s² per √Hz, m/s² per √Hz) both positive, got {value!r}")
        self.angular_accel_rad_s2, self.linear_accel_m_s2 = angular, linear

    def reset(self, pose: Pose, covariance: np.ndarray, timestamp: float, twist: np.ndarray | None = None) -> None:
        """Start a new belief: ``pose`` (``T_cam_obj``) with its (6, 6) ``[ω, v]`` covariance at
        ``timestamp`` (s), twist ``twist`` (6,) (rad/s, m/s; default zero, with
        ``initial_twist_sigma``). Any earlier history is dropped."""
        if not isinstance(pose, Pose):
            raise TypeError(f"pose: expected a hybridpose Pose (T_cam_obj), got {type(pose).__name__}")
        cov = as_covariance6(covariance, "covariance")
        if not np.isfinite(timestamp):
            raise ValueError(f"timestamp: expected finite seconds, got {timestamp}")
        twist = np.zeros(6) if twist is None else np.asarray(twist, dtype=np.float64)
        if twist.shape != (6,) or not np.all(np.isfinite(twist)):
            raise ValueError(f"twist: expected (6,) finite [ω (rad/s), v (m/s)], got {twist!r}")
        self._reset(pose, symmetrised(np.array(cov)), float(timestamp), twist)
        self.timestamp = float(timestamp)

    def predict(self, timestamp: float) -> Estimate:
        """Propagate the belief to ``timestamp`` (s, ≥ the current time; equal is a no-op)."""
        self._check_started("predict")
        if not np.isfinite(timestamp):
            raise ValueError(f"timestamp: expected finite seconds, got {timestamp}")
        if timestamp < self.timestamp:
            raise ValueError(f"timestamp: {timestamp:.6f} s is before the current {self.timestamp:.6f} s "
                             "(timestamps must not decrease)")
        if timestamp > self.timestamp:
            dt = float(timestamp) - self.timestamp
            try:
                self._predict(dt, float(timestamp))
            except (np.linalg.LinAlgError, DegenerateBelief):
                # a coast of seconds with no measurement (the object lost: ≈ 9 s at 30 fps) leaves the
                # pose next to no information: the UKF's sigma points go indefinite (a Cholesky of its
                # covariance fails), gtsam finds the system indeterminate. The belief starts over at the
                # constant-velocity prediction, with the spread it had
                pose, cov, twist = self._state()
                self._reset(pose.retract(twist * dt), cov, float(timestamp), twist)
            self.timestamp = float(timestamp)
        return self.estimate

    def update(self, measurement: Measurement) -> bool:
        """Fuse ``measurement`` (taken at the current time: call :meth:`predict` first).

        Returns False, leaving the belief unchanged, when the measurement is lost (no pose) or its
        squared Mahalanobis distance from the prediction exceeds ``gate_chi2``; True when fused.
        The distance is kept in ``last_mahalanobis2``.
        """
        self._check_started("update")
        if not isinstance(measurement, Measurement):
            raise TypeError(f"measurement: expected a hybridpose Measurement, got {type(measurement).__name__}")
        if measurement.timestamp != self.timestamp:
            raise ValueError(f"measurement.timestamp: {measurement.timestamp:.6f} s differs from the filter's "
                             f"{self.timestamp:.6f} s (call predict(measurement.timestamp) first)")
        self.last_mahalanobis2 = float("nan")
        if measurement.pose is None:
            return False
        d2 = mahalanobis2(*self._innovation(measurement.pose, measurement.covariance))
        self.last_mahalanobis2 = d2
        if not d2 <= self.gate_chi2:
            return False
        self._update(measurement.pose, np.asarray(measurement.covariance))
        return True

    @property
    def estimate(self) -> Estimate:
        """The current belief: pose, (6, 6) pose covariance, body twist, timestamp; status "tracking"
        (the estimator that owns the fusion sets its own status)."""
        self._check_started("estimate")
        pose, cov, twist = self._state()
        return Estimate(pose=pose, covariance=symmetrised(cov), timestamp=self.timestamp, status="tracking",
                        velocity=twist)

    # --- for subclasses -------------------------------------------------------------------------
    @abstractmethod
    def _reset(self, pose: Pose, covariance: np.ndarray, timestamp: float, twist: np.ndarray) -> None:
        """Start from ``pose`` / ``covariance`` / ``twist`` at ``timestamp`` (inputs checked)."""

    @abstractmethod
    def _predict(self, dt: float, timestamp: float) -> None:
        """Propagate the state ``dt`` > 0 seconds, to ``timestamp``."""

    @abstractmethod
    def _innovation(self, pose: Pose, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(6,) ``Log(T̂⁻¹ · pose)`` at the predicted pose T̂ and its (6, 6) covariance (prediction +
        measurement), for gating."""

    @abstractmethod
    def _update(self, pose: Pose, covariance: np.ndarray) -> None:
        """Fuse a pose measurement that passed the gate."""

    @abstractmethod
    def _state(self) -> tuple[Pose, np.ndarray, np.ndarray]:
        """(pose, (6, 6) pose covariance, (6,) twist) at the current time."""

    def _check_started(self, what: str) -> None:
        if self.timestamp is None:
            raise RuntimeError(f"{self.name}: {what}() called before reset(pose, covariance, timestamp)")


def adjoint(pose: Pose) -> np.ndarray:
    """(6, 6) adjoint of ``pose`` in the ``[ω, v]`` order: ``Exp(Ad·ξ) = T·Exp(ξ)·T⁻¹``."""
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = pose.R
    A[3:, :3] = skew(pose.t) @ pose.R
    return A


def mahalanobis2(xi: np.ndarray, S: np.ndarray) -> float:
    """``ξᵀ S⁻¹ ξ`` for a (6,) tangent and its (6, 6) covariance; inf where ``S`` is singular."""
    try:
        return float(xi @ np.linalg.solve(S, xi))
    except np.linalg.LinAlgError:
        return float("inf")


def pose_mahalanobis2(a: Pose, cov_a: np.ndarray, b: Pose, cov_b: np.ndarray) -> float:
    """Squared Mahalanobis distance between two uncertain poses (right-perturbation covariances),
    ``ξ = Log(a⁻¹ b)`` against ``cov_a + Ad(a⁻¹ b)·cov_b·Ad(a⁻¹ b)ᵀ`` (cov_b moved to a's tangent)."""
    rel = a.inverse() @ b
    xi = rel.log()
    A = adjoint(rel)
    return mahalanobis2(xi, np.asarray(cov_a) + A @ np.asarray(cov_b) @ A.T)


def nearest_equivalent_measurement(m: Measurement, near: Pose, symmetries) -> Measurement:
    """``m`` restated as the equivalent pose ``m.pose @ S`` (``S`` one of the object's ``symmetries``,
    or the identity) nearest ``near`` in rotation, its right-perturbation covariance carried along:
    ``T·Exp(ξ)·S = (T·S)·Exp(Ad(S⁻¹)·ξ)``, so ``Σ' = Ad(S⁻¹) Σ Ad(S⁻¹)ᵀ``. ``m`` itself when it has no
    pose, the object no symmetry, or the identity is nearest."""
    if m.pose is None or near is None or not symmetries:
        return m
    identity = Pose.identity()
    best = min((identity, *symmetries), key=lambda S: rotation_error_rad(m.pose @ S, near))  # first on a tie
    return m if best is identity else equivalent_measurement(m, best)


def equivalent_measurement(m: Measurement, S: Pose) -> Measurement:
    """``m`` restated as the equivalent pose ``m.pose @ S`` (``S`` a symmetry of the object), its
    right-perturbation covariance carried along (``Σ' = Ad(S⁻¹) Σ Ad(S⁻¹)ᵀ``)."""
    A = adjoint(S.inverse())
    return replace(m, pose=m.pose @ S, covariance=A @ np.asarray(m.covariance) @ A.T)


def measured_twist(previous: Measurement | None, m: Measurement, max_gap_s: float) -> np.ndarray | None:
    """Body twist (6,) rad/s, m/s from the pose of ``previous`` to that of ``m`` (a tracker's two
    measurements) where both have poses and lie at most ``max_gap_s`` apart in time; None (zero twist)
    otherwise."""
    if previous is None or previous.pose is None or m.pose is None:
        return None
    dt = m.timestamp - previous.timestamp
    if not 0 < dt <= max_gap_s:
        return None
    return previous.pose.local(m.pose) / dt
