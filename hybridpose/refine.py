"""A fitted network refined on the user's own footage, labelled by the tracker (``hybridpose fit
--refine-on VIDEO``).

Renders are not the world: a fit's network may find the part in every render and nowhere in the
user's video (its print, the lens, the light, the scene). No labels come with that video, but a
tracker that holds the part through a stretch of it gives a pose per frame, good to a degree or two
where it is sure — from the hybrid's own start, or from an initial pose the user gives (as ViSP's
trackers start from one). Those frames become training views: the network is fine-tuned on them
from the fit's weights at the re-fit learning rate, within a budget, as the fit trains (bfloat16 where
the device runs it fast, crops cut from the frames decoded once).

What it gained is measured, not assumed: the last ``HELD_BACK`` share of the tracked frames (a later
stretch of the footage) is kept out of the training, and the report gives the network's errors there before and after — against the
tracker's poses, the only labels there are (a tracker's frame is trusted at ``MIN_QUALITY``; a frame
it lost or doubted is neither trained on nor scored).

Layout (inside the fit's folder): ``refine/data/train`` and ``refine/data/held_back`` (BOP scenes of
the tracked frames, undistorted), ``refine/run`` (the training run), ``refine/best.pt`` (the refined
checkpoint, its covariance calibrated on the fit's calibration renders and its hybrid policy the
fit's), ``refine/eval_before`` and ``refine/eval_after``, ``refine/refine.json``, and a section of
``report.md``. The fit's own ``best.pt`` is left as it was.
"""
from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .core import Frame, Status
from .geometry import Camera, Pose
from .io import atomic_write_json, atomic_write_text, read_json
from .objects import ObjectModel

HELD_BACK = 0.25  # the last share of the tracked frames, never trained on: where before/after is measured
MIN_QUALITY = 0.6  # a tracker's frame below this (or lost) is neither a label nor scored
MIN_TRAIN_FRAMES = 30  # fewer tracked frames than this teach nothing but the frames themselves
DEFAULT_BUDGET_MIN = 10.0  # a sixth of the fit's default hour: the network already knows the part, it adapts to the footage
PATIENCE_EPOCHS = 60  # epochs without a better loss on the frames kept out of the training before it stops short of the budget


def labelled_frames(frames: Iterator[Frame], obj: ObjectModel, checkpoint, tracker: str = "combined",
                    init_pose: Pose | None = None) -> Iterator[tuple[Frame, Pose]]:
    """The frames a tracker holds with confidence and its pose in each (object→camera, metres):
    ``tracker`` alone from ``init_pose`` at the first frame where given (never re-initialised), else
    the hybrid with the network ``checkpoint`` (its frames while tracking: a start is the image's verdict,
    not the truth). A frame is kept where the tracker reports it not lost at ``MIN_QUALITY`` or more."""
    from .estimator import HybridEstimator
    from .registry import create

    if init_pose is not None:
        trk = create("tracker", tracker, object=obj)
        for k, frame in enumerate(frames):
            if k == 0:
                try:
                    trk.init(frame, init_pose)
                except ValueError as exc:  # the tracker finds nothing of the part there
                    raise ValueError(f"--init-pose: {exc}") from None
            m = trk.track(frame)
            if not m.lost and m.pose is not None and m.quality >= MIN_QUALITY:
                yield frame, m.pose
        return
    est = HybridEstimator.from_names(object=obj, tracker=tracker, regressor=str(checkpoint))
    for frame in frames:
        e = est.step(frame)
        m = est.last_tracker
        if (e.status == Status.TRACKING and e.pose is not None and m is not None and not m.lost
                and m.quality >= MIN_QUALITY):
            yield frame, e.pose


