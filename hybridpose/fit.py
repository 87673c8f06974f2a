"""``hybridpose fit``: a CNN pose regressor for any CAD model, on a CPU, within a time budget.

One command renders a randomised training set of the part, trains the ``default`` keypoint network
on it starting from the shipped weights, calibrates its covariance on held-out renders and evaluates
it there. Every stage resumes: run the same command again after a stop. Two looks (``look``):

- ``"random"`` (default), a part on a bench or in a hand: cluttered or photo backgrounds, ambient and
  extra lights, random colours (:mod:`hybridpose.render.appearance`); whole-frame crops in training
  so that the network finds the part itself on any background (``detection="network"``);
- ``"space"``, a part in orbit: black space and the sun alone, as the shipped truss network saw; the
  part is found as the sunlit pixels (``detection="bright"``).

Layout of ``out``: ``fit.json`` (the plan and what is done), ``data/train/`` (training views, BOP),
``data/calib/`` and ``data/test/`` (held-out views: half calibrate the covariance, half measure the
model), ``run/`` (the training run), ``best.pt`` (the exported checkpoint, its covariance calibrated:
``--regressor out/best.pt``), ``eval/`` (the held-out evaluation) and ``report.md`` (what was made, how
long it took, how accurate it is).
"""
from __future__ import annotations

import shutil
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from .fit_plan import (IMAGE_SIZE, TRAIN_BATCH, FitPlan, cache_fits, make_plan, measure_speeds, measure_train_speed,
                       parse_budget, plan_training, working_distances)
from .geometry import Camera
from .io import atomic_write_json, atomic_write_text, read_json
from .objects import ObjectModel

SHIPPED = "shipped"  # fit's backgrounds: the photos that come with hybridpose (render.appearance.SHIPPED_PHOTOS)
MIN_BUDGET_MIN = 5.0  # below this nothing usable can be trained on a CPU
# a new object's keypoint heads start afresh even from the shipped features: the from-scratch rate
# (1.5e-4 left a 40-minute box fit at 127° on its validation views after 3 epochs)
FIT_LR = 1e-3
# a start that already knows the part (its keypoints are the part's: re-fitting the built-in truss, or a
# fit resumed from an earlier one) is fine-tuned at the shipped network's last stages' rate instead
REFIT_LR = 5e-5
# the hybrid policy a new part's network recommends: its covariance, calibrated to cover its gross errors,
# let two answers 65° apart agree and restart a lost track at a wrong pose; within 20° they agree only
# near the truth (docs/decisions.md)
NEW_PART_POLICY = {"reacquire_deg": 20.0}
LOOKS = ("random", "space")
SUN_CONE_DEG = 85.0  # each view's sun within this of the look's centre direction
SPACE_SUN_CENTRE = (0.0, 0.0, 1.0)  # the "space" look's: the optical axis (light travelling away from the camera)
FULL_VIEW = 0.3  # share of training crops showing the whole frame (the network learns to find the part)
OCCLUDED_SHARE = 0.0  # share of training views with the arm in front of part of the object (docs/decisions.md)
TEXTURED_SHARE = 0.3  # share of training views with a random print on the part (docs/decisions.md)
# where a training view's print lies: "faces", a patch per face cut at its edges, as on a printed carton
# ("image": one picture across the silhouette); with GREY_SHARE of the views grey as a monochrome camera
# gives them, a 20-minute fit of the hand-held printed cube held 4 603 of 7 200 tuning frames (against
# 3 495), trusted 203 (244) > 10° off (docs/decisions.md)
PRINT_ON = "faces"
GREY_SHARE = 0.25  # ViSP's tutorial videos, machine-vision and space cameras are often monochrome
CARTON_SHARE = 0.0  # share of the prints drawn as a carton's (panels and lettering on card: render.carton)
MIN_OBJECT_PX = 24  # the part's image diameter at the far distance must be at least this
MIN_NEAR_M = 0.05  # a part that must come nearer than this to fill the image is too small to see (or mis-scaled)


