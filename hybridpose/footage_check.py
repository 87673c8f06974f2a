"""A fitted network checked on the user's own footage, without labels (``hybridpose fit --video FILE``).

Renders are not the world: a fit's held-out renders say how it does on views like its training views,
not on the user's camera, lighting and scene. With no ground truth on the user's video, the check asks
what the hybrid itself would ask at a start: on frames spread over the video, does the CNN find the
part, and does the tracker's fit from the CNN's pose confirm it (:meth:`HybridEstimator.step` from a
fresh start, the same policy as ``hybridpose track``)? A confirmed start is the tracker's verdict, not
the truth, but a network whose answers the tracker never confirms will not start the hybrid there.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .geometry import Camera
from .objects import ObjectModel

CHECK_FRAMES = 40  # frames checked, evenly spaced over the video


@dataclass(frozen=True)
class FootageCheck:
    """What :func:`check_on_footage` found: ``frames`` checked (of ``video_frames``), the CNN ``found``
    the part (a pose) on some, the tracker ``confirmed`` the start from it on some; ``confirmed_at``:
    their frame indices; ``ms_per_frame``: CNN and confirmation together."""

    source: str
    video_frames: int
    frames: int
    found: int
    confirmed: int
    confirmed_at: tuple[int, ...]
    tracker: str
    ms_per_frame: float

    def text(self) -> str:
        """The report's paragraph."""
        if self.frames == 0:
            return f"On `{self.source}`: no frames to check."
        share = 100.0 * self.confirmed / self.frames
        first = f"; the first at frame {self.confirmed_at[0]}" if self.confirmed_at else ""
        return (f"On your footage (`{self.source}`, {self.frames} of its {self.video_frames} frames, evenly spaced; "
                f"no labels): the CNN gave a pose on {self.found} and the `{self.tracker}` tracker confirmed the "
                f"start from it on **{self.confirmed} ({share:.0f} %)**{first} — where the hybrid can start "
                f"({self.ms_per_frame:.0f} ms a frame). A confirmed start is the tracker's verdict, not ground "
                "truth; none confirmed means the hybrid will not start on this footage: fit with photos like "
                "its scenes (`--backgrounds`), more views printed if the part is printed (`--textured-share 0.5`), "
                "its distances (`--distances`), a longer budget, or refine it on this footage from the part's "
                "pose in its first frame (`--refine-on VIDEO --init-pose FILE`).")


class _Remembering:
    """A regressor that remembers whether any of its answers since :meth:`forget` had a pose (the
    start's CNN call inside the estimator), so that the check asks the CNN once a frame."""

    def __init__(self, regressor) -> None:
        self.regressor, self.found = regressor, False
        self.hybrid_config = regressor.hybrid_config

    def forget(self) -> None:
        self.found = False

    def predict(self, frame, *args, **kwargs):
        m = self.regressor.predict(frame, *args, **kwargs)
        self.found = self.found or m.pose is not None
        return m


def _count_frames(source) -> int:
    from .tracking import _raw_frames

    return sum(1 for _ in _raw_frames(source, None))


def check_on_footage(source, obj: ObjectModel, camera: Camera, regressor: str, tracker: str = "combined",
                     frames: int = CHECK_FRAMES) -> FootageCheck:
    """Check the network ``regressor`` (a checkpoint path or registered name) on ``frames`` frames spread
    evenly over the video or image folder ``source`` (``camera``: its camera): each frame is a fresh
    start of the hybrid (``tracker``; the checkpoint's recommended policy), counted confirmed where the
    start gives a pose. ValueError naming ``video`` for a source with no frames."""
    from .estimator import HybridEstimator
    from .tracking import read_frames

    if frames < 1:
        raise ValueError(f"frames: expected ≥ 1 frames to check, got {frames}")
    total = _count_frames(source)
    if total == 0:
        raise ValueError(f"video: {source} holds no frames")
    chosen = set(np.linspace(0, total - 1, min(frames, total)).round().astype(int).tolist())
    built = HybridEstimator.from_names(object=obj, tracker=tracker, regressor=regressor)
    cnn = _Remembering(built.regressor)
    est = HybridEstimator(built.tracker, cnn, built.fusion, config=built.config)
    found = confirmed = 0
    at, ms = [], []
    for k, frame in enumerate(read_frames(source, camera)):
        if k not in chosen:
            continue
        t0 = time.perf_counter()
        est.reset()
        cnn.forget()
        e = est.step(frame)
        found += cnn.found
        if e.pose is not None:
            confirmed += 1
            at.append(k)
        ms.append(1000 * (time.perf_counter() - t0))
    return FootageCheck(str(source), total, len(ms), int(found), confirmed, tuple(at), tracker,
                        float(np.mean(ms)) if ms else float("nan"))