def write_views(frames: Iterator[Frame], poses: dict[int, Pose], obj: ObjectModel, camera: Camera,
                roots: tuple[Path, Path], cut: int) -> None:
    """The ``frames`` with a pose in ``poses`` (frame index → object→camera pose) into the BOP dataset
    ``roots[0]`` (indices before ``cut``) or ``roots[1]`` (the others), undistorted to ``camera``'s
    pinhole model, the part's mask from its model at the pose (what covers it is not known: all of it
    counts as seen)."""
    from .datasets.bop import BopSceneWriter, write_camera_json, write_models
    from .edges import ModelView

    pinhole = camera.pinhole()
    view = ModelView(obj)
    writers = []
    for root in roots:
        write_models(root, obj)
        write_camera_json(root, pinhole)
        writers.append(BopSceneWriter(root / "000000", pinhole, load=False))
    for frame in frames:
        pose = poses.get(frame.index)
        if pose is None:
            continue
        image = camera.undistort(frame.image) if camera.dist else frame.image
        mask = view.facet_ids(pose, pinhole, scale=1.0) > 0
        writers[frame.index >= cut].write(frame.index, image, np.zeros(mask.shape, np.float32), mask, mask, pose,
                                          obj.bbox_corners)
    for w in writers:
        w.flush()


