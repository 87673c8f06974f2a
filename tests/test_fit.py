"""``hybridpose fit``: budget and plan, input checks before long work, and a tiny fit end to end."""
import json
import time

import cv2
import numpy as np
import pytest
import trimesh

from hybridpose.cli import main
from hybridpose.fit import FIT_LR, REFIT_LR, check_inputs, fit, start_learning_rate, training_render_settings
from hybridpose.fit_plan import (EVAL_RESERVE_MIN, PLAN_MARGIN, RENDER_SHARE, REPLAN_MARGIN, FitPlan, make_plan,
                                 measure_speeds, parse_budget, plan_training, working_distances)
from hybridpose.geometry import Camera
from hybridpose.objects import load_object
from hybridpose.regressors.models import torch_device
from hybridpose.render import SpaceLighting
from hybridpose.training.precision import fast_bf16


@pytest.fixture(scope="module")
def box_mesh(tmp_path_factory):
    """A 20 × 12 × 8 cm box, in millimetres as CAD exports often are."""
    path = tmp_path_factory.mktemp("mesh") / "box_mm.obj"
    trimesh.creation.box(extents=(200.0, 120.0, 80.0)).export(path)
    return path


def test_budgets_read_as_minutes():
    assert parse_budget("60m") == 60 and parse_budget("1h") == 60 and parse_budget("1h30m") == 90
    assert parse_budget("90s") == 1.5 and parse_budget(45) == 45 and parse_budget("2.5") == 2.5
    for bad in ("", "soon", "10 parsecs", "m"):
        with pytest.raises(ValueError, match="budget: expected a time"):
            parse_budget(bad)


def test_the_plan_grows_with_the_budget_and_fits_it():
    from hybridpose.fit_plan import TRAIN_SHARE

    assert RENDER_SHARE + TRAIN_SHARE < 1  # room left for calibration and evaluation
    small = make_plan(15, 0.05, 0.02, (0.3, 1.2))
    large = make_plan(60, 0.05, 0.02, (0.3, 1.2))
    assert large.train_views >= small.train_views and large.test_views >= small.test_views
    for p in (small, large):
        # the rendering fits its share, and at least two epochs over the views fit the training time
        assert (p.train_views + p.test_views) * p.render_s_per_view <= 60 * p.budget_min * RENDER_SHARE + 1
        assert 2 * p.train_views * p.train_s_per_view <= 60 * p.train_min + 1e-6
        assert p.epochs * p.train_views * p.train_s_per_view <= 60 * p.train_min * 1.01


