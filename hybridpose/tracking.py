"""``hybridpose track``: follow a user's object through a video file or an image folder — with the
hybrid estimator (no initial pose) or with a tracker alone from a given pose — and write what it saw.

Inputs are converted at this edge: video/image frames (BGR on disk) → RGB ``Frame``; an initial pose
file in metres (``quat_wxyz`` + ``t_m``, or ``R`` + ``t_m``) or BOP (``cam_R_m2c`` + ``cam_t_m2c`` in
mm) or ViSP (``.pos``) → ``Pose``. Outputs in ``out``, all written atomically: an overlay video of the model's edges at
the estimated pose (``overlay.webm``, or ``.mp4`` where OpenCV has H.264), ``poses.csv`` (metres,
quaternion w, x, y, z; empty pose cells where there was none) and BOP ``scene_gt.json`` (mm, the
frames with a trusted pose).
"""
from __future__ import annotations

import csv
import io
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from .core import Estimate, Frame, Measurement
from .edges.silhouette import SPACE_DARK_SHARE, dark_share
from .geometry import Camera, Pose, as_rgb_image
from .hybrid_config import HybridConfig
from .io import VideoFile, atomic_write_json, atomic_write_text, read_json
from .viz import SITE_LEGEND, draw_edge_sites, draw_wireframe, put_label

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
POSE_FIELDS = ["frame", "timestamp_s", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m"]
# 1-σ of the pose as reported (Pose.covariance_in_camera): rotation about the camera's x, y, z (°), and
# of tx, ty, tz themselves (m); empty where there is no pose or no uncertainty (a given initial pose)
SIGMA_FIELDS = ["sd_rx_deg", "sd_ry_deg", "sd_rz_deg", "sd_tx_m", "sd_ty_m", "sd_tz_m"]
# and the whole covariance of [δθx, δθy, δθz (rad), δtx, δty, δtz (m)] in the camera frame, for a navigation
# filter: its upper triangle, row by row (rad², rad·m, m²)
_AXES = ("rx", "ry", "rz", "tx", "ty", "tz")
COV_FIELDS = [f"cov_{a}_{b}" for i, a in enumerate(_AXES) for b in _AXES[i:]]
HYBRID_FIELDS = POSE_FIELDS + SIGMA_FIELDS + COV_FIELDS + ["status", "sources", "ms"]
TRACKER_FIELDS = POSE_FIELDS + SIGMA_FIELDS + COV_FIELDS + ["quality", "lost"]
STATUS_COLOURS = {"tracking": (60, 255, 60), "init": (255, 220, 0), "reinit": (255, 220, 0), "lost": (255, 60, 60)}
OVERLAY_FPS = 30.0  # a one-frame run's overlay rate (longer runs take the source's, from two timestamps)


# --- inputs ----------------------------------------------------------------------------------------
def load_pose(path) -> Pose:
    """Initial ``T_cam_obj`` from JSON: ``{"quat_wxyz": [4], "t_m": [3]}``, ``{"R": [[3]×3], "t_m": [3]}``
    or BOP ``{"cam_R_m2c": [9], "cam_t_m2c": [3] (mm)}``; or from a ViSP pose file (``.pos``: tx ty tz
    in metres, then θu_x θu_y θu_z, the rotation vector in radians, of ``cMo`` = T_cam_obj); errors
    name the file."""
    from .datasets.bop import pose_from_bop

    if Path(path).suffix.lower() == ".pos":
        return _load_visp_pose(Path(path))
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


def _load_visp_pose(path: Path) -> Pose:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: pose file not found")
    try:
        values = np.array(path.read_text().split(), dtype=np.float64)
    except ValueError:
        values = np.array([])
    if values.shape != (6,) or not np.all(np.isfinite(values)):
        raise ValueError(f"{path}: expected a ViSP pose, six numbers: tx ty tz (m) θux θuy θuz (rad)")
    return Pose.from_rotvec_t(values[3:], values[:3])


def read_frames(source, camera: Camera, fps: float | None = None) -> Iterator[Frame]:
    """Frames of a video file or an image folder (sorted by name), as RGB, checked against ``camera``.

    Timestamps: frame index / fps (the video's own rate, else ``fps``, else 30).
    """
    for bgr, index, rate, where in _raw_frames(source, fps):
        yield _frame(bgr, camera, index, rate, where)


def with_sun(frames: Iterator[Frame], sun_dir: str) -> Iterator[Frame]:
    """``frames`` carrying the sun's direction (``Frame.sun_direction_cam``: the way sunlight travels in
    the camera frame, x right, y down, z forward) from ``sun_dir``: ``"x,y,z"`` for every frame, or a
    CSV file of it over time, as a sun sensor logs it — columns ``timestamp_s`` (seconds, the frames'
    clock: index / fps) or ``frame`` (index), and ``x``, ``y``, ``z``. By time the direction between
    two rows is interpolated (normalised linear) and held before the first and after the last; by
    frame only the listed frames carry one. Read at once: ValueError naming ``--sun-dir`` (and the
    line) before any frame is read."""
    sun_at = _sun_lookup(sun_dir)
    return (f if (sun := sun_at(f)) is None else replace(f, sun_direction_cam=sun) for f in frames)


def _sun_lookup(sun_dir: str) -> Callable[[Frame], np.ndarray | None]:
    from .geometry.checks import as_unit_direction

    path = Path(sun_dir)
    if not path.is_file():
        try:
            sun = as_unit_direction([float(x) for x in sun_dir.split(",")], "--sun-dir")
        except ValueError as exc:
            raise ValueError(f"--sun-dir: expected x,y,z, the direction the sunlight travels in the camera frame, "
                             f"or a CSV file of it over time; got {sun_dir!r}") from exc
        return lambda frame: sun
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    columns = set(rows[0]) if rows else set()
    key = "timestamp_s" if "timestamp_s" in columns else "frame" if "frame" in columns else None
    if key is None or not {"x", "y", "z"} <= columns:
        raise ValueError(f"--sun-dir: {path}: expected a header with timestamp_s (or frame), x, y, z; got "
                         f"{', '.join(sorted(columns)) or 'no rows'}")
    at, dirs = [], []
    for i, row in enumerate(rows, start=2):  # line numbers as an editor shows them, after the header
        try:
            at.append(float(row[key]))
            dirs.append(as_unit_direction([float(row[c]) for c in "xyz"], "direction"))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"--sun-dir: {path}: line {i}: expected numbers {key}, x, y, z (a direction, not "
                             f"zero): {exc}") from None
    at_a, dirs_a = np.asarray(at), np.asarray(dirs)
    if np.any(np.diff(at_a) <= 0):
        raise ValueError(f"--sun-dir: {path}: {key} must increase from line to line")
    if key == "frame":
        by_frame = dict(zip(at_a.astype(int).tolist(), dirs_a))
        return lambda frame: by_frame.get(frame.index)

    def at_time(frame: Frame) -> np.ndarray:
        k = int(np.searchsorted(at_a, frame.timestamp))
        if k == 0 or k == len(at_a):
            return dirs_a[min(k, len(at_a) - 1)]
        w = (frame.timestamp - at_a[k - 1]) / (at_a[k] - at_a[k - 1])
        return (1 - w) * dirs_a[k - 1] + w * dirs_a[k]  # Frame normalises it

    return at_time


