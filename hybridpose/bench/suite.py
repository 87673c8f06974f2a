"""Seeded sequence suites, rendered on first use and cached in BOP format.

A suite is a list of :class:`SuiteEntry` (a unique name and a
:class:`~hybridpose.render.sequences.SequenceSpec`). Seeds come in two disjoint splits: **tuning**
(used while choosing the estimator's parameters) and **report** (the published figures); a figure on
the report split was never seen while tuning.

Suites:

- ``occlusion``: tumble, fly-around and approach, each seed with a partial, full or long arm
  occlusion (seed mod 3);
- ``standard``: ``occlusion`` plus a distance sweep, an eclipse (the sun fades to 10 % and back), a
  fast tumble (60°/s) and tumbles that start within 15° of edge-on — 7 kinds × 20 seeds;
- ``smoke``: one short sequence of three kinds (seconds; what CI runs);
- ``realistic``: off black space (:mod:`hybridpose.render.handheld`): a printed 8.5-cm ``cube`` on a
  photo, the same in procedural clutter with a hand passing in front, and a plain ``box`` on a photo,
  each filmed by a hand-held camera (5–30 px a frame, stops and turns, blur, exposure, noise, JPEG);
  90 frames a sequence, seeds of their own (report 1–10, tuning 101–120).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..geometry import Camera
from ..render.sequences import SequenceSpec

OCCLUSION_TRAJECTORIES = ("tumble", "fly-around", "approach")
OCCLUSION_KINDS = ("arm-partial", "arm-full", "arm-long")
# seeds that tuned the hybrid's thresholds (20 per kind; the defaults chosen before were chosen on
# 900–909) and seeds only ever used for reporting
TUNING_SEEDS = tuple(range(900, 920))
REPORT_SEEDS = tuple(range(500, 520))
# seeds a caller may add to the tuning split (``--seeds``); the report split never takes one of them
TUNING_SEED_RANGE = range(900, 1000)
SMOKE_SEEDS = (950,)  # one tuning seed: the smoke suite checks the plumbing, not accuracy
# the edge-on kind draws its seeds from these pools, keeping those whose first view is near edge-on
EDGE_ON_POOLS = {"report": range(2000, 3000), "tuning": range(5000, 6000), "smoke": range(7000, 7100)}
EDGE_ON_BELOW_DEG = 15.0  # view elevation (°) below which a first view counts as edge-on
FAST_RATE_DEG_S = 60.0  # tumble rate (°/s) of the fast kind: about 4° a frame at 15 fps
# the realistic suite: kind → (built-in part, HandheldSpec options); its seeds are its own
REALISTIC_KINDS = {
    "printed-cube-photo": ("cube", {"printed": True, "background": "photo"}),
    "printed-cube-clutter-hand": ("cube", {"printed": True, "background": "clutter", "hand": True}),
    "plain-box-photo": ("box", {"printed": False, "background": "photo"}),
}
REALISTIC_SEEDS = {"report": tuple(range(1, 11)), "tuning": tuple(range(101, 121))}
REALISTIC_TUNING_RANGE = range(100, 200)
REALISTIC_FRAMES = 90  # frames a hand-held sequence: the hand's pass and a stretch after it
SUITES = ("standard", "occlusion", "smoke", "realistic")
SPLITS = ("report", "tuning")


@dataclass(frozen=True)
class SuiteEntry:
    """One sequence of a suite: ``name`` (unique, a folder name) and the spec that renders it."""

    name: str
    spec: SequenceSpec
    split: str  # "tuning" | "report" | "smoke"
    object: str = "truss"  # the built-in part it shows


def _seeds(split: str, seeds=None) -> tuple[int, ...]:
    defaults = {"report": REPORT_SEEDS, "tuning": TUNING_SEEDS, "smoke": SMOKE_SEEDS}
    if split not in defaults:
        raise ValueError(f"split: expected one of {sorted(defaults)}, got {split!r}")
    return defaults[split] if seeds is None else check_seeds(seeds, split)


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"920-979"``, ``"501,507"`` or both (``"520-539,560"``) → the seeds, in order, without repeats."""
    out: list[int] = []
    try:
        for part in str(text).split(","):
            part = part.strip()
            lo, _, hi = part.partition("-")
            first, last = int(lo), int(hi) if hi else int(lo)
            if last < first:
                raise ValueError
            out += [s for s in range(first, last + 1) if s not in out]
    except ValueError:
        raise ValueError(f"--seeds: expected seeds like 920-979 or 501,507, got {text!r}") from None
    return tuple(out)


