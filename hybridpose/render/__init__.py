"""Rendering: MuJoCo (EGL) space-lit views of an object, arm occluder, trajectories, sequences, and
randomised looks (backgrounds, lights, colours) for the world outside space, and hand-held scenes with
ground truth (a printed or plain part in a lit, cluttered room: :mod:`hybridpose.render.handheld`)."""
from .appearance import Appearance, AppearanceSpec, clutter_background, random_appearance
from .handheld import HandheldFrame, HandheldSpec, handheld_sequence
from .lighting import SensorModel, SpaceLighting, earth_background
from .occluder import ArmState, OcclusionEvent, arm_state
from .renderer import Renderer, RenderResult
from .trajectories import Trajectory, random_poses

__all__ = [
    "Appearance", "AppearanceSpec", "ArmState", "HandheldFrame", "HandheldSpec", "OcclusionEvent", "Renderer", "RenderResult", "SensorModel", "SpaceLighting",
    "Trajectory", "arm_state", "clutter_background", "earth_background", "handheld_sequence", "random_appearance",
    "random_poses",
]
