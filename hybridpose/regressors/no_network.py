"""``none``: no network at all — a regressor that never finds the part, for a part the hybrid finds by
its look alone: its keypoint memory holds the print of a mesh that carries one from the first frame
(:mod:`hybridpose.regressors.keypoint_memory`), so a printed part needs no ``hybridpose fit``. A plain
part never starts with it."""
from __future__ import annotations

from ..core import LOST_COVARIANCE, Frame, Measurement
from ..registry import register
from .base import PoseRegressor, check_roi


@register("regressor", "none")
class NoNetwork(PoseRegressor):
    """Finds nothing in any frame (``pose`` None, ``lost``): the hybrid's keypoint memory alone starts
    and restarts the track.

    Args:
        object: the object (unused; taken as every regressor takes it).
        threads: unused.
    """

    name = "none"

    def __init__(self, object=None, threads: int | None = None) -> None:
        self.object = object

    def predict(self, frame: Frame, roi=None) -> Measurement:
        if not isinstance(frame, Frame):
            raise TypeError(f"frame: expected a hybridpose Frame, got {type(frame).__name__}")
        check_roi(roi, frame)
        return Measurement(None, LOST_COVARIANCE, 0.0, f"regressor:{self.name}", frame.timestamp)
