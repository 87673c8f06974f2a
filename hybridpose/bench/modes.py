"""The three modes on the same frames, and what each did per frame.

- ``tracker``: the tracker alone, given the true pose at frame 0 and never re-initialised;
- ``cnn``: the regressor on every frame, no prior;
- ``hybrid``: :class:`~hybridpose.estimator.HybridEstimator`, no ground truth at all.

Each returns one :class:`FrameRecord` per frame; :func:`sequence_stats` turns them into the figures
a benchmark reports (errors on the frames where the object is at least half visible, silent failures,
loss and recovery, cost).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..core import Frame
from ..geometry import Pose
from ..metrics import auc, nearest_equivalent, pose_errors, rotation_error_deg

HALF_VISIBLE = 0.5  # errors are reported on frames where at least this share of the object is visible
COVERED = 0.05  # below this visible share the object counts as covered
SILENT_DEG = 5.0  # a frame with a larger error that is not flagged lost is a silent failure
RECOVERED_DEG = 2.0  # recovery: rotation error back below this (and a trusted pose)
CLEAR = 0.9  # a frame this visible is clear: flagging it lost at a good pose is a false alarm
GOOD_DEG = 2.0  # a pose within this is right (false alarms, recoveries count from it)
BASIN_DEG, BASIN_PCT = 10.0, 5.0  # a pose this close starts a tracker that converges (its basin)
COMPONENTS = ("tracker", "regressor", "fusion")  # the parts of a frame's cost reported apart
NEES_90 = 10.645  # 90 % point of χ²₆: a calibrated covariance holds 90 % of the errors inside it


@dataclass(frozen=True)
class SequenceFrame:
    """One frame of a benchmark sequence and its truth."""

    frame: Frame
    truth: Pose
    visible: float  # visible share of the object, 0..1


@dataclass(frozen=True)
class FrameRecord:
    """What a mode said about one frame: ``pose`` (None when it said nothing), ``trusted`` (False when
    it flagged the object lost), milliseconds, CNN calls made for this frame, the hybrid's status,
    the (6, 6) covariance of ``pose``, and ``raw_pose``: the pose it would have given had it not
    flagged the frame (the tracker's solver pose, the hybrid's prediction), to tell false alarms;
    ``ms_parts``: milliseconds per component (``"tracker"``, ``"regressor"``, ``"fusion"``)."""

    pose: Pose | None
    trusted: bool
    ms: float
    cnn_calls: int = 0
    status: str = ""
    covariance: np.ndarray | None = None
    raw_pose: Pose | None = None
    ms_parts: dict | None = None


def load_sequence(scene_dir, sun: bool = True) -> list[SequenceFrame]:
    """Frames, true poses and visible shares of a rendered BOP scene (``scene_meta.json`` timestamps
    where present, else 30 fps). With ``sun``, the frames of a space-lit scene carry the sun's
    direction (:attr:`Frame.sun_direction_cam <hybridpose.core.Frame>`, as a spacecraft's sun sensors
    give it) where ``scene_meta.json`` records it; see :func:`sun_is_only_light`."""
    from ..datasets.bop import BopScene
    from ..io import read_json

    scene = BopScene(scene_dir)
    meta_path = Path(scene_dir) / "scene_meta.json"
    meta = read_json(meta_path).get("frames", {}) if meta_path.is_file() else {}
    sun = sun and sun_is_only_light(scene_dir)
    out = []
    for k, i in enumerate(scene.image_ids):
        img = scene.image(i)
        extra = meta.get(str(i), {})
        t = float(extra.get("timestamp_s", k / 30.0))
        sun_dir = extra.get("sun_direction_cam") if sun else None
        out.append(SequenceFrame(Frame(scene.rgb(i), img.camera, t, i, sun_dir), img.pose, img.visib_fract))
    return out


def sun_is_only_light(scene_dir) -> bool:
    """Whether the scene was rendered by ``hybridpose render`` in space: its dataset's
    ``hybridpose.json`` (two folders up, BOP's ``<dataset>/<split>/<scene>``) records the lighting and
    no randomised appearance (ambient light, lamps, a photo behind: the sun is not the only light)."""
    from ..datasets.generate import CONFIG_FILE
    from ..io import read_json

    path = Path(scene_dir).resolve().parent.parent / CONFIG_FILE
    if not path.is_file():
        return False
    config = read_json(path)
    return "lighting" in config and "appearance" not in config


def without_sun(seq: list[SequenceFrame]) -> list[SequenceFrame]:
    """The same frames with the sun's direction left out (an ablation: a sun that is not known)."""
    return [replace(s, frame=replace(s.frame, sun_direction_cam=None)) for s in seq]


def run_tracker(seq: list[SequenceFrame], tracker) -> list[FrameRecord]:
    """The tracker from the true first pose, never re-initialised (its own last pose as the prior)."""
    first = seq[0]
    t0 = time.perf_counter()
    tracker.init(first.frame, first.truth)
    ms = 1000 * (time.perf_counter() - t0)
    records = [FrameRecord(first.truth, True, ms, raw_pose=first.truth, ms_parts={"tracker": ms})]
    for s in seq[1:]:
        t0 = time.perf_counter()
        m = tracker.track(s.frame)
        ms = 1000 * (time.perf_counter() - t0)
        records.append(FrameRecord(m.pose, not m.lost, ms, covariance=m.covariance,
                                   raw_pose=getattr(tracker, "pose", None) if m.lost else m.pose,
                                   ms_parts={"tracker": ms}))
    return records


def run_cnn(seq: list[SequenceFrame], regressor) -> list[FrameRecord]:
    """The regressor on every frame, full image, no prior."""
    records = []
    for s in seq:
        t0 = time.perf_counter()
        m = regressor.predict(s.frame)
        ms = 1000 * (time.perf_counter() - t0)
        records.append(FrameRecord(m.pose, not m.lost, ms, cnn_calls=1, covariance=m.covariance,
                                   ms_parts={"regressor": ms}))
    return records


def run_hybrid(seq: list[SequenceFrame], estimator) -> list[FrameRecord]:
    """The hybrid estimator from scratch (``reset`` first), no ground truth."""
    estimator.reset()
    records = []
    for s in seq:
        before = estimator.regressor_calls
        e = estimator.step(s.frame)
        records.append(hybrid_record(e, estimator.regressor_calls - before))
    return records


def hybrid_record(e, cnn_calls: int) -> FrameRecord:
    """The record of one hybrid :class:`~hybridpose.core.Estimate` (``cnn_calls`` made for its frame):
    trusted unless lost or without a pose; its pose is also the raw pose (the prediction when lost)."""
    parts = {k: v for k, v in e.timings_ms.items() if k in COMPONENTS}
    return FrameRecord(e.pose, e.status != "lost" and e.pose is not None, e.timings_ms["total"], cnn_calls=cnn_calls,
                       status=e.status, covariance=e.covariance, raw_pose=e.pose, ms_parts=parts)


def trusted_errors_deg(seq: list[SequenceFrame], records: list[FrameRecord], symmetries=()) -> list[float | None]:
    """Rotation error (°) per frame where the mode gave a trusted pose, None elsewhere (to the nearest
    of the truth's symmetric equivalents, ``symmetries`` of the object)."""
    return [rotation_error_deg(r.pose, nearest_equivalent(r.pose, s.truth, symmetries))
            if r.trusted and r.pose is not None else None for s, r in zip(seq, records)]


ADD_AUC_MAX_M = 0.1  # the ADD(-S) AUC's largest threshold (PoseCNN / YCB-Video)


def mean_edge_shift_px(cam, edge_pts: np.ndarray, pose, truth) -> float:
    """Mean image distance (px) of the model's edge points at ``pose`` from where they are at
    ``truth``; inf where ``pose`` puts one of them at or behind the camera (a grossly wrong pose)."""
    at_pose = pose @ edge_pts
    if not np.all(cam.in_front(at_pose)):
        return float("inf")
    return float(np.linalg.norm(cam.project_cam(at_pose) - cam.project(edge_pts, truth), axis=1).mean())


def sequence_stats(seq: list[SequenceFrame], records: list[FrameRecord], obj=None) -> dict:
    """Per-sequence figures of one mode.

    Errors (``rot_*_deg``, ``trans_*``, ``speed``, and with the object model ``obj`` the ADD(-S)
    figures) are over the frames where the object is at least half visible and the mode gave a
    trusted pose; ``coverage`` is the share of those frames that had one. ``add_recall``: share of
    those half-visible frames (a frame without a trusted pose counts as a miss) with ADD (ADD-S for a
    symmetric object) below 0.1 × the diameter; ``add_auc``: the ADD(-S) AUC up to 0.1 m, misses
    counted as infinite errors. For a symmetric ``obj`` every error is to the nearest of the truth's
    symmetric equivalents (:func:`~hybridpose.metrics.nearest_equivalent`).
    ``in_basin``: share of the half-visible frames with a trusted pose a tracker can start from
    (within ``BASIN_DEG`` and ``BASIN_PCT`` % of the distance). ``edge_px_median``: the median over
    those frames of the mean image distance (px) between the model's sharp-edge points at the pose
    and at the truth.
    ``silent_failures``: frames (any visibility) with a trusted pose more than ``SILENT_DEG`` off.
    ``covered_tracking_10deg``: frames with the object < ``COVERED`` visible and a trusted pose more
    than 10° off. ``false_alarms``: frames at least ``CLEAR`` visible flagged lost although the pose
    the mode had (``raw_pose``) was within ``GOOD_DEG`` (out of ``clear_good_frames``).
    ``nees_coverage90``: share of the trusted half-visible frames whose error lies inside the 90 %
    ellipsoid of the reported covariance (0.9 when calibrated). ``recover_frames``: after each full
    occlusion, the frames from the first frame the object is half visible again until a trusted pose
    within ``RECOVERED_DEG`` (None: never). ``ms_per_frame``: mean wall time of a frame;
    ``ms_tracker``, ``ms_regressor``, ``ms_fusion``: its mean share per component; ``ms_by_state``:
    for the hybrid, ``{state: [total ms, frames]}`` over its states (``tracking``, ``lost``, ``init``,
    ``reinit``: a real-time budget must hold the costly ones); ``ms_frame_max``: the slowest frame.
    """
    rot, trans, pct, speed, add_err, silent, covered_bad, lost = [], [], [], [], [], 0, 0, 0
    in_basin, edge_px = 0, []
    edge_pts = _edge_points(obj) if obj is not None else None
    clear_good, false_alarms, nees_in, nees_n = 0, 0, 0, 0
    considered = 0
    points = obj.sample_surface(500, rng=0) if obj is not None else None
    symmetric = obj is not None and obj.symmetric
    syms = obj.symmetries if obj is not None else ()
    for s, r in zip(seq, records):
        truth = nearest_equivalent(r.pose, s.truth, syms) if r.pose is not None else s.truth
        err = rotation_error_deg(r.pose, truth) if r.pose is not None else None
        if not r.trusted:
            lost += 1
        if (s.visible >= CLEAR and r.raw_pose is not None
                and rotation_error_deg(r.raw_pose, nearest_equivalent(r.raw_pose, s.truth, syms)) < GOOD_DEG):
            clear_good += 1
            false_alarms += int(not r.trusted)
        if r.trusted and err is not None:
            silent += int(err > SILENT_DEG)
            covered_bad += int(s.visible < COVERED and err > 10.0)
        if s.visible >= HALF_VISIBLE:
            considered += 1
            if r.trusted and err is not None:
                errors = pose_errors(r.pose, s.truth, syms, points, symmetric)
                rot.append(err)
                trans.append(errors["trans_m"])
                pct.append(100 * errors["trans_m"] / s.truth.distance_m)
                in_basin += int(err <= BASIN_DEG and pct[-1] <= BASIN_PCT)
                speed.append(errors["speed"])
                if edge_pts is not None:
                    edge_px.append(mean_edge_shift_px(s.frame.camera, edge_pts, r.pose, truth))
                if r.covariance is not None:
                    xi = r.pose.local(truth)
                    try:
                        nees_in += int(float(xi @ np.linalg.solve(r.covariance, xi)) <= NEES_90)
                        nees_n += 1
                    except np.linalg.LinAlgError:
                        pass
                if points is not None:
                    add_err.append(errors["add_m"])
            elif points is not None:
                add_err.append(np.inf)
    rot_a = np.array(rot) if rot else np.array([np.nan])
    recover = _recovery(seq, records, syms)
    add_stats = {}
    if points is not None and add_err:
        add_stats = {"add_recall": float(np.mean(np.array(add_err) < 0.1 * obj.diameter)),
                     "add_auc": auc(np.minimum(add_err, 1e9), ADD_AUC_MAX_M)}
    cam = seq[0].frame.camera
    return {
        "frames": len(seq),
        "image_size": [cam.width, cam.height],
        "frames_half_visible": considered,
        "coverage": len(rot) / max(considered, 1),
        "rot_mean_deg": float(np.mean(rot_a)),
        "rot_median_deg": float(np.median(rot_a)),
        "rot_p90_deg": float(np.percentile(rot_a, 90)),
        "rot_max_deg": float(np.max(rot_a)),
        "trans_mean_m": float(np.mean(trans)) if trans else float("nan"),
        "trans_mean_pct": float(np.mean(pct)) if pct else float("nan"),
        "trans_median_pct": float(np.median(pct)) if pct else float("nan"),
        "speed_mean": float(np.mean(speed)) if speed else float("nan"),
        "in_basin": in_basin / max(considered, 1),
        "edge_px_median": float(np.median(edge_px)) if edge_px else float("nan"),
        **add_stats,
        "silent_failures": silent,
        "false_alarms": false_alarms,
        "clear_good_frames": clear_good,
        "nees_coverage90": nees_in / nees_n if nees_n else float("nan"),
        "covered_tracking_10deg": covered_bad,
        "frames_lost": lost,
        "recover_frames": recover,
        "recover_frames_max": max((n for n in recover if n is not None), default=None),
        "ms_per_frame": float(np.mean([r.ms for r in records])),
        "ms_frame_max": float(np.max([r.ms for r in records])),
        "ms_by_state": _ms_by_state(records),
        **{f"ms_{part}": float(np.mean([(r.ms_parts or {}).get(part, 0.0) for r in records])) for part in COMPONENTS},
        "cnn_calls_per_100": 100.0 * sum(r.cnn_calls for r in records) / len(records),
    }


def _ms_by_state(records: list[FrameRecord]) -> dict[str, list[float]]:
    """``{status: [total ms, frames]}`` over the records that carry a status (the hybrid's)."""
    out: dict[str, list[float]] = {}
    for r in records:
        if r.status:
            total = out.setdefault(r.status, [0.0, 0])
            total[0] += r.ms
            total[1] += 1
    return out


def _edge_points(obj) -> np.ndarray:
    """(N, 3) points along the object's sharp edges (ends and midpoints), metres."""
    seg = obj.sharp_edges
    return np.concatenate([seg[:, 0], seg[:, 1], 0.5 * (seg[:, 0] + seg[:, 1])])


def _recovery(seq: list[SequenceFrame], records: list[FrameRecord], symmetries=()) -> list[int | None]:
    out, covered = [], False
    k = 0
    while k < len(seq):
        if seq[k].visible < COVERED:
            covered = True
        elif covered and seq[k].visible >= HALF_VISIBLE:
            covered = False
            n = None
            for j in range(k, len(seq)):
                r = records[j]
                if (r.trusted and r.pose is not None
                        and rotation_error_deg(r.pose, nearest_equivalent(r.pose, seq[j].truth, symmetries)) <= RECOVERED_DEG):
                    n = j - k
                    break
            out.append(n)
        k += 1
    return out
