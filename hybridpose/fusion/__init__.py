"""Fusion backends: one pose + twist belief over time from tracker and regressor measurements.

``ukf`` (filterpy Unscented Kalman filter on SE(3)), ``isam2`` (gtsam incremental fixed-lag smoother)
and ``none`` (pass-through, for ablations), all built through ``registry.create("fusion", name)``.
"""
from .base import DEFAULT_GATE_CHI2, DegenerateBelief, Fusion, nearest_equivalent_measurement, pose_mahalanobis2, process_noise

__all__ = ["DEFAULT_GATE_CHI2", "DegenerateBelief", "Fusion", "nearest_equivalent_measurement", "pose_mahalanobis2", "process_noise"]
