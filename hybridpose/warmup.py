"""Compile the numba kernels before the first frame, not in it.

The edge fits, the combined tracker's solver, the camera projections and the UKF run as numba
kernels, compiled on first use and cached next to the package (``__pycache__``). On a fresh install
the first frame would pay the compilation (15–35 s on a 2-core CPU) and hide it in a mean; with the
cache warm it costs milliseconds. :func:`warm_up` runs every kernel once on a small drawn scene (a cube
seen by a 160 × 120 camera, no renderer): ``hybridpose track`` and ``hybridpose demo`` call it before
their first frame and say how long it took where it took long; in Python, call it before the loop.
"""
from __future__ import annotations

import time

import numpy as np

COMPILE_NOTICE_S = 1.0  # a warm-up this long compiled something: worth telling the user


def _drawn_frame(view, camera, pose, index: int, sun=None):
    """The cube at ``pose`` drawn as flat-shaded faces (grey level per facet) on a dark ground."""
    from .core import Frame

    ids = view.facet_ids(pose, camera, scale=1.0)
    grey = np.where(ids > 0, 60 + (ids.astype(np.int64) * 37) % 180, 20).astype(np.uint8)
    return Frame(np.repeat(grey[..., None], 3, axis=2), camera, index / 30.0, index, sun)


def warm_up(trackers=("edges", "combined"), fusions=("ukf", "isam2")) -> float:
    """Run each named tracker and fusion once (two frames, one update) on a drawn cube, so that their
    compiled kernels are built or loaded from the cache; returns the seconds it took."""
    from .core import Measurement
    from .edges import ModelView, sunlit_agreement
    from .geometry import Camera, Pose
    from .objects import load_object
    from .registry import create

    t0 = time.perf_counter()
    cube = load_object("cube")
    camera = Camera(160, 120, 150.0, 150.0, 79.5, 59.5)
    view = ModelView(cube)
    poses = [Pose.from_rotvec_t([0.5, 0.4, 0.1], [0.0, 0.0, 0.5]), Pose.from_rotvec_t([0.52, 0.41, 0.1], [0.004, 0.0, 0.5])]
    for sun in (None, [0.6, 0.4, 0.7]):  # the edge fits take other paths where the sun is known
        frames = [_drawn_frame(view, camera, p, k, sun) for k, p in enumerate(poses)]
        for name in trackers:
            tracker = create("tracker", name, object=cube)
            tracker.init(frames[0], poses[0])
            tracker.track(frames[1])
        if sun is not None:  # the hybrid's check of a new start against the sunlit surface (shadow map)
            sunlit_agreement(view, frames[1], poses[1])
    cov = np.diag([1e-4] * 3 + [1e-6] * 3)
    for name in fusions:
        fusion = create("fusion", name)
        fusion.reset(poses[0], cov, 0.0)
        fusion.predict(1 / 30)
        fusion.update(Measurement(poses[1], cov, 1.0, "warm-up", 1 / 30))
    return time.perf_counter() - t0