def check_inputs(obj: ObjectModel, camera: Camera, budget_min: float,
                 distance_range_m: tuple[float, float] | None = None) -> tuple[float, float]:
    """Refuse, before any long work, what cannot give a usable model; returns the distance range
    (``distance_range_m``, metres, where the caller gives one, else :func:`working_distances`)."""
    if not budget_min >= MIN_BUDGET_MIN:
        raise ValueError(f"budget: {budget_min:g} min is too little to train anything on a CPU; "
                         f"give at least {MIN_BUDGET_MIN:g} min (60m is a usable model)")
    if distance_range_m is None:
        near, far = working_distances(obj, camera)
    else:
        near, far = (float(d) for d in distance_range_m)
        if not MIN_NEAR_M <= near < far:
            raise ValueError(f"distances: expected {MIN_NEAR_M:g} <= near < far in metres, got {near:g}, {far:g}")
    px_far = min(camera.fx, camera.fy) * obj.diameter / far
    if obj.diameter > 20.0:
        raise ValueError(f"object: {obj.name} is {obj.diameter:.1f} m across — is the mesh in millimetres? "
                         "pass --scale 0.001")
    if near < MIN_NEAR_M:
        raise ValueError(f"object: {obj.name} is {1000 * obj.diameter:.1f} mm across: it would fill this camera's image "
                         f"only {1000 * near:.0f} mm from the lens (at least {1000 * MIN_NEAR_M:.0f} mm expected) — "
                         "too small to see; is --scale right (a mesh in millimetres needs --scale 0.001, one in "
                         "metres none)?")
    if px_far < MIN_OBJECT_PX:
        raise ValueError(f"object: {obj.name} would be {px_far:.0f} px across at {far:.2f} m with this camera; "
                         f"at least {MIN_OBJECT_PX} px are needed")
    return near, far


def training_render_settings(backgrounds, distance_range_m, occluded_share: float = 0.0,
                             textured_share: float = 0.0, look: str = "random") -> dict:
    """The :func:`~hybridpose.datasets.render_random_dataset` settings of a fit's views (its held-out
    views: without the arm and the print, the shares' defaults). Each view's sun lies within 85° of a
    centre direction, at 0.6–1.3 × its intensity. ``"random"``: around the renderer's default sun
    direction (:class:`~hybridpose.render.SpaceLighting`, 46° off the optical axis: front-, side- and
    some back-light), beside ambient and fill lights. ``"space"``: the sun alone on black, around the
    optical axis (light from every side of the image, as the shipped truss network's last stages saw:
    centred on the default direction, a truss re-fit lost 2° mean on views lit from the far side).
    Depths are drawn log-uniformly over the range (as many views at 0.3–0.6 m as at 1.2–2.4 m): drawn
    uniformly, 0.4 % of a tea box fit's views lay at its video's 0.4–0.5 m."""
    from .render import AppearanceSpec, SpaceLighting

    real = look == "random"
    looks = AppearanceSpec(look, backgrounds and str(backgrounds), texture_share=textured_share, camera_effects=real,
                           print_on=PRINT_ON, grey_share=GREY_SHARE if real else 0.0,
                           carton_share=CARTON_SHARE if real and PRINT_ON == "faces" else 0.0)
    lighting = SpaceLighting(sun_direction_cam=SPACE_SUN_CENTRE) if look == "space" else SpaceLighting()
    return dict(distance_range_m=tuple(distance_range_m), in_view=True, appearance=looks, lighting=lighting,
                sun_cone_deg=SUN_CONE_DEG, sun_scale_range=(0.6, 1.3), occluded_share=occluded_share, log_depth=True)


def default_textured_share(look: str) -> float:
    """The share of a fit's training views with a random print on the part, unless told: real parts on a
    bench are often printed (a tea box, ViSP's cubes: fits without a print found neither), while the
    ``"space"`` look draws no print."""
    return TEXTURED_SHARE if look == "random" else 0.0