def refine_on_footage(fit_dir, source, obj: ObjectModel, camera: Camera, budget_min: float = DEFAULT_BUDGET_MIN,
                      tracker: str = "combined", init_pose: Pose | None = None, seed: int = 0,
                      patience: int = PATIENCE_EPOCHS, progress=print) -> dict:
    """Refine the fit in ``fit_dir`` (its ``best.pt``) on the video or image folder ``source`` (seen
    with ``camera``; see the module doc). Returns the record written to ``refine/refine.json``.

    The training stops at ``budget_min`` minutes or sooner, once ``patience`` epochs in a row (0:
    never) brought no better loss on a tenth of the training frames kept out of it: the network has
    learnt the frames' labels and more epochs at a constant rate only spend the user's time.

    Raises:
        FileNotFoundError: no ``best.pt`` in ``fit_dir`` (fit first). ValueError: no budget, a patience
        that is not a whole number of epochs >= 0, or fewer
        than ``MIN_TRAIN_FRAMES`` tracked frames before the held-back share (the message says how
        many the tracker held and what to try).
    """
    from .fit import FULL_VIEW, IMAGE_SIZE, REFIT_LR, TRAIN_BATCH, held_out_accuracy, record_hybrid_policy
    from .fit_plan import cache_fits
    from .regressors.checkpoints import export_checkpoint, load_checkpoint
    from .regressors.models import torch_device
    from .tracking import read_frames
    from .training.evaluate import evaluate_checkpoint
    from .training.precision import fast_bf16
    from .training.train import TrainConfig, train

    fit_dir = Path(fit_dir)
    checkpoint = fit_dir / "best.pt"
    if not checkpoint.is_file():
        raise FileNotFoundError(f"{checkpoint}: no fitted network to refine — run `hybridpose fit` into that folder first")
    if not budget_min > 0:
        raise ValueError(f"budget: expected minutes of training > 0, got {budget_min!r}")
    if isinstance(patience, bool) or not isinstance(patience, int) or patience < 0:
        raise ValueError(f"patience: expected a whole number of epochs >= 0 (0: train to the budget), got {patience!r}")
    out = fit_dir / "refine"
    roots = (out / "data" / "train", out / "data" / "held_back")
    t0 = time.perf_counter()
    how = f"`{tracker}` from your initial pose" if init_pose is not None else f"the hybrid (`{tracker}` and the fit's network)"
    progress(f"refine: tracking `{source}` with {how}")
    total = 0

    def counted(frames):  # the video's length, from the labelling pass rather than another decode
        nonlocal total
        for frame in frames:
            total += 1
            yield frame

    poses = {f.index: p for f, p in labelled_frames(counted(read_frames(source, camera)), obj, checkpoint, tracker,
                                                    init_pose)}
    # the last share of the tracked frames is held back: a later stretch of the same footage
    order = sorted(poses)
    cut = order[int(round(len(order) * (1.0 - HELD_BACK)))] if order else 0
    n_train, n_held = sum(k < cut for k in order), sum(k >= cut for k in order)
    if n_train >= MIN_TRAIN_FRAMES:
        write_views(read_frames(source, camera), poses, obj, camera, roots, cut)
    record = {"source": str(source), "frames": total, "held_back_from": cut, "tracker": tracker,
              "from_initial_pose": init_pose is not None, "train_frames": n_train, "held_back_frames": n_held,
              "minutes": {"track": (time.perf_counter() - t0) / 60}}
    if n_train < MIN_TRAIN_FRAMES:
        raise ValueError(f"--refine-on: the tracker held the part with confidence on {len(order)} frames "
                         f"(at least {MIN_TRAIN_FRAMES} needed); give an initial pose of the first frame (--init-pose) "
                         "or a video where the hybrid starts")
    progress(f"refine: {n_train} tracked frames to train on, {n_held} held back (from frame {cut} on)")
    t0 = time.perf_counter()
    size = int(load_checkpoint(checkpoint)["config"].get("image_size", IMAGE_SIZE))  # the fit's crop scale
    cache = out / "data" / "decoded"
    # no epoch cap of its own: the budget or the patience ends the training
    cfg = TrainConfig(model="default", data=str(roots[0]), out=str(out / "run"), epochs=100_000, batch=TRAIN_BATCH,
                      lr=REFIT_LR, image_size=size, val_fraction=0.1, seed=seed, patience=patience, schedule="constant",
                      init_from=str(checkpoint), time_limit_min=budget_min, full_view=FULL_VIEW, workers=1,
                      # as the fit trains: bfloat16 where the device runs it fast, crops cut from frames decoded once
                      amp=fast_bf16(torch_device("auto")),
                      cache_images=str(cache) if cache_fits(n_train, camera, out) else None)
    record["training_bf16"] = cfg.amp
    progress(f"refine: training for {budget_min:g} minutes from the fit's weights"
             f"{' in bfloat16' if cfg.amp else ''} (the report follows)")
    trained = train(cfg, resume=(out / "run" / "last.pt").is_file(), progress=False)
    record["epochs_trained"], record["patience_epochs"] = trained["epochs_run"], patience
    record["stopped_early"] = trained["early_stop"]
    shutil.rmtree(cache, ignore_errors=True)  # rebuilt in seconds by a resumed run
    export_checkpoint(out / "run" / "best.pt", out / "best.pt")
    record_hybrid_policy(checkpoint, out / "best.pt", refit=True)  # the fit's own policy
    skipped = recalibrated(out / "best.pt", fit_dir / "data" / "calib")
    if skipped:
        record["calibration_skipped"] = skipped
    record["minutes"]["train"] = (time.perf_counter() - t0) / 60
    if n_held:
        for name, ck in (("before", checkpoint), ("after", out / "best.pt")):
            evaluate_checkpoint(ck, roots[1], out / f"eval_{name}", timing_images=0, gradcam_count=0)
            record[name] = held_out_accuracy(read_json(out / f"eval_{name}" / "report.json"), obj)
            record[name]["hybrid"] = hybrid_from(read_frames(source, camera), cut, obj, ck, tracker, poses)
    atomic_write_json(out / "refine.json", record)
    text = refine_report(record)
    report_md = fit_dir / "report.md"
    previous = report_md.read_text().split("\n## Refined on your footage")[0].rstrip("\n") if report_md.is_file() else ""
    atomic_write_text(report_md, previous + "\n\n## Refined on your footage\n\n" + text + "\n")
    progress(f"refine: {text}")
    return record


def recalibrated(checkpoint: Path, calib: Path) -> str | None:
    """Calibrate ``checkpoint``'s covariance in place on the fit's calibration renders ``calib``; None
    where done, else why not (the report says so, the refinement stands): too few poses there, or the
    renders are gone (a fit folder whose ``data/`` was deleted to save space)."""
    from .training.evaluate import calibrate_checkpoint

    if not Path(calib).is_dir():
        return f"the fit's calibration renders are gone: {calib} not found"
    try:
        calibrate_checkpoint(checkpoint, calib, checkpoint)
    except ValueError as exc:
        return str(exc)
    return None


