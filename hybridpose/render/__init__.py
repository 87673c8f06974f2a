"""Rendering: MuJoCo (EGL) space-lit views of an object, arm occluder, trajectories, sequences, and
randomised looks (backgrounds, lights, colours) for the world outside space."""
from .appearance import Appearance, AppearanceSpec, clutter_background, random_appearance
from .lighting import SensorModel, SpaceLighting, earth_background
from .occluder import ArmState, OcclusionEvent, arm_state
from .renderer import Renderer, RenderResult
from .trajectories import Trajectory, random_poses

__all__ = [
    "Appearance", "AppearanceSpec", "ArmState", "OcclusionEvent", "Renderer", "RenderResult", "SensorModel", "SpaceLighting",
    "Trajectory", "arm_state", "clutter_background", "earth_background", "random_appearance", "random_poses",
]
