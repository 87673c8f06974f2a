"""``hybridpose track``: follow a user's object through a video file or an image folder.

Inputs are converted at this edge: video/image frames (BGR on disk) → RGB ``Frame``; an initial
pose file in metres (``quat_wxyz`` + ``t_m``, or ``R`` + ``t_m``) or BOP (``cam_R_m2c`` +
``cam_t_m2c`` in mm) → ``Pose``. Outputs: ``overlay.mp4`` (wireframe: green tracking, red lost),
``poses.csv`` (metres, quaternion w, x, y, z) and BOP ``scene_gt.json`` (mm), all written atomically.
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

from ..core import Frame, Measurement
from ..geometry import Camera, Pose
from ..io import atomic_write_json, atomic_write_text, read_json
from ..viz import draw_wireframe, put_label
from .base import Tracker

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
CSV_FIELDS = ["frame", "timestamp_s", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m", "quality", "lost"]


def load_pose(path) -> Pose:
    """Initial ``T_cam_obj`` from JSON: ``{"quat_wxyz": [4], "t_m": [3]}``, ``{"R": [[3]×3], "t_m": [3]}``
    or BOP ``{"cam_R_m2c": [9], "cam_t_m2c": [3] (mm)}``; errors name the file."""
    from ..datasets.bop import pose_from_bop

    data = read_json(path)
    if isinstance(data, list) and data:
        data = data[0]  # a BOP scene_gt entry list
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object with quat_wxyz + t_m, R + t_m, or cam_R_m2c + cam_t_m2c (mm)")
    try:
        if "cam_R_m2c" in data:
            return pose_from_bop(data, where=str(path))
        if "t_m" not in data:
            raise KeyError("t_m")
        if "quat_wxyz" in data:
            return Pose.from_quat_t(data["quat_wxyz"], data["t_m"])
        if "R" in data:
            return Pose(np.asarray(data["R"], dtype=np.float64), np.asarray(data["t_m"], dtype=np.float64))
        raise KeyError("quat_wxyz or R")
    except KeyError as exc:
        raise ValueError(f"{path}: missing {exc.args[0]} (expected quat_wxyz + t_m in metres, R + t_m, "
                         "or BOP cam_R_m2c + cam_t_m2c in mm)") from None
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc


def read_frames(source, camera: Camera, fps: float | None = None) -> Iterator[Frame]:
    """Frames of a video file or an image folder (sorted by name), as RGB, checked against ``camera``.

    Timestamps: frame index / fps (the video's own rate, else ``fps``, else 30).
    """
    source = Path(source)
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise ValueError(f"{source}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
        rate = fps or 30.0
        for i, f in enumerate(files):
            bgr = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if bgr is None:
                raise ValueError(f"{f}: unreadable image")
            yield _frame(bgr, camera, i, rate, f)
        return
    if not source.is_file():
        raise FileNotFoundError(f"{source}: no such video file or image folder")
    if source.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"{source}: expected a video ({', '.join(VIDEO_SUFFIXES)}) or a folder of images")
    cap = cv2.VideoCapture(str(source))
    if not cap.isOpened():
        raise ValueError(f"{source}: OpenCV cannot open this video")
    rate = fps or cap.get(cv2.CAP_PROP_FPS) or 30.0
    try:
        i = 0
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            yield _frame(bgr, camera, i, rate, source)
            i += 1
    finally:
        cap.release()


def _frame(bgr: np.ndarray, camera: Camera, index: int, rate: float, where) -> Frame:
    h, w = bgr.shape[:2]
    if (w, h) != (camera.width, camera.height):
        raise ValueError(f"{where}: frame {index} is {w}×{h} but the camera file says {camera.width}×{camera.height}")
    return Frame(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), camera, index / rate, index)


@dataclass
class TrackResult:
    frames: int
    lost: int
    ms_per_frame: float
    out: Path


def pose_row(frame: Frame, pose: Pose | None, quality: float, lost: bool) -> list:
    """One ``poses.csv`` row (:data:`CSV_FIELDS`); a frame without a pose has empty pose cells."""
    cells = ([f"{v:.9f}" for v in pose.quat_wxyz] + [f"{v:.6f}" for v in pose.t]) if pose is not None else [""] * 7
    return [frame.index, f"{frame.timestamp:.6f}", *cells, f"{quality:.4f}", int(lost)]


def draw_tracking(frame: Frame, obj, m: Measurement, label: str) -> np.ndarray:
    """The frame with the model's edges at the measured pose (green tracking, red lost) and a label."""
    color = (255, 60, 60) if m.lost else (60, 255, 60)
    img = draw_wireframe(frame.image, obj, m.pose, frame.camera, color) if m.pose is not None else frame.image
    return put_label(img, f"{label}  q={m.quality:.2f}{'  LOST' if m.lost else ''}")


def track_sequence(frames: Iterator[Frame], tracker: Tracker, init_pose: Pose, out, max_frames: int | None = None,
                   progress: Callable[[int], None] | None = None,
                   on_frame: Callable[[Frame, Measurement, np.ndarray], None] | None = None) -> TrackResult:
    """Track from ``init_pose`` at the first frame; write overlay.mp4, poses.csv, scene_gt.json to ``out``.

    ``on_frame(frame, measurement, overlay_rgb)`` is called for every frame (e.g. to keep pictures).
    """
    import time

    from ..datasets.bop import pose_to_bop

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows, scene_gt, writer, tmp_video, n_lost, elapsed = [], {}, None, None, 0, 0.0
    try:
        for k, frame in enumerate(frames):
            if max_frames is not None and k >= max_frames:
                break
            if k == 0:
                tracker.init(frame, init_pose)
                m = Measurement(init_pose, np.eye(6) * 1e-6, 1.0, f"tracker:{tracker.name}", frame.timestamp)
                fd, tmp_video = tempfile.mkstemp(dir=out, prefix=".overlay.", suffix=".mp4")
                os.close(fd)
                writer = cv2.VideoWriter(tmp_video, cv2.VideoWriter_fourcc(*"mp4v"), 30.0,
                                         (frame.camera.width, frame.camera.height))
            else:
                t0 = time.perf_counter()
                m = tracker.track(frame)
                elapsed += time.perf_counter() - t0
            n_lost += int(m.lost)
            rows.append(pose_row(frame, m.pose, m.quality, m.lost))
            if m.pose is not None:
                scene_gt[str(frame.index)] = [{"obj_id": 1, **pose_to_bop(m.pose)}]
            overlay = draw_tracking(frame, tracker.object, m, f"{tracker.name} #{frame.index}")
            writer.write(cv2.cvtColor(overlay, cv2.COLOR_RGB2BGR))
            if on_frame:
                on_frame(frame, m, overlay)
            if progress:
                progress(k + 1)
        if not rows:
            raise ValueError("source: no frames to track")
        writer.release()
        writer = None
        os.chmod(tmp_video, 0o644)
        os.replace(tmp_video, out / "overlay.mp4")
    finally:
        if writer is not None:
            writer.release()
        if tmp_video is not None and Path(tmp_video).exists():
            Path(tmp_video).unlink()
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_FIELDS)
    w.writerows(rows)
    atomic_write_text(out / "poses.csv", buf.getvalue())
    atomic_write_json(out / "scene_gt.json", scene_gt)
    return TrackResult(frames=len(rows), lost=n_lost, ms_per_frame=1000 * elapsed / max(len(rows) - 1, 1), out=out)
