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
from ..machine import cpu_label, describe_cpu
from ..metrics import add_recall, nearest_equivalent, rotation_error_deg
from ..metrics import pose_errors as metric_errors
from ..objects import light_azimuth_deg, sun_phase_angle_deg, view_elevation_deg
from ..regressors.calibration import COVERAGE as COVARIANCE_COVERAGE
from ..regressors.calibration import MIN_BAND_POSES, nees, quality_scale
from ..regressors.engines import call_ms, keypoint_engine
from ..regressors.keypoint_passes import image_batch
from ..regressors.calibration import uncalibrated_record
from .gradcam import write_gradcam_sheet
from ..regressors.options import KeypointOptions
from ..regressors.predictor import CheckpointRegressor

log = logging.getLogger(__name__)

# The paper's results after 100 epochs on its truss data (mean rot °, median rot °, mean trans m).
PAPER = {"VGG-16": (13.56, 12.33, 0.18), "VGG-19": (12.21, 11.34, 0.15),
         "Branched VGG-19": (8.34, 7.34, 0.06), "Parallel VGG-19": (4.61, 4.41, 0.03)}
DISTANCE_BINS_M = np.linspace(0.3, 1.2, 10)
FAILED_ROT_DEG = 180.0  # a lost prediction counts as the worst possible rotation…
FAILED_TRANS_M = 1.0    # …and a 1 m translation error
GROSS_ERROR_DEG = 30.0
ROI_SOURCES = ("none", "truth")  # evaluate_checkpoint's roi: no prior, or each view's true object box
# Edge-on views (a flat object seen along its plane) hold most of the gross errors: bins fine near 0°.
ELEVATION_BINS_DEG = np.array([0.0, 6.0, 12.0, 20.0, 30.0, 45.0, 90.0])
QUALITY_GATES = (0.0, 0.2, 0.3, 0.4, 0.5)
# Lighting geometry of a view (datasets written by `hybridpose render` record each image's sun):
# phase angle 0° sun behind the camera, 90° side-lit; azimuth where the light travels in the image.
PHASE_BINS_DEG = np.array([0.0, 30.0, 45.0, 60.0, 75.0, 90.0, 180.0])
AZIMUTH_BINS_DEG = np.arange(0.0, 361.0, 45.0)


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


# Below coverage by more than this (≈ 3 binomial σ at 100 views) the report says over-confident.
OVER_CONFIDENT_MARGIN = 0.1


def over_confident(check: dict) -> bool:
    """Whether a :func:`covariance_check` shows the covariance over-confident: fewer errors inside
    the ellipsoid (to the nearest box twin, what the covariance promises) than its coverage by
    more than :data:`OVER_CONFIDENT_MARGIN`."""
    return bool(check.get("views")) and check["inside_share_twin"] < check["coverage"] - OVER_CONFIDENT_MARGIN


MIN_CALIBRATION_POSES = 20


