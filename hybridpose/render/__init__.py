"""Rendering: MuJoCo (EGL) space-lit views of an object, arm occluder, trajectories, sequences, and
randomised looks (backgrounds, lights, colours) for the world outside space, and hand-held scenes with
ground truth (a printed or plain part in a lit, cluttered room: :mod:`hybridpose.render.handheld`)."""
from .appearance import Appearance, AppearanceSpec, clutter_background, random_appearance
from .handheld import HandheldFrame, HandheldScene, HandheldSpec, handheld_scene, handheld_sequence, printed_part
from .lighting import SensorModel, SpaceLighting, earth_background
from .occluder import ArmState, OcclusionEvent, arm_state
from .renderer import Renderer, RenderResult
from .trajectories import Trajectory, random_poses

__all__ = [
    "Appearance", "AppearanceSpec", "ArmState", "HandheldFrame", "HandheldScene", "HandheldSpec", "OcclusionEvent", "Renderer", "RenderResult", "SensorModel", "SpaceLighting",
    "Trajectory", "arm_state", "clutter_background", "earth_background", "handheld_scene", "handheld_sequence",
    "printed_part", "random_appearance", "random_poses",
]
