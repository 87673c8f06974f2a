"""Model-based trackers: moving edges on the CAD model, cv2.rapid silhouette trackers, KLT + PnP."""
from .base import LOST_COVARIANCE, Tracker
from .model_view import EdgeSamples, ModelView

__all__ = ["LOST_COVARIANCE", "EdgeSamples", "ModelView", "Tracker"]
