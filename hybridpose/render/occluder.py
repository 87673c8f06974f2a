"""A robot-arm occluder: two capsule links and a tool disc that sweep between camera and object.

The arm's shoulder sits beside the camera, out of view (as on a small spacecraft whose camera looks
along its own arm). During an occlusion event the wrist moves in from the side, holds in front of
the object at a fraction of its distance, then retracts the way it came.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .trajectories import smoothstep

COVERAGES = ("partial", "full")
# tool-disc radius as a multiple of the object's apparent radius at the tool's depth
_TOOL_RADIUS_FACTOR = {"partial": 0.55, "full": 1.35}
_IN_FRACTION = 0.3  # share of an event spent moving in (and the same moving out)


@dataclass(frozen=True, eq=False)
class Capsule:
    """Segment ``p0 → p1`` (camera frame, metres) swept by a sphere of ``radius_m``."""

    p0: np.ndarray
    p1: np.ndarray
    radius_m: float


@dataclass(frozen=True, eq=False)
class ArmState:
    """Where the arm is in one frame, all in the camera frame (metres).

    Attributes:
        links: the upper-arm and forearm capsules.
        tool_centre: (3,) centre of the tool disc.
        tool_axis: (3,) unit normal of the disc (points from the camera towards the object).
        tool_radius_m: disc radius.
        tool_half_thickness_m: half the disc thickness.
    """

    links: tuple[Capsule, Capsule]
    tool_centre: np.ndarray
    tool_axis: np.ndarray
    tool_radius_m: float
    tool_half_thickness_m: float = 0.015


@dataclass(frozen=True)
class OcclusionEvent:
    """The arm passes in front of the object between ``start_s`` and ``end_s`` (seconds).

    ``coverage`` is ``"partial"`` (a small tool off-centre) or ``"full"`` (the tool hides the whole
    object while it holds); ``side`` is +1 (arm comes from the right) or -1 (left).
    """

    start_s: float
    end_s: float
    coverage: str = "full"
    side: int = 1

    def __post_init__(self) -> None:
        if not self.end_s > self.start_s:
            raise ValueError(f"OcclusionEvent: end_s ({self.end_s}) must be after start_s ({self.start_s})")
        if self.coverage not in COVERAGES:
            raise ValueError(f"coverage: expected one of {COVERAGES}, got {self.coverage!r}")
        if self.side not in (1, -1):
            raise ValueError(f"side: expected +1 or -1, got {self.side!r}")

    def progress(self, t: float) -> float | None:
        """0..1 through the event at time ``t``, None outside it."""
        if self.start_s <= t <= self.end_s:
            return (t - self.start_s) / (self.end_s - self.start_s)
        return None


def insertion(progress: float) -> float:
    """0 (parked beside the view) → 1 (holding in front of the object) → 0, smooth."""
    if progress < _IN_FRACTION:
        return smoothstep(progress / _IN_FRACTION)
    if progress > 1 - _IN_FRACTION:
        return smoothstep((1 - progress) / _IN_FRACTION)
    return 1.0


def arm_state(
    object_centre_cam: np.ndarray,
    object_radius_m: float,
    progress: float,
    coverage: str = "full",
    side: int = 1,
    depth_fraction: float = 0.5,
    hfov_deg: float = 60.0,
) -> ArmState:
    """The arm's geometry at ``progress`` (0..1) through an occlusion event.

    Args:
        object_centre_cam: (3,) object centre in the camera frame, metres.
        object_radius_m: half the object's diameter, metres.
        progress: 0..1 through the event (see :func:`insertion`).
        coverage: ``"partial"`` or ``"full"``.
        side: +1 from the right, -1 from the left.
        depth_fraction: the tool holds at this fraction of the object's distance.
        hfov_deg: camera horizontal field of view, to park the tool outside it.
    """
    if coverage not in COVERAGES:
        raise ValueError(f"coverage: expected one of {COVERAGES}, got {coverage!r}")
    c = np.asarray(object_centre_cam, dtype=np.float64)
    hold = c * depth_fraction
    apparent_r = object_radius_m * depth_fraction
    tool_r = _TOOL_RADIUS_FACTOR[coverage] * apparent_r
    if coverage == "partial":
        hold = hold + np.array([side * 0.6 * apparent_r, 0.0, 0.0])
    half_width = np.tan(np.radians(hfov_deg) / 2) * hold[2]
    parked = np.array([side * (half_width + tool_r + 0.08), hold[1], hold[2]])
    a = insertion(progress)
    wrist = parked + a * (hold - parked)
    shoulder = np.array([side * 0.30, 0.25, 0.12])
    elbow = 0.5 * (shoulder + wrist) + np.array([0.0, -0.12, 0.0])
    axis = wrist / np.linalg.norm(wrist)
    return ArmState(
        links=(Capsule(shoulder, elbow, 0.04), Capsule(elbow, wrist, 0.035)),
        tool_centre=wrist,
        tool_axis=axis,
        tool_radius_m=float(tool_r),
    )
