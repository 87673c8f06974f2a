"""Render datasets to disk in BOP format: random views (CNN training) and sequences (tracking).

Jobs are deterministic (poses from ``seed``, per-image noise from ``(seed, index)``), write every
file atomically and **resume**: re-running the same command skips images already done; a
different configuration in the same ``out`` is refused.
"""
from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable

import numpy as np

from ..geometry import Camera, Pose
from ..io import atomic_write_json, read_json
from ..objects import ObjectModel
from ..render import Renderer, SensorModel, SpaceLighting, random_poses
from ..render.appearance import AppearanceSpec
from ..render.camera_effects import camera_effects
from ..render.occluder import ArmState, arm_state
from ..render.sequences import SequenceSpec, make_sequence
from ..workers import spawn_pool
from .bop import BopSceneWriter, write_camera_json, write_models
from .labels import Label, write_labels

log = logging.getLogger(__name__)

CONFIG_FILE = "hybridpose.json"
CHECKPOINT_EVERY = 25  # images per work unit
FLUSH_EVERY_S = 10.0  # the scene JSONs are rewritten whole: at 40k images each rewrite takes ~0.5 s


def _open_job(out: Path, kind: str, obj: ObjectModel, camera: Camera, lighting: SpaceLighting,
              sensor: SensorModel, **params) -> None:
    """Record the job's configuration in ``out/hybridpose.json``, or refuse when ``out`` already
    holds a job with another configuration (a resume must be the same job)."""
    claim_folder(out, {"kind": kind, "object": obj.name, "camera": camera.to_dict(), **params,
                       "lighting": {**asdict(lighting), "sun_direction_cam": list(lighting.sun_direction_cam)},
                       "sensor": asdict(sensor)})


def claim_folder(out: Path, config: dict) -> None:
    """Record a job's ``config`` in ``out/hybridpose.json``, or refuse (ValueError naming ``out``) when
    ``out`` already holds a job with another configuration."""
    out.mkdir(parents=True, exist_ok=True)
    config = json.loads(json.dumps(config))  # as read back: tuples are lists
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


def _render_chunk(scene_dir: Path, obj: ObjectModel, camera: Camera, chunk, seed: int,
                  lighting: SpaceLighting, sensor: SensorModel, looks: AppearanceSpec) -> BopSceneWriter:
    """Worker process: render and write the images of ``chunk`` ([(index, item), ...]); returns a
    writer holding only their ground-truth records (the parent merges and flushes them)."""
    writer = BopSceneWriter(scene_dir, camera, load=False)
    with Renderer(obj, camera, lighting, sensor) as renderer:
        for _ in _render_into(renderer, writer, obj, chunk, seed, looks):
            pass
    return writer


def _render_into(renderer: Renderer, writer: BopSceneWriter, obj: ObjectModel, chunk, seed: int,
                 looks: AppearanceSpec):
    """Render the images of ``chunk`` ([(index, item), ...]) into ``writer``, yielding after each."""
    cam = renderer.camera
    for i, (pose, arm, sun, sun_dir) in chunk:
        res = renderer.render(pose, arm=arm, sun_scale=sun, rng=np.random.default_rng([seed, i]),
                              sun_direction_cam=sun_dir, appearance=looks.draw(cam.width, cam.height, seed, i))
        rgb = (camera_effects(res.rgb, np.random.default_rng([seed, i, 31]), looks.grey_share)
               if looks.camera_effects else res.rgb)
        writer.write(i, rgb, res.depth, res.mask, res.mask_visib, pose, obj.vertices)
        yield i


def _flush_now(writer: BopSceneWriter, last_flush: float) -> float:
    """Flush ``writer`` when ``FLUSH_EVERY_S`` has passed since ``last_flush``; returns the flush time."""
    if time.monotonic() - last_flush < FLUSH_EVERY_S:
        return last_flush
    writer.flush()
    return time.monotonic()