def test_decoded_training_views_are_kept_only_where_the_disk_has_room(tmp_path):
    import shutil

    from hybridpose.fit_plan import CACHE_DISK_SHARE, cache_fits

    cam = Camera.default()
    free = shutil.disk_usage(tmp_path).free
    fits = int(CACHE_DISK_SHARE * free // (cam.width * cam.height * 3))
    assert cache_fits(fits, cam, tmp_path) and not cache_fits(fits + 1, cam, tmp_path)


def test_the_training_fills_the_time_the_rendering_left():
    plan = make_plan(60, 0.05, 0.0134, (0.3, 1.2))
    quick = plan_training(plan, spent_min=14.0)
    # the budget's rest after rendering, less the reserve for calibration and evaluation
    assert quick.train_min == pytest.approx(60 - 14 - EVAL_RESERVE_MIN) and quick.train_min > plan.train_min
    assert quick.epochs > plan.epochs and quick.train_views == plan.train_views
    assert quick.epochs * REPLAN_MARGIN * quick.train_views * quick.train_s_per_view <= 60 * quick.train_min
    assert (quick.epochs + 1) * REPLAN_MARGIN * quick.train_views * quick.train_s_per_view > 60 * quick.train_min
    # a render stage that overran leaves half the planned training, not none
    late = plan_training(plan, spent_min=59.0)
    assert late.train_min == pytest.approx(0.5 * plan.train_min) and late.epochs >= 1


def test_a_measured_plan_trains_for_the_time_left_after_rendering(box_mesh, tmp_path, monkeypatch):
    import hybridpose.fit as fit_module
    import hybridpose.training.train as train_module

    cam = Camera.default().scaled((320, 240))
    box = load_object(str(box_mesh), scale=0.001)
    tiny = FitPlan(budget_min=6.0, train_views=32, test_views=4, epochs=1, train_min=1.0, render_s_per_view=0.05,
                   train_s_per_view=0.05, distance_range_m=working_distances(box, cam))
    monkeypatch.setattr(fit_module, "measure_speeds", lambda *a, **k: (0.05, 0.05))
    monkeypatch.setattr(fit_module, "make_plan", lambda *a, **k: tiny)
    # the machine was busy when the fit began: training runs five times faster than first measured
    monkeypatch.setattr(fit_module, "measure_train_speed", lambda *a, **k: 0.01)
    runs = []

    class Stop(Exception):
        pass

    def no_training(cfg, **kw):
        runs.append(cfg)
        raise Stop

    monkeypatch.setattr(train_module, "train", no_training)
    out = tmp_path / "fit"
    with pytest.raises(Stop):
        fit(box_mesh, out, camera=cam, scale=0.001, budget="6m", progress=lambda *_: None)
    record = json.loads((out / "fit.json").read_text())
    spent = record["minutes"]["measure"] + record["minutes"]["render"]
    assert record["training_planned"] and record["plan"]["train_min"] == pytest.approx(6.0 - spent - EVAL_RESERVE_MIN)
    # …planned at the speed measured just before training, not the first one
    assert record["plan"]["train_s_per_view"] == 0.01
    assert record["plan"]["epochs"] == min(200, int(60 * record["plan"]["train_min"] / (REPLAN_MARGIN * 32 * 0.01)))
    assert record["plan"]["epochs"] > int(60 * record["plan"]["train_min"] / (REPLAN_MARGIN * 32 * 0.05))
    assert runs[0].time_limit_min == record["plan"]["train_min"] and runs[0].epochs == record["plan"]["epochs"] > 1
    assert runs[0].amp == fast_bf16(torch_device("auto"))  # bf16 forward passes where the device is fast at them
    # resumed, the training keeps the plan it was given (its schedule runs over those epochs)
    with pytest.raises(Stop):
        fit(box_mesh, out, camera=cam, scale=0.001, budget="6m", progress=lambda *_: None)
    assert runs[1].epochs == runs[0].epochs and runs[1].time_limit_min == runs[0].time_limit_min
    # the machine busy when measured again instead: the first, faster measurement plans the training
    monkeypatch.setattr(fit_module, "measure_train_speed", lambda *a, **k: 1.0)
    with pytest.raises(Stop):
        fit(box_mesh, tmp_path / "busy", camera=cam, scale=0.001, budget="6m", progress=lambda *_: None)
    assert json.loads((tmp_path / "busy" / "fit.json").read_text())["plan"]["train_s_per_view"] == 0.05


def test_this_machine_is_measured_before_planning(box_mesh):
    box = load_object(str(box_mesh), scale=0.001)
    render_s, train_s = measure_speeds(box, Camera.default().scaled((320, 240)), views=2)
    assert 0 < render_s < 5 and 0 < train_s < 5
    plan = make_plan(30, render_s, train_s, (0.3, 1.2))
    assert plan.train_views >= 100 and plan.epochs >= 1


def test_the_render_speed_leaves_out_the_renderer_start_up(box_mesh, monkeypatch):
    """A process's first render call also starts GL and loads the mesh: timed in the shorter of the two
    runs, it cancelled the views' own time out (a truss fit planned 0.018 s a view, rendered 0.05)."""
    import hybridpose.datasets as datasets

    started = []

    def fake_render(out, obj, camera, count, seed=0, **kw):
        if not started:
            started.append(True)
            time.sleep(0.3)
        time.sleep(0.01 * count)

    monkeypatch.setattr(datasets, "render_random_dataset", fake_render)
    render_s, _ = measure_speeds(load_object(str(box_mesh), scale=0.001), Camera.default().scaled((320, 240)),
                                 views=8)
    assert 0.008 < render_s < 0.02


def test_the_render_speed_is_measured_on_the_fits_own_render_processes(box_mesh, monkeypatch):
    """Rendering on two processes is not twice as fast where one process's software GL already uses
    both cores: the speed is measured with the fit's processes, and the plan takes it as it is (a
    2-process truss fit planned twice one process's rate and rendered at 1.1 times it)."""
    import hybridpose.datasets as datasets

    from hybridpose.datasets.generate import CHECKPOINT_EVERY

    seen = []

    def one_process_speed(out, obj, camera, count, seed=0, workers=1, **kw):
        seen.append(workers)
        if workers > 1 and count > CHECKPOINT_EVERY:  # a pool: its processes start within the call
            time.sleep(0.3)
        time.sleep(0.005 * count)  # the same wall time on any number of processes

    monkeypatch.setattr(datasets, "render_random_dataset", one_process_speed)
    render_s, train_s = measure_speeds(load_object(str(box_mesh), scale=0.001), Camera.default().scaled((320, 240)),
                                       workers=2)
    # both timed runs start a pool (timed 2 views against 34, the pool's start read 0.138 s a view for 0.042)
    assert seen == [2, 2, 2] and 0.004 < render_s < 0.008
    plan = make_plan(60, render_s, train_s, (0.3, 1.2))
    assert (plan.train_views + plan.test_views) * render_s <= 60 * 60 * RENDER_SHARE / PLAN_MARGIN + 1


def test_the_render_speed_is_measured_on_views_like_the_training_views(box_mesh, tmp_path, monkeypatch):
    """The plan's render time comes from views with the fit's own photos, lights and shares: measured
    on plain views, a fit's quarter of the budget for rendering once took half of it."""
    import hybridpose.datasets as datasets

    calls = []

    class Stop(Exception):
        pass

    def fake_render(out, obj, camera, count, seed=0, **kw):
        calls.append(kw)
        if len(calls) > 3:  # the three measuring runs, then the training views: enough seen
            raise Stop
        return None

    monkeypatch.setattr(datasets, "render_random_dataset", fake_render)
    photos = tmp_path / "photos"
    photos.mkdir()
    cv2.imwrite(str(photos / "grey.png"), np.full((64, 64, 3), 90, np.uint8))
    with pytest.raises(Stop):
        fit(str(box_mesh), tmp_path / "fit", scale=0.001, budget="30m", backgrounds=photos, textured_share=0.25,
            occluded_share=0.2, progress=lambda _line: None)
    measured, training = calls[2], calls[3]
    for key in ("appearance", "distance_range_m", "lighting", "sun_cone_deg", "sun_scale_range", "occluded_share",
                "in_view"):
        assert measured[key] == training[key], key
    # a part on a bench: the sun's cone around the renderer's default direction, beside other lights
    assert training["lighting"].sun_direction_cam == SpaceLighting().sun_direction_cam
    assert measured["appearance"].backgrounds == str(photos) and measured["appearance"].texture_share == 0.25


class _Stop(Exception):
    """Raised by the fake renderer of :func:`_renders`: what the fit asked for is seen."""


def _renders(monkeypatch) -> list:
    """The renderer replaced: each call's (camera, keywords) recorded, then ``_Stop`` raised."""
    import hybridpose.datasets as datasets

    calls = []

    def fake_render(out, obj, camera, count, seed=0, **kw):
        calls.append((camera, kw))
        raise _Stop

    monkeypatch.setattr(datasets, "render_random_dataset", fake_render)
    return calls


def test_by_default_a_fit_cuts_half_its_backgrounds_from_the_photos_hybridpose_ships(box_mesh, tmp_path, monkeypatch):
    """Procedural clutter alone left a network blind to a printed cube in real footage: unless told
    otherwise (a folder of the user's photos, or None) a fit draws on the shipped public-domain photos."""
    from hybridpose.render.appearance import SHIPPED_PHOTOS, PhotoBackgrounds

    calls = _renders(monkeypatch)
    assert len(PhotoBackgrounds(str(SHIPPED_PHOTOS)).files) >= 5  # in the package, readable
    for kw, expected in (({}, str(SHIPPED_PHOTOS)), ({"backgrounds": None}, None), ({"look": "space"}, None)):
        with pytest.raises(_Stop):
            fit(str(box_mesh), tmp_path / f"fit{len(calls)}", scale=0.001, budget="30m", progress=lambda _line: None,
                **kw)
        assert calls[-1][1]["appearance"].backgrounds == expected


def test_a_fit_renders_on_every_core_unless_told(box_mesh, tmp_path, monkeypatch):
    """One software-GL process left half of a 2-core CPU idle (0.069 s a view against 0.042 on two): by
    default a fit measures and renders on one process per usable core; ``workers`` overrides it."""
    import hybridpose.workers as workers

    calls = _renders(monkeypatch)
    monkeypatch.setattr(workers, "usable_cores", lambda: 3)
    for kw, expected in (({}, 3), ({"workers": 1}, 1)):
        with pytest.raises(_Stop):
            fit(str(box_mesh), tmp_path / f"fit{len(calls)}", scale=0.001, budget="30m", progress=lambda _line: None,
                **kw)
        assert calls[-1][1]["workers"] == expected
    with pytest.raises(ValueError, match="workers"):
        fit(str(box_mesh), tmp_path / "bad", scale=0.001, budget="30m", workers=0, progress=lambda _line: None)


def test_a_camera_with_lens_distortion_is_rendered_through_its_pinhole(box_mesh, tmp_path, monkeypatch):
    """The renderer is a pinhole and the regressor undistorts every frame: a calibrated camera's views
    are rendered with its K and no distortion, and the fit says so."""
    calls, lines = _renders(monkeypatch), []
    lens = Camera(640, 480, 610.0, 612.0, 321.0, 238.0, (-0.2, 0.05, 0.0, 0.0, 0.0))
    box = load_object(str(box_mesh), scale=0.001)
    plan = FitPlan(budget_min=2.0, train_views=8, test_views=4, epochs=1, train_min=1.0, render_s_per_view=0.05,
                   train_s_per_view=0.05, distance_range_m=working_distances(box, lens))
    with pytest.raises(_Stop):
        fit(str(box_mesh), tmp_path / "fit", camera=lens, scale=0.001, plan=plan, progress=lines.append)
    assert calls[0][0] == lens.pinhole() and not calls[0][0].dist
    assert any("pinhole model (same K)" in line for line in lines)


def test_what_cannot_work_is_refused_before_long_work(box_mesh):
    cam = Camera.default()
    in_mm = load_object(str(box_mesh))
    with pytest.raises(ValueError, match="millimetres.*--scale 0.001"):
        check_inputs(in_mm, cam, 60)
    box = load_object(str(box_mesh), scale=0.001)
    near, far = check_inputs(box, cam, 60)
    assert 0 < near < far and (near, far) == working_distances(box, cam)
    with pytest.raises(ValueError, match="too little"):
        check_inputs(box, cam, 2)
    with pytest.raises(ValueError, match="px across"):
        check_inputs(box, Camera.default().scaled((40, 30)), 60)
    tiny = load_object(str(box_mesh), scale=0.00001)  # mm read as 10 µm: a 2-mm part
    with pytest.raises(ValueError, match="too small to see; is --scale right"):
        check_inputs(tiny, cam, 60)


def test_a_fit_prints_the_part_in_some_views_unless_in_space():
    from hybridpose.fit import TEXTURED_SHARE, default_textured_share

    assert default_textured_share("random") == TEXTURED_SHARE > 0 and default_textured_share("space") == 0.0
    views = training_render_settings(None, (0.3, 2.0), textured_share=default_textured_share("random"))
    assert views["appearance"].texture_share == TEXTURED_SHARE and views["log_depth"]
    # the print on the part's faces, a share of the views grey as a monochrome camera gives them; in
    # space neither (the renders are the sunlit part on black, grey already)
    looks = views["appearance"]
    assert looks.print_on == "faces" and 0 < looks.grey_share < 1 and looks.camera_effects
    assert training_render_settings(None, (0.3, 2.0), look="space")["appearance"].grey_share == 0.0


def test_the_working_distances_reach_a_part_that_fills_the_frame(box_mesh):
    """The near end is where the part's diameter spans the image's height (ViSP's tea box 0.45 m from its
    839-px camera spans 77 % of it: inside, where a 70 % end left it out)."""
    box = load_object(str(box_mesh), scale=0.001)
    cam = Camera.from_K(np.array([[839.2, 0, 325.7], [0, 839.4, 243.7], [0, 0, 1]]), 640, 480)
    near, far = working_distances(box, cam)
    span = cam.fx * box.diameter / near
    assert span == pytest.approx(480, rel=1e-3) and far > 8 * near


@pytest.mark.slow  # tens of seconds on a 2-core CPU: CI runs it in its slow step
def test_a_tiny_fit_renders_trains_calibrates_evaluates_and_resumes(box_mesh, tmp_path, capsys, monkeypatch):
    from hybridpose.datasets.torch_dataset import PoseDataset

    sources = []  # the training cuts its crops from decoded views, then the fit removes them
    real_cache = PoseDataset.cache_sources
    monkeypatch.setattr(PoseDataset, "cache_sources",
                        lambda self, d, **kw: sources.append(d) or real_cache(self, d, **kw))
    cam = Camera.default().scaled((320, 240))
    box = load_object(str(box_mesh), scale=0.001)
    plan = FitPlan(budget_min=2.0, train_views=32, test_views=44, epochs=1, train_min=1.0, render_s_per_view=0.05,
                   train_s_per_view=0.05, distance_range_m=working_distances(box, cam))
    out = tmp_path / "fit"
    record = fit(box_mesh, out, camera=cam, scale=0.001, seed=3, plan=plan, progress=lambda *_: None,
                 occluded_share=0.25, textured_share=0.5)
    assert record["done"] == ["render", "train", "calibrate", "evaluate"]
    assert (out / "best.pt").is_file() and (out / "eval" / "report.json").is_file()
    assert [str(d) for d in sources] == [str(out / "data" / "decoded")] and not (out / "data" / "decoded").exists()
    acc = record["accuracy"]
    assert acc["views"] == 22 and 0.0 <= acc["in_tracker_basin"] <= acc["in_tracker_basin_twin"] <= 1.0
    assert np.isfinite(acc["rot_median_deg"]) and acc["rot_twin_median_deg"] <= acc["rot_median_deg"]
    report = (out / "report.md").read_text()
    assert "within a tracker's basin" in report and "32 training and 44 held-out views" in report and "equivalent poses" in report
    # the training's precision is the machine's fast one, and the report says which
    assert record["training_bf16"] == fast_bf16(torch_device("auto"))
    assert ("its forward passes in bfloat16" in report) == record["training_bf16"]
    # a new part's network carries the hybrid policy it wants, and the estimator applies it
    assert record["hybrid_config"] == {"reacquire_deg": 20.0} and "hybrid policy `reacquire_deg=20`" in report
    # the rendered views have random looks, not black space
    cfg = json.loads((out / "data" / "train" / "hybridpose.json").read_text())
    assert cfg["appearance"]["kind"] == "random"
    assert cfg["log_depth"]  # as many views in each doubling of the distance
    # the arm in front of a quarter of the training views, never in the held-out ones
    assert cfg["occluded_share"] == 0.25 and record["request"]["occluded_share"] == 0.25
    assert "the arm partly in front of it in 25% of the training views" in report
    assert "occluded_share" not in json.loads((out / "data" / "test" / "hybridpose.json").read_text())
    # a print on the part in half the training views, none in the held-out ones
    assert cfg["appearance"]["texture_share"] == 0.5 and record["request"]["textured_share"] == 0.5
    assert "a random print on its faces in 50% of the training views" in report
    assert "texture_share" not in json.loads((out / "data" / "test" / "hybridpose.json").read_text())["appearance"]
    # the checkpoint finds the part itself (trained with whole-frame crops)
    from hybridpose.regressors.predictor import CheckpointRegressor

    reg = CheckpointRegressor(out / "best.pt")
    assert reg.detection == "network" and reg.hybrid_config == {"reacquire_deg": 20.0}
    # started from the truss network's weights, but with the box's own keypoints
    assert np.allclose(reg.keypoints_m, box.keypoints)
    # the box's corners look alike under its half-turns: one unlabelled heatmap, PnP tries the labellings
    assert reg.net.unlabelled and reg.passes.unlabelled is not None and reg.twins == [] and not reg.has_twin_head
    # a second run resumes: nothing is done again
    stamp = (out / "best.pt").stat().st_mtime_ns
    again = fit(box_mesh, out, camera=cam, scale=0.001, seed=3, plan=plan, progress=lambda *_: None,
                occluded_share=0.25, textured_share=0.5)
    assert again["minutes"] == record["minutes"] and (out / "best.pt").stat().st_mtime_ns == stamp
    # a fit made before checkpoints carried their policy gets it when run again, nothing else redone
    from hybridpose.regressors.checkpoints import load_checkpoint, save_checkpoint

    old = json.loads((out / "fit.json").read_text())
    del old["hybrid_config"]
    (out / "fit.json").write_text(json.dumps(old))
    save_checkpoint(out / "best.pt", {k: v for k, v in load_checkpoint(out / "best.pt").items() if k != "hybrid_config"})
    upgraded = fit(box_mesh, out, camera=cam, scale=0.001, seed=3, plan=plan, progress=lambda *_: None,
                   occluded_share=0.25, textured_share=0.5)
    assert upgraded["hybrid_config"] == {"reacquire_deg": 20.0} and upgraded["minutes"] == record["minutes"]
    assert CheckpointRegressor(out / "best.pt").hybrid_config == {"reacquire_deg": 20.0}
    with pytest.raises(ValueError, match="other settings.*seed 3 there, 4 now.*give its settings to resume"):
        fit(box_mesh, out, camera=cam, scale=0.001, seed=4, plan=plan, progress=lambda *_: None, occluded_share=0.25,
            textured_share=0.5)
    with pytest.raises(ValueError, match="other settings.*occluded_share"):
        fit(box_mesh, out, camera=cam, scale=0.001, seed=3, plan=plan, progress=lambda *_: None, textured_share=0.5)
    with pytest.raises(ValueError, match="other settings.*textured_share"):
        fit(box_mesh, out, camera=cam, scale=0.001, seed=3, plan=plan, progress=lambda *_: None, occluded_share=0.25)


@pytest.mark.slow  # tens of seconds on a 2-core CPU: CI runs it in its slow step
def test_a_symmetric_parts_covariance_is_calibrated_on_its_errors_to_the_nearest_equivalent_pose(
        box_mesh, tmp_path, monkeypatch):
    """A regressor that answers each view with one of the box's equivalent poses (no image tells them
    apart), 0.2° and 1 mm off it, is calibrated as one that answers with the true pose: before, the
    errors counted to the true pose put the half-turns' 180° into the covariance."""
    from hybridpose.core import Measurement
    from hybridpose.datasets.bop import BopScene
    from hybridpose.training import evaluate
    from hybridpose.regressors.predictor import CheckpointRegressor

    cam = Camera.default().scaled((320, 240))
    box = load_object(str(box_mesh), scale=0.001)
    plan = FitPlan(budget_min=2.0, train_views=32, test_views=120, epochs=1, train_min=1.0, render_s_per_view=0.05,
                   train_s_per_view=0.05, distance_range_m=working_distances(box, cam))
    out = tmp_path / "fit"
    fit(box_mesh, out, camera=cam, scale=0.001, seed=5, plan=plan, progress=lambda *_: None)
    truths = {}
    for scene in (BopScene(p) for p in sorted((out / "data" / "calib").glob("*/*")) if p.is_dir()):
        truths.update({im_id: scene.image(im_id).pose for im_id in scene.image_ids})
    rng = np.random.default_rng(0)
    cov = np.diag([np.radians(0.2) ** 2] * 3 + [0.001 ** 2] * 3)

    def answer(equivalent: bool):
        def predict(self, frame, roi=None, sun_direction_cam=None):
            pose = truths[frame.index].retract(rng.multivariate_normal(np.zeros(6), cov))
            if equivalent:
                pose = pose @ box.symmetries[frame.index % len(box.symmetries)]
            return Measurement(pose, cov, 0.9, "regressor:scripted", frame.timestamp)
        return predict

    scales = []
    for equivalent in (False, True):
        monkeypatch.setattr(CheckpointRegressor, "predict", answer(equivalent))
        rec = evaluate.calibrate_checkpoint(out / "best.pt", out / "data" / "calib", tmp_path / f"cal{equivalent}.pt",
                                            by_quality=False)
        scales.append(rec["scale"])
    assert scales[1] == pytest.approx(scales[0], rel=0.5)


def test_fit_command_refuses_bad_input_with_a_message(box_mesh, tmp_path, capsys):
    assert main(["fit", str(box_mesh), "--out", str(tmp_path / "a"), "--budget", "60m"]) == 2
    assert "--scale 0.001" in capsys.readouterr().err
    assert main(["fit", str(box_mesh), "--scale", "0.001", "--out", str(tmp_path / "b"), "--budget", "1m"]) == 2
    assert "too little" in capsys.readouterr().err
    assert main(["fit", str(box_mesh), "--scale", "0.001", "--out", str(tmp_path / "c"), "--occluded-share", "2"]) == 2
    assert "occluded_share" in capsys.readouterr().err
    assert main(["fit", str(box_mesh), "--scale", "0.001", "--out", str(tmp_path / "c"), "--textured-share", "-1"]) == 2
    assert "textured_share: expected a share" in capsys.readouterr().err
    assert main(["fit", str(box_mesh), "--scale", "0.001", "--out", str(tmp_path / "c"), "--budget", "soon"]) == 2
    assert "budget: expected a time" in capsys.readouterr().err
    assert main(["fit", str(box_mesh), "--scale", "0.001", "--out", str(tmp_path / "c"), "--distances", "1.2,0.3"]) == 2
    assert "distances: expected" in capsys.readouterr().err
    assert main(["fit", str(box_mesh), "--scale", "0.001", "--out", str(tmp_path / "c"), "--look", "space",
                 "--backgrounds", str(tmp_path)]) == 2
    assert "look 'space' has black space" in capsys.readouterr().err


def test_a_space_fit_renders_black_space_at_the_given_distances_and_trains_without_whole_frames(
        box_mesh, tmp_path, monkeypatch):
    """look='space': the views have the sun alone on black (the part found as its sunlit pixels, so
    no whole-frame crops), its cone around the optical axis (light from every side of the image);
    distances given by the user reach the views and the record."""
    import hybridpose.datasets as datasets
    import hybridpose.training.train as train_module

    calls, runs = [], []

    class Stop(Exception):
        pass

    def fake_render(out, obj, camera, count, seed=0, **kw):
        calls.append(kw)

    def no_training(cfg, **kw):
        runs.append(cfg)
        raise Stop

    monkeypatch.setattr(datasets, "render_random_dataset", fake_render)
    monkeypatch.setattr(train_module, "train", no_training)
    cam = Camera.default().scaled((320, 240))
    plan = FitPlan(budget_min=6.0, train_views=32, test_views=4, epochs=1, train_min=1.0, render_s_per_view=0.05,
                   train_s_per_view=0.05, distance_range_m=(0.5, 2.0))
    out = tmp_path / "fit"
    with pytest.raises(Stop):
        fit(box_mesh, out, camera=cam, scale=0.001, plan=plan, look="space", distance_range_m=(0.5, 2.0),
            progress=lambda *_: None)
    assert len(calls) == 3 and all(kw["appearance"].kind == "space" for kw in calls)
    assert all(kw["distance_range_m"] == (0.5, 2.0) for kw in calls)
    assert all(np.allclose(kw["lighting"].sun_direction_cam, (0, 0, 1)) and kw["sun_cone_deg"] == 85 for kw in calls)
    assert runs[0].full_view == 0.0
    record = json.loads((out / "fit.json").read_text())
    assert record["request"]["look"] == "space" and record["request"]["distance_range_m"] == [0.5, 2.0]
    with pytest.raises(ValueError, match="other settings.*look"):
        fit(box_mesh, out, camera=cam, scale=0.001, plan=plan, distance_range_m=(0.5, 2.0), progress=lambda *_: None)


def test_a_start_that_knows_the_part_is_fine_tuned_gently(truss, box_mesh):
    """The shipped network re-fitted on the truss keeps its keypoint heads: the shipped stages' rate;
    another part's heads start afresh: the from-scratch rate."""
    from hybridpose.regressors.checkpoints import shipped_checkpoint

    shipped = shipped_checkpoint("default")
    assert start_learning_rate(shipped, truss) == REFIT_LR < FIT_LR
    assert start_learning_rate(shipped, load_object(str(box_mesh), scale=0.001)) == FIT_LR
    assert start_learning_rate(None, truss) == FIT_LR


def test_a_start_from_another_objects_network_keeps_this_objects_keypoints(truss):
    """--init-from copies the features, never the 3D keypoints the network's PnP uses."""
    from hybridpose.regressors.checkpoints import shipped_checkpoint
    from hybridpose.regressors.models import build_model
    from hybridpose.training.checkpoint_io import load_matching_weights

    other = 0.5 * truss.keypoints  # as many keypoints as the shipped truss network has, elsewhere
    net = build_model("default", keypoints_m=other, image_size=128)
    load_matching_weights(net, shipped_checkpoint("default"))
    assert np.allclose(net.keypoints_m.numpy(), other, atol=1e-6)


def test_a_refit_lit_from_every_side_keeps_its_starts_sun_side(tmp_path):
    """The start learnt light from one side and its crops are turned to it; a re-fit on views lit
    around the optical axis (a record that asks for no turn) keeps the start's record; a re-fit lit
    from one side of its own, or a start with no side, leaves the export as it is."""
    from hybridpose.fit import keep_start_sun
    from hybridpose.regressors.checkpoints import load_checkpoint, save_checkpoint

    one_side = {"sun_direction_cam": [0.6, 0.4, 0.7], "sun_cone_deg": 40.0}
    around_axis = {"sun_direction_cam": [0.0, 0.0, 1.0], "sun_cone_deg": 85.0}

    def write(name, lighting):
        save_checkpoint(tmp_path / name, {"model": {}, "dataset": {"object": "truss", "lighting": lighting}})
        return tmp_path / name

    start, no_side = write("start.pt", one_side), write("no_side.pt", around_axis)
    refit = write("refit.pt", around_axis)
    assert keep_start_sun(start, refit)
    assert load_checkpoint(refit)["dataset"] == {"object": "truss", "lighting": one_side}
    own_side = write("own_side.pt", {"sun_direction_cam": [-0.6, 0.4, 0.7], "sun_cone_deg": 30.0})
    assert not keep_start_sun(start, own_side)
    assert load_checkpoint(own_side)["dataset"]["lighting"]["sun_direction_cam"] == [-0.6, 0.4, 0.7]
    refit2 = write("refit2.pt", around_axis)
    assert not keep_start_sun(no_side, refit2)
    assert load_checkpoint(refit2)["dataset"]["lighting"] == around_axis


def test_a_new_parts_fit_recommends_its_policy_and_a_refit_inherits_its_starts(tmp_path):
    """A new part's network recommends ``NEW_PART_POLICY``; a re-fit recommends what its start did
    (the shipped truss network: nothing, and the export is left as it is)."""
    from hybridpose.fit import NEW_PART_POLICY, record_hybrid_policy
    from hybridpose.regressors.checkpoints import load_checkpoint, save_checkpoint, shipped_checkpoint

    def write(name, **extra):
        save_checkpoint(tmp_path / name, {"model": {}, **extra})
        return tmp_path / name

    new_part = write("new.pt")
    assert record_hybrid_policy(shipped_checkpoint("default"), new_part, refit=False) == NEW_PART_POLICY
    assert load_checkpoint(new_part)["hybrid_config"] == NEW_PART_POLICY
    refit_of_part = write("refit_part.pt")
    assert record_hybrid_policy(new_part, refit_of_part, refit=True) == NEW_PART_POLICY
    assert load_checkpoint(refit_of_part)["hybrid_config"] == NEW_PART_POLICY
    refit_of_truss = write("refit_truss.pt")
    assert record_hybrid_policy(shipped_checkpoint("default"), refit_of_truss, refit=True) == {}
    assert "hybrid_config" not in load_checkpoint(refit_of_truss)
