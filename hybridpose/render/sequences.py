"""Sequences: a trajectory sampled at a frame rate, with an arm-occlusion schedule and lighting."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import registry
from ..geometry import Camera, Pose
from ..objects import ObjectModel
from .occluder import ArmState, OcclusionEvent, arm_state

OCCLUSIONS = ("none", "arm", "arm-partial", "arm-full", "arm-long")
LIGHTINGS = ("constant", "eclipse")


def occlusion_schedule(kind: str, duration_s: float) -> list[OcclusionEvent]:
    """Named arm-occlusion schedules over a sequence of ``duration_s`` seconds.

    - ``none``: no arm.
    - ``arm``: a partial pass at 15–35 % of the sequence, a full one at 55–80 % (from the other side).
    - ``arm-partial`` / ``arm-full``: one pass at 30–70 %.
    - ``arm-long``: a full occlusion covering 25–85 % (a long loss of sight).
    """
    T = float(duration_s)
    schedules = {
        "none": [],
        "arm": [OcclusionEvent(0.15 * T, 0.35 * T, "partial", 1), OcclusionEvent(0.55 * T, 0.80 * T, "full", -1)],
        "arm-partial": [OcclusionEvent(0.30 * T, 0.70 * T, "partial", 1)],
        "arm-full": [OcclusionEvent(0.30 * T, 0.70 * T, "full", 1)],
        "arm-long": [OcclusionEvent(0.25 * T, 0.85 * T, "full", 1)],
    }
    if kind not in schedules:
        raise ValueError(f"occlusion: expected one of {OCCLUSIONS}, got {kind!r}")
    return schedules[kind]


def sun_schedule(kind: str, t: float, duration_s: float) -> float:
    """Sun intensity factor at ``t``: ``constant`` = 1; ``eclipse`` fades to 10 % over the middle
    third of the sequence and back (entering and leaving the Earth's shadow)."""
    if kind == "constant":
        return 1.0
    if kind != "eclipse":
        raise ValueError(f"lighting: expected one of {LIGHTINGS}, got {kind!r}")
    x = t / duration_s
    dip = np.clip(1.0 - abs(x - 0.5) / (1.0 / 6.0), 0.0, 1.0)  # 1 at the middle, 0 outside the middle third
    return float(1.0 - 0.9 * min(1.0, 2.0 * dip))


@dataclass(frozen=True, eq=False)
class SequenceFrame:
    """Ground truth of one frame: pose, time, arm geometry (None = arm out of view), sun factor."""

    index: int
    timestamp: float
    pose: Pose
    arm: ArmState | None = None
    sun_scale: float = 1.0
    occlusion: str = "none"  # "none" or the coverage of the current arm event


@dataclass(frozen=True)
class SequenceSpec:
    """Everything that defines a rendered sequence (serialised next to the data for resuming).

    Attributes:
        trajectory: registered trajectory name (``registry.available("trajectory")``).
        frames: number of frames.
        fps: frames per second.
        occlusion: one of :data:`OCCLUSIONS`.
        lighting: one of :data:`LIGHTINGS`.
        seed: seeds the trajectory (and, per frame, the renderer's noise).
        trajectory_kwargs: extra keyword arguments of the trajectory (e.g. ``rate_deg_s``).
    """

    trajectory: str
    frames: int
    fps: float = 30.0
    occlusion: str = "none"
    lighting: str = "constant"
    seed: int = 0
    trajectory_kwargs: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError(f"frames: expected ≥ 1, got {self.frames}")
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise ValueError(f"fps: expected a positive frame rate, got {self.fps}")
        registry.get("trajectory", self.trajectory)  # raises with the list of names
        occlusion_schedule(self.occlusion, 1.0)
        sun_schedule(self.lighting, 0.0, 1.0)

    @property
    def duration_s(self) -> float:
        return self.frames / self.fps


def make_sequence(spec: SequenceSpec, obj: ObjectModel, camera: Camera) -> list[SequenceFrame]:
    """Sample the trajectory at ``spec.fps``, place the arm per the occlusion schedule."""
    duration = spec.duration_s
    traj = registry.create("trajectory", spec.trajectory, duration_s=duration, rng=spec.seed, **spec.trajectory_kwargs)
    events = occlusion_schedule(spec.occlusion, duration)
    radius = 0.5 * obj.diameter
    out = []
    for i in range(spec.frames):
        t = i / spec.fps
        pose = traj.pose_at(t)
        arm, occl = None, "none"
        for ev in events:
            p = ev.progress(t)
            if p is not None:
                centre = pose @ obj.center
                arm = arm_state(centre, radius, p, ev.coverage, ev.side, hfov_deg=camera.hfov_deg)
                occl = ev.coverage
        out.append(SequenceFrame(i, t, pose, arm, sun_schedule(spec.lighting, t, duration), occl))
    return out