def _run_job(
    out: Path,
    split: str,
    obj: ObjectModel,
    camera: Camera,
    items: list[tuple[Pose, ArmState | None, float, np.ndarray | None]],
    seed: int,
    lighting: SpaceLighting,
    sensor: SensorModel,
    progress: Callable[[int, int], None] | None,
    workers: int = 1,
    looks: AppearanceSpec = AppearanceSpec(),
) -> Path:
    if workers < 1:
        raise ValueError(f"workers: expected ≥ 1 processes, got {workers}")
    scene_dir = out / split / "000000"
    writer = BopSceneWriter(scene_dir, camera)
    todo = [i for i in range(len(items)) if not writer.done(i)]
    if len(todo) < len(items):
        log.info("resuming %s: %d of %d images already rendered", out, len(items) - len(todo), len(items))
    write_models(out, obj)
    write_camera_json(out, camera)
    chunks = [[(i, items[i]) for i in todo[k:k + CHECKPOINT_EVERY]] for k in range(0, len(todo), CHECKPOINT_EVERY)]
    done, last_flush = len(items) - len(todo), time.monotonic()
    if workers == 1 or len(chunks) <= 1:
        # one process: a single renderer (GL context) for the whole job
        with Renderer(obj, camera, lighting, sensor) as renderer:
            for chunk in chunks:
                for _ in _render_into(renderer, writer, obj, chunk, seed, looks):
                    done += 1
                    if progress:
                        progress(done, len(items))
                last_flush = _flush_now(writer, last_flush)
    else:
        # Worker processes render chunks and write the image files; the parent alone merges their
        # records and rewrites the scene JSONs, so a stop loses at most the chunks in flight.
        # "spawn": a forked GL context is not safe.
        with spawn_pool(workers) as pool:
            jobs = [pool.apply_async(_render_chunk, (scene_dir, obj, camera, chunk, seed, lighting, sensor, looks))
                    for chunk in chunks]
            for chunk, job in zip(chunks, jobs):
                writer.merge(job.get())
                last_flush = _flush_now(writer, last_flush)
                done += len(chunk)
                if progress:
                    progress(done, len(items))
    writer.flush()
    labels = [Label(f"{split}/000000/rgb/{i:06d}.png", items[i][0]) for i in range(len(items))]
    write_labels(out / "labels.csv", labels)
    return scene_dir


def sun_directions_in_cone(axis, cone_deg: float, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count, 3) unit directions uniform on the spherical cap of half-angle ``cone_deg`` around ``axis``."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    cos_t = rng.uniform(np.cos(np.deg2rad(cone_deg)), 1.0, count)
    phi = rng.uniform(0, 2 * np.pi, count)
    sin_t = np.sqrt(1 - cos_t**2)
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    return (cos_t[:, None] * axis + (sin_t * np.cos(phi))[:, None] * e1 + (sin_t * np.sin(phi))[:, None] * e2)


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
    sun_cone_deg: float = 0.0,
    sun_scale_range: tuple[float, float] = (1.0, 1.0),
    in_view: bool = False,
    workers: int = 1,
    elevation_range_deg: tuple[float, float] | None = None,
    appearance: AppearanceSpec | None = None,
    occluded_share: float = 0.0,
    log_depth: bool = False,
) -> Path:
    """``count`` random views within arm's reach (split ``train``) + ``labels.csv``; resumable.

    ``in_view`` keeps the whole object in the image (its bounding-box corners project inside);
    otherwise only its centre is. ``elevation_range_deg`` (low, high) keeps only views seen that
    far from edge-on (:func:`~hybridpose.objects.view_elevation_deg`), e.g. ``(0, 20)`` to render
    more of the near edge-on views where a flat object's pose is hardest. ``sun_cone_deg`` > 0 draws each image's sun direction uniformly within that cone around
    ``lighting.sun_direction_cam`` (up to 180°: beyond 90° around the optical axis the cone holds
    side- and back-lit views) and ``sun_scale_range`` its intensity factor, so a network
    trained on the data does not learn one shading; each image's sun (unit direction the light
    travels, camera frame, and intensity factor) is recorded in ``<scene>/scene_meta.json``.
    ``workers`` > 1 renders in that many processes (identical images: each image's noise is seeded
    by its index). ``appearance`` ``AppearanceSpec("random", backgrounds=DIR)`` draws each image's
    background, ambient and fill lights and part colour (:mod:`hybridpose.render.appearance`): data
    for a part on a bench or in a hand rather than in space. ``occluded_share`` of the views (a
    seeded draw per view) have the arm's tool and forearm in front of part of the object
    (:func:`random_partial_occluder`): a network that has seen the part cut by something in front
    of it still finds it when a hand or the arm covers it. ``log_depth`` draws the depth's logarithm
    uniformly in ``distance_range_m`` (:func:`random_poses`). Returns the scene directory.
    """
    appearance = appearance or AppearanceSpec()
    if count < 1:
        raise ValueError(f"count: expected ≥ 1 images, got {count}")
    if not 0.0 <= occluded_share <= 1.0:
        raise ValueError(f"occluded_share: expected a share of the views in [0, 1], got {occluded_share}")
    if not 0 <= sun_cone_deg <= 180:
        raise ValueError(f"sun_cone_deg: expected 0..180 degrees (180: the sun anywhere), got {sun_cone_deg}")
    lo, hi = sun_scale_range
    if not 0 <= lo <= hi:
        raise ValueError(f"sun_scale_range: expected 0 ≤ low ≤ high, got {sun_scale_range}")
    out = Path(out)
    lighting, sensor = lighting or SpaceLighting(), sensor or SensorModel()
    _open_job(out, "random", obj, camera, lighting, sensor, count=count, seed=seed,
              distance_range_m=list(distance_range_m), sun_cone_deg=float(sun_cone_deg),
              sun_scale_range=[float(lo), float(hi)], in_view=bool(in_view),
              # recorded only when set, so that datasets written before the option still resume
              **({} if elevation_range_deg is None
                 else {"elevation_range_deg": [float(v) for v in elevation_range_deg]}),
              **({} if appearance == AppearanceSpec() else {"appearance": appearance.record()}),
              **({} if occluded_share == 0 else {"occluded_share": float(occluded_share)}),
              **({"log_depth": True} if log_depth else {}))
    poses = random_poses(count, camera, distance_range_m, rng=seed, in_view_points=obj.bbox_corners if in_view else None,
                         elevation_range_deg=elevation_range_deg, obj=obj, log_depth=log_depth)
    # lighting draws use their own stream so that the poses of a seed never change
    sun_rng = np.random.default_rng([seed, 7])
    dirs = (sun_directions_in_cone(lighting.sun_direction_cam, sun_cone_deg, count, sun_rng)
            if sun_cone_deg > 0 else [None] * count)
    scales = sun_rng.uniform(lo, hi, count) if hi > lo else np.full(count, lo)
    # occluders from a stream of their own too: the poses and suns of a seed stay as they were
    occ_rng = np.random.default_rng([seed, 11])
    arms = [random_partial_occluder(p, obj.diameter / 2, camera, occ_rng) if occ_rng.random() < occluded_share else None
            for p in poses] if occluded_share > 0 else [None] * len(poses)
    items = [(p, a, float(k), d) for p, a, k, d in zip(poses, arms, scales, dirs)]
    scene_dir = _run_job(out, "train", obj, camera, items, seed, lighting, sensor, progress, workers, appearance)
    default_dir = list(lighting.sun_direction_cam)
    # Each image's sun, so that an evaluation can report error against the lighting geometry
    # (phase angle, where the light comes from in the image): written last, from the same draws.
    meta = {str(i): {"sun_direction_cam": default_dir if d is None else [float(x) for x in d / np.linalg.norm(d)],
                     "sun_scale": float(k)} for i, (_, _, k, d) in enumerate(items)}
    atomic_write_json(scene_dir / "scene_meta.json", {"frames": meta})
    return scene_dir