def start_learning_rate(start, obj: ObjectModel) -> float:
    """The training rate for a fit of ``obj`` from the checkpoint ``start`` (None: from scratch):
    ``REFIT_LR`` where ``start`` was trained on ``obj``'s own keypoints (its heads already place them:
    the from-scratch rate would throw away what they learnt), else ``FIT_LR`` (new keypoint heads)."""
    if start is None:
        return FIT_LR
    from .regressors.checkpoints import load_checkpoint

    known = (load_checkpoint(start).get("build") or {}).get("keypoints_m")
    same = known is not None and np.shape(known) == np.shape(obj.keypoints) and np.allclose(known, obj.keypoints, atol=1e-6)
    return REFIT_LR if same else FIT_LR


def keep_start_sun(start, checkpoint) -> bool:
    """Give ``checkpoint`` (a re-fit's export, rewritten in place) the sun record of its ``start`` when
    the re-fit's own light came from every side (its cone holds the optical axis, so its record asks
    for no crop turn) while the start's came from one side: the start's features learnt that side, and
    a fine-tune at ``REFIT_LR`` keeps them, so its crops still want the light turned there
    (:func:`~hybridpose.regressors.sun_turn.sun_turn_deg`). A truss re-fit on views lit around the axis
    measured 5.19° mean on such views with its start's record, 6.31° with its own. Returns whether it
    changed ``checkpoint``."""
    from .regressors.checkpoints import load_checkpoint, save_checkpoint
    from .regressors.sun_turn import trained_light_azimuth_deg

    start_light = (load_checkpoint(start).get("dataset") or {}).get("lighting")
    payload = load_checkpoint(checkpoint)
    dataset = payload.setdefault("dataset", {})
    if trained_light_azimuth_deg(start_light) is None or trained_light_azimuth_deg(dataset.get("lighting")) is not None:
        return False
    dataset["lighting"] = dict(start_light)
    save_checkpoint(Path(checkpoint), payload)
    return True


def record_hybrid_policy(start, checkpoint, refit: bool) -> dict:
    """Write into ``checkpoint`` (a fit's export, rewritten in place) the hybrid policy recommended
    for it (``hybrid_config``: :class:`~hybridpose.hybrid_config.HybridConfig` fields the estimator
    applies where its caller gives no config): for a new part's network, ``NEW_PART_POLICY``; for a
    re-fit, whatever its ``start`` recommended (the shipped truss network: nothing). Returns it."""
    from .regressors.checkpoints import load_checkpoint, save_checkpoint

    policy = dict(load_checkpoint(start).get("hybrid_config") or {}) if refit and start is not None else dict(NEW_PART_POLICY)
    if policy:
        payload = load_checkpoint(checkpoint)
        payload["hybrid_config"] = policy
        save_checkpoint(Path(checkpoint), payload)
    return policy


