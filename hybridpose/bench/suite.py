"""Seeded sequence suites, rendered on first use and cached in BOP format.

A suite is a list of :class:`SuiteEntry` (a name and a :class:`~hybridpose.render.sequences.SequenceSpec`).
Each entry's seeds belong either to the *tuning* split (used while choosing the estimator's
parameters) or to the *report* split (the figures we publish); the two never overlap, so a figure
on the report split was never seen while tuning.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..geometry import Camera
from ..render.sequences import SequenceSpec

OCCLUSION_TRAJECTORIES = ("tumble", "fly-around", "approach")
OCCLUSION_KINDS = ("arm-partial", "arm-full", "arm-long")
# seeds that tuned the hybrid's thresholds (10 per trajectory) and seeds only ever used for reporting
TUNING_SEEDS = tuple(range(900, 910))
REPORT_SEEDS = tuple(range(500, 520))
SMOKE_SEEDS = (950,)


@dataclass(frozen=True)
class SuiteEntry:
    """One sequence of a suite: ``name`` (unique, a folder name) and the spec that renders it."""

    name: str
    spec: SequenceSpec
    split: str  # "tuning" | "report" | "smoke"


def occlusion_suite(split: str = "report", frames: int = 60, fps: float = 30.0) -> list[SuiteEntry]:
    """Arm-occlusion sequences: tumble, fly-around and approach, each seed with one of a partial, a full
    and a long occlusion (seed mod 3), ``frames`` frames at ``fps``.

    Args:
        split: ``"report"`` (20 seeds per trajectory), ``"tuning"`` (10 seeds per trajectory, disjoint
            from the report seeds) or ``"smoke"`` (one short sequence per trajectory).
    """
    seeds = {"report": REPORT_SEEDS, "tuning": TUNING_SEEDS, "smoke": SMOKE_SEEDS}
    if split not in seeds:
        raise ValueError(f"split: expected one of {sorted(seeds)}, got {split!r}")
    if frames < 10:
        raise ValueError(f"frames: expected at least 10 (an occlusion needs room to start and end), got {frames}")
    entries = []
    for traj in OCCLUSION_TRAJECTORIES:
        for seed in seeds[split]:
            occ = OCCLUSION_KINDS[seed % len(OCCLUSION_KINDS)]
            spec = SequenceSpec(trajectory=traj, frames=frames, fps=fps, occlusion=occ, seed=seed)
            entries.append(SuiteEntry(f"{traj}_{occ}_s{seed}", spec, split))
    return entries


def render_suite(entries: list[SuiteEntry], root, camera: Camera | None = None, object_name: str = "truss",
                 progress: Callable[[str], None] | None = None) -> dict[str, Path]:
    """Render (or reuse, resuming where interrupted) every entry under ``root/<name>``.

    Returns ``{name: scene_dir}`` (the BOP scene folder holding ``rgb/``, ``scene_gt.json``, ...).
    """
    from ..datasets import render_sequence_dataset
    from ..objects import load_object

    obj = load_object(object_name)
    camera = camera or Camera.default()
    root = Path(root)
    scenes = {}
    for e in entries:
        scenes[e.name] = render_sequence_dataset(root / e.name, obj, camera, e.spec)
        if progress:
            progress(e.name)
    return scenes