def random_partial_occluder(pose: Pose, object_radius_m: float, camera: Camera, rng: np.random.Generator) -> ArmState:
    """The arm somewhere on its way in front of the object at ``pose`` (T_cam_obj): the partial
    occlusion's tool (about half the object's apparent size, beside its centre), from the left or
    the right, at 30–70 % of the object's distance, between parked beside the view and holding
    (:func:`~hybridpose.render.occluder.arm_state`); it may miss the object altogether."""
    return arm_state(pose.t, object_radius_m, progress=float(rng.uniform(0.1, 0.5)), coverage="partial",
                     side=int(rng.choice((-1, 1))), depth_fraction=float(rng.uniform(0.3, 0.7)),
                     hfov_deg=camera.hfov_deg)


def render_sequence_dataset(
    out,
    obj: ObjectModel,
    camera: Camera,
    spec: SequenceSpec,
    lighting: SpaceLighting | None = None,
    sensor: SensorModel | None = None,
    progress: Callable[[int, int], None] | None = None,
    workers: int = 1,
    appearance: AppearanceSpec | None = None,
) -> Path:
    """A rendered sequence (split ``test``) with timestamps and occlusion per frame; resumable.

    Per-frame extras (timestamp, occlusion state, sun factor and direction) go to ``<scene>/scene_meta.json``.
    ``appearance`` ``AppearanceSpec("random", ...)`` gives the whole sequence one drawn look (background,
    lights, part colour: a camera watching a part on a bench), whatever its ``fixed``.
    """
    out = Path(out)
    lighting, sensor = lighting or SpaceLighting(), sensor or SensorModel()
    looks = replace(appearance, fixed=True) if appearance is not None else AppearanceSpec()
    _open_job(out, "sequence", obj, camera, lighting, sensor, spec=asdict(spec),
              **({} if looks == AppearanceSpec() else {"appearance": looks.record()}))
    frames = make_sequence(spec, obj, camera)
    items = [(f.pose, f.arm, f.sun_scale, None) for f in frames]
    scene_dir = _run_job(out, "test", obj, camera, items, spec.seed, lighting, sensor, progress, workers, looks)
    meta = {str(f.index): {"timestamp_s": f.timestamp, "occlusion": f.occlusion, "sun_scale": f.sun_scale,
                           "sun_direction_cam": list(lighting.sun_direction_cam)} for f in frames}
    atomic_write_json(scene_dir / "scene_meta.json", {"fps": spec.fps, "frames": meta})
    return scene_dir