def first_frame_size(source) -> tuple[int, int]:
    """(W, H) pixels of the first frame of a video file or image folder (errors as :func:`read_frames`)."""
    first = first_frame(source)
    return first.shape[1], first.shape[0]


def first_frame(source) -> np.ndarray:
    """(H, W, 3) uint8 RGB: the first frame of a video file or image folder (errors as :func:`read_frames`)."""
    first = next(_raw_frames(source, None), None)
    if first is None:
        raise ValueError(f"{source}: no frame could be read")
    return cv2.cvtColor(first[0], cv2.COLOR_BGR2RGB)


# ``auto``'s choice: ``edges`` where the first frame shows black space (edges.silhouette.SPACE_DARK_SHARE
# of its pixels dark), ``combined`` anywhere else
AUTO_TRACKERS = {"space": "edges", "lit": "combined"}
AUTO_TRACKER = "auto"  # the name that asks for the choice (`hybridpose track --tracker`'s default)


def chosen_tracker(name: str, first: np.ndarray) -> tuple[str, str | None]:
    """``name``, or where it is ``AUTO_TRACKER`` the tracker :func:`auto_tracker` takes for a video whose
    first frame is ``first`` ((H, W, 3) uint8 RGB); with why it was taken (None where ``name`` was given)."""
    if name != AUTO_TRACKER:
        return name, None
    tracker, dark = auto_tracker(first)
    scene = "black space" if tracker == AUTO_TRACKERS["space"] else "a lit scene"
    return tracker, f"auto: {dark:.0%} of the first frame dark, {scene}"