def check_seeds(seeds, split: str, tuning_range: range = TUNING_SEED_RANGE) -> tuple[int, ...]:
    """``seeds`` for ``split`` in place of its default ones: tuning seeds lie in ``tuning_range``
    (:data:`TUNING_SEED_RANGE`; the realistic suite's :data:`REALISTIC_TUNING_RANGE`) and report seeds
    outside it, so that no figure is reported on a seed that tuned anything. ValueError naming
    ``--seeds`` otherwise."""
    if split not in ("tuning", "report"):
        raise ValueError(f"--seeds: only the tuning and report splits take seeds, not {split!r}")
    seeds = tuple(int(s) for s in seeds)
    if not seeds or min(seeds) < 0:
        raise ValueError(f"--seeds: expected one or more seeds ≥ 0, got {seeds}")
    tuning = [s for s in seeds if s in tuning_range]
    if split == "tuning" and len(tuning) < len(seeds):
        raise ValueError(f"--seeds: the tuning split's seeds lie in {tuning_range.start}–"
                         f"{tuning_range.stop - 1}; {sorted(set(seeds) - set(tuning))[:5]} do not")
    if split == "report" and tuning:
        raise ValueError(f"--seeds: {tuning[:5]} are tuning seeds ({tuning_range.start}–"
                         f"{tuning_range.stop - 1}); report figures come from seeds nothing was tuned on")
    return seeds


def occlusion_suite(split: str = "report", frames: int = 60, fps: float = 30.0, seeds=None) -> list[SuiteEntry]:
    """Arm-occlusion sequences: tumble, fly-around and approach, each seed with one of a partial, a full
    and a long occlusion (seed mod 3), ``frames`` frames at ``fps``.

    Args:
        split: ``"report"`` (20 seeds per trajectory), ``"tuning"`` (20 seeds per trajectory, disjoint
            from the report seeds) or ``"smoke"`` (one seed).
        seeds: the split's seeds instead of its default ones (:func:`check_seeds`).
    """
    if frames < 10:
        raise ValueError(f"frames: expected at least 10 (an occlusion needs room to start and end), got {frames}")
    entries = []
    for traj in OCCLUSION_TRAJECTORIES:
        for seed in _seeds(split, seeds):
            occ = OCCLUSION_KINDS[seed % len(OCCLUSION_KINDS)]
            spec = SequenceSpec(trajectory=traj, frames=frames, fps=fps, occlusion=occ, seed=seed)
            entries.append(SuiteEntry(f"{traj}_{occ}_s{seed}", spec, split))
    return entries


def edge_on_seeds(split: str, count: int, frames: int = 60, fps: float = 30.0) -> list[int]:
    """The first ``count`` seeds of the split's pool whose tumble starts within ``EDGE_ON_BELOW_DEG``
    of edge-on (the views where the truss shows least and both the tracker and the CNN struggle)."""
    from ..objects import load_object, view_elevation_deg
    from ..registry import create

    obj = load_object("truss")
    out = []
    for seed in EDGE_ON_POOLS[split]:
        first = create("trajectory", "tumble", duration_s=frames / fps, rng=seed).pose_at(0.0)
        if view_elevation_deg(first, obj) < EDGE_ON_BELOW_DEG:
            out.append(seed)
            if len(out) == count:
                return out
    raise RuntimeError(f"only {len(out)} edge-on starts in the {split} pool; widen EDGE_ON_POOLS")


def standard_suite(split: str = "report", frames: int = 60, fps: float = 30.0, seeds=None) -> list[SuiteEntry]:
    """:func:`occlusion_suite` plus distance sweep, eclipse, fast tumble and edge-on starts (no arm);
    ``seeds`` as there (the edge-on kind then takes as many of its split's pool)."""
    seeds = _seeds(split, seeds)
    entries = occlusion_suite(split, frames, fps, seeds)
    for seed in seeds:
        entries.append(SuiteEntry(f"distance-sweep_none_s{seed}",
                                  SequenceSpec("distance-sweep", frames=frames, fps=fps, seed=seed), split))
        entries.append(SuiteEntry(f"tumble-eclipse_none_s{seed}",
                                  SequenceSpec("tumble", frames=frames, fps=fps, lighting="eclipse", seed=seed), split))
        entries.append(SuiteEntry(f"tumble-fast_none_s{seed}",
                                  SequenceSpec("tumble", frames=frames, fps=fps, seed=seed,
                                               trajectory_kwargs={"rate_deg_s": FAST_RATE_DEG_S}), split))
    for seed in edge_on_seeds(split if split in EDGE_ON_POOLS else "report", len(seeds), frames, fps):
        entries.append(SuiteEntry(f"tumble-edgeon_none_s{seed}", SequenceSpec("tumble", frames=frames, fps=fps, seed=seed),
                                  split))
    return entries


