"""Render datasets to disk in BOP format: random views (CNN training) and sequences (tracking).

Jobs are deterministic (poses from ``seed``, per-image noise from ``(seed, index)``), write every
file atomically and **resume**: re-running the same command skips images already done; a
different configuration in the same ``out`` is refused.
"""
from __future__ import annotations

import logging
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np

from ..geometry import Camera, Pose
from ..io import atomic_write_json, read_json
from ..objects import ObjectModel
from ..render import Renderer, SensorModel, SpaceLighting, random_poses
from ..render.occluder import ArmState
from ..render.sequences import SequenceSpec, make_sequence
from .bop import BopSceneWriter, write_camera_json, write_models
from .labels import Label, write_labels

log = logging.getLogger(__name__)

CONFIG_FILE = "hybridpose.json"
CHECKPOINT_EVERY = 25


def _open_job(out: Path, kind: str, obj: ObjectModel, camera: Camera, lighting: SpaceLighting,
              sensor: SensorModel, **params) -> None:
    """Record the job's configuration in ``out/hybridpose.json``, or refuse when ``out`` already
    holds a job with another configuration (a resume must be the same job)."""
    config = {"kind": kind, "object": obj.name, "camera": camera.to_dict(), **params,
              "lighting": {**asdict(lighting), "sun_direction_cam": list(lighting.sun_direction_cam)},
              "sensor": asdict(sensor)}
    out.mkdir(parents=True, exist_ok=True)
    path = out / CONFIG_FILE
    if path.exists():
        old = read_json(path)
        diff = sorted(k for k in set(old) | set(config) if old.get(k) != config.get(k))
        if diff:
            raise ValueError(
                f"out: {out} already holds a different dataset (differs in: {', '.join(diff)}); "
                "choose another --out or delete it"
            )
    else:
        atomic_write_json(path, config)


def _run_job(
    out: Path,
    split: str,
    obj: ObjectModel,
    camera: Camera,
    items: list[tuple[Pose, ArmState | None, float]],
    seed: int,
    lighting: SpaceLighting,
    sensor: SensorModel,
    progress: Callable[[int, int], None] | None,
) -> Path:
    scene_dir = out / split / "000000"
    writer = BopSceneWriter(scene_dir, camera)
    todo = [i for i in range(len(items)) if not writer.done(i)]
    if len(todo) < len(items):
        log.info("resuming %s: %d of %d images already rendered", out, len(items) - len(todo), len(items))
    write_models(out, obj)
    write_camera_json(out, camera)
    if todo:
        with Renderer(obj, camera, lighting, sensor) as renderer:
            for n, i in enumerate(todo, 1):
                pose, arm, sun = items[i]
                res = renderer.render(pose, arm=arm, sun_scale=sun, rng=np.random.default_rng([seed, i]))
                writer.write(i, res.rgb, res.depth, res.mask, res.mask_visib, pose, obj.vertices)
                if n % CHECKPOINT_EVERY == 0:
                    writer.flush()
                if progress:
                    progress(len(items) - len(todo) + n, len(items))
    writer.flush()
    labels = [Label(f"{split}/000000/rgb/{i:06d}.png", items[i][0]) for i in range(len(items))]
    write_labels(out / "labels.csv", labels)
    return scene_dir


def render_random_dataset(
    out,
    obj: ObjectModel,
    camera: Camera,
    count: int,
    seed: int = 0,
    distance_range_m: tuple[float, float] = (0.3, 1.2),
    lighting: SpaceLighting | None = None,
    sensor: SensorModel | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """``count`` random views within arm's reach (split ``train``) + ``labels.csv``; resumable.

    Returns the scene directory.
    """
    if count < 1:
        raise ValueError(f"count: expected ≥ 1 images, got {count}")
    out = Path(out)
    lighting, sensor = lighting or SpaceLighting(), sensor or SensorModel()
    _open_job(out, "random", obj, camera, lighting, sensor, count=count, seed=seed,
              distance_range_m=list(distance_range_m))
    poses = random_poses(count, camera, distance_range_m, rng=seed)
    items = [(p, None, 1.0) for p in poses]
    return _run_job(out, "train", obj, camera, items, seed, lighting, sensor, progress)


def render_sequence_dataset(
    out,
    obj: ObjectModel,
    camera: Camera,
    spec: SequenceSpec,
    lighting: SpaceLighting | None = None,
    sensor: SensorModel | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """A rendered sequence (split ``test``) with timestamps and occlusion per frame; resumable.

    Per-frame extras (timestamp, occlusion state, sun factor) go to ``<scene>/scene_meta.json``.
    """
    out = Path(out)
    lighting, sensor = lighting or SpaceLighting(), sensor or SensorModel()
    _open_job(out, "sequence", obj, camera, lighting, sensor, spec=asdict(spec))
    frames = make_sequence(spec, obj, camera)
    items = [(f.pose, f.arm, f.sun_scale) for f in frames]
    scene_dir = _run_job(out, "test", obj, camera, items, spec.seed, lighting, sensor, progress)
    meta = {str(f.index): {"timestamp_s": f.timestamp, "occlusion": f.occlusion, "sun_scale": f.sun_scale} for f in frames}
    atomic_write_json(scene_dir / "scene_meta.json", {"fps": spec.fps, "frames": meta})
    return scene_dir