def auto_tracker(image: np.ndarray) -> tuple[str, float]:
    """The tracker ``--tracker auto`` takes for a video whose first frame is ``image`` ((H, W, 3) uint8
    RGB), and the share (0..1) of its pixels that are dark: ``edges`` on black space (the edge cues,
    the lit share and the sun's shading it checks a fit by hold there), ``combined`` on a lit scene (a
    lab, a workshop, the Earth behind the part: its texture and region cues, and a quality that takes
    clutter and a print for no evidence against a pose)."""
    from .edges import to_gray8

    dark = dark_share(to_gray8(as_rgb_image(image)))
    return AUTO_TRACKERS["space" if dark >= SPACE_DARK_SHARE else "lit"], dark


def _raw_frames(source, fps: float | None) -> Iterator[tuple[np.ndarray, int, float, Path]]:
    """(BGR image, index, frames per second, where it came from) of each frame of ``source``."""
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
            yield bgr, i, rate, f
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
            yield bgr, i, rate, source
            i += 1
    finally:
        cap.release()


def _frame(bgr: np.ndarray, camera: Camera, index: int, rate: float, where) -> Frame:
    h, w = bgr.shape[:2]
    if (w, h) != (camera.width, camera.height):
        raise ValueError(f"{where}: frame {index} is {w}×{h} but the camera file says {camera.width}×{camera.height}")
    return Frame(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), camera, index / rate, index)


# --- outputs ---------------------------------------------------------------------------------------
def _sigma_cells(pose: Pose | None, covariance: np.ndarray | None) -> list[str]:
    """The ``SIGMA_FIELDS`` and ``COV_FIELDS`` cells of a pose and its (6, 6) right-perturbation covariance."""
    if pose is None or covariance is None:
        return [""] * (len(SIGMA_FIELDS) + len(COV_FIELDS))
    cov = pose.covariance_in_camera(covariance)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return ([f"{np.degrees(v):.4f}" for v in sd[:3]] + [f"{v:.6f}" for v in sd[3:]]
            + [f"{v:.6e}" for v in cov[np.triu_indices(6)]])


def _pose_cells(frame: Frame, pose: Pose | None) -> list:
    cells = ([f"{v:.9f}" for v in pose.quat_wxyz] + [f"{v:.6f}" for v in pose.t]) if pose is not None else [""] * 7
    return [frame.index, f"{frame.timestamp:.6f}", *cells]


@dataclass
class RunResult:
    """What a run wrote: frames, frames lost, re-initialisations (hybrid), the cost, the video, the
    folder. ``ms_per_frame``: the mean over the frames after the first; ``first_frame_ms`` apart (it
    loads and, on a cold cache, compiles the kernels: seconds, once); ``wall_ms_per_frame``: the same
    frames' whole loop (reading the source, the run, drawing, encoding the overlay)."""

    frames: int
    lost: int
    reinits: int
    ms_per_frame: float
    video: Path
    out: Path
    interrupted: bool = False  # stopped by the user (Ctrl-C): the outputs hold the frames done
    first_frame_ms: float = float("nan")
    note: str = ""  # what the user should hear of the run (a hybrid that never started: why, and what to do)
    wall_ms_per_frame: float = float("nan")


def _run(frames: Iterator[Frame], step: Callable[[Frame], tuple], out, fields: list[str], max_frames: int | None,
         progress: Callable[[int], None] | None, on_frame: Callable | None) -> RunResult:
    """The loop both runs share: ``step(frame)`` → (result for ``on_frame``, pose written or None, trusted,
    lost, reinit, ms, extra csv cells, overlay); video, poses.csv and scene_gt.json written at the end —
    also when the user stops the run (Ctrl-C), with the frames done by then."""
    out = Path(out)
    made = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        return _loop(frames, step, out, fields, max_frames, progress, on_frame)
    except BaseException:
        if made and not any(out.iterdir()):  # a run that failed before its first frame leaves no empty folder
            out.rmdir()
        raise