def calibrate_checkpoint(checkpoint, data, out, limit: int | None = None, progress=None,
                         coverage: float = COVARIANCE_COVERAGE, by_quality: bool = True, **options) -> dict:
    """Re-scale a checkpoint's covariance on the whole inference path; write it to ``out``.

    The training calibration (:func:`~hybridpose.regressors.calibration.calibrate`) sees the first
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
    (:func:`~hybridpose.regressors.calibration.quality_scale`, stored as ``quality_scale``), so that
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


def error_vs_distance(rows) -> list[dict]:
    """Mean ± 1σ of rotation (°) and translation (m) errors per distance bin (successful predictions)."""
    d = np.array([r["distance_m"] for r in rows])
    ok = np.array([not r["lost"] for r in rows])
    rot = np.array([r["rot_deg"] for r in rows])
    trans = np.array([r["trans_m"] for r in rows])
    out = []
    for lo, hi in zip(DISTANCE_BINS_M[:-1], DISTANCE_BINS_M[1:]):
        sel = ok & (d >= lo) & (d < hi)
        if sel.any():
            out.append({"lo_m": float(lo), "hi_m": float(hi), "n": int(sel.sum()),
                        "rot_mean_deg": float(rot[sel].mean()), "rot_std_deg": float(rot[sel].std()),
                        "trans_mean_m": float(trans[sel].mean()), "trans_std_m": float(trans[sel].std())})
    return out


def error_vs_elevation(rows) -> list[dict]:
    """Per view-elevation bin (°, :func:`view_elevation_deg`): count, mean / median rotation error (°)
    and the share of views more than ``GROSS_ERROR_DEG`` off (failures included, as 180°)."""
    return error_in_bins(rows, "elevation_deg", ELEVATION_BINS_DEG)


def error_in_bins(rows, key: str, edges) -> list[dict]:
    """Per bin ``[lo, hi)`` of ``row[key]`` (the last bin closed): count, mean / median rotation error (°)
    and the share more than ``GROSS_ERROR_DEG`` off (failures included, as 180°). Rows without
    ``key`` (e.g. no recorded sun) are left out; no such rows, no bins."""
    rows = [r for r in rows if r.get(key) is not None]
    if not rows:
        return []
    value = np.array([r[key] for r in rows])
    rot = np.array([r["rot_deg"] for r in rows])
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (value >= lo) & ((value < hi) | (hi == edges[-1]))
        if sel.any():
            out.append({"lo_deg": float(lo), "hi_deg": float(hi), "n": int(sel.sum()),
                        "rot_mean_deg": float(rot[sel].mean()), "rot_median_deg": float(np.median(rot[sel])),
                        "gross_error_share": float(np.mean(rot[sel] > GROSS_ERROR_DEG))})
    return out


def lighting_columns(sun_direction_cam, pose: Pose, obj) -> dict:
    """A report row's lighting geometry: the sun's direction (camera frame), phase angle and image
    azimuth (:func:`sun_phase_angle_deg`, :func:`light_azimuth_deg`); empty without a recorded sun."""
    if sun_direction_cam is None:
        return {}
    return {"sun_direction_cam": [float(x) for x in sun_direction_cam],
            "sun_phase_deg": sun_phase_angle_deg(sun_direction_cam, pose, obj),
            "light_azimuth_deg": light_azimuth_deg(sun_direction_cam)}


def bins_table(bins, label: str) -> list[str]:
    """Markdown rows of :func:`error_in_bins` output under a ``label`` column."""
    lines = [f"| {label} | n | mean rot ° | median rot ° | > 30° |", "|---|---|---|---|---|"]
    for b in bins:
        lines.append(f"| {b['lo_deg']:.0f}–{b['hi_deg']:.0f} | {b['n']} | {b['rot_mean_deg']:.2f} | "
                     f"{b['rot_median_deg']:.2f} | {b['gross_error_share']:.1%} |")
    return lines


def plot_error_vs_distance(bins, path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not bins:
        return
    c = [(b["lo_m"] + b["hi_m"]) / 2 for b in bins]
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for ax, key, unit in ((axes[0], "rot", "°"), (axes[1], "trans", "m")):
        mean = np.array([b[f"{key}_mean_{'deg' if key == 'rot' else 'm'}"] for b in bins])
        std = np.array([b[f"{key}_std_{'deg' if key == 'rot' else 'm'}"] for b in bins])
        ax.errorbar(c, mean, yerr=std, fmt="o-", capsize=3)
        ax.set_xlabel("distance from camera (m)")
        ax.set_ylabel(f"{'rotation' if key == 'rot' else 'translation'} error ({unit})")
        ax.grid(alpha=0.3)
    fig.suptitle(f"{title}: error vs distance (mean ± 1σ)")
    fig.tight_layout()
    from ..io import atomic_write_with

    try:
        atomic_write_with(path, lambda f: fig.savefig(f, format="png", dpi=110))
    finally:
        plt.close(fig)


def accuracy_by_quality(rows, gates=QUALITY_GATES) -> list[dict]:
    """Per gate ``g``: the share of all views whose measurement has quality ≥ ``g`` (``kept_share``;
    failures, quality 0, are kept only by the gate 0) and, over those kept, mean / median rotation
    error (°), mean translation error (m) and the share more than ``GROSS_ERROR_DEG`` off. A gate
    that keeps no view reports only ``kept_share`` = 0."""
    quality = np.array([r["quality"] for r in rows], dtype=float)
    rot = np.array([r["rot_deg"] for r in rows], dtype=float)
    trans = np.array([r["trans_m"] for r in rows], dtype=float)
    out = []
    for g in gates:
        sel = quality >= g
        row = {"min_quality": float(g), "kept_share": float(sel.mean()) if len(sel) else 0.0}
        if sel.any():
            row.update(rot_mean_deg=float(rot[sel].mean()), rot_median_deg=float(np.median(rot[sel])),
                       trans_mean_m=float(trans[sel].mean()), gross_error_share=float(np.mean(rot[sel] > GROSS_ERROR_DEG)))
        out.append(row)
    return out


def report_markdown(s: dict) -> str:
    lines = [
        f"# Evaluation of `{s['model']}` on `{s['data']}` ({s['images']} images)",
        "",
        *([] if s.get("roi", "none") == "none" else
          ["Each view given its true object box as `roi` (what a tracker on the object passes; the timings run "
           "without it).", ""]),
        "| model | mean rot ° | median rot ° | mean trans m | SPEED | ADD-0.1d | > 30° | failures | ms/img 1 thr | ms/img 2 thr |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, (mr, md, mt) in PAPER.items():
        lines.append(f"| paper: {name} | {mr:.2f} | {md:.2f} | {mt:.2f} | – | – | – | – | – | – |")
    ms = s["ms_per_image"]
    lines.append(f"| **ours: {s['model']}** | {s['rot_mean_deg']:.2f} | {s['rot_median_deg']:.2f} | {s['trans_mean_m']:.3f} | "
                 f"{s['speed_score']:.3f} | {s['add_0.1d_recall']:.2f} | {s['gross_error_share']:.1%} | {s['failures']} | "
                 f"{_ms_cell(ms, '1_thread')} | {_ms_cell(ms, '2_threads')} |")
    lines += ["", "Failures (no pose) count as 180° / 1 m in the means. Error vs distance: `error_vs_distance.png`; "
              "Grad-CAM of the best and worst predictions: `gradcam.png`."]
    if "network_1_thread" in ms:
        lines += ["", f"Timed on {cpu_label(s.get('machine', {}))}: ms/img is the whole `predict` path; one bare "
                  f"network call (batch 1, on {s.get('engine', 'torch')}) takes {ms['network_1_thread']:.1f} ms on 1 thread here, "
                  f"{ms.get('network_2_threads', float('nan')):.1f} ms on 2 (compare machines by it)."]
    if "1_thread_p95" in ms:
        lines += ["", f"Latency per image on 1 thread (the views the mean was taken on): median {ms['1_thread_p50']:.1f} ms, "
                  f"95th percentile {ms['1_thread_p95']:.1f} ms, largest {ms['1_thread_max']:.1f} ms (the hard views run "
                  "extra network passes and edge fits)."]
    lines += [""]
    lines += ["| distance m | n | rot ° (mean ± σ) | trans m (mean ± σ) |", "|---|---|---|---|"]
    for b in s["error_vs_distance"]:
        lines.append(f"| {b['lo_m']:.1f}–{b['hi_m']:.1f} | {b['n']} | {b['rot_mean_deg']:.2f} ± {b['rot_std_deg']:.2f} | "
                     f"{b['trans_mean_m']:.3f} ± {b['trans_std_m']:.3f} |")
    if s.get("error_vs_elevation"):
        lines += ["", "View elevation: the line of sight's angle to the object's main plane (0° edge-on, 90° face-on).", ""]
        lines += bins_table(s["error_vs_elevation"], "elevation °")
    if s.get("error_vs_phase"):
        lines += ["", "Sun phase angle: at the object, the angle between the directions to the sun and to the camera "
                  "(0° sun behind the camera, 90° side-lit, 180° back-lit).", ""]
        lines += bins_table(s["error_vs_phase"], "phase °")
    if s.get("error_vs_light_azimuth"):
        lines += ["", "Light azimuth: the direction the sunlight travels across the image, from +x (right) towards "
                  "+y (down); 0° light from the left, 90° from above, 180° from the right, 270° from below.", ""]
        lines += bins_table(s["error_vs_light_azimuth"], "azimuth °")
    if s.get("accuracy_by_quality"):
        lines += ["", quality_table(s["accuracy_by_quality"])]
    lines += covariance_lines(s.get("covariance_check") or {}, s.get("checkpoint", "CK"))
    return "\n".join(lines) + "\n"


def covariance_lines(c: dict, checkpoint="CK") -> list[str]:
    """Markdown lines of a :func:`covariance_check` (none without views), with how to re-scale an
    over-confident covariance of ``checkpoint``."""
    lines = []
    if c.get("views"):
        lines += ["", f"Covariance check: of the {c['views']} views with a pose, {c['inside_share']:.1%} lie inside the "
                      f"{c['coverage']:.0%} χ²₆ ellipsoid of the reported covariance around the true pose, "
                      f"{c['inside_share_twin']:.1%} around the nearest box twin (calibrated: ≈ {c['coverage']:.0%}; "
                      "far below: over-confident)."]
        if c.get("by_quality"):
            lines[-1] += " By measurement quality (nearest twin): " + "; ".join(
                f"{b['min_quality']:.1f}–{b['max_quality']:.1f}" if b["max_quality"] is not None else f"≥ {b['min_quality']:.1f}"
                for b in c["by_quality"]) + " → " + "; ".join(
                f"{b['inside_share_twin']:.0%} of {b['views']}" for b in c["by_quality"]) + "."
        if over_confident(c):
            lines += ["", f"**Over-confident covariance** (the training calibration saw only the network's first pass): "
                          f"re-scale it on the whole inference path over held-out views before a filter uses it: "
                          f"`hybridpose calibrate --checkpoint {checkpoint} --data OTHER_DIR "
                          "--out calibrated.pt`."]
    return lines


def quality_table(gates) -> str:
    """Markdown of :func:`accuracy_by_quality`."""
    lines = ["Accuracy by quality: the views a caller keeps when it trusts only measurements of quality ≥ the gate.", "",
             "| quality ≥ | views kept | mean rot ° | median rot ° | mean trans m | > 30° |", "|---|---|---|---|---|---|"]
    for g in gates:
        if g["kept_share"] == 0:
            lines.append(f"| {g['min_quality']:.2f} | 0 % | – | – | – | – |")
            continue
        lines.append(f"| {g['min_quality']:.2f} | {g['kept_share']:.1%} | {g['rot_mean_deg']:.2f} | {g['rot_median_deg']:.2f} | "
                     f"{g['trans_mean_m']:.3f} | {g['gross_error_share']:.1%} |")
    return "\n".join(lines)


def _ms_cell(ms: dict, key: str) -> str:
    """A table cell of ms: ``ms[key]`` to 0.1 ms, or – where it was not timed (``timing_images=0``)."""
    return f"{ms[key]:.1f}" if key in ms else "–"


