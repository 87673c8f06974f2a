"""Run the hybrid estimator over a video or image folder and write what it saw.

Outputs in ``out``: ``overlay.webm`` (or ``overlay.mp4`` where OpenCV has H.264): the model's edges
at the estimated pose, coloured by status (green tracking, yellow init/reinit, red lost: the
predicted pose), one label per frame; ``poses.csv`` (metres, quaternion w, x, y, z, status) and BOP
``scene_gt.json`` (mm, frames with a trusted pose). All written atomically.
"""
from __future__ import annotations

import csv
import io
import logging
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from .core import Estimate, Frame
from .io import atomic_write_json, atomic_write_text
from .viz import draw_wireframe, put_label

log = logging.getLogger(__name__)

STATUS_COLOURS = {"tracking": (60, 255, 60), "init": (255, 220, 0), "reinit": (255, 220, 0), "lost": (255, 60, 60)}
CSV_FIELDS = ["frame", "timestamp_s", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m", "status", "sources", "ms"]
# browsers play H.264 .mp4 and VP9/VP8 .webm; MPEG-4 Part 2 ('mp4v') only as a last resort
VIDEO_CODECS = (("avc1", ".mp4"), ("VP90", ".webm"), ("VP80", ".webm"), ("mp4v", ".mp4"))


class VideoFile:
    """An RGB video written to a temporary file and renamed to ``<stem><ext>`` on :meth:`close`, in
    the first codec of :data:`VIDEO_CODECS` this OpenCV build can write."""

    def __init__(self, stem, fps: float, size: tuple[int, int]) -> None:
        self.stem = Path(stem)
        self.stem.parent.mkdir(parents=True, exist_ok=True)
        for fourcc, ext in VIDEO_CODECS:
            fd, tmp = tempfile.mkstemp(dir=self.stem.parent, prefix=f".{self.stem.name}.", suffix=ext)
            os.close(fd)
            writer = _quiet_video_writer(tmp, fourcc, float(fps), tuple(size))
            if writer.isOpened():
                self.writer, self.tmp, self.path, self.codec = writer, Path(tmp), self.stem.with_suffix(ext), fourcc
                if fourcc == "mp4v":
                    log.warning("this OpenCV writes neither H.264 nor VP9/VP8: %s is MPEG-4 Part 2, which "
                                "browsers do not play (VLC and ffplay do)", self.path)
                return
            writer.release()
            Path(tmp).unlink(missing_ok=True)
        raise RuntimeError(f"{self.stem}: OpenCV cannot write any of {[c for c, _ in VIDEO_CODECS]}")

    def write(self, rgb: np.ndarray) -> None:
        self.writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))

    def close(self, keep: bool = True) -> Path:
        self.writer.release()
        if keep:
            os.chmod(self.tmp, 0o644)
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)
        return self.path


def draw_estimate(frame: Frame, obj, e: Estimate, label: str | None) -> np.ndarray:
    """The frame with the model's edges at ``e.pose`` in the status colour and, unless ``label`` is
    None (a caller that labels after resizing), one label line."""
    img = frame.image
    if e.pose is not None:
        img = draw_wireframe(img, obj, e.pose, frame.camera, STATUS_COLOURS[e.status])
    return img if label is None else put_label(img, f"{label}  {e.status.upper()}")


def _quiet_video_writer(path: str, fourcc: str, fps: float, size) -> cv2.VideoWriter:
    """``cv2.VideoWriter``, with FFmpeg's complaints about codecs it lacks (printed straight to the
    process's stderr while probing) kept off the user's terminal."""
    try:
        saved = os.dup(2)
    except OSError:
        return cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*fourcc), fps, size)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            return cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*fourcc), fps, size)
    finally:
        os.dup2(saved, 2)
        os.close(saved)


@dataclass
class HybridRunResult:
    frames: int
    lost: int
    reinits: int
    ms_per_frame: float
    video: Path
    out: Path


def run_hybrid_on_frames(frames: Iterator[Frame], estimator, out, max_frames: int | None = None,
                         progress: Callable[[int], None] | None = None,
                         on_frame: Callable[[Frame, Estimate, np.ndarray], None] | None = None) -> HybridRunResult:
    """``estimator.step`` over ``frames`` (no initial pose); writes the overlay video, ``poses.csv`` and
    ``scene_gt.json`` to ``out``. ``on_frame(frame, estimate, overlay_rgb)`` is called for every frame."""
    from .datasets.bop import pose_to_bop

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows, scene_gt, video, ms, lost, reinits = [], {}, None, [], 0, 0
    obj = estimator.object
    try:
        for k, frame in enumerate(frames):
            if max_frames is not None and k >= max_frames:
                break
            if video is None:
                video = VideoFile(out / "overlay", 30.0, (frame.camera.width, frame.camera.height))
            e = estimator.step(frame)
            ms.append(e.timings_ms["total"])
            lost += int(e.status == "lost")
            reinits += int(e.status == "reinit")
            p = e.pose
            cells = ([f"{v:.9f}" for v in p.quat_wxyz] + [f"{v:.6f}" for v in p.t]) if p is not None else [""] * 7
            rows.append([frame.index, f"{frame.timestamp:.6f}", *cells, e.status, "+".join(e.sources),
                         f"{e.timings_ms['total']:.2f}"])
            if p is not None and e.status != "lost":
                scene_gt[str(frame.index)] = [{"obj_id": 1, **pose_to_bop(p)}]
            overlay = draw_estimate(frame, obj, e, f"#{frame.index}")
            video.write(overlay)
            if on_frame:
                on_frame(frame, e, overlay)
            if progress:
                progress(k + 1)
        if not rows:
            raise ValueError("source: no frames to track")
        path = video.close()
        video = None
    finally:
        if video is not None:
            video.close(keep=False)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_FIELDS)
    w.writerows(rows)
    atomic_write_text(out / "poses.csv", buf.getvalue())
    atomic_write_json(out / "scene_gt.json", scene_gt)
    return HybridRunResult(frames=len(rows), lost=lost, reinits=reinits, ms_per_frame=float(np.mean(ms)), video=path,
                           out=out)