def _loop(frames: Iterator[Frame], step: Callable[[Frame], tuple], out: Path, fields: list[str],
          max_frames: int | None, progress: Callable[[int], None] | None, on_frame: Callable | None) -> RunResult:
    from .datasets.bop import pose_to_bop

    rows, scene_gt, video, ms, lost, reinits, interrupted = [], {}, None, [], 0, 0, False
    held: list[tuple[float, np.ndarray]] = []  # overlays before the video opens at the source's rate

    def open_video(size: tuple[int, int]) -> VideoFile:
        gap = held[1][0] - held[0][0] if len(held) > 1 else 0.0
        return VideoFile(out / "overlay", 1.0 / gap if gap > 0 else OVERLAY_FPS, size)

    def write_held() -> None:
        for _, image in held:
            video.write(image)
        held.clear()

    try:
        try:
            for k, frame in enumerate(frames):
                if max_frames is not None and k >= max_frames:
                    break
                size = (frame.camera.width, frame.camera.height)
                result, pose, trusted, was_lost, reinit, elapsed, cells, overlay = step(frame)
                ms.append(elapsed)
                lost += int(was_lost)
                reinits += int(reinit)
                rows.append(_pose_cells(frame, pose) + cells)
                if pose is not None and trusted:
                    scene_gt[str(frame.index)] = [{"obj_id": 1, **pose_to_bop(pose)}]
                held.append((frame.timestamp, overlay))
                if video is None and len(held) > 1:
                    video = open_video(size)
                if video is not None:
                    write_held()
                if on_frame:
                    on_frame(frame, result, overlay)
                if progress:
                    progress(k + 1)
                if k == 0:
                    after_first = time.perf_counter()
        except KeyboardInterrupt:  # a long video stopped by hand: keep what was tracked
            if not rows:
                raise
            interrupted = True
        if not rows:
            raise ValueError("source: no frames to track")
        if video is None:
            video = open_video(size)
        write_held()
        path = video.close()
        video = None
        wall_ms = 1000 * (time.perf_counter() - after_first) / (len(rows) - 1) if len(rows) > 1 else float("nan")
    finally:
        if video is not None:
            video.close(keep=False)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(fields)
    w.writerows(rows)
    atomic_write_text(out / "poses.csv", buf.getvalue())
    atomic_write_json(out / "scene_gt.json", scene_gt)
    return RunResult(frames=len(rows), lost=lost, reinits=reinits, ms_per_frame=float(np.mean(ms[1:] or ms)), video=path,
                     out=out, interrupted=interrupted, first_frame_ms=float(ms[0]), wall_ms_per_frame=wall_ms)


# --- the two runs ----------------------------------------------------------------------------------
def draw_estimate(frame: Frame, obj, e: Estimate, label: str | None) -> np.ndarray:
    """The frame with the model's edges at ``e.pose`` in the status colour and, unless ``label`` is
    None (a caller that labels after resizing), one label line."""
    img = frame.image
    if e.pose is not None:
        img = draw_wireframe(img, obj, e.pose, frame.camera, STATUS_COLOURS[e.status])
    return img if label is None else put_label(img, f"{label}  {e.status.upper()}")


def with_sites(image: np.ndarray, sites, camera: Camera, legend: bool = True) -> np.ndarray:
    """``image`` (of ``camera``) with a tracker's last edge sites drawn
    (:func:`~hybridpose.viz.draw_edge_sites`; the fits' pinhole pixels put where ``camera``'s lens
    shows them) and, with ``legend``, their legend along the bottom."""
    drawn = draw_edge_sites(image, sites, camera.distort_pixels if camera.dist else None)
    return put_label(drawn, SITE_LEGEND, bottom=True) if legend else drawn


