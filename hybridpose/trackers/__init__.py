"""Model-based trackers: moving edges on the CAD model, cv2.rapid silhouette trackers, KLT + PnP.
What they share with the regressors (visible model edges, the edge fit) lives in :mod:`hybridpose.edges`."""
from .base import LOST_COVARIANCE, Tracker

__all__ = ["LOST_COVARIANCE", "Tracker"]
