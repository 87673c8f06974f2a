"""``hybridpose eval``: a trained regressor on a held-out BOP dataset, reported as the paper did and more.

Writes to ``--out``: ``report.json`` and ``report.md`` (the paper's table — mean/median rotation °,
mean translation m — beside ours, plus SPEED score, ADD-0.1d recall, failures, ms/image at 1 and 2
threads), ``error_vs_distance.png`` (mean ± 1σ per distance bin, as in the paper) and
``gradcam.png`` (Grad-CAM of the best and worst predictions, as in the paper), and errors per
bin of view elevation (how far from edge-on the object is seen, :func:`view_elevation_deg`), of sun
phase angle and of light azimuth in the image (where the dataset records each image's sun, as
``hybridpose render`` does), and accuracy by quality: what a caller that only trusts measurements above a quality keeps, and how
accurate those are (the fusion layer's gate on re-initialisation).
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import torch
from scipy.stats import chi2

from ..core import Frame
from ..datasets.bop import BopScene, find_scenes
from ..geometry import Pose
from ..io import atomic_write_json, atomic_write_text
from ..machine import describe_cpu
from ..metrics import add_recall, nearest_equivalent, rotation_error_deg
from ..metrics import pose_errors as metric_errors
from ..objects import light_azimuth_deg, sun_phase_angle_deg, view_elevation_deg
from ..regressors.calibration import COVERAGE as COVARIANCE_COVERAGE
from ..regressors.calibration import MIN_BAND_POSES, nees
from ..regressors.engines import call_ms, keypoint_engine
from ..regressors.keypoint_passes import image_batch
from ..regressors.calibration import uncalibrated_record
from ..regressors.options import KeypointOptions
from ..regressors.predictor import CheckpointRegressor
from .calibrate import quality_scale
from .eval_report import (AZIMUTH_BINS_DEG, GROSS_ERROR_DEG, PHASE_BINS_DEG, accuracy_by_quality, error_in_bins,
                          error_vs_distance, error_vs_elevation, over_confident, plot_error_vs_distance,
                          report_markdown)
from .gradcam import write_gradcam_sheet

log = logging.getLogger(__name__)

FAILED_ROT_DEG = 180.0  # a lost prediction counts as the worst possible rotation…
FAILED_TRANS_M = 1.0    # …and a 1 m translation error
ROI_SOURCES = ("none", "truth")  # evaluate_checkpoint's roi: no prior, or each view's true object box


def evaluate_checkpoint(checkpoint, data, out, limit: int | None = None, timing_images: int = 100,
                        gradcam_count: int = 4, progress=None, device="cpu", engine: str = "auto",
                        sun_known: bool = False, roi: str = "none", options: KeypointOptions | None = None,
                        **overrides) -> dict:
    """Run the full inference path (:class:`CheckpointRegressor`) on every image of ``data``.

    Errors are to the nearest of the truth's equivalent poses where the dataset's object is
    symmetric (its BOP ``symmetries_discrete``; :func:`~hybridpose.metrics.nearest_equivalent`), with
    ADD-S for ADD; ``rot_twin_deg`` is also up to the checkpoint's box twins (what a near-symmetric
    part invites). ``gross_error_share`` in the summary is the share of images more than
    ``GROSS_ERROR_DEG`` off in rotation (failures included). ``device`` is where the network runs
    (``"cuda"`` for the VGG models on a GPU machine); the ms/image timings are then those of that
    device with 1 and 2 CPU threads beside it; ``engine``: :class:`CheckpointRegressor`'s, the
    summary's ``engine`` names the one that ran the network. ``sun_known``: give the regressor each
    image's sun as the dataset records it (``predict(..., sun_direction_cam=...)``: what a caller
    with a sun sensor can do). ``roi``: ``"none"`` (the default: no prior, the object found by
    detection; the parallel model crops around its own translation where nothing is detected) or
    ``"truth"`` (each view's true object box, ``bbox_obj`` of ``scene_gt_info.json``: what a tracker on
    the object passes in the hybrid, and the paper's "bounded image"); the timings run without it.
    ``options`` / ``overrides``: the keypoint stages
    (:class:`~hybridpose.regressors.options.KeypointOptions`, or its fields as keywords).
    """
    if roi not in ROI_SOURCES:
        raise ValueError(f"roi: expected one of {', '.join(ROI_SOURCES)}, got {roi!r}")
    if isinstance(timing_images, bool) or not isinstance(timing_images, (int, np.integer)) or timing_images < 0:
        raise ValueError(f"timing_images: expected a whole number of images ≥ 0 (0: no timing), got {timing_images!r}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    reg = CheckpointRegressor(checkpoint, device=device, engine=engine, options=options, **overrides)
    scenes = [BopScene(p) for p in find_scenes(data)]
    items = [(s, i) for s in scenes for i in s.image_ids]
    if not items:
        raise ValueError(f"data: {data} holds no images")
    if limit is not None:
        items = items[:limit]
    if sun_known and any(scene.sun_direction_cam(i) is None for scene, i in items):
        raise ValueError(f"data: {data} does not record each image's sun (scene_meta.json, written by "
                         "`hybridpose render`); evaluate it without sun_known (--sun-known)")
    from ..datasets.bop import dataset_object

    obj = dataset_object(data)
    points = obj.sample_surface(500, rng=0)
    rows = []
    for k, (scene, im_id) in enumerate(items):
        gt = scene.image(im_id)
        frame = Frame(scene.rgb(im_id), gt.camera, float(im_id), im_id)
        sun = scene.sun_direction_cam(im_id)
        box = None
        if roi == "truth":
            if gt.bbox_obj[2] <= 0 or gt.bbox_obj[3] <= 0:
                raise ValueError(f"data: {scene.dir} image {im_id} has no bbox_obj in scene_gt_info.json; "
                                 "evaluate it without roi='truth' (--roi truth)")
            box = gt.bbox_obj
        m = reg.predict(frame, roi=box, sun_direction_cam=sun if sun_known else None)
        row = {"image": f"{scene.dir.name}/{im_id:06d}", "distance_m": float(gt.pose.t[2]),
               "elevation_deg": view_elevation_deg(gt.pose, obj), "lost": m.lost, "quality": m.quality,
               **lighting_columns(sun, gt.pose, obj)}
        if m.pose is None:
            row.update(rot_deg=FAILED_ROT_DEG, rot_twin_deg=FAILED_ROT_DEG, trans_m=FAILED_TRANS_M, speed=np.pi + FAILED_TRANS_M / np.linalg.norm(gt.pose.t),
                       add_m=float("inf"))
        else:
            row.update(pose_errors(m.pose, gt.pose, obj, points, reg.twins), **covariance_nees(
                m, nearest_equivalent(m.pose, gt.pose, obj.symmetries), reg.twins))
        rows.append(row)
        if progress:
            progress(k + 1, len(items))
    rot = np.array([r["rot_deg"] for r in rows])
    trans = np.array([r["trans_m"] for r in rows])
    summary = {
        "checkpoint": str(checkpoint), "model": reg.model_name, "data": str(data), "images": len(rows),
        "symmetries": len(obj.symmetries),
        "refine_edges": reg.options.refine_edges and reg.twin_check is not None, "passes": reg.options.passes, "turns": reg.options.turns,
        "pnp_outliers": reg.options.pnp_outliers, "turn_pnp_outliers": reg.options.turn_pnp_outliers, "sun_known": bool(sun_known), "roi": roi,
        "mirror_check": reg.mirror_verifier is not None,
        "edge_on_expert": None if reg.expert is None else str(reg.expert.path),
        "expert_rule": None if reg.expert is None else reg.options.expert_rule, "dim_fallback": reg.options.dim_fallback,
        "max_depth_m": reg.max_depth_m if reg.kind == "keypoints" else None,
        "device": str(reg.device), "engine": reg.engine.name if reg.engine is not None else "torch",
        "machine": describe_cpu(),
        "rot_mean_deg": float(rot.mean()), "rot_median_deg": float(np.median(rot)), "trans_mean_m": float(trans.mean()),
        "trans_median_m": float(np.median(trans)), "gross_error_share": float(np.mean(rot > GROSS_ERROR_DEG)), "speed_score": float(np.mean([r["speed"] for r in rows])),
        "add_0.1d_recall": add_recall([r["add_m"] for r in rows], obj.diameter),
        "failures": int(sum(r["lost"] for r in rows)),
        "ms_per_image": time_inference(reg, items[:timing_images]),
    }
    bins = error_vs_distance(rows)
    summary["error_vs_distance"] = bins
    summary["error_vs_elevation"] = error_vs_elevation(rows)
    summary["error_vs_phase"] = error_in_bins(rows, "sun_phase_deg", PHASE_BINS_DEG)
    summary["error_vs_light_azimuth"] = error_in_bins(rows, "light_azimuth_deg", AZIMUTH_BINS_DEG)
    summary["accuracy_by_quality"] = accuracy_by_quality(rows)
    summary["covariance_check"] = covariance_check(rows)
    if over_confident(summary["covariance_check"]):
        log.warning("%s: only %.0f %% of the errors lie inside the %.0f %% covariance ellipsoid (over-confident); "
                    "`hybridpose calibrate` re-scales it on held-out views", checkpoint,
                    100 * summary["covariance_check"]["inside_share_twin"], 100 * summary["covariance_check"]["coverage"])
    plot_error_vs_distance(bins, out / "error_vs_distance.png", reg.model_name)
    order = np.argsort(rot)
    picks = [items[i] for i in order[:gradcam_count]] + [items[i] for i in order[::-1][:gradcam_count]]
    labels = [f"best {rows[i]['rot_deg']:.1f}°" for i in order[:gradcam_count]] + \
             [f"worst {rows[i]['rot_deg']:.1f}°" for i in order[::-1][:gradcam_count]]
    if gradcam_count > 0:
        write_gradcam_sheet(reg, picks, labels, out / "gradcam.png")
    atomic_write_json(out / "report.json", {"summary": summary, "per_image": rows})
    atomic_write_text(out / "report.md", report_markdown(summary))
    return summary


def pose_errors(est: Pose, truth: Pose, obj, points, twins=()) -> dict:
    """One estimate's errors against ``truth`` (T_cam_obj, metres): rotation (°) and translation (m)
    to the nearest of the truth's equivalent poses under ``obj``'s symmetries, the rotation also up to
    the checkpoint's box ``twins`` (``rot_twin_deg``), the SPEED score, and ADD (ADD-S for a symmetric
    object) over ``points`` (N, 3) object points, metres."""
    errors = metric_errors(est, truth, obj.symmetries, points, obj.symmetric)
    near = errors.pop("nearest")
    # to the nearest box twin: the error a truly box-symmetric part cannot avoid
    errors["rot_twin_deg"] = min(rotation_error_deg(est, near @ S) for S in (Pose.identity(), *twins))
    return errors


def covariance_nees(m, truth: Pose, twins=()) -> dict:
    """NEES ``ξᵀ Σ⁻¹ ξ`` of a measurement's error ``ξ = m.pose.local(truth)`` under its covariance:
    ``nees`` to the true pose and ``nees_twin`` to the nearest of its box ``twins`` (what a keypoint
    model's calibrated covariance promises to cover: the twin is the quality's business)."""
    cov = np.asarray(m.covariance, dtype=float)
    values = [nees(m.pose.local(truth @ S), cov) for S in (Pose.identity(), *twins)]
    return {"nees": float(values[0]), "nees_twin": float(min(values))}


# quality bands (lower edges) of the covariance check: a covariance calibrated for all views at once can
# still be over-confident where the measurement is poor and under-confident where it is good
COVERAGE_QUALITY_EDGES = (0.0, 0.2, 0.3, 0.4, 0.5)


def covariance_check(rows, coverage: float = COVARIANCE_COVERAGE) -> dict:
    """Share of the views with a pose whose error lies inside the ``coverage`` χ²₆ ellipsoid of the
    reported covariance — about ``coverage`` when it is calibrated, well below when over-confident
    (what the fusion layer must not be fed): to the true pose and to the nearest box twin; and, per
    band of measurement quality (``COVERAGE_QUALITY_EDGES``), to the nearest twin (``by_quality``)."""
    bound = float(chi2.ppf(coverage, 6))
    got = [r for r in rows if "nees" in r]
    if not got:
        return {"coverage": coverage, "views": 0}
    by_quality = []
    for lo, hi in zip(COVERAGE_QUALITY_EDGES, COVERAGE_QUALITY_EDGES[1:] + (np.inf,)):
        band = [r for r in got if lo <= r["quality"] < hi]
        if band:
            by_quality.append({"min_quality": lo, "max_quality": None if hi == np.inf else hi, "views": len(band),
                               "inside_share_twin": float(np.mean([r["nees_twin"] <= bound for r in band]))})
    return {"coverage": coverage, "views": len(got),
            "inside_share": float(np.mean([r["nees"] <= bound for r in got])),
            "inside_share_twin": float(np.mean([r["nees_twin"] <= bound for r in got])), "by_quality": by_quality}


MIN_CALIBRATION_POSES = 20  # fewer held-out poses than this: no calibration


def calibrate_checkpoint(checkpoint, data, out, limit: int | None = None, progress=None,
                         coverage: float = COVARIANCE_COVERAGE, by_quality: bool = True, **options) -> dict:
    """Re-scale a checkpoint's covariance on the whole inference path; write it to ``out``.

    The training calibration (:func:`~hybridpose.training.calibrate.calibrate`) sees the first
    network pass's PnP pose on training-like crops; what a caller gets went through detection, the
    crop turns, the twin choice and the edge refinement, and its errors spread differently (the
    shipped ``default`` had 81 % of the seed-100 test views inside its 90 % ellipsoid). This runs
    :class:`CheckpointRegressor` (with ``options``, e.g. ``turns``) on every image of ``data`` —
    rendered with another seed than the training and test sets — and multiplies the covariance by
    the factor that puts ``coverage`` of the errors to the nearest box twin inside the χ²₆
    ellipsoid of that probability (the quality, not the covariance, says when a pose may be turned
    end for end; a symmetric object's errors count to its nearest equivalent pose). Both directions:
    a path more precise than its training calibration gets a smaller covariance.

    ``by_quality`` (keypoint models): also a factor per band of the measurements' quality
    (:func:`~hybridpose.training.calibrate.quality_scale`, stored as ``quality_scale``), so that
    poor measurements are not over-confident and good ones not under-confident; False: one factor
    for all (any bands stored before are dropped).

    A checkpoint without a calibration (its training one failed) starts from the inflated default
    the regressor would use. Returns the new calibration record (also in ``out``'s ``calibration``,
    with a ``full_path`` entry: data, poses used, factor, share inside before). Writes atomically;
    ``out`` may be ``checkpoint`` itself.
    """
    from ..regressors.checkpoints import load_checkpoint, save_checkpoint

    if not 0.5 <= coverage < 1.0:
        raise ValueError(f"coverage: expected a probability in [0.5, 1), got {coverage}")
    ck = load_checkpoint(checkpoint)
    reg = CheckpointRegressor(checkpoint, **options)
    if "engine" not in options and reg.engine is not None and reg.engine.name == "onnxruntime-int8":
        # the calibrated file is not the one the 8-bit model beside `checkpoint` was made from (engine="auto"
        # skips it there as stale), so the path is measured as the output will run it: this network in float
        # (no checkpoint given: no 8-bit lookup), the edge-on expert on whatever its own file resolves to
        reg.engine = keypoint_engine("auto", reg.net, reg.device, reg.image_size, reg.memory_format)
    # a checkpoint whose training calibration failed starts from the inflated default the predictor uses;
    # the errors are measured under its single scale (bands fitted before are not applied)
    cal = {k: v for k, v in (ck.get("calibration") or uncalibrated_record(reg.kind)).items() if k != "quality_scale"}
    reg.calibration = cal
    items = [(sc, i) for sc in (BopScene(p) for p in find_scenes(data)) for i in sc.image_ids][:limit]
    from ..datasets.bop import dataset_object

    symmetries = dataset_object(data).symmetries
    values, qualities = [], []
    for k, (scene, im_id) in enumerate(items):
        gt = scene.image(im_id)
        m = reg.predict(Frame(scene.rgb(im_id), gt.camera, float(im_id), im_id))
        if m.pose is not None:
            # a symmetric object's error to its nearest equivalent pose, as the evaluation scores it
            truth = nearest_equivalent(m.pose, gt.pose, symmetries)
            values.append(covariance_nees(m, truth, reg.twins)["nees_twin"])
            qualities.append(m.quality)
        if progress:
            progress(k + 1, len(items))
    if len(values) < MIN_CALIBRATION_POSES:
        raise ValueError(f"data: {data} gave {len(values)} poses; calibrating needs at least {MIN_CALIBRATION_POSES} "
                         f"(the regressor reported {len(items) - len(values)} of {len(items)} views lost: too few "
                         "views, or a checkpoint that does not see the object)")
    bound = float(chi2.ppf(coverage, 6))
    factor = float(np.quantile(values, coverage)) / bound
    new = dict(cal)
    if cal.get("kind") == "pnp":
        new["scale"] = float(cal["scale"]) * factor
        if by_quality and len(values) >= MIN_BAND_POSES:
            new["quality_scale"] = quality_scale(qualities, values, coverage)
    else:
        new["covariance"] = (factor * np.asarray(cal["covariance"], dtype=float)).tolist()
    new["full_path"] = {"data": str(data), "poses": len(values), "images": len(items), "factor": factor,
                        "coverage": coverage, "inside_share_before": float(np.mean(np.asarray(values) <= bound)),
                        "options": {k: v for k, v in options.items() if isinstance(v, (str, int, float, bool, type(None)))}}
    ck["calibration"] = new
    save_checkpoint(Path(out), ck)
    return new


def time_inference(reg: CheckpointRegressor, items, threads=(1, 2), repeats: int = 3) -> dict:
    """Mean ms per image of ``predict`` (the whole path: detection, passes, PnP, edge fits) per thread
    count. The mean, not the median: the extra passes, turns and fits run only on the hard views, and
    a median over mostly easy views would hide what they cost a stream of frames. The images are run
    ``repeats`` times and the lowest of the means is kept (as ``timeit`` does): on a shared machine
    the other processes only ever add time, and one run's mean moved by ±2 ms here. Beside each mean
    (key ``"1_thread"``, ``"2_threads"``, …), that run's per-image median, 95th percentile and
    largest ms (``"1_thread_p50"``, ``"1_thread_p95"``, ``"1_thread_max"``): the latency a caller must
    budget for a re-initialisation is the tail's, not the mean's."""
    if not items:  # nothing to time (evaluate_checkpoint(timing_images=0)): no timing keys at all
        return {}
    before = torch.get_num_threads()
    out = {}
    try:
        frames = [Frame(s.rgb(i), s.image(i).camera, 0.0) for s, i in items]
        for n in threads:
            torch.set_num_threads(n)
            reg.predict(frames[0])  # warm-up
            runs = []
            for _ in range(max(1, int(repeats))):
                ms = []
                for f in frames:
                    t0 = time.perf_counter()
                    reg.predict(f)
                    ms.append(1000 * (time.perf_counter() - t0))
                runs.append(np.asarray(ms))
            key = f"{n}_thread{'s' if n > 1 else ''}"
            best = min(runs, key=np.mean)
            out[key] = float(best.mean())
            out.update({f"{key}_p50": float(np.percentile(best, 50)), f"{key}_p95": float(np.percentile(best, 95)),
                        f"{key}_max": float(best.max())})
            out[f"network_{key}"] = network_call_ms(reg)
    finally:
        torch.set_num_threads(before)
    return out


def network_call_ms(reg: CheckpointRegressor, calls: int = 20, repeats: int = 3, on_torch: bool = False) -> float:
    """ms of one bare network call (batch 1, the model's input size, its device and memory layout) at
    the current thread count, lowest of ``repeats`` means over ``calls``. The part of ``predict`` that
    scales with the machine's arithmetic speed: beside the path's ms/image it tells a faster CPU from a
    faster path (:mod:`hybridpose.machine`). Keypoint models: on the engine ``predict`` uses (torch or
    ONNX Runtime), or with ``on_torch`` on torch whatever the engine (the yardstick earlier records used)."""
    image = np.zeros((reg.image_size, reg.image_size, 3), np.uint8)
    if reg.engine is not None and not on_torch:
        run, x = reg.engine, image_batch(image)
    elif reg.model_name == "parallel-vgg19":
        # both streams, as predict runs them: the whole frame and the bounded image, each at the input size
        run, x = (lambda v: reg.net(v, v)), reg.tensor(image)
    else:
        run, x = reg.net, reg.tensor(image)
    with torch.inference_mode():
        return call_ms(run, x, calls, repeats, sync=torch.cuda.synchronize if reg.device.type == "cuda" else None)


def lighting_columns(sun_direction_cam, pose: Pose, obj) -> dict:
    """A report row's lighting geometry: the sun's direction (camera frame), phase angle and image
    azimuth (:func:`sun_phase_angle_deg`, :func:`light_azimuth_deg`); empty without a recorded sun."""
    if sun_direction_cam is None:
        return {}
    return {"sun_direction_cam": [float(x) for x in sun_direction_cam],
            "sun_phase_deg": sun_phase_angle_deg(sun_direction_cam, pose, obj),
            "light_azimuth_deg": light_azimuth_deg(sun_direction_cam)}