def smoke_suite(frames: int = 12) -> list[SuiteEntry]:
    """Three short sequences (a partial arm pass, an eclipse, a fast tumble): the machinery, in seconds."""
    seed = SMOKE_SEEDS[0]
    return [
        SuiteEntry(f"tumble_arm-partial_s{seed}", SequenceSpec("tumble", frames=frames, fps=15.0, occlusion="arm-partial",
                                                               seed=seed), "smoke"),
        SuiteEntry(f"tumble-eclipse_none_s{seed}", SequenceSpec("tumble", frames=frames, fps=15.0, lighting="eclipse",
                                                                seed=seed), "smoke"),
        SuiteEntry(f"tumble-fast_none_s{seed}", SequenceSpec("tumble", frames=frames, fps=15.0, seed=seed,
                                                             trajectory_kwargs={"rate_deg_s": FAST_RATE_DEG_S}), "smoke"),
    ]


def realistic_suite(split: str = "report", seeds=None) -> list[SuiteEntry]:
    """The hand-held kinds of :data:`REALISTIC_KINDS`, one sequence per seed (``seeds``: instead of
    the split's :data:`REALISTIC_SEEDS`, checked against :data:`REALISTIC_TUNING_RANGE`)."""
    from ..render.handheld import HandheldSpec

    if split not in REALISTIC_SEEDS:
        raise ValueError(f"split: expected one of {sorted(REALISTIC_SEEDS)}, got {split!r}")
    seeds = REALISTIC_SEEDS[split] if seeds is None else check_seeds(seeds, split, REALISTIC_TUNING_RANGE)
    return [SuiteEntry(f"{kind}_s{seed}", HandheldSpec(frames=REALISTIC_FRAMES, seed=seed, **options), split, part)
            for kind, (part, options) in REALISTIC_KINDS.items() for seed in seeds]


def split_seeds(name: str, split: str) -> tuple[int, ...]:
    """The default seeds of suite ``name``'s ``split``."""
    if name == "realistic":
        return REALISTIC_SEEDS[split]
    return SMOKE_SEEDS if name == "smoke" else _seeds(split)


def suite(name: str, split: str = "report", seeds=None) -> list[SuiteEntry]:
    """The named suite (:data:`SUITES`) on ``split`` (:data:`SPLITS`; ignored by ``smoke``), on
    ``seeds`` instead of the split's default ones where given (:func:`check_seeds`)."""
    if name not in SUITES:
        raise ValueError(f"suite: expected one of {', '.join(SUITES)}, got {name!r}")
    if split not in SPLITS:
        raise ValueError(f"split: expected one of {', '.join(SPLITS)}, got {split!r}")
    if name == "smoke":
        if seeds is not None:
            raise ValueError("--seeds: the smoke suite has its own seeds; use --suite standard or occlusion")
        return smoke_suite()
    if name == "realistic":
        return realistic_suite(split, seeds)
    return standard_suite(split, seeds=seeds) if name == "standard" else occlusion_suite(split, seeds=seeds)


def render_suite(entries: list[SuiteEntry], root, camera: Camera | None = None,
                 progress: Callable[[str], None] | None = None) -> dict[str, Path]:
    """Render (or reuse, resuming where interrupted) every entry under ``root/<name>`` (hand-held
    entries under ``root/handheld-photos/<name>``, or ``handheld-procedural`` without scikit-image's
    photos).

    Returns ``{name: scene_dir}`` (the BOP scene folder holding ``rgb/``, ``scene_gt.json``, ...).
    """
    from ..datasets import render_sequence_dataset
    from ..datasets.handheld import render_handheld_dataset, sample_photos
    from ..objects import load_object

    camera = camera or Camera.default()
    root = Path(root)
    objects, photos, scenes = {}, None, {}
    for e in entries:
        if e.object not in objects:
            objects[e.object] = load_object(e.object)
        if isinstance(e.spec, SequenceSpec):
            scenes[e.name] = render_sequence_dataset(root / e.name, objects[e.object], camera, e.spec)
        else:
            photos = photos or sample_photos(root / "photos")
            where = root / ("handheld-photos" if photos else "handheld-procedural") / e.name
            scenes[e.name] = render_handheld_dataset(where, objects[e.object], camera, e.spec, photos)
        if progress:
            progress(e.name)
    return scenes
