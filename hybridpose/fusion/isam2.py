"""``isam2``: gtsam's incremental fixed-lag smoother over poses and body twists.

The graph, per frame k (time t_k)::

    X(k) Pose3 (T_cam_obj)     V(k) Vector6 body twist [ω, v]
    constant velocity:   Log((X(k) · Exp(V(k)·dt))⁻¹ · X(k+1)) ~ N(0, Q_pose(dt))     (CustomFactor)
    twist random walk:   V(k+1) − V(k) ~ N(0, Q_twist(dt))                             (BetweenFactorVector)
    measurement:         PriorFactorPose3(X(k), pose, Huber(Gaussian(covariance)))

Q is the white-acceleration model of :func:`~hybridpose.fusion.base.process_noise` (its pose and
twist blocks; their cross term, which a two-factor form cannot carry, is left out). The Huber
kernel keeps one bad measurement that passes the gate from pulling the track; variables older
than ``lag_s`` are marginalised, so memory is bounded however long the run. The estimate is the
smoothed newest pose and its marginal covariance (gtsam's ``Pose3`` tangent is ``[ω, v]`` with right
perturbation, as ours).
"""
from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import V, X

from ..geometry import Pose
from ..registry import register
from .base import DegenerateBelief, Fusion, process_noise


def _to_gtsam(pose: Pose) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(pose.R), pose.t)


def _from_gtsam(p: gtsam.Pose3) -> Pose:
    return Pose(np.asarray(p.rotation().matrix()), np.asarray(p.translation()))


def _constant_velocity_error(dt: float):
    """CustomFactor error of keys (X(k), V(k), X(k+1)): ``e = Log(E)``, ``E = (X(k)·Exp(V dt))⁻¹ X(k+1)``.

    Jacobians (right perturbations, J_r the right Jacobian of SE(3)):
    ∂e/∂X(k+1) = J_r⁻¹(e); ∂e/∂X(k) = −J_r⁻¹(e)·Ad(X(k+1)⁻¹ X(k)); ∂e/∂V = −J_r⁻¹(e)·Ad(E⁻¹)·J_r(V dt)·dt.
    """

    def error(factor, values, jacobians):
        k0, kv, k1 = factor.keys()
        x0, x1 = values.atPose3(k0), values.atPose3(k1)
        d = values.atVector(kv) * dt
        a = x0.compose(gtsam.Pose3.Expmap(d))
        E = a.between(x1)
        e = gtsam.Pose3.Logmap(E)
        if jacobians is not None:
            jinv = gtsam.Pose3.LogmapDerivative(E)
            jacobians[0] = -jinv @ x1.between(x0).AdjointMap()
            jacobians[1] = -jinv @ E.inverse().AdjointMap() @ gtsam.Pose3.ExpmapDerivative(d) * dt
            jacobians[2] = jinv
        return e

    return error


@register("fusion", "isam2")
class ISAM2Fusion(Fusion):
    """Fixed-lag smoother (see the module docstring).

    Args:
        lag_s: variables older than this many seconds are marginalised out.
        huber_k: threshold of the Huber kernel on measurement factors, in standard deviations.
        **kw: :class:`~hybridpose.fusion.base.Fusion` noise and gating parameters.
    """

    name = "isam2"

    def __init__(self, lag_s: float = 1.0, huber_k: float = 2.0, **kw) -> None:
        super().__init__(**kw)
        if not lag_s > 0:
            raise ValueError(f"lag_s: expected a positive number of seconds, got {lag_s}")
        if not huber_k > 0:
            raise ValueError(f"huber_k: expected a positive number of standard deviations, got {huber_k}")
        self.lag_s, self.huber_k = float(lag_s), float(huber_k)

    def _reset(self, pose, covariance, timestamp, twist) -> None:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(1e-3)
        self.smoother = gtsam.IncrementalFixedLagSmoother(self.lag_s, params)
        self.k = 0
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        graph.add(gtsam.PriorFactorPose3(X(0), _to_gtsam(pose), gtsam.noiseModel.Gaussian.Covariance(covariance)))
        graph.add(gtsam.PriorFactorVector(V(0), twist, gtsam.noiseModel.Gaussian.Covariance(self.initial_twist_covariance)))
        values.insert(X(0), _to_gtsam(pose))
        values.insert(V(0), twist)
        self._commit(graph, values, timestamp)

    def _predict(self, dt: float, timestamp: float) -> None:
        k, k1 = self.k, self.k + 1
        Q = process_noise(dt, self.angular_accel_rad_s2, self.linear_accel_m_s2)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        graph.add(gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(Q[:6, :6]), [X(k), V(k), X(k1)],
                                     _constant_velocity_error(dt)))
        graph.add(gtsam.BetweenFactorVector(V(k), V(k1), np.zeros(6), gtsam.noiseModel.Gaussian.Covariance(Q[6:, 6:])))
        values.insert(X(k1), self._pose.compose(gtsam.Pose3.Expmap(self._twist * dt)))
        values.insert(V(k1), self._twist)
        self.k = k1
        self._commit(graph, values, timestamp)

    def _innovation(self, pose, covariance):
        return gtsam.Pose3.Logmap(self._pose.between(_to_gtsam(pose))), self._cov + covariance

    def _update(self, pose, covariance) -> None:
        graph = gtsam.NonlinearFactorGraph()
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(self.huber_k),
                                               gtsam.noiseModel.Gaussian.Covariance(covariance))
        graph.add(gtsam.PriorFactorPose3(X(self.k), _to_gtsam(pose), noise))
        self._commit(graph, gtsam.Values(), None)

    def _state(self):
        return _from_gtsam(self._pose), self._cov.copy(), self._twist.copy()

    def _commit(self, graph, values, timestamp) -> None:
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        if timestamp is not None:
            stamps.insert((X(self.k), timestamp))
            stamps.insert((V(self.k), timestamp))
        try:
            self.smoother.update(graph, values, stamps)
        except RuntimeError as exc:
            # gtsam's IndeterminantLinearSystemException reaches Python as a bare RuntimeError: told apart by
            # its message ("Indeterminate linear system", "Indeterminant" before gtsam 4.3), so that any
            # other failure still surfaces
            if "indetermina" not in str(exc).lower():
                raise
            raise DegenerateBelief(f"{self.name}: {str(exc).splitlines()[0].strip()}") from exc
        est = self.smoother.calculateEstimate()
        self._pose = est.atPose3(X(self.k))
        self._twist = np.asarray(est.atVector(V(self.k)))
        self._cov = np.asarray(self.smoother.marginalCovariance(X(self.k)))