def run_hybrid_on_frames(frames: Iterator[Frame], estimator, out, max_frames: int | None = None,
                         progress: Callable[[int], None] | None = None,
                         on_frame: Callable[[Frame, Estimate, np.ndarray], None] | None = None,
                         draw_sites: bool = False) -> RunResult:
    """``estimator.step`` over ``frames`` (no initial pose). The video's edges: green tracking, yellow
    (re)initialised, red lost (the predicted pose); with ``draw_sites`` also the sites of the tracker's
    last edge fit of the frame (:func:`with_sites`). ``poses.csv`` adds the 1-σ of the pose
    (``SIGMA_FIELDS``), status, sources and ms."""
    obj = estimator.object
    started = False

    def step(frame: Frame):
        nonlocal started
        e = estimator.step(frame)
        started = started or e.pose is not None
        cells = [*_sigma_cells(e.pose, e.covariance), e.status, "+".join(e.sources), f"{e.timings_ms['total']:.2f}"]
        overlay = draw_estimate(frame, obj, e, f"#{frame.index}")
        if draw_sites:
            overlay = with_sites(overlay, getattr(estimator.tracker, "last_sites", None), frame.camera)
        return (e, e.pose, e.status != "lost", e.status == "lost", e.status == "reinit", e.timings_ms["total"], cells,
                overlay)

    res = _run(frames, step, out, HYBRID_FIELDS, max_frames, progress, on_frame)
    if started or res.frames == 0:
        return res
    return replace(res, note=never_started_text(estimator.best_start_fit, estimator.config))


def never_started_text(best_fit: float, config: HybridConfig) -> str:
    """What a run from no initial pose that never started tells its user: ``best_fit``, the best quality a
    start's fit reached (:attr:`~hybridpose.estimator.HybridEstimator.best_start_fit`), against the bars of
    ``config``, and what to do."""
    if best_fit <= 0:
        return ("the hybrid never started: no network pose gave a fit of the model at all (is the part in view, "
                "and are --object and --camera the right ones?); give --init-pose FILE, the first frame's pose")
    return (f"the hybrid never started: the best fit from a network pose scored {best_fit:.2f} where a start needs "
            f"{config.start_quality:g} (start_quality; a plain part in a lit scene {config.plain_start_quality:g}, "
            "plain_start_quality) and a pose the image singles out; give --init-pose FILE (the first frame's pose), "
            "or a fit that finds the part in these frames (hybridpose fit --video)")


def draw_tracking(frame: Frame, obj, m: Measurement, label: str, pose: Pose | None = None) -> np.ndarray:
    """The frame with the model's edges at the measured pose (green), or at ``pose`` in red where the
    tracker lost the object, and a label with the quality."""
    shown, color = (m.pose, (60, 255, 60)) if not m.lost else (pose, (255, 60, 60))
    img = draw_wireframe(frame.image, obj, shown, frame.camera, color) if shown is not None else frame.image
    return put_label(img, f"{label}  q={m.quality:.2f}{'  LOST' if m.lost else ''}")


def track_sequence(frames: Iterator[Frame], tracker, init_pose: Pose, out, max_frames: int | None = None,
                   progress: Callable[[int], None] | None = None,
                   on_frame: Callable[[Frame, Measurement, np.ndarray], None] | None = None,
                   draw_sites: bool = False) -> RunResult:
    """A tracker alone from ``init_pose`` at the first frame (no CNN, no fusion); ``poses.csv`` adds
    the 1-σ of each fit, quality and lost (a lost frame has empty pose cells; the video shows the tracker's
    last pose in red, and with ``draw_sites`` its edge fit's sites: :func:`with_sites`)."""
    first = [True]

    def step(frame: Frame):
        t0 = time.perf_counter()
        given = first[0]  # the initial pose the user gave: no uncertainty of ours to report
        if first[0]:
            first[0] = False
            tracker.init(frame, init_pose)
            m = Measurement(init_pose, np.eye(6) * 1e-6, 1.0, f"tracker:{tracker.name}", frame.timestamp)
        else:
            m = tracker.track(frame)
        elapsed = 1000 * (time.perf_counter() - t0)
        overlay = draw_tracking(frame, tracker.object, m, f"{tracker.name} #{frame.index}", getattr(tracker, "pose", None))
        if draw_sites:
            overlay = with_sites(overlay, getattr(tracker, "last_sites", None), frame.camera)
        cells = [*_sigma_cells(m.pose, None if given else m.covariance), f"{m.quality:.4f}", int(m.lost)]
        return m, m.pose, not m.lost, m.lost, False, elapsed, cells, overlay

    return _run(frames, step, out, TRACKER_FIELDS, max_frames, progress, on_frame)
