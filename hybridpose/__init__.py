"""hybridpose — 6-DoF pose tracking of a known rigid object in monocular video.

Conventions (see docs/conventions.md): ``Pose`` is ``T_cam_obj`` in metres, OpenCV camera frame,
quaternions (w, x, y, z), tangent ``[ω, v]``, images (H, W, 3) uint8 RGB.
"""
from .core import Estimate, Frame, Measurement, Status
from .estimator import HybridConfig, HybridEstimator
from .geometry import Camera, Pose
from .objects import ObjectModel
from .threads import set_threads
from .warmup import warm_up

__version__ = "0.1.0"
__all__ = ["Camera", "Estimate", "Frame", "HybridConfig", "HybridEstimator", "Measurement", "ObjectModel", "Pose",
           "Status", "__version__", "set_threads", "warm_up"]