def hybrid_from(frames: Iterator[Frame], cut: int, obj: ObjectModel, checkpoint, tracker: str,
                labels: dict[int, Pose]) -> dict:
    """The hybrid with the network ``checkpoint`` and no initial pose over the ``frames`` from index
    ``cut`` on: the first frame it trusts a pose at, how many it trusts, and of those with a tracker
    label in ``labels`` (index → pose) how many lie within 5° and 2 cm of it and how many more than
    10° from it (to the nearest equivalent pose of a symmetric part)."""
    from .estimator import HybridEstimator
    from .metrics import nearest_equivalent, rotation_error_deg

    est = HybridEstimator.from_names(object=obj, tracker=tracker, regressor=str(checkpoint))
    out = {"first_pose_at": None, "trusted": 0, "scored": 0, "within_5deg_2cm": 0, "over_10deg": 0}
    for frame in frames:
        if frame.index < cut:
            continue
        e = est.step(frame)
        if e.status != Status.TRACKING or e.pose is None:
            continue
        out["trusted"] += 1
        out["first_pose_at"] = frame.index if out["first_pose_at"] is None else out["first_pose_at"]
        label = labels.get(frame.index)
        if label is None:
            continue
        label = nearest_equivalent(e.pose, label, obj.symmetries)
        rot, trans = rotation_error_deg(e.pose, label), float(np.linalg.norm(e.pose.t - label.t))
        out["scored"] += 1
        out["within_5deg_2cm"] += rot <= 5.0 and trans <= 0.02
        out["over_10deg"] += rot > 10.0
    return out


def refine_report(record: dict) -> str:
    """The report's paragraph: what was trained on, and the held-back frames before and after."""
    how = "from your initial pose" if record["from_initial_pose"] else "by the hybrid from no initial pose"
    text = (f"`{record['tracker']}` tracked `{record['source']}` {how}; the network was refined on the "
            f"{record['train_frames']} frames it held with confidence before frame {record['held_back_from']} "
            f"(`refine/best.pt`; the fit's `best.pt` is unchanged).")
    if "epochs_trained" in record:
        why = (f"its loss on frames kept out of the training no better for {record['patience_epochs']} epochs"
               if record.get("stopped_early") else "the budget")
        text += f" It trained {record['epochs_trained']} epochs (stopped by {why})."
    if "calibration_skipped" in record:
        text += f" **Its covariance was not re-calibrated** ({record['calibration_skipped']})."
    if "before" not in record:
        return text + " No frame after it was tracked with confidence: nothing to measure the refinement on."
    b, a = record["before"], record["after"]
    return text + (f" On the {a['views']} frames held back (from frame {record['held_back_from']} on, scored against "
                   f"the tracker's poses): rotation error median {b['rot_median_deg']:.1f}° → {a['rot_median_deg']:.1f}°, "
                   f"translation {b['trans_median_pct']:.1f} → {a['trans_median_pct']:.1f} % of the distance, in a "
                   f"tracker's basin (≤ 10°, ≤ 5 %) {100 * b['in_tracker_basin']:.0f} → {100 * a['in_tracker_basin']:.0f} %. "
                   f"The hybrid from no initial pose over the frames from {record['held_back_from']} on: "
                   f"{_hybrid_text(b['hybrid'])} before, {_hybrid_text(a['hybrid'])} after. "
                   "Track with `--regressor refine/best.pt` where it did better.")


def _hybrid_text(h: dict) -> str:
    if h["first_pose_at"] is None:
        return "never started"
    return (f"first pose at frame {h['first_pose_at']}, {h['trusted']} frames trusted, of the {h['scored']} the tracker "
            f"labelled {h['within_5deg_2cm']} within 5° and 2 cm of it and {h['over_10deg']} more than 10° off")
