"""``none``: no filtering — the estimate is the last measurement (for ablations).

Between measurements the pose is held (zero-order hold: extrapolating with a finite-difference twist
of noisy measurements amplifies their noise by 1/dt) and its covariance grows by the twist's
``initial_twist_sigma`` over the elapsed time; the reported velocity is the finite difference of
the last two accepted measurements. Gating works as in every backend (a
measurement far outside the prediction's and its own covariance is refused).
"""
from __future__ import annotations

import numpy as np

from ..geometry import Pose
from ..registry import register
from .base import Fusion, process_noise


@register("fusion", "none")
class PassThroughFusion(Fusion):
    """The last measurement, as it is (see the module docstring); ``**kw`` as :class:`Fusion`."""

    name = "none"

    def _reset(self, pose, covariance, timestamp, twist) -> None:
        self.pose, self.covariance, self.twist = pose, covariance, twist
        self.last_update = (pose, timestamp)

    def _predict(self, dt: float, timestamp: float) -> None:
        self.covariance = (self.covariance + self.initial_twist_covariance * dt**2
                           + process_noise(dt, self.angular_accel_rad_s2, self.linear_accel_m_s2)[:6, :6])

    def _innovation(self, pose, covariance):
        return self.pose.local(pose), self.covariance + covariance

    def _update(self, pose: Pose, covariance: np.ndarray) -> None:
        last_pose, last_t = self.last_update
        if self.timestamp > last_t:
            self.twist = last_pose.local(pose) / (self.timestamp - last_t)
        self.pose, self.covariance = pose, np.array(covariance)
        self.last_update = (pose, self.timestamp)

    def _state(self):
        return self.pose, self.covariance, self.twist
