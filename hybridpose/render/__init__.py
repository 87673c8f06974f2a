"""Rendering: MuJoCo (EGL) space-lit views of an object, arm occluder, trajectories, sequences."""
from .lighting import SensorModel, SpaceLighting, earth_background
from .occluder import ArmState, OcclusionEvent, arm_state
from .renderer import Renderer, RenderResult
from .trajectories import Trajectory, random_poses

__all__ = [
    "ArmState", "OcclusionEvent", "Renderer", "RenderResult", "SensorModel", "SpaceLighting",
    "Trajectory", "arm_state", "earth_background", "random_poses",
]