def fit(mesh, out, camera: Camera | None = None, scale: float = 1.0, budget="60m", seed: int = 0,
        backgrounds=SHIPPED, workers: int | None = None, init_from="default", progress=print,
        plan: FitPlan | None = None, bar=None, occluded_share: float = OCCLUDED_SHARE,
        textured_share: float | None = None, look: str = "random",
        distance_range_m: tuple[float, float] | None = None) -> dict:
    """Render, train, calibrate and evaluate a ``default`` keypoint regressor for ``mesh``.

    Args:
        mesh: a mesh file (metres, or ``scale`` to metres) or a built-in object name.
        out: the fit's folder (layout: module docstring); an interrupted fit resumes there.
        camera: the camera the part will be seen with (default 640×480, f = 600 px). Its views are
            rendered through its pinhole model (same K): the regressor undistorts each frame before
            its network sees it.
        budget: the time for the whole fit (``"60m"``, ``"1h"``, minutes as a number).
        seed: seeds of the training (``seed``), held-out (``seed + 1``) and calibration (``seed + 2``)
            renders and of the training run.
        backgrounds: a folder of photos: half the training backgrounds are crops of them; ``"shipped"``
            (default): the few public-domain photos that come with hybridpose (``"random"`` look;
            ``"space"`` has none); None: procedural clutter alone.
        workers: render processes; None: one per usable core. The software GL renderer spreads one
            process over the cores only partly: a box fit's views rendered at 0.069 s a view on one
            process of a 2-core CPU, 0.042 on two, 0.051 on three.
        init_from: the checkpoint the training starts from (its matching weights): ``"default"``
            (the shipped truss network's features), a path, or None (from scratch).
        occluded_share: share of the training views with the arm partly in front of the part
            (:func:`~hybridpose.datasets.render_random_dataset`); held-out views have none.
        textured_share: share of the training views whose part carries a random print (photo crops
            or procedural clutter, :func:`~hybridpose.render.appearance.part_texture`), as real parts
            are often printed or painted; held-out views stay plain. None: ``TEXTURED_SHARE`` with the
            ``"random"`` look, 0 in ``"space"``; 0 for a part known to be plain.
        look: ``"random"`` (a part on a bench or in a hand) or ``"space"`` (black space and the
            sun): see the module docstring. ``backgrounds`` needs ``"random"``.
        distance_range_m: (near, far) metres of the part in the training and held-out views, where
            the use is known (an arm's reach); default :func:`working_distances`.
        plan: views and epochs fixed by the caller instead of measured for ``budget`` (its
            ``budget_min`` is then not checked against the minimum, and its training is not
            re-planned after rendering: for tests and small trials). A measured plan's training is
            re-planned once the views are rendered, to fill the budget (:func:`plan_training`).
        progress: called with one line per stage. bar: ``bar(description)`` → a ``(done, total)``
            callback for the long stages (rendering, calibration, evaluation); None: silent.
    Returns:
        The fit record (``fit.json``): plan, minutes per stage, paths, held-out accuracy.
    """
    from .objects import load_object
    from .regressors.checkpoints import checkpoint_or_shipped, export_checkpoint
    from .training.evaluate import calibrate_checkpoint, evaluate_checkpoint
    from .regressors.models import torch_device
    from .training.precision import fast_bf16
    from .training.train import TrainConfig, train
    from .datasets import render_random_dataset
    from .workers import usable_cores

    out = Path(out)
    obj = load_object(str(mesh), scale=scale)
    camera = camera or Camera.default()
    if camera.dist:
        progress("fit: the views are rendered with the camera's pinhole model (same K); frames are undistorted "
                 "before the network sees them")
        camera = camera.pinhole()
    from .render.appearance import SHIPPED_PHOTOS

    if backgrounds == SHIPPED:
        backgrounds = SHIPPED if look == "random" else None
    textured_share = default_textured_share(look) if textured_share is None else textured_share
    photos = SHIPPED_PHOTOS if backgrounds == SHIPPED else backgrounds  # what the views are cut from
    measured = plan is None
    budget_min = parse_budget(budget) if plan is None else plan.budget_min
    distances = check_inputs(obj, camera, budget_min if plan is None else MIN_BUDGET_MIN, distance_range_m)
    record_path = out / "fit.json"
    request = {"mesh": str(mesh), "scale": float(scale), "camera": camera.to_dict(), "budget_min": budget_min,
               "seed": int(seed), "backgrounds": None if backgrounds is None else str(backgrounds),
               "init_from": None if init_from is None else str(init_from),
               # recorded only when set, so that fits made before the option still resume
               **({} if occluded_share == 0 else {"occluded_share": float(occluded_share)}),
               **({} if textured_share == 0 else {"textured_share": float(textured_share)}),
               **({} if look == "random" else {"look": look}),
               **({} if distance_range_m is None else {"distance_range_m": list(distances)})}
    workers = usable_cores() if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers: expected ≥ 1 render processes (or None: one per core), got {workers}")
    if not 0.0 <= occluded_share <= 1.0:
        raise ValueError(f"occluded_share: expected a share of the training views in [0, 1], got {occluded_share}")
    if not 0.0 <= textured_share <= 1.0:
        raise ValueError(f"textured_share: expected a share of the training views in [0, 1], got {textured_share}")
    if look not in LOOKS:
        raise ValueError(f"look: expected one of {', '.join(LOOKS)}, got {look!r}")
    if look == "space" and backgrounds is not None:
        raise ValueError("backgrounds: photos are backgrounds of the 'random' look; look 'space' has black space")
    if record_path.is_file():
        record = read_json(record_path)
        if record["request"] != request:
            diff = sorted(k for k in {*request, *record["request"]} if record["request"].get(k) != request.get(k))
            was = ", ".join(f"{k} {record['request'].get(k)!r} there, {request.get(k)!r} now" for k in diff)
            raise ValueError(f"out: {out} holds a fit with other settings ({was}); give its settings to resume it, "
                             "or choose another --out")
        plan = FitPlan(**{**record["plan"], "distance_range_m": tuple(record["plan"]["distance_range_m"])})
        progress(f"fit: resuming in {out}")
    else:
        minutes = {}
        if plan is None:
            progress(f"fit: measuring this machine ({obj.name}, {camera.width}×{camera.height})")
            t0 = time.time()
            speeds = measure_speeds(obj, camera, workers=workers, **training_render_settings(
                photos, distances, occluded_share, textured_share, look))
            plan = make_plan(budget_min, *speeds, distances)
            minutes["measure"] = (time.time() - t0) / 60
        record = {"request": request, "plan": asdict(plan), "minutes": minutes, "done": []}
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(record_path, record)
    progress(f"fit: plan — {plan.train_views} training + {plan.test_views} held-out views, {plan.epochs} epochs "
             f"within {plan.train_min:.0f} min of training, budget {plan.budget_min:g} min")

    def stage(name, fn):
        if name in record["done"]:
            return
        t0 = time.time()
        progress(f"fit: {name}")
        fn()
        record["minutes"][name] = record["minutes"].get(name, 0.0) + (time.time() - t0) / 60
        record["done"].append(name)
        atomic_write_json(record_path, record)

    training_views = training_render_settings(photos, plan.distance_range_m, occluded_share, textured_share, look)
    held_out = training_render_settings(photos, plan.distance_range_m, look=look)
    tick = bar or (lambda _desc: None)
    half = max(1, plan.test_views // 2)
    stage("render", lambda: (
        render_random_dataset(out / "data" / "train", obj, camera, plan.train_views, seed=seed, workers=workers,
                              progress=tick("render training views"), **training_views),
        render_random_dataset(out / "data" / "calib", obj, camera, half, seed=seed + 2, workers=workers,
                              progress=tick("render calibration views"), **held_out),
        render_random_dataset(out / "data" / "test", obj, camera, plan.test_views - half, seed=seed + 1,
                              workers=workers, progress=tick("render held-out views"), **held_out)))

    def run_training():
        cache = out / "data" / "decoded"
        start = None if init_from is None else str(checkpoint_or_shipped(init_from))
        cfg = TrainConfig(model="default", data=str(out / "data" / "train"), out=str(out / "run"),
                          epochs=plan.epochs, batch=TRAIN_BATCH, lr=start_learning_rate(start, obj),
                          image_size=IMAGE_SIZE, val_fraction=0.05, seed=seed, patience=0, schedule="cosine",
                          init_from=start, time_limit_min=plan.train_min, fill_time=True,
                          full_view=FULL_VIEW if look == "random" else 0.0, workers=1,
                          amp=fast_bf16(torch_device("auto")),
                          cache_images=str(cache) if cache_fits(plan.train_views, camera, out) else None)
        record["learning_rate"] = cfg.lr
        record["training_bf16"] = cfg.amp
        record["epochs_trained"] = train(cfg, resume=(out / "run" / "last.pt").is_file(), progress=bar is not None)["epochs_run"]
        if cfg.cache_images:  # rebuilt in under a minute by a resumed run: not worth gigabytes in the fit's folder
            shutil.rmtree(cache, ignore_errors=True)
        export_checkpoint(out / "run" / "best.pt", out / "best.pt")
        if cfg.lr == REFIT_LR and keep_start_sun(start, out / "best.pt"):
            progress("fit: kept the start's sun side (its crops are turned to the light it learnt)")

    if measured and "train" not in record["done"] and not record.get("training_planned"):
        # the training speed measured again, and the faster of the two measurements kept: what else ran
        # on the machine at either moment is no guide (a fit measured beside another job planned 10
        # epochs at 0.034 s a view, trained them at 0.016 and stopped after 5 of its 14 minutes; a
        # 60-minute fit measured again while a test suite ran planned 1 epoch and trained 7 of 44)
        plan = replace(plan, train_s_per_view=min(plan.train_s_per_view, measure_train_speed(obj)))
        plan = plan_training(plan, sum(record["minutes"].values()))
        record.update(plan=asdict(plan), training_planned=True)
        atomic_write_json(record_path, record)
        progress(f"fit: training re-planned for the time left — about {plan.epochs} epochs within {plan.train_min:.0f} min "
                 "(counted again after each)")
    stage("train", run_training)
    if "hybrid_config" not in record:  # also brings a fit made before checkpoints carried their policy up to date
        start = None if init_from is None else str(checkpoint_or_shipped(init_from))
        record["hybrid_config"] = record_hybrid_policy(start, out / "best.pt",
                                                       refit=start_learning_rate(start, obj) == REFIT_LR)
        atomic_write_json(record_path, record)

    def run_calibration():
        try:
            calibrate_checkpoint(out / "best.pt", out / "data" / "calib", out / "best.pt", progress=tick("calibrate"))
        except ValueError as exc:  # too few poses: the model is not usable yet; the report says so
            record["calibration_skipped"] = str(exc)
            progress(f"fit: covariance not re-calibrated ({exc})")

    stage("calibrate", run_calibration)
    stage("evaluate", lambda: evaluate_checkpoint(out / "best.pt", out / "data" / "test", out / "eval", gradcam_count=2,
                                                  timing_images=20, progress=tick("evaluate")))
    report = read_json(out / "eval" / "report.json")
    record["accuracy"] = held_out_accuracy(report, obj)
    atomic_write_json(record_path, record)
    atomic_write_text(out / "report.md", fit_report(record, obj))
    progress(f"fit: wrote {out / 'best.pt'} and {out / 'report.md'}")
    return record


def held_out_accuracy(report: dict, obj: ObjectModel) -> dict:
    """The held-out figures a user asks first: median / mean rotation (°) and translation (% of the
    distance), and the share of views a tracker can start from (≤ 10° and ≤ 5 % of the distance) —
    each also up to the part's box twins (``*_twin``: what a box-symmetric part cannot tell apart).
    The evaluation already scores a symmetric part against the nearest of its equivalent poses."""
    rows = report["per_image"]
    rot_twin = np.array([r.get("rot_twin_deg", r["rot_deg"]) for r in rows], float)
    rot = np.array([r["rot_deg"] for r in rows], float)
    pct = np.array([100 * r["trans_m"] / max(r["distance_m"], 1e-9) for r in rows], float)
    return {"views": len(rows), "rot_median_deg": float(np.median(rot)), "rot_mean_deg": float(np.mean(rot)),
            "rot_twin_median_deg": float(np.median(rot_twin)), "trans_median_pct": float(np.median(pct)),
            "in_tracker_basin": float(np.mean((rot <= 10.0) & (pct <= 5.0))),
            "in_tracker_basin_twin": float(np.mean((rot_twin <= 10.0) & (pct <= 5.0))),
            "lost": int(sum(bool(r.get("lost")) for r in rows))}


def fit_report(record: dict, obj: ObjectModel) -> str:
    p, a, req = record["plan"], record["accuracy"], record["request"]
    from .hybrid_config import changes_text, recommended_config

    policy = record.get("hybrid_config") or {}
    carried = changes_text(recommended_config(policy))  # named as bench rows and track's log name it
    why = (f" The checkpoint carries the hybrid policy `{carried}`, which both apply"
           + (" (a new part's network is sometimes far off where it looks sure: two of its answers must agree "
              "within 20° to restart a lost track)" if "reacquire_deg" in policy else "")
           + "; `--hybrid-option NAME=VALUE` (`config={...}`) changes it." if policy else "")
    minutes = " · ".join(f"{k} {v:.1f}" for k, v in record["minutes"].items())
    return "\n".join([
        f"# hybridpose fit: {obj.name}", "",
        f"Mesh `{req['mesh']}` (×{req['scale']:g} → metres, {obj.diameter:.3f} m across), camera "
        f"{req['camera']['width']}×{req['camera']['height']}, budget {p['budget_min']:g} min, seed {req['seed']}.", "",
        f"- Rendered {p['train_views']} training and {p['test_views']} held-out views ("
        + ("black space and the sun alone" if req.get("look") == "space" else
           f"random backgrounds ({_backgrounds(req.get('backgrounds'))}), lights, colours and camera effects, "
           f"{GREY_SHARE:.0%} of the views grey")
        + f"; the part {p['distance_range_m'][0]:.2f}–{p['distance_range_m'][1]:.2f} m away"
        + (f"; the arm partly in front of it in {req['occluded_share']:.0%} of the training views" if req.get("occluded_share") else "")
        + ("; the part's own print, from its mesh file" if obj.texture is not None else "")
        + (f"; a random print on {'its faces' if PRINT_ON == 'faces' else 'it'} in {req['textured_share']:.0%} of the training views"
           + (f", {CARTON_SHARE:.0%} of them a carton's (panels and lettering)" if CARTON_SHARE and PRINT_ON == "faces" else "")
           if req.get("textured_share") else "") + ").",
        f"- Trained the `default` network ({IMAGE_SIZE} px, "
        + ("found as the sunlit pixels" if req.get("look") == "space" else f"{FULL_VIEW:.0%} whole-frame crops")
        + (f"; one unlabelled heatmap of its {len(obj.keypoints)} keypoints, which look alike under its symmetries"
           if obj.symmetric else "") + ") for "
        + (f"{record['epochs_trained']} epochs" if "epochs_trained" in record else f"up to {p['epochs']} epochs")
        + f" within {p['train_min']:.0f} min" + (", its forward passes in bfloat16" if record.get("training_bf16") else "")
        + f", from `{req['init_from']}`.",
        f"- Minutes per stage: {minutes}.", "",
        f"Held-out views ({a['views']}, not those that calibrated the covariance): rotation error median "
        f"{a['rot_median_deg']:.2f}°, mean {a['rot_mean_deg']:.2f}°; translation median {a['trans_median_pct']:.2f} % "
        f"of the distance; **{100 * a['in_tracker_basin']:.0f} % within a tracker's basin** (≤ 10° and ≤ 5 % of the "
        f"distance); {a['lost']} found nothing"
        + (f" — errors to the nearest of the part's {len(obj.symmetries) + 1} equivalent poses (it is symmetric)."
           if obj.symmetric else
           f". Up to the part's box twins (end-for-end turns a near-symmetric part invites): median "
           f"{a['rot_twin_median_deg']:.2f}°, {100 * a['in_tracker_basin_twin']:.0f} % within the basin."), "",
        *([f"**The covariance was not re-calibrated**: {record['calibration_skipped']} — the model needs a larger "
           "budget (or `--backgrounds` closer to the real scenes) before it is usable.", ""]
          if record.get("calibration_skipped") else []),
        f"Use it: `hybridpose track VIDEO --object MESH --camera CAM --regressor best.pt` or "
        f"`HybridEstimator.from_names(object=MESH, regressor=\"best.pt\")`.{why}",
        "The full evaluation: `eval/report.md`.",
        ""])


def _backgrounds(recorded) -> str:
    """What a fit's record says its views' backgrounds were, in words."""
    if recorded is None:
        return "procedural clutter"
    return ("half procedural clutter, half hybridpose's photos" if recorded == SHIPPED
            else f"half procedural clutter, half crops of `{recorded}`")
