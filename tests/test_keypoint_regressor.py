"""Keypoint model pieces (soft-argmax, PnP, Jacobian, covariance) and the checkpoint regressor backend."""
import os

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from hybridpose.core import Frame
from hybridpose.geometry import Camera, Pose, projection_jacobian, random_quat
from hybridpose.metrics import rotation_error_deg
from hybridpose.regressors.calibration import nees, pnp_covariance
from hybridpose.regressors.keypoint_net import KeypointNet, keypoint_loss, soft_argmax, widen_state_dict
from hybridpose.regressors.engines import TorchEngine
from hybridpose.regressors.keypoint_pnp import solve_pnp
from hybridpose.regressors.keypoint_passes import KeypointEstimate
from hybridpose.regressors.predictor import CheckpointRegressor
from hybridpose.regressors.twin_choice import TWIN_EDGE_WEIGHT, twin_scores
from hybridpose.regressors.detection import detect_bright_object, detect_dim_object
from hybridpose.registry import available, create


def _pose(rng, z=0.6):
    return Pose.from_quat_t(random_quat(None, rng), [rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), z])


def test_soft_argmax_finds_a_peak_at_the_cell_centre():
    logits = torch.full((1, 2, 8, 8), -50.0)
    logits[0, 0, 3, 5] = 50.0
    logits[0, 1, 0, 0] = 50.0
    uv, spread = soft_argmax(logits, stride=4)
    assert torch.allclose(uv[0, 0], torch.tensor([4 * 5 + 1.5, 4 * 3 + 1.5]))
    assert torch.allclose(uv[0, 1], torch.tensor([1.5, 1.5]))
    assert spread.max() < 1e-2


def test_keypoint_loss_ignores_keypoints_outside_the_crop():
    pred = torch.zeros(1, 2, 2)
    true = torch.tensor([[[10.0, 0.0], [500.0, 0.0]]])
    loss = keypoint_loss(pred, torch.zeros(1, 2), true, image_size=100, spread_weight=0.0)
    assert loss.item() == pytest.approx(0.1)


def test_keypoint_net_shapes_and_size_check(truss):
    net = KeypointNet(truss.keypoints, width=8, image_size=64).eval()
    uv, spread = net(torch.rand(2, 3, 64, 64))
    assert uv.shape == (2, len(truss.keypoints), 2) and spread.shape == (2, len(truss.keypoints))
    with pytest.raises(ValueError, match="expected 64×64 crops"):
        net(torch.rand(1, 3, 96, 96))
    with pytest.raises(ValueError, match="multiple of 32"):
        KeypointNet(truss.keypoints, image_size=100)


def test_projection_jacobian_matches_central_differences(rng, camera):
    pose = _pose(rng)
    pts = rng.uniform(-0.2, 0.2, (10, 3))
    uv, J = projection_jacobian(pose, pts, camera.K)
    ref, _ = cv2.projectPoints(pts, cv2.Rodrigues(pose.R)[0], pose.t, camera.K, None)
    assert np.allclose(uv, ref.reshape(-1, 2), atol=1e-9)
    eps = 1e-6
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        num = (projection_jacobian(pose.retract(d), pts, camera.K)[0] - projection_jacobian(pose.retract(-d), pts, camera.K)[0]) / (2 * eps)
        assert np.allclose(J[:, :, k], num, atol=1e-4 * np.abs(num).max() + 1e-6)


def test_drop_worst_fit_leaves_out_the_outliers_and_hands_hard_cases_to_ransac(truss, rng, camera):
    from hybridpose.regressors.keypoint_pnp import drop_worst_fit

    pose = _pose(rng)
    uv = camera.project(truss.keypoints, pose) + rng.normal(0, 0.3, (len(truss.keypoints), 2))
    pts3 = np.ascontiguousarray(truss.keypoints, dtype=np.float64).reshape(-1, 1, 3)
    clean = drop_worst_fit(pts3, uv.reshape(-1, 1, 2), camera.K, 3.0, 5)
    assert clean is not None and clean[0].all(), "no outlier: one fit on all points"
    off = uv.copy()
    off[[1, 4, 9]] += [[60.0, -45.0], [-50.0, 30.0], [35.0, 55.0]]
    kept, rvec, tvec = drop_worst_fit(pts3, off.reshape(-1, 1, 2), camera.K, 3.0, 5)
    assert not kept[[1, 4, 9]].any() and kept.sum() == len(uv) - 3
    assert np.linalg.norm(np.ravel(tvec) - pose.t) < 0.01
    scrambled = uv.copy()
    scrambled[: len(uv) // 2 + 1] = rng.uniform(0, 640, (len(uv) // 2 + 1, 2))
    assert drop_worst_fit(pts3, scrambled.reshape(-1, 1, 2), camera.K, 3.0, 5) is None, "most points off: RANSAC's job"


def test_line_jacobian_is_the_projection_jacobian_along_the_normals(rng, camera):
    from hybridpose.geometry import line_jacobian

    pose = _pose(rng)
    pts = rng.uniform(-0.2, 0.2, (25, 3))
    normals = rng.normal(size=(25, 2))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    uv, J = projection_jacobian(pose, pts, camera.K)
    uv_line, J_line = line_jacobian(pose, pts, camera.K, normals)
    np.testing.assert_allclose(uv_line, uv, atol=1e-9)
    np.testing.assert_allclose(J_line, np.einsum("si,sij->sj", normals, J), rtol=1e-10, atol=1e-9)


def test_solve_pnp_recovers_the_pose_and_rejects_outliers(truss, rng, camera):
    pose = _pose(rng)
    uv = camera.project(truss.keypoints, pose) + rng.normal(0, 0.3, (len(truss.keypoints), 2))
    uv[[2, 7]] += [[40.0, -25.0], [-30.0, 35.0]]
    res = solve_pnp(uv, truss.keypoints, camera.K, threshold_px=3.0)
    assert res is not None
    assert not res.inliers[2] and not res.inliers[7] and res.inliers.sum() == len(uv) - 2
    assert np.linalg.norm(pose.local(res.pose)[:3]) < np.deg2rad(1.0)
    assert np.linalg.norm(res.pose.t - pose.t) < 0.01
    cov = pnp_covariance(res.information, res.rms_px)
    assert np.all(np.linalg.eigvalsh(cov) > 0) and np.isfinite(nees(res.pose.local(pose), cov))


def test_solve_pnp_without_ransac_gives_none_where_most_points_disagree(truss, rng, camera):
    pose = _pose(rng)
    uv = camera.project(truss.keypoints, pose) + rng.normal(0, 0.3, (len(truss.keypoints), 2))
    few = uv.copy()
    few[[2, 7]] += [[40.0, -25.0], [-30.0, 35.0]]
    a = solve_pnp(few, truss.keypoints, camera.K, threshold_px=3.0)
    b = solve_pnp(few, truss.keypoints, camera.K, threshold_px=3.0, outliers="drop-worst-only")
    assert a.pose.allclose(b.pose, atol=1e-12) and np.array_equal(a.inliers, b.inliers)
    most = uv.copy()
    most[: len(uv) // 2 + 1] = rng.uniform(0, 640, (len(uv) // 2 + 1, 2))
    assert solve_pnp(most, truss.keypoints, camera.K, threshold_px=3.0, outliers="drop-worst-only") is None


def test_turned_passes_use_their_own_outlier_strategy(tiny_checkpoint, truss, camera, monkeypatch):
    """``turn_pnp_outliers`` reaches the PnP of the turned crops only (the first pass keeps ``pnp_outliers``);
    by default no RANSAC there, with None the turned crops use ``pnp_outliers`` too, and the edge-on
    expert inherits both."""
    from hybridpose.regressors import keypoint_passes as passes
    from hybridpose.render import Renderer

    cam = Camera.default().scaled(160)
    with Renderer(truss, cam) as r:
        frame = Frame(r.render(Pose.from_rotvec_t([0.2, 0.1, 0.0], [0.0, 0.0, 0.7])).rgb, cam, 0.0)
    seen, solve = [], passes.solve_pnp
    monkeypatch.setattr(passes, "solve_pnp", lambda *a, outliers, **k: seen.append(outliers) or solve(*a, outliers=outliers, **k))
    CheckpointRegressor(tiny_checkpoint, turns="always", passes=1, edge_on_expert=None,
                        turn_pnp_outliers=None).predict(frame)
    # (an untrained network: its box may give no plausible pose, and the dim fallback makes its passes again)
    assert seen and len(seen) % 5 == 0 and set(seen) == {"drop-worst"}
    seen.clear()
    reg = CheckpointRegressor(tiny_checkpoint, turns="always", passes=1, edge_on_expert=tiny_checkpoint,
                              expert_below_deg=90.0)
    assert reg.expert.options.turn_pnp_outliers == "drop-worst-only"
    reg.predict(frame)
    assert seen and len(seen) % 5 == 0 and seen == (["drop-worst"] + ["drop-worst-only"] * 4) * (len(seen) // 5)


def test_solve_pnp_gives_none_for_collapsed_points(truss, camera):
    assert solve_pnp(np.full((len(truss.keypoints), 2), 100.0), truss.keypoints, camera.K) is None
    with pytest.raises(ValueError, match="finite"):
        solve_pnp(np.full((len(truss.keypoints), 2), np.nan), truss.keypoints, camera.K)


def test_detect_bright_object_boxes_the_lit_pixels():
    img = np.zeros((100, 120, 3), np.uint8)
    img[20:40, 30:70] = 200
    img[80, 5] = 255  # a star / hot pixel
    assert detect_bright_object(img) == (30.0, 20.0, 40.0, 20.0)
    assert detect_bright_object(np.zeros_like(img)) is None


def test_detection_grows_from_a_glint_over_the_dim_object_but_not_over_noise():
    rng = np.random.default_rng(0)
    img = np.zeros((240, 320, 3), np.uint8)
    img[60:160, 40:240] = 6                      # grazing sun: the truss barely above black…
    img[100:110, 200:220] = 80                   # …and one glint
    noisy = np.clip(img + rng.normal(0, 4, img.shape), 0, 255).astype(np.uint8)   # σ = 4 sensor noise
    for frame in (img, noisy):
        x, y, w, h = detect_bright_object(frame)
        assert abs(x - 40) <= 4 and abs(y - 60) <= 4 and abs(w - 200) <= 8 and abs(h - 100) <= 8
    assert detect_bright_object(img, grow=False) == (200.0, 100.0, 20.0, 10.0)   # the glint alone
    for sigma in (10.0, 14.0):                   # clipped noise lifts black: the growth must not spread over it
        x, y, w, h = detect_bright_object(np.clip(img + rng.normal(0, sigma, img.shape), 0, 255).astype(np.uint8))
        assert x >= 30 and y >= 50 and x + w <= 250 and y + h <= 170
    lit = np.zeros_like(img)
    lit[60:160, 40:240] = 6
    lit[60:160, 40:200] = 150                    # mostly lit: a dim, shadowed end does not grow the box
    assert detect_bright_object(lit) == (40.0, 60.0, 160.0, 100.0)


def test_detect_dim_object_finds_a_faint_object_without_glints_but_not_noise_or_specks():
    rng = np.random.default_rng(1)
    img = np.zeros((240, 320, 3), np.uint8)
    img[60:160, 40:240] = 6                      # sun grazing the whole truss: no pixel over the bright threshold
    assert detect_bright_object(img) is None
    x, y, w, h = detect_dim_object(img)
    assert abs(x - 40) <= 4 and abs(y - 60) <= 4 and abs(w - 200) <= 8 and abs(h - 100) <= 8
    assert detect_dim_object(np.zeros_like(img)) is None
    speck = np.zeros_like(img)
    speck[100:106, 100:106] = 8                  # 36 px: a star or a hot cluster, not an object
    assert detect_dim_object(speck) is None
    for sigma in (2.0, 6.0):                     # sensor noise alone finds nothing
        assert detect_dim_object(np.clip(rng.normal(0, sigma, img.shape), 0, 255).astype(np.uint8)) is None
    with_noise = np.clip(img + rng.normal(0, 1.0, img.shape), 0, 255).astype(np.uint8)
    assert detect_dim_object(with_noise) is not None   # below the noise-aware threshold only once noise drowns it


def test_regressor_backends_are_registered():
    assert {"default", "keypoints", "vgg16", "vgg19", "branched-vgg19", "parallel-vgg19"} <= set(available("regressor"))


def test_checkpoint_regressor_returns_a_valid_measurement(tiny_checkpoint, truss, camera):
    reg = create("regressor", "default", checkpoint=tiny_checkpoint, object=truss)
    from hybridpose.render import Renderer

    with Renderer(truss, camera) as r:
        img = r.render(Pose.from_quat_t([1, 0, 0, 0], [0.0, 0.0, 0.6])).rgb
    frame = Frame(img, camera, 1.5)
    for roi in (None, (250, 180, 140, 120)):
        m = reg.predict(frame, roi=roi)
        assert m.source == "regressor:default" and m.timestamp == 1.5 and 0.0 <= m.quality <= 1.0
        assert m.covariance.shape == (6, 6) and np.all(np.isfinite(m.covariance))
        assert (m.pose is None) == m.lost
    black = reg.predict(Frame(np.zeros_like(img), camera, 0.0))
    assert black.lost and black.pose is None


def test_size_ratio_compares_the_projected_extent_with_the_box(truss, camera, rng, monkeypatch):
    """Oracle: cv2.projectPoints of the same points; a pose far behind the box's size is refused."""
    from hybridpose.regressors import keypoint_passes as passes

    pose = _pose(rng, z=0.8)
    uv = cv2.projectPoints(truss.keypoints, cv2.Rodrigues(pose.R)[0], pose.t, camera.K, None)[0][:, 0]
    x0, y0 = uv.min(0)
    w, h = uv.max(0) - uv.min(0)
    assert passes.size_ratio(pose, truss.keypoints, camera, (x0, y0, w, h)) == pytest.approx(1.0)
    assert passes.size_ratio(pose, truss.keypoints, camera, (x0, y0, 2 * w, 2 * h)) == pytest.approx(2.0)
    far = Pose(pose.R, pose.t * 4.0)                    # the PnP depth blow-up: 4× too far, ≈ 4× too small
    assert passes.size_ratio(far, truss.keypoints, camera, (x0, y0, w, h)) > passes.SIZE_RATIO_MAX
    behind = Pose(pose.R, -pose.t)
    assert passes.size_ratio(behind, truss.keypoints, camera, (x0, y0, w, h)) == float("inf")


def test_regressor_refuses_a_pose_that_does_not_fit_the_box(tiny_checkpoint, truss, camera, monkeypatch):
    from hybridpose.regressors import keypoint_passes as passes
    from hybridpose.render import Renderer

    with Renderer(truss, camera) as r:
        frame = Frame(r.render(Pose.from_quat_t([1, 0, 0, 0], [0.0, 0.0, 0.6])).rgb, camera, 0.0)
    reg = create("regressor", "default", checkpoint=tiny_checkpoint, object=truss)
    monkeypatch.setattr(passes, "size_ratio", lambda *a: passes.SIZE_RATIO_MAX * 1.01)
    m = reg.predict(frame)
    assert m.lost and m.pose is None and m.quality == 0.0


def test_depth_gate_refuses_estimates_far_beyond_the_trained_depths(tiny_checkpoint, truss, camera, monkeypatch):
    """The end-on truss near the camera and the truss across the view far away fill the same box, so
    size_ratio passes both; an estimate deeper than the gate is no plausible pose. "auto" is 3x the far
    end of the depths train recorded from the dataset (0.3-1.2 m here)."""
    from hybridpose.regressors import keypoint_passes as passes
    from hybridpose.regressors import predictor
    from hybridpose.regressors.keypoint_pnp import PnPResult
    from hybridpose.render import Renderer

    ck = torch.load(tiny_checkpoint, weights_only=False)
    assert ck["dataset"]["distance_range_m"] == [0.3, 1.2]
    with Renderer(truss, camera) as r:
        frame = Frame(r.render(Pose.from_quat_t([1, 0, 0, 0], [0.0, 0.0, 0.6])).rgb, camera, 0.0)
    depth = {"z": 5.0}

    def pnp_at_depth(points_2d, points_m, K, **kw):
        return PnPResult(pose=Pose(np.eye(3), [0.0, 0.0, depth["z"]]), inliers=np.ones(len(points_2d), bool),
                         rms_px=1.0, information=np.eye(6))

    monkeypatch.setattr(passes, "solve_pnp", pnp_at_depth)
    monkeypatch.setattr(passes, "size_ratio", lambda *a: 1.0)
    kw = dict(checkpoint=tiny_checkpoint, object=truss, refine_edges=False, check_twins=False)
    assert create("regressor", "default", **kw).max_depth_m is None   # off unless asked for
    auto = create("regressor", "default", max_depth_m="auto", **kw)
    assert auto.max_depth_m == pytest.approx(predictor.DEPTH_BEYOND_TRAINED * 1.2)
    assert auto.predict(frame).lost                                     # 5 m > 3.6 m
    assert not create("regressor", "default", max_depth_m=None, **kw).predict(frame).lost
    assert create("regressor", "default", max_depth_m=4.0, **kw).predict(frame).lost
    depth["z"] = 2.0                                                    # beyond 1.2 m, within the gate
    m = auto.predict(frame)
    assert not m.lost and m.pose.t[2] == pytest.approx(2.0)
    for bad in (-1.0, 0, "far", True, float("nan")):
        with pytest.raises(ValueError, match="max_depth_m: expected a positive depth in metres"):
            create("regressor", "default", max_depth_m=bad, **kw)


def test_checkpoint_regressor_bad_input(tiny_checkpoint, truss, camera, tmp_path):
    import trimesh

    from hybridpose.objects import ObjectModel

    reg = CheckpointRegressor(tiny_checkpoint)
    frame = Frame(np.zeros((camera.height, camera.width, 3), np.uint8), camera, 0.0)
    with pytest.raises(ValueError, match="roi: expected positive width"):
        reg.predict(frame, roi=(10, 10, 0, 5))
    with pytest.raises(ValueError, match="outside the 640×480 image"):
        reg.predict(frame, roi=(700, 10, 20, 20))
    with pytest.raises(TypeError, match="Frame"):
        reg.predict(frame.image)
    big = ObjectModel("big", trimesh.creation.box((1.0, 0.5, 0.2)))
    with pytest.raises(ValueError, match="trained on 'truss'.*hybridpose fit MESH"):
        CheckpointRegressor(tiny_checkpoint, object=big)
    with pytest.raises(ValueError, match="holds a 'default' model, not 'vgg16'"):
        create("regressor", "vgg16", checkpoint=tiny_checkpoint)
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="corrupt or truncated"):
        CheckpointRegressor(bad)
    with pytest.raises(FileNotFoundError, match="no trained 'vgg19' checkpoint ships"):
        create("regressor", "vgg19")
    for bad_passes in (3, "two", True):
        with pytest.raises(ValueError, match="passes: expected 1 or 2 network passes, or 'auto'"):
            CheckpointRegressor(tiny_checkpoint, passes=bad_passes)
    for bad_turns in ("on", None, 20):
        with pytest.raises(ValueError, match="turns: expected one of auto, always, off"):
            CheckpointRegressor(tiny_checkpoint, turns=bad_turns)
    with pytest.raises(ValueError, match="pnp_outliers: expected one of drop-worst, ransac, drop-worst-only, got 'lmeds'"):
        CheckpointRegressor(tiny_checkpoint, pnp_outliers="lmeds")
    with pytest.raises(ValueError, match="turn_pnp_outliers: expected None or one of drop-worst, .*got 'off'"):
        CheckpointRegressor(tiny_checkpoint, turn_pnp_outliers="off")
    with pytest.raises(ValueError, match="outliers: expected one of drop-worst, ransac"):
        solve_pnp(np.zeros((12, 2)), np.zeros((12, 3)), np.eye(3), outliers="all")
    with pytest.raises(ValueError, match="device: expected 'auto', 'cpu', 'cuda' or 'cuda:N', got 'gpu0'"):
        CheckpointRegressor(tiny_checkpoint, device="gpu0")
    with pytest.raises(ValueError, match="device: expected 'auto', 'cpu', 'cuda' or 'cuda:N', got 'meta'"):
        CheckpointRegressor(tiny_checkpoint, device="meta")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="device: 'cuda' asked for, but torch sees no CUDA GPU"):
            CheckpointRegressor(tiny_checkpoint, device="cuda")


@pytest.mark.gpu
def test_regressor_on_cuda_matches_cpu(truss, camera, device="cuda"):
    """The shipped network on the GPU gives the CPU's keypoints (float32 both): the same pose."""
    if device == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    from hybridpose.render import Renderer

    pose = Pose.from_rotvec_t([0.3, -0.2, 0.1], [0.02, -0.01, 0.7])
    with Renderer(truss, camera) as r:
        frame = Frame(r.render(pose).rgb, camera, 0.0)
    m_cpu = create("regressor", "default", refine_edges=False).predict(frame)
    m_gpu = create("regressor", "default", refine_edges=False, device=device).predict(frame)
    assert m_gpu.pose is not None and m_cpu.pose is not None
    assert np.allclose(m_gpu.pose.t, m_cpu.pose.t, atol=1e-3)
    assert abs(np.dot(m_gpu.pose.quat_wxyz, m_cpu.pose.quat_wxyz)) > 1 - 1e-5


def test_eval_writes_the_report_plots_and_gradcam(tiny_checkpoint, tmp_path, capsys):
    import json

    from hybridpose.cli import main

    data = tiny_checkpoint.parent.parent / "ds"
    assert main(["eval", "--checkpoint", str(tiny_checkpoint), "--data", str(data), "--out", str(tmp_path / "rep"),
                 "--limit", "10", "--turns", "always", "--pnp-outliers", "ransac", "--turn-pnp-outliers", "drop-worst-only",
                 "--edge-on-expert", str(tiny_checkpoint),
                 "--expert-rule", "pooled", "--no-dim-fallback", "--max-depth", "auto", "--engine", "onnxruntime",
                 "--roi", "truth"]) == 0
    rep = json.loads((tmp_path / "rep" / "report.json").read_text())
    s = rep["summary"]
    assert s["turns"] == "always" and s["pnp_outliers"] == "ransac" and s["engine"] == "onnxruntime"
    assert s["turn_pnp_outliers"] == "drop-worst-only"
    assert s["roi"] == "truth"
    assert s["max_depth_m"] == pytest.approx(3.6)                    # 3 × the 1.2 m the tiny run recorded
    assert s["expert_rule"] == "pooled" and s["dim_fallback"] is False and s["edge_on_expert"] == str(tiny_checkpoint)
    assert s["images"] == 10 and len(rep["per_image"]) == 10
    assert {"rot_mean_deg", "rot_median_deg", "trans_mean_m", "speed_score", "add_0.1d_recall", "failures"} <= set(s)
    rot = [r["rot_deg"] for r in rep["per_image"]]
    assert s["gross_error_share"] == pytest.approx(sum(r > 30 for r in rot) / 10)
    ms = s["ms_per_image"]
    assert set(ms) == {f"{n}{tail}" for n in ("1_thread", "2_threads") for tail in ("", "_p50", "_p95", "_max")} | {
        "network_1_thread", "network_2_threads"}
    assert ms["network_1_thread"] > 0
    assert 0 < ms["1_thread_p50"] <= ms["1_thread_p95"] <= ms["1_thread_max"] and ms["1_thread"] <= ms["1_thread_max"]
    assert s["machine"]["cpus"] == os.cpu_count() and s["machine"]["cpu_model"]
    assert sum(b["n"] for b in s["error_vs_elevation"]) == 10
    assert all(0.0 <= r["elevation_deg"] <= 90.0 for r in rep["per_image"])
    # the dataset records its sun: errors per phase angle and light azimuth
    assert sum(b["n"] for b in s["error_vs_phase"]) == 10 and sum(b["n"] for b in s["error_vs_light_azimuth"]) == 10
    assert all(0.0 <= r["sun_phase_deg"] <= 180.0 for r in rep["per_image"])
    assert [r["light_azimuth_deg"] for r in rep["per_image"]] == [pytest.approx(33.69, abs=0.01)] * 10  # one default sun
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "| elevation ° | n | mean rot ° | median rot ° | > 30° |" in md
    assert "| phase ° | n |" in md and "| azimuth ° | n |" in md
    assert s["accuracy_by_quality"][0]["kept_share"] == 1.0 and "| quality ≥ | views kept |" in md
    assert "paper: Parallel VGG-19 | 4.61 | 4.41 | 0.03" in md and "ours: default" in md
    assert f"95th percentile {ms['1_thread_p95']:.1f} ms" in md
    c = s["covariance_check"]
    posed = [r for r in rep["per_image"] if "nees" in r]
    assert c["views"] == len(posed) and all(r["nees_twin"] <= r["nees"] for r in posed)
    if posed:
        assert 0.0 <= c["inside_share"] <= c["inside_share_twin"] <= 1.0 and "Covariance check:" in md
    assert (tmp_path / "rep" / "gradcam.png").stat().st_size > 1000
    out = capsys.readouterr().out
    assert "eval default on 10 images" in out and "a call on onnxruntime" in out


def test_eval_without_gradcam_writes_no_sheet(tiny_checkpoint, tmp_path):
    from hybridpose.training.evaluate import evaluate_checkpoint

    data = tiny_checkpoint.parent.parent / "ds"
    s = evaluate_checkpoint(tiny_checkpoint, data, tmp_path / "rep", limit=3, timing_images=2, gradcam_count=0)
    assert s["images"] == 3 and (tmp_path / "rep" / "report.json").is_file()
    assert not (tmp_path / "rep" / "gradcam.png").exists()


def test_eval_without_timing_has_no_timings(tiny_checkpoint, tmp_path, capsys):
    """timing_images=0 (eval --timing-images 0): accuracy only, no timing keys, and the CLI says so."""
    from hybridpose.cli import main
    from hybridpose.training.evaluate import evaluate_checkpoint

    data = tiny_checkpoint.parent.parent / "ds"
    s = evaluate_checkpoint(tiny_checkpoint, data, tmp_path / "rep", limit=2, timing_images=0, gradcam_count=0)
    assert s["images"] == 2 and s["ms_per_image"] == {}
    assert "| – | – |\n" in (tmp_path / "rep" / "report.md").read_text()   # the ms columns: not timed
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="timing_images: expected a whole number"):
            evaluate_checkpoint(tiny_checkpoint, data, tmp_path / "rep", limit=2, timing_images=bad)
    assert main(["eval", "--checkpoint", str(tiny_checkpoint), "--data", str(data), "--out", str(tmp_path / "r2"),
                 "--limit", "2", "--timing-images", "0"]) == 0
    assert "not timed (engine" in capsys.readouterr().out


def test_eval_can_give_the_regressor_each_images_sun(tiny_checkpoint, tmp_path):
    import shutil

    from hybridpose.training.evaluate import evaluate_checkpoint

    data = tiny_checkpoint.parent.parent / "ds"
    s = evaluate_checkpoint(tiny_checkpoint, data, tmp_path / "rep", limit=3, timing_images=1, gradcam_count=0,
                            sun_known=True)
    assert s["sun_known"] is True and s["images"] == 3
    bare = tmp_path / "bare"
    shutil.copytree(data, bare)
    (bare / "train" / "000000" / "scene_meta.json").unlink()
    with pytest.raises(ValueError, match="does not record each image's sun"):
        evaluate_checkpoint(tiny_checkpoint, bare, tmp_path / "rep2", limit=3, sun_known=True)


def test_eval_can_give_the_regressor_each_views_true_box(tiny_checkpoint, tmp_path, monkeypatch):
    import json
    import shutil

    from hybridpose.datasets.bop import BopScene
    from hybridpose.training import evaluate
    from hybridpose.regressors.predictor import CheckpointRegressor

    data = tiny_checkpoint.parent.parent / "ds"
    seen, predict = [], CheckpointRegressor.predict

    def spy(self, frame, roi=None, sun_direction_cam=None):
        seen.append(roi)
        return predict(self, frame, roi=roi, sun_direction_cam=sun_direction_cam)

    monkeypatch.setattr(CheckpointRegressor, "predict", spy)
    s = evaluate.evaluate_checkpoint(tiny_checkpoint, data, tmp_path / "rep", limit=3, timing_images=1,
                                     gradcam_count=0, roi="truth")
    scene = BopScene(data / "train" / "000000")
    assert s["roi"] == "truth" and seen[:3] == [scene.image(i).bbox_obj for i in scene.image_ids[:3]]
    assert all(r is None for r in seen[3:])  # the timings run the path without a prior
    assert "true object box" in (tmp_path / "rep" / "report.md").read_text()
    with pytest.raises(ValueError, match="roi: expected one of none, truth"):
        evaluate.evaluate_checkpoint(tiny_checkpoint, data, tmp_path / "rep2", limit=1, roi="detector")
    bare = tmp_path / "bare"
    shutil.copytree(data, bare)
    info_path = bare / "train" / "000000" / "scene_gt_info.json"
    info = json.loads(info_path.read_text())
    info_path.write_text(json.dumps({k: [{kk: vv for kk, vv in e.items() if kk != "bbox_obj"} for e in v]
                                     for k, v in info.items()}))
    with pytest.raises(ValueError, match="has no bbox_obj"):
        evaluate.evaluate_checkpoint(tiny_checkpoint, bare, tmp_path / "rep3", limit=1, roi="truth")


def test_covariance_check_counts_errors_inside_the_ellipsoid():
    from scipy.stats import chi2

    from hybridpose.core import Measurement
    from hybridpose.training.eval_report import covariance_lines, over_confident
    from hybridpose.training.evaluate import covariance_check, covariance_nees

    truth = Pose.from_rotvec_t([0.1, 0.2, -0.3], [0.05, 0.0, 0.8])
    half_turn = Pose.from_rotvec_t([0.0, 0.0, np.pi], [0.0, 0.0, 0.0])
    cov = np.diag([1e-4] * 3 + [1e-6] * 3)  # σ = 0.57°, 1 mm
    xi = np.array([0.01, 0, 0, 0, 0, 0])     # 0.57° about x: NEES 1
    near = covariance_nees(Measurement(pose=truth.retract(xi), covariance=cov, quality=1.0, source="t", timestamp=0.0), truth, [half_turn])
    assert near["nees"] == pytest.approx(1.0, rel=1e-6) and near["nees_twin"] == pytest.approx(1.0, rel=1e-6)
    flipped = covariance_nees(Measurement(pose=(truth @ half_turn).retract(xi), covariance=cov, quality=1.0, source="t", timestamp=0.0),
                              truth, [half_turn])
    assert flipped["nees"] > 1e4 and flipped["nees_twin"] == pytest.approx(1.0, rel=1e-6)
    bound = chi2.ppf(0.9, 6)
    rows = [{"nees": 1.0, "nees_twin": 1.0, "quality": 0.6}, {"nees": 2 * bound, "nees_twin": 1.0, "quality": 0.35},
            {"nees": 2 * bound, "nees_twin": 2 * bound, "quality": 0.1}, {"rot_deg": 180.0, "quality": 0.0}]  # the last: a failure, no pose
    c = covariance_check(rows)
    by_quality = c.pop("by_quality")
    assert c == {"coverage": 0.9, "views": 3, "inside_share": pytest.approx(1 / 3), "inside_share_twin": pytest.approx(2 / 3)}
    assert [(b["min_quality"], b["max_quality"], b["views"], b["inside_share_twin"]) for b in by_quality] == [
        (0.0, 0.2, 1, 0.0), (0.3, 0.4, 1, 1.0), (0.5, None, 1, 1.0)]
    assert "0.0–0.2; 0.3–0.4; ≥ 0.5 → 0% of 1; 100% of 1; 100% of 1" in "\n".join(covariance_lines({**c, "by_quality": by_quality}))
    # 2/3 inside a 90 % ellipsoid: the report says over-confident and how to re-scale
    assert over_confident(c) and not over_confident({**c, "inside_share_twin": 0.85}) and not over_confident({"views": 0})
    md = "\n".join(covariance_lines(c, "runs/x/best.pt"))
    assert "Over-confident covariance" in md and "hybridpose calibrate --checkpoint runs/x/best.pt" in md
    assert "Over-confident" not in "\n".join(covariance_lines({**c, "inside_share_twin": 0.9}))
    assert covariance_lines({"coverage": 0.9, "views": 0}) == []


def test_calibrate_refuses_bad_coverage_and_too_few_poses(tiny_checkpoint, tmp_path):
    from hybridpose.training.evaluate import MIN_CALIBRATION_POSES, calibrate_checkpoint

    data = tiny_checkpoint.parent.parent / "ds"
    with pytest.raises(ValueError, match="coverage: expected a probability"):
        calibrate_checkpoint(tiny_checkpoint, data, tmp_path / "x.pt", coverage=1.0)
    with pytest.raises(ValueError, match=f"calibrating needs at least {MIN_CALIBRATION_POSES}"):
        calibrate_checkpoint(tiny_checkpoint, data, tmp_path / "x.pt", limit=3)
    assert not (tmp_path / "x.pt").exists()


def test_accuracy_by_quality_keeps_what_a_gate_would_trust():
    from hybridpose.training.eval_report import accuracy_by_quality, quality_table

    rows = [{"quality": q, "rot_deg": r, "trans_m": t} for q, r, t in
            [(0.9, 1.0, 0.01), (0.6, 3.0, 0.03), (0.4, 170.0, 0.2), (0.0, 180.0, 1.0)]]  # the last: a failure
    g0, g5, g95 = accuracy_by_quality(rows, gates=(0.0, 0.5, 0.95))
    assert g0["kept_share"] == 1.0 and g0["rot_mean_deg"] == pytest.approx(88.5) and g0["gross_error_share"] == 0.5
    assert g5["kept_share"] == 0.5 and g5["rot_mean_deg"] == pytest.approx(2.0) and g5["rot_median_deg"] == pytest.approx(2.0)
    assert g5["trans_mean_m"] == pytest.approx(0.02) and g5["gross_error_share"] == 0.0
    assert g95 == {"min_quality": 0.95, "kept_share": 0.0}
    assert "| 0.95 | 0 % | – |" in quality_table([g0, g5, g95])


def _write_report(path, rot_deg, lost=(), model="m"):
    import json

    rows = [{"image": f"000000/{i:06d}", "lost": i in lost, "rot_deg": 180.0 if i in lost else float(r)}
            for i, r in enumerate(rot_deg)]
    path.mkdir(parents=True, exist_ok=True)
    (path / "report.json").write_text(json.dumps({"summary": {"model": model}, "per_image": rows}))
    return path


def test_compare_reports_pairs_the_views(tmp_path, capsys):
    """McNemar counts and p against scipy's binomial test; the bootstrap interval holds the true shift."""
    from scipy.stats import binomtest

    from hybridpose.cli import main
    from hybridpose.training.compare import compare_reports

    rng = np.random.default_rng(0)
    base = rng.gamma(2.0, 0.5, 400)                   # degrees, none gross
    rot_a, rot_b = base.copy(), base + 0.3            # B: 0.3° worse everywhere...
    rot_a[[0, 1, 2, 3]] = 170.0                       # ...gross on 4 views A gets wrong
    rot_b[[3, 4]] = 175.0                             # one shared, one of its own,
    a = _write_report(tmp_path / "a", rot_a, model="default")
    b = _write_report(tmp_path / "b", rot_b, lost={5}, model="keypoints")   # and one failure (180°)
    c = compare_reports(a, b / "report.json")
    assert (c["gross_only_a"], c["gross_only_b"], c["gross_both"]) == (3, 2, 1)
    assert c["mcnemar_p"] == pytest.approx(binomtest(2, 5).pvalue)
    assert c["a"]["model"] == "default" and c["b"]["gross_share"] == pytest.approx(3 / 400)
    lo, hi = c["rot_median_diff_deg"]["ci95"]
    assert lo <= 0.3 <= hi and c["rot_median_diff_deg"]["estimate"] == pytest.approx(0.3, abs=0.05)
    want_mean = (np.where(np.arange(400) == 5, 180.0, rot_b) - rot_a).mean()
    assert c["rot_mean_diff_deg"]["estimate"] == pytest.approx(want_mean)
    # gross shares 4/400 (A) and 3/400 (B): B − A = −1/400, inside its own bootstrap interval
    gross = c["gross_share_diff"]
    assert gross["estimate"] == pytest.approx(-1 / 400) and gross["ci95"][0] <= -1 / 400 <= gross["ci95"][1]
    assert gross["ci95"][0] < gross["ci95"][1]
    assert main(["compare", str(a), str(b), "--out", str(tmp_path / "c.json")]) == 0
    out = capsys.readouterr().out
    assert "gross in A only 3, in B only 2, in both 1" in out and "B − A -0.25 points" in out
    assert (tmp_path / "c.json").is_file()
    # two test sets pooled: the counts add up, the views of both are resampled together
    a2, b2 = _write_report(tmp_path / "a2", [1.0, 100.0, 2.0]), _write_report(tmp_path / "b2", [1.0, 1.0, 99.0])
    pooled = compare_reports([a, a2], [b, b2])
    assert (pooled["images"], pooled["gross_only_a"], pooled["gross_only_b"], pooled["gross_both"]) == (403, 4, 3, 1)
    assert main(["compare", str(a), str(b), str(a2), str(b2)]) == 0
    assert "Paired comparison on 403 images" in capsys.readouterr().out
    assert main(["compare", str(a), str(b), str(a2)]) == 2
    assert "reports: expected pairs" in capsys.readouterr().err


def test_compare_reports_bad_input(tmp_path):
    from hybridpose.training.compare import compare_reports

    a = _write_report(tmp_path / "a", [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="not the same images in the same order"):
        compare_reports(a, _write_report(tmp_path / "b", [1.0, 2.0]))
    with pytest.raises(FileNotFoundError, match="no report"):
        compare_reports(a, tmp_path / "missing")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "report.json").write_text('{"per_image": [{"image": "x"}]}')
    with pytest.raises(ValueError, match="not a `hybridpose eval` report.json"):
        compare_reports(a, tmp_path / "bad")
    with pytest.raises(ValueError, match="gross_deg: expected a rotation error > 0 degrees"):
        compare_reports(a, a, gross_deg=0)
    with pytest.raises(ValueError, match="expected as many reports of A as of B"):
        compare_reports([a, a], [a])


def test_twin_loss_scores_the_best_matching_labelling():
    pred = torch.zeros(1, 2, 2)
    labels = torch.tensor([[[[10.0, 0.0], [10.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]]]])  # (B, T, N, 2)
    assert keypoint_loss(pred, torch.zeros(1, 2), labels, 100, spread_weight=0.0).item() == pytest.approx(0.0)
    assert keypoint_loss(pred, torch.zeros(1, 2), labels[:, :1], 100, spread_weight=0.0).item() == pytest.approx(0.1)


def test_box_twins_are_half_turns_that_map_the_box_onto_itself(truss):
    from hybridpose.regressors.verify import box_half_turns

    corners = truss.bbox_corners
    for S in box_half_turns(truss):
        assert np.allclose(S.R @ S.R, np.eye(3)) and np.isclose(np.linalg.det(S.R), 1.0)
        moved = S @ corners
        assert np.allclose(np.sort(moved, axis=0), np.sort(corners, axis=0), atol=1e-9)


def test_twin_check_finds_the_true_pose_among_its_twins(truss, camera):
    from hybridpose.regressors.verify import TwinCheck
    from hybridpose.render import Renderer, random_poses

    check = TwinCheck(truss)
    poses = random_poses(6, camera, (0.5, 0.9), rng=4, in_view_points=truss.bbox_corners)
    with Renderer(truss, camera) as r:
        for pose in poses:
            frame = Frame(r.render(pose).rgb, camera, 0.0)
            for S in check.twins:
                chosen, support, flipped = check.best(frame, pose @ S)
                assert flipped and rotation_error_deg(chosen, pose) < 1e-6, "the flipped twin was kept"
            chosen, _, flipped = check.best(frame, pose)
            assert not flipped


def test_export_keeps_inference_state_only(tiny_checkpoint, tmp_path, truss, camera):
    from hybridpose.cli import main

    assert main(["export", "--checkpoint", str(tiny_checkpoint), "--out", str(tmp_path / "w.pt")]) == 0
    ck = torch.load(tmp_path / "w.pt", map_location="cpu", weights_only=False)
    assert "optimizer" not in ck and "torch_rng" not in ck and {"config", "model", "build", "validation"} <= set(ck)
    reg = CheckpointRegressor(tmp_path / "w.pt", object=truss)
    m = reg.predict(Frame(np.zeros((camera.height, camera.width, 3), np.uint8), camera, 0.0))
    assert m.lost
    assert main(["export", "--checkpoint", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "x.pt")]) == 2


def test_twin_scores_weigh_head_against_edges():
    # hand-computed: log(0.6) + 8 log(0.501) = -6.04 < log(0.4) + 8 log(0.901) = -1.75, so the better
    # edge fit wins over a head that is only mildly sure; a failed fit (quality 0) scores -55 + log p
    score = twin_scores([[0.6, 0.4], [0.9, 0.1]], [[0.5, 0.9], [0.0, 0.7]])
    np.testing.assert_allclose(score[0], [np.log(0.600001) + 8 * np.log(0.501), np.log(0.400001) + 8 * np.log(0.901)])
    assert score[0].argmax() == 1 and score[1].argmax() == 1
    np.testing.assert_allclose(score[0], [-6.0400, -1.7503], atol=1e-3)
    # with a weight of 0 the head alone decides
    assert twin_scores([0.6, 0.4], [0.5, 0.9], edge_weight=0.0).argmax() == 0
    with pytest.raises(ValueError, match="prob and quality: expected the same shape"):
        twin_scores([0.6, 0.4], [0.5, 0.9, 0.1])


def test_view_elevation_is_zero_edge_on_and_ninety_face_on(truss):
    from scipy.spatial.transform import Rotation

    from hybridpose.objects import view_elevation_deg

    assert int(np.argmin(truss.extents)) == 2  # the truss is flat in its z
    face_on = Pose(np.eye(3), np.array([0.0, 0.0, 0.8]) - truss.center)      # looking along object z
    assert view_elevation_deg(face_on, truss) == pytest.approx(90.0)
    edge_on = Pose(Rotation.from_euler("x", 90, degrees=True).as_matrix(), np.array([0.0, 0.0, 0.8]))
    assert view_elevation_deg(edge_on, truss) == pytest.approx(0.0, abs=0.5)  # box centre ≈ origin
    for deg in (10.0, 35.0, 70.0):  # tilt the plane by ``deg`` out of edge-on, object centred on the axis
        R = Rotation.from_euler("x", 90 - deg, degrees=True).as_matrix()
        pose = Pose(R, np.array([0.0, 0.0, 0.8]) - R @ truss.center)
        assert view_elevation_deg(pose, truss) == pytest.approx(deg, abs=1e-6)


def test_sun_turn_aligns_the_light_with_the_training_sun(tiny_checkpoint, truss):
    from hybridpose.regressors.predictor import CheckpointRegressor
    from hybridpose.regressors.sun_turn import SUN_TURN_BEYOND_DEG, sun_turn_deg, trained_light_azimuth_deg
    from hybridpose.regressors.checkpoints import load_checkpoint

    # the training data's sun is recorded (the tiny set: the default sun, no cone)
    light = load_checkpoint(tiny_checkpoint)["dataset"]["lighting"]
    assert light["sun_cone_deg"] == 0.0 and trained_light_azimuth_deg(light) == pytest.approx(33.690, abs=1e-3)
    # lit from every side (the cone holds the optical axis), or no record: nothing to align to
    assert trained_light_azimuth_deg({"sun_direction_cam": [0.1, 0.0, 1.0], "sun_cone_deg": 85.0}) is None
    assert trained_light_azimuth_deg(None) is None and sun_turn_deg([1, 0, 0], None) == 0.0
    assert sun_turn_deg(None, 33.7) == 0.0
    # light travelling up the image (270°) vs trained 0°: turn the crop 90° clockwise on screen, i.e. -90° in
    # OpenCV's counter-clockwise sense; within SUN_TURN_BEYOND_DEG of the training azimuth: no turn
    assert sun_turn_deg([0, -1, 0.5], 0.0) == pytest.approx(-90.0)
    assert sun_turn_deg([-1, 0, 0.5], 0.0) == pytest.approx(-180.0)
    assert sun_turn_deg([1, 0.5, 0.5], 0.0) == 0.0 and np.degrees(np.arctan2(0.5, 1)) < SUN_TURN_BEYOND_DEG
    # the turn moves the light to the training azimuth: rotate the light's image direction by the turn
    rng = np.random.default_rng(1)
    for _ in range(20):
        d, trained = rng.normal(size=3), rng.uniform(0, 360)
        a = np.radians(sun_turn_deg(d, trained, beyond_deg=0.0))
        turn = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])  # cv2.getRotationMatrix2D's 2×2
        x, y = turn @ d[:2]
        assert (np.degrees(np.arctan2(y, x)) - trained + 180) % 360 - 180 == pytest.approx(0.0, abs=1e-6)
    # every network pass of predict starts from the sun turn
    reg = CheckpointRegressor(tiny_checkpoint, turns="always", passes=1)
    seen, solve = [], reg.passes.solve_turned
    reg.passes.solve_turned = lambda crop, K, angles, *rest: seen.append(tuple(angles)) or solve(crop, K, angles, *rest)
    from hybridpose.render import Renderer

    cam = Camera.default().scaled(160)
    with Renderer(truss, cam) as r:
        frame = Frame(r.render(Pose.from_rotvec_t([0.2, 0.1, 0.0], [0.0, 0.0, 0.7])).rgb, cam, 0.0)
    reg.predict(frame, sun_direction_cam=[-0.6, -0.4, 0.7])  # the default sun's opposite: turn by ±180°
    assert seen and abs(seen[0][0]) == pytest.approx(180.0) and len(seen[1]) == 4
    assert [a - seen[0][0] for a in seen[1]] == pytest.approx([20.0, -20.0, 40.0, -40.0])
    seen.clear()
    reg.predict(frame)
    assert seen[0] == (0.0,)
    seen.clear()  # the frame's own sun where the call gives none
    from dataclasses import replace

    reg.predict(replace(frame, sun_direction_cam=[-0.6, -0.4, 0.7]))
    assert abs(seen[0][0]) == pytest.approx(180.0)


def test_sun_phase_angle_and_light_azimuth(truss):
    from scipy.spatial.transform import Rotation

    from hybridpose.objects import light_azimuth_deg, sun_phase_angle_deg
    from hybridpose.training.eval_report import error_in_bins

    R = Rotation.from_euler("xyz", [20, -35, 60], degrees=True).as_matrix()
    on_axis = Pose(R, np.array([0.0, 0.0, 0.9]) - R @ truss.center)  # box centre on the optical axis
    assert sun_phase_angle_deg([0, 0, 1], on_axis, truss) == pytest.approx(0.0, abs=1e-6)     # sun behind the camera
    assert sun_phase_angle_deg([0, 0, -2], on_axis, truss) == pytest.approx(180.0, abs=1e-6)  # back-lit
    assert sun_phase_angle_deg([1, 0, 0], on_axis, truss) == pytest.approx(90.0)              # side-lit
    # oracle: the angle between the unit vectors to the sun and to the camera, by scipy's rotation of one onto the other
    rng = np.random.default_rng(5)
    for _ in range(20):
        d, t = rng.normal(size=3), np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(0.4, 1.2)])
        pose = Pose(R, t - R @ truss.center)
        to_sun, to_cam = -d / np.linalg.norm(d), -t / np.linalg.norm(t)
        rot, _ = Rotation.align_vectors([to_cam], [to_sun])
        assert sun_phase_angle_deg(d, pose, truss) == pytest.approx(np.degrees(rot.magnitude()), abs=1e-5)
    for d, az in (([1, 0, 0.3], 0.0), ([0, 1, 0.3], 90.0), ([-1, 0, 0.3], 180.0), ([0, -1, 0.3], 270.0),
                  ([0.6, 0.4, 0.7], 33.690)):
        assert light_azimuth_deg(d) == pytest.approx(az, abs=1e-3)
    rows = [{"rot_deg": 1.0, "sun_phase_deg": 10.0}, {"rot_deg": 90.0, "sun_phase_deg": 80.0},
            {"rot_deg": 3.0, "sun_phase_deg": 180.0}, {"rot_deg": 5.0}]  # the last: no recorded sun
    bins = error_in_bins(rows, "sun_phase_deg", np.array([0.0, 45.0, 90.0, 180.0]))
    assert [(b["n"], b["gross_error_share"]) for b in bins] == [(1, 0.0), (1, 1.0), (1, 0.0)]
    assert error_in_bins(rows[3:], "sun_phase_deg", np.array([0.0, 180.0])) == []


def test_auto_passes_run_the_second_pass_only_where_the_head_is_unsure(tiny_checkpoint):
    from hybridpose.regressors.keypoint_passes import SECOND_PASS_BELOW, wants_second_pass

    reg = CheckpointRegressor(tiny_checkpoint)
    assert reg.options.passes == "auto" and CheckpointRegressor(tiny_checkpoint, passes="2").options.passes == 2
    res = object()  # any PnP result
    sure, unsure = np.array([SECOND_PASS_BELOW + 0.05, 0.0]), np.array([SECOND_PASS_BELOW - 0.05, 0.1])
    assert not wants_second_pass("auto", res, sure) and wants_second_pass("auto", res, unsure)
    assert wants_second_pass("auto", None, sure), "a failed first PnP gets a second chance"
    assert wants_second_pass("auto", res, None), "no twin head: no belief to trust, two passes"
    assert not wants_second_pass(1, None, unsure)
    assert wants_second_pass(2, res, sure)


def test_auto_turns_only_where_the_first_pnp_drops_keypoints(tiny_checkpoint):
    from types import SimpleNamespace

    from hybridpose.regressors.keypoint_passes import TURNS_BELOW_INLIERS, wants_turns

    reg = CheckpointRegressor(tiny_checkpoint)
    assert reg.options.turns == "auto"
    consistent = SimpleNamespace(inlier_ratio=1.0)
    split = SimpleNamespace(inlier_ratio=TURNS_BELOW_INLIERS - 0.05)
    assert not wants_turns("auto", consistent) and wants_turns("auto", split) and wants_turns("auto", None)
    assert not wants_turns("off", None)
    assert wants_turns("always", consistent)


class _BrightestPixelNet(torch.nn.Module):
    """Stands in for the keypoint network: every keypoint at the brightest pixel of each crop it gets."""

    def __init__(self, num_keypoints: int, twin_classes: int) -> None:
        super().__init__()
        self.n, self.t, self.seen = num_keypoints, twin_classes, []

    def forward(self, x, with_twin=False):
        self.seen.append(x.shape[0])
        b, _, h, w = x.shape
        idx = x.sum(1).reshape(b, -1).argmax(1)
        uv = torch.stack([idx % w, idx // w], -1).float()[:, None].expand(b, self.n, 2)
        return uv, torch.ones(b, self.n), torch.zeros(b, self.t)


def test_turned_crops_map_their_keypoints_back_to_the_crop(tiny_checkpoint):
    """A dot seen in crops turned by ±20°/±40° must come back where it is in the unturned crop (the
    turn's direction and centre convention checked against a known answer)."""
    reg = CheckpointRegressor(tiny_checkpoint)
    fake = _BrightestPixelNet(len(reg.keypoints_m), len(reg.twins) + 1)
    reg.engine = TorchEngine(fake, torch.device("cpu"))
    S = reg.image_size
    crop = np.zeros((S, S, 3), np.uint8)
    dot = (44, 21)  # (x, y) crop pixels, off centre so that a wrong turn direction or centre shows
    crop[dot[1], dot[0]] = 255
    crop = cv2.GaussianBlur(crop, (5, 5), 1.0)  # a turned dot stays the brightest pixel near its place
    K_crop = np.array([[100.0, 0, S / 2], [0, 100.0, S / 2], [0, 0, 1]])
    turned = reg.passes.solve_turned(crop, K_crop, (0.0, 20.0, -20.0, 40.0, -40.0))
    assert fake.seen == [5], "one batch for all turns"
    for res, uv, order, prob in turned:
        assert res is None  # all keypoints on one pixel: no pose
        np.testing.assert_allclose(uv, np.tile(dot, (len(uv), 1)), atol=1.0)
        assert prob.shape == (len(reg.twins) + 1,) and order[0] == 0


def test_turned_pass_wins_only_with_more_keypoints_kept(tiny_checkpoint, monkeypatch):
    from types import SimpleNamespace

    from hybridpose.regressors.keypoint_passes import TURNS_DEG

    reg = CheckpointRegressor(tiny_checkpoint)
    ratio = {0.0: 0.6, **{a: 0.5 for a in TURNS_DEG}, TURNS_DEG[2]: 0.8}
    uv0 = np.zeros((len(reg.keypoints_m), 2))

    def fake(crop, K_crop, angles, outliers=None):
        return [(SimpleNamespace(inlier_ratio=ratio[a], rms_px=1.0, angle=a), uv0, [0, 1, 2, 3], None) for a in angles]

    monkeypatch.setattr(reg.passes, "solve_turned", fake)
    image, K = np.zeros((480, 640, 3), np.uint8), Camera.default().K
    res, *_ = reg.passes.network_pass(image, K, (320.0, 240.0, 200.0), turns=True)
    assert res.angle == TURNS_DEG[2]
    ratio[0.0] = 0.95  # the first pass keeps enough keypoints: no turns tried
    res, *_ = reg.passes.network_pass(image, K, (320.0, 240.0, 200.0), turns=True)
    assert res.angle == 0.0
    ratio[0.0] = 0.6
    res, *_ = reg.passes.network_pass(image, K, (320.0, 240.0, 200.0), turns=False)
    assert res.angle == 0.0


def _trained_looking(net: KeypointNet) -> KeypointNet:
    """Random weights plus batch-norm statistics that are not the identity (a few train-mode passes)."""
    net.train()
    with torch.no_grad():
        for _ in range(3):
            net(torch.rand(4, 3, net.image_size, net.image_size) * 2.0)
    return net.eval()


@pytest.mark.parametrize("new_width", [12, 16, 20])
def test_widened_net_computes_what_the_narrow_one_did(truss, new_width):
    """Net2WiderNet without noise is exact (eval mode), with noise it starts close and its copies differ."""
    torch.manual_seed(0)
    narrow = _trained_looking(KeypointNet(truss.keypoints, width=8, image_size=64, twin_classes=4))
    wide = KeypointNet(truss.keypoints, width=new_width, image_size=64, twin_classes=4).eval()
    x = torch.rand(3, 3, 64, 64)
    with torch.no_grad():
        want = narrow(x, with_twin=True)
        wide.load_state_dict(widen_state_dict(narrow.state_dict(), wide.state_dict(), noise=0.0))
        for got, ref in zip(wide(x, with_twin=True), want):
            torch.testing.assert_close(got, ref, atol=1e-4, rtol=1e-4)
        wide.load_state_dict(widen_state_dict(narrow.state_dict(), wide.state_dict(), noise=0.002, seed=1))
        uv, _, _ = wide(x, with_twin=True)
    assert (uv - want[0]).abs().max() < 0.5                      # pixels, in a 64-pixel crop
    w = wide.state_dict()["layer1.conv1.weight"]                 # (new_width, new_width, 3, 3)
    first_copy = w[8]
    assert not any(torch.allclose(first_copy, w[i]) for i in range(8))


def test_widen_state_dict_bad_input(truss):
    narrow = KeypointNet(truss.keypoints, width=8, image_size=64, twin_classes=4).state_dict()
    narrower = KeypointNet(truss.keypoints, width=4, image_size=64, twin_classes=4).state_dict()
    no_head = KeypointNet(truss.keypoints, width=16, image_size=64).state_dict()
    with pytest.raises(ValueError, match="target: 4 channels where the trained net has 8; it can only widen"):
        widen_state_dict(narrow, narrower)
    with pytest.raises(ValueError, match="state: not the same layers as the target net"):
        widen_state_dict(narrow, no_head)
    with pytest.raises(ValueError, match="noise: expected a finite fraction ≥ 0, got nan"):
        widen_state_dict(narrow, narrow, noise=float("nan"))


def _verifier_checkpoint(path, obj):
    from hybridpose.regressors.twin_verifier import CHECKPOINT_FORMAT, TwinVerifierNet

    torch.save({"format": CHECKPOINT_FORMAT, "width": 8, "model": TwinVerifierNet(8).state_dict(),
                "object": obj.name, "diameter_m": float(obj.diameter)}, path)
    return path


def test_twin_scores_add_the_verifier_belief():
    base = twin_scores([0.6, 0.4], [0.9, 0.9])
    score = twin_scores([0.6, 0.4], [0.9, 0.9], verifier_prob=[0.1, 0.9], verifier_weight=2.0)
    np.testing.assert_allclose(score - base, [2 * np.log(0.100001), 2 * np.log(0.900001)])
    assert base.argmax() == 0 and score.argmax() == 1
    with pytest.raises(ValueError, match="verifier_prob"):
        twin_scores([0.6, 0.4], [0.9, 0.9], verifier_prob=[1.0])


def test_regressor_asks_the_verifier_only_where_the_head_is_unsure(tiny_checkpoint, truss, camera, tmp_path):
    from hybridpose.regressors.twin_choice import VERIFIER_SURE
    from hybridpose.render import Renderer

    assert CheckpointRegressor(tiny_checkpoint, verifier=None).verifier is None
    with pytest.raises(FileNotFoundError, match="twin verifier"):
        CheckpointRegressor(tiny_checkpoint, verifier=tmp_path / "missing.pt")
    reg = CheckpointRegressor(tiny_checkpoint, verifier=_verifier_checkpoint(tmp_path / "tv.pt", truss))
    assert reg.verifier is not None
    pose = Pose.from_rotvec_t([0.4, 0.3, 0.2], [0.0, 0.0, 0.7])
    with Renderer(truss, camera) as r:
        frame = Frame(r.render(pose).rgb, camera, 0.0)
    calls = []
    real = reg.verifier.probabilities

    def spy(image, K, candidates, strip_pose=None):
        calls.append(candidates)
        return real(image, K, candidates, strip_pose)

    reg.verifier.probabilities = spy
    reg.twin_choice.refine(frame, pose, [0, 1, 2, 3], np.array([VERIFIER_SURE + 0.02, 0.01, 0.01, 0.01]))
    assert not calls, "a sure head decides alone"
    reg.twin_choice.refine(frame, pose, [0, 1, 2, 3], np.array([VERIFIER_SURE - 0.05, 0.03, 0.01, 0.01]))
    assert len(calls) == 1, "with a verifier the head must be surer (VERIFIER_SURE) to decide alone"
    calls.clear()
    reg.twin_choice.refine(frame, pose, [0, 1, 2, 3], np.array([0.4, 0.3, 0.2, 0.1]))
    assert len(calls) == 1 and len(calls[0]) == 4
    assert rotation_error_deg(calls[0][0], pose) < 1e-6  # the head's choice first: the strip follows it
    # a verifier for another object is refused by name
    other = _verifier_checkpoint(tmp_path / "other.pt", truss)
    ck = torch.load(other, weights_only=True)
    ck["diameter_m"] = 2.0
    torch.save(ck, other)
    with pytest.raises(ValueError, match="not on 'truss'"):
        CheckpointRegressor(tiny_checkpoint, verifier=other)


def test_verifier_choice_before_fitting_fits_only_the_chosen_twin(tiny_checkpoint, truss, camera, tmp_path,
                                                                 monkeypatch):
    """VERIFIER_EDGE_WEIGHT = 0: the edge fits would not change the choice, so head × verifier choose
    first and only that twin is edge-fitted (one fit, not four)."""
    import hybridpose.regressors.twin_choice as twin_choice
    import hybridpose.edges.fit as edges
    from hybridpose.render import Renderer

    reg = CheckpointRegressor(tiny_checkpoint, verifier=_verifier_checkpoint(tmp_path / "tv.pt", truss))
    pose = Pose.from_rotvec_t([0.4, 0.3, 0.2], [0.0, 0.0, 0.7])
    with Renderer(truss, camera) as r:
        frame = Frame(r.render(pose).rgb, camera, 0.0)
    order, head = [0, 1, 2, 3], np.array([0.4, 0.3, 0.2, 0.1])  # unsure
    reg.verifier.probabilities = lambda image, K, candidates, strip_pose=None: np.array([0.01, 0.01, 0.97, 0.01])
    fitted = []
    real_fit = edges.fit_edges

    def spy(view, frame, start, **kw):
        fitted.append(start)
        return real_fit(view, frame, start, **kw)

    monkeypatch.setattr(edges, "fit_edges", spy)
    reg.twin_choice.refine(frame, pose, order, head)
    assert 2 <= len(fitted) <= 4, "edges weighed in the choice: twins fitted until none left can win"
    fitted.clear()
    monkeypatch.setattr(twin_choice, "VERIFIER_EDGE_WEIGHT", 0.0)
    got, twin = reg.twin_choice.refine(frame, pose, order, head)
    assert twin == 2 and len(fitted) == 1  # log 0.2 + log 0.97 beats log 0.4 + log 0.01
    assert rotation_error_deg(fitted[0], reg.twin_choice.starts(pose, order)[2]) < 1e-6


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(0.0, 1.0),
                          st.booleans()), min_size=1, max_size=6),
       st.sampled_from([0.0, 2.0, TWIN_EDGE_WEIGHT]), st.booleans())
def test_pruned_twin_fits_choose_as_fitting_them_all(cands, edge_weight, with_verifier):
    """best_fitted_start = fit every start and take the first best twin_scores, with no more fits (a fit's
    quality ≤ 1 bounds each start's score); failed fits (None) score as quality 0."""
    from types import SimpleNamespace

    from hybridpose.regressors.twin_choice import best_fitted_start

    head = [c[0] + 1e-3 for c in cands]
    ver = [c[1] + 1e-3 for c in cands] if with_verifier else None
    fits = [SimpleNamespace(quality=c[2]) if c[3] else None for c in cands]
    starts = list(range(len(cands)))
    fitted = []

    def fake_fit(start):
        fitted.append(start)
        return fits[start]

    best, fit = best_fitted_start(fake_fit, starts, head, ver, edge_weight)
    every = twin_scores(head, [f.quality if f else 0.0 for f in fits], edge_weight=edge_weight, verifier_prob=ver)
    assert best == int(np.argmax(every)) and fit is fits[best]
    assert len(fitted) == len(set(fitted)) <= len(cands)


def test_twin_candidates_need_a_twin_head(tiny_checkpoint, camera):
    reg = CheckpointRegressor(tiny_checkpoint, verifier=None)
    frame = Frame(np.zeros((camera.height, camera.width, 3), np.uint8), camera, 0.0)
    assert reg.twin_candidates(frame) is None  # nothing lit: nothing found
    reg.has_twin_head = False
    with pytest.raises(ValueError, match="twin head"):
        reg.twin_candidates(frame)


def test_folding_batch_norm_keeps_the_outputs(truss):
    from hybridpose.regressors.models import fold_batch_norm

    torch.manual_seed(0)
    net = _trained_looking(KeypointNet(truss.keypoints, width=8, image_size=64, twin_classes=4))
    x = torch.rand(3, 3, 64, 64)
    with torch.no_grad():
        uv, spread, twin = net(x, with_twin=True)
        folded = fold_batch_norm(net)
        assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in folded.modules())
        uv_f, spread_f, twin_f = folded(x, with_twin=True)
    torch.testing.assert_close(uv_f, uv, atol=1e-3, rtol=0)
    torch.testing.assert_close(spread_f, spread, atol=1e-3, rtol=0)
    torch.testing.assert_close(twin_f, twin, atol=1e-4, rtol=1e-4)
    with pytest.raises(ValueError, match="eval mode"):
        fold_batch_norm(KeypointNet(truss.keypoints, width=8, image_size=64).train())


def test_components_in_the_masks_box_are_the_full_frames(rng):
    """Labelling only the box around a mask's pixels must find what labelling the frame finds."""
    from hybridpose.regressors.detection import mask_components

    for _ in range(20):
        mask = np.zeros((120, 160), np.uint8)
        for _ in range(rng.integers(1, 6)):
            x, y = rng.integers(0, 150), rng.integers(0, 110)
            mask[y:y + rng.integers(1, 15), x:x + rng.integers(1, 15)] = 1
        include = (int(rng.integers(0, 100)), int(rng.integers(0, 80)), 30, 20)
        labels, stats, (x, y, w, h) = mask_components(mask, include=include)
        n, ref_labels, ref_stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        assert x <= include[0] and y <= include[1] and x + w >= include[0] + 30 and y + h >= include[1] + 20
        assert len(stats) == n
        order = np.lexsort(stats[1:, :4].T[::-1]), np.lexsort(ref_stats[1:, :4].T[::-1])
        np.testing.assert_array_equal(stats[1:][order[0]], ref_stats[1:][order[1]])
        assert np.array_equal(labels > 0, ref_labels[y:y + h, x:x + w] > 0)
    assert mask_components(np.zeros((10, 10), np.uint8)) is None


def test_edge_on_mirror_mirrors_the_sight_and_keeps_what_the_image_shows(truss, camera, rng):
    """The mirror keeps the box centre and the elevation, mirrors the line of sight across the long
    axis within the main plane (object frame: long x, thin z) and undoes itself; seen edge-on from
    afar, the box's corners project where the pose's do (cv2.projectPoints): what makes it ambiguous."""
    from scipy.spatial.transform import Rotation

    from hybridpose.objects import view_elevation_deg
    from hybridpose.regressors.verify import edge_on_mirror

    c = truss.center
    for _ in range(5):
        pose = Pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform([-0.1, -0.1, 0.5], [0.1, 0.1, 1.2]))
        m = edge_on_mirror(pose, truss)
        np.testing.assert_allclose(m.R @ c + m.t, pose.R @ c + pose.t, atol=1e-12)
        assert view_elevation_deg(m, truss) == pytest.approx(view_elevation_deg(pose, truss), abs=1e-9)
        sight, sight_m = pose.R.T @ -(pose.R @ c + pose.t), m.R.T @ -(m.R @ c + m.t)
        np.testing.assert_allclose(sight_m, sight * [1, -1, 1], atol=1e-12)
        back = edge_on_mirror(m, truss)
        assert rotation_error_deg(back, pose) < 1e-6 and np.allclose(back.t, pose.t)
    # edge-on (the sight in the x-y plane), 40° from the long axis, 30 m away: the two images coincide
    R = Rotation.from_euler("x", 90, degrees=True).as_matrix() @ Rotation.from_euler("z", 50, degrees=True).as_matrix()
    pose = Pose(R, np.array([0.0, 0.0, 30.0]) - R @ c)
    m = edge_on_mirror(pose, truss)
    assert rotation_error_deg(m, pose) > 60
    corners = truss.bbox_corners

    def project(p):
        uv, _ = cv2.projectPoints(corners, cv2.Rodrigues(p.R)[0], p.t, camera.K, np.zeros(5))
        return uv.reshape(-1, 2)

    a, b = project(pose), project(m)
    # the same set of corner images (to 0.05 px at 30 m): each corner of one lands on a corner of the other
    assert np.abs(a[:, None] - b[None]).max(-1).min(1).max() < 0.05


def test_mirror_check_runs_near_edge_on_and_switches_only_when_sure(tiny_checkpoint, truss, camera, tmp_path):
    from scipy.spatial.transform import Rotation

    from hybridpose.objects import view_elevation_deg
    from hybridpose.regressors.twin_choice import MIRROR_SWITCH_P, REFINE_MIN_QUALITY, REFINE_SEARCH_PX
    from hybridpose.edges import fit_edges
    from hybridpose.regressors.verify import MIRROR_BELOW_DEG, box_half_turns, edge_on_mirror
    from hybridpose.render import Renderer

    assert CheckpointRegressor(tiny_checkpoint, mirror_verifier=None).mirror_verifier is None
    ck = _verifier_checkpoint(tmp_path / "mv.pt", truss)
    assert CheckpointRegressor(tiny_checkpoint, mirror_verifier=ck, refine_edges=False).mirror_verifier is None
    with pytest.raises(FileNotFoundError, match="twin verifier"):
        CheckpointRegressor(tiny_checkpoint, mirror_verifier=tmp_path / "missing.pt")
    reg = CheckpointRegressor(tiny_checkpoint, mirror_verifier=ck)
    c = truss.center
    R = Rotation.from_euler("x", 95, degrees=True).as_matrix() @ Rotation.from_euler("z", 50, degrees=True).as_matrix()
    edge_on = Pose(R, np.array([0.0, 0.0, 0.8]) - R @ c)               # 5° from edge-on
    face_on = Pose(np.eye(3), np.array([0.0, 0.0, 0.8]) - c)
    calls = []
    answer = {"p": None}

    def stub(image, K, candidates, strip_pose=None):
        calls.append((candidates, strip_pose))
        return answer["p"]

    reg.mirror_verifier.probabilities = stub
    with Renderer(truss, camera) as r:
        frame = Frame(r.render(edge_on).rgb, camera, 0.0)
    assert reg.twin_choice.mirror_check(frame, face_on) is None and not calls, "far from edge-on: no check"
    assert view_elevation_deg(edge_on, truss) < MIRROR_BELOW_DEG
    answer["p"] = np.array([0.9, 0.02, 0.02, 0.02, 0.01, 0.01, 0.01, 0.01])
    pose, p, k = reg.twin_choice.mirror_check(frame, edge_on)                         # the pose itself is believed
    assert k == 0 and p == 0.9 and pose is edge_on
    cands, strip_pose = calls[-1]
    assert len(cands) == 8 and rotation_error_deg(strip_pose, edge_on) < 1e-9
    mirror = edge_on_mirror(edge_on, truss)
    S = [Pose.identity(), *box_half_turns(truss)]
    for got, want in zip(cands, [edge_on @ s for s in S] + [mirror @ s for s in S]):
        assert rotation_error_deg(got, want) < 1e-9 and np.allclose(got.t, want.t)
    answer["p"] = np.full(8, 0.01)
    answer["p"][5] = MIRROR_SWITCH_P - 0.02
    assert reg.twin_choice.mirror_check(frame, edge_on)[2] == 0                       # not sure enough
    answer["p"][5] = MIRROR_SWITCH_P + 0.02
    pose, p, k = reg.twin_choice.mirror_check(frame, edge_on)
    assert k == 5 and p == pytest.approx(MIRROR_SWITCH_P + 0.02)
    # the believed candidate (the mirror's first twin), edge-fitted where the fit is good, as _refine does
    fit = fit_edges(reg.twin_check.view, frame, mirror @ S[1], search_px=REFINE_SEARCH_PX)
    want = fit.pose if fit is not None and fit.quality >= REFINE_MIN_QUALITY else mirror @ S[1]
    assert rotation_error_deg(pose, want) < 1e-6 and np.allclose(pose.t, want.t)
    assert rotation_error_deg(pose, edge_on) > 30


def test_a_mirror_switch_returns_that_pose_with_the_verifiers_belief_in_its_quality(truss, camera, tmp_path,
                                                                                   monkeypatch):
    """predict: where the mirror check replaces the pose, the measurement carries it, and its quality
    weighs the verifier's belief instead of the twin head's; where it keeps the pose, nothing changes."""
    from hybridpose.regressors.checkpoints import shipped_checkpoint
    from hybridpose.render import Renderer

    pose = Pose.from_rotvec_t([0.4, 0.3, 0.2], [0.0, 0.0, 0.7])
    with Renderer(truss, camera) as r:
        frame = Frame(r.render(pose).rgb, camera, 0.0)
    reg = CheckpointRegressor(shipped_checkpoint("default"),
                              mirror_verifier=_verifier_checkpoint(tmp_path / "mv.pt", truss))
    kept = reg.predict(frame)
    assert not kept.lost and kept.quality > 0
    other = Pose.from_rotvec_t([0.1, -0.2, 0.3], [0.01, 0.0, 0.8])
    monkeypatch.setattr(reg.twin_choice, "mirror_check", lambda frame, pose: (pose, 0.6, 0))
    assert reg.predict(frame).quality == pytest.approx(kept.quality)
    monkeypatch.setattr(reg.twin_choice, "mirror_check", lambda frame, pose: (other, 0.5, 5))
    m = reg.predict(frame)
    assert rotation_error_deg(m.pose, other) < 1e-9 and np.allclose(m.pose.t, other.t)
    assert m.quality > 0
    # the same PnP covariance, in the band of the new quality
    from hybridpose.regressors.calibration import quality_factor

    np.testing.assert_allclose(m.covariance / quality_factor(reg.calibration, m.quality),
                               kept.covariance / quality_factor(reg.calibration, kept.quality))
    monkeypatch.setattr(reg.twin_choice, "mirror_check", lambda frame, pose: (other, 1.0, 5))
    assert reg.predict(frame).quality == pytest.approx(2 * m.quality)   # the belief, not the head's p, weighs it


def _near_edge_on_view(truss, camera, R):
    """A truss pose with rotation ``R`` and its box centre 0.8 m ahead, its rendered frame, and the PnP
    result of its exact keypoints (a stand-in for a network's estimate: the tiny network's own would
    be noise)."""
    from hybridpose.render import Renderer

    pose = Pose(R, np.array([0.0, 0.0, 0.8]) - R @ truss.center)
    with Renderer(truss, camera) as r:
        frame = Frame(r.render(pose).rgb, camera, 0.0)
    p = (pose @ truss.keypoints) @ camera.K.T
    return pose, frame, solve_pnp(p[:, :2] / p[:, 2:3], truss.keypoints, camera.K, threshold_px=4.0)


def test_edge_on_expert_replaces_the_estimate_only_below_its_gate(tiny_checkpoint, truss, camera, tmp_path):
    """The expert re-estimates where the first estimate is seen within ``expert_below_deg`` of edge-on,
    on the same detection, and its estimate is what the measurement carries; elsewhere it is not run;
    an expert for other keypoints, or a gate outside [0, 90]°, is refused by name."""
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from hybridpose.objects import view_elevation_deg
    from hybridpose.regressors.checkpoints import load_checkpoint, save_checkpoint

    assert CheckpointRegressor(tiny_checkpoint, edge_on_expert=None).expert is None
    with pytest.raises(ValueError, match="expert_below_deg"):
        CheckpointRegressor(tiny_checkpoint, edge_on_expert=tiny_checkpoint, expert_below_deg=120.0)
    with pytest.raises(ValueError, match="expert_rule"):
        CheckpointRegressor(tiny_checkpoint, edge_on_expert=tiny_checkpoint, expert_rule="vote")
    ck = load_checkpoint(tiny_checkpoint)
    ck["model"]["keypoints_m"] = ck["model"]["keypoints_m"] * 1.5
    save_checkpoint(tmp_path / "other.pt", ck)
    with pytest.raises(ValueError, match="edge_on_expert: .*other.pt"):
        CheckpointRegressor(tiny_checkpoint, edge_on_expert=tmp_path / "other.pt")
    # a checkpoint for other keypoints (a user's object) just goes without the shipped expert
    assert CheckpointRegressor(tmp_path / "other.pt", edge_on_expert="auto").expert is None

    R = Rotation.from_euler("x", 80, degrees=True).as_matrix() @ Rotation.from_euler("z", 30, degrees=True).as_matrix()
    near, frame, res = _near_edge_on_view(truss, camera, R)
    elevation = view_elevation_deg(near, truss)
    assert 5 < elevation < 15
    reg = CheckpointRegressor(tiny_checkpoint, edge_on_expert=tiny_checkpoint, check_twins=False, refine_edges=False,
                              expert_rule="replace")
    assert np.allclose(reg.keypoints_m, truss.keypoints)
    order, prob = [0, 1, 2, 3], np.array([0.97, 0.01, 0.01, 0.01])
    expert_pose = Pose.from_rotvec_t([0.3, -0.2, 0.1], [0.01, 0.02, 0.75])
    calls = []
    reg.passes.estimate_in = lambda image, cam, seen, sun_turn=0.0: KeypointEstimate(replace(res, pose=near), order, prob, 64)

    def expert(image, cam, seen, sun_turn=0.0):
        calls.append(seen)
        return KeypointEstimate(replace(res, pose=expert_pose), order, prob, 64)

    reg.expert.passes.estimate_in = expert
    for gate, runs in ((elevation + 1.0, True), (elevation - 1.0, False)):
        reg.configure(expert_below_deg=gate)
        m = reg.predict(frame, roi=(200, 150, 240, 180))
        assert bool(calls) == runs
        want = expert_pose if runs else near
        assert rotation_error_deg(m.pose, want) < 1e-9 and np.allclose(m.pose.t, want.t)
        if runs:
            assert calls[-1] == (200, 150, 240, 180), "the expert sees the same detection"
        calls.clear()
    reg.expert.passes.estimate_in = lambda *a, **k: None              # the expert finds nothing: the first estimate
    reg.configure(expert_below_deg=90.0)
    m = reg.predict(frame)
    assert rotation_error_deg(m.pose, near) < 1e-9


def test_quality_scale_recovers_each_bands_spread_and_never_rises_with_quality():
    """Errors that spread s_k times wider (in NEES) in band k give back factors ≈ s_k relative to the
    one factor for all; sparse bands merge upwards; a better band never gets a larger factor."""
    from scipy.stats import chi2

    from hybridpose.regressors.calibration import quality_factor
    from hybridpose.training.calibrate import quality_scale

    rng = np.random.default_rng(0)
    spread = {0.05: 9.0, 0.25: 2.0, 0.45: 0.5}          # quality → NEES multiplier
    q = np.concatenate([np.full(2000, k) for k in spread])
    v = np.concatenate([s * rng.chisquare(6, 2000) for s in spread.values()])
    bands = quality_scale(q, v, edges=(0.0, 0.2, 0.4))
    assert bands["edges"] == [0.0, 0.2, 0.4] and bands["poses"] == [2000, 2000, 2000]
    overall = float(np.quantile(v, 0.9)) / chi2.ppf(0.9, 6)
    assert bands["overall"] == pytest.approx(overall)
    for f, s in zip(bands["factors"], spread.values()):
        assert f * overall == pytest.approx(s, rel=0.1)
    rec = {"quality_scale": bands}
    assert quality_factor(rec, 0.1) == bands["factors"][0] and quality_factor(rec, 0.2) == bands["factors"][1]
    assert quality_factor(rec, 0.99) == bands["factors"][2] and quality_factor(None, 0.3) == 1.0
    # a band with too few poses joins the next one up; factors do not rise with quality
    q2 = np.concatenate([np.full(10, 0.05), np.full(200, 0.15), np.full(200, 0.3)])
    v2 = np.concatenate([np.full(10, 1.0), np.full(200, 1.0), 3.0 * rng.chisquare(6, 200)])
    b2 = quality_scale(q2, v2, edges=(0.0, 0.1, 0.2), min_poses=50)
    assert b2["edges"] == [0.0, 0.2] and b2["poses"] == [210, 200]
    assert b2["factors"][0] == b2["factors"][1], "the low band's tiny spread is raised to the better band's"
    with pytest.raises(ValueError, match="nees_values"):
        quality_scale(q[:10], v[:10])
    with pytest.raises(ValueError, match="finite"):
        quality_scale(np.full(60, np.nan), np.ones(60))


def test_edge_on_expert_quality_rule_returns_the_better_measurement(tiny_checkpoint, truss, camera, monkeypatch):
    """expert_rule="quality": both estimates are measured and the one of higher quality is returned
    (the first on a tie); each estimate's quality uses its own crop side (the expert may run at
    another resolution: the same RMS in pixels of a larger crop is a smaller error)."""
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from hybridpose.regressors import predictor

    near, frame, res = _near_edge_on_view(truss, camera, Rotation.from_euler("x", 85, degrees=True).as_matrix())
    order, prob = [0, 1, 2, 3], np.array([0.97, 0.01, 0.01, 0.01])
    other = Pose.from_rotvec_t([0.3, -0.2, 0.1], [0.01, 0.02, 0.75])
    reg = CheckpointRegressor(tiny_checkpoint, edge_on_expert=tiny_checkpoint, check_twins=False, refine_edges=False,
                              expert_below_deg=90.0, expert_rule="quality")
    assert CheckpointRegressor(tiny_checkpoint).options.expert_rule == "pooled-unsure"   # the default
    assert res.inlier_ratio == 1.0
    first = replace(res, pose=near, rms_px=2.0)
    reg.passes.estimate_in = lambda image, cam, seen, sun_turn=0.0: KeypointEstimate(first, order, prob, 64)
    measured = []  # one covariance per estimate measured
    covariance = predictor.pnp_covariance
    monkeypatch.setattr(predictor, "pnp_covariance", lambda *a: measured.append(1) or covariance(*a))
    for rms, crop_px, want in ((1.0, 64, other), (3.0, 64, near), (2.0, 64, near), (2.4, 96, other)):
        second = replace(res, pose=other, rms_px=rms)
        reg.expert.passes.estimate_in = lambda image, cam, seen, sun_turn=0.0, e=second, s=crop_px: KeypointEstimate(e, order, prob, s)
        measured.clear()
        m = reg.predict(frame, roi=(200, 150, 240, 180))
        assert m.pose.allclose(want), (rms, crop_px)
        # an estimate that cannot beat the first one's quality is not measured (edge-fitted) at all
        assert len(measured) == (2 if want is other else 1), (rms, crop_px)
        q = np.exp(-(rms if want is other else 2.0) / (0.02 * (crop_px if want is other else 64))) * 0.97
        assert m.quality == pytest.approx(q)


@pytest.mark.parametrize("wrong_first", [False, True])
def test_pooled_rule_returns_the_best_scored_twin_of_both_estimates_with_fewer_fits(
        tiny_checkpoint, truss, camera, monkeypatch, wrong_first):
    """expert_rule="pooled": of the four box twins of both estimates, the candidate of highest
    log p_head + w_edge · log q_fit + w_verifier · log p_verifier + log q_pnp is returned — the same one
    that fitting all eight and scoring them gives — after fitting only until no other can win. With
    ``wrong_first`` both heads favour an end-for-end twin of the truth, whose edges do not fit."""
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    import hybridpose.edges.fit as edges
    from hybridpose.regressors.keypoint_passes import pnp_quality
    from hybridpose.regressors.twin_choice import REFINE_MIN_QUALITY, REFINE_SEARCH_PX, VERIFIER_EDGE_WEIGHT

    near, frame, res = _near_edge_on_view(truss, camera, Rotation.from_euler("x", 84, degrees=True).as_matrix())
    reg = CheckpointRegressor(tiny_checkpoint, edge_on_expert=tiny_checkpoint, expert_below_deg=90.0,
                              expert_rule="pooled")
    assert reg.verifier is not None and reg.twin_check is not None
    turned = Pose(Rotation.from_rotvec([0.0, 0.0, 0.06]).as_matrix(), np.zeros(3)) @ near   # a 3.4° worse estimate
    if wrong_first:   # the keypoints' pose is turned to the head's twin (order[0]), here a wrong one
        twin = reg.twin_check.twins[0]
        ests = [KeypointEstimate(replace(res, pose=near @ twin, rms_px=1.5), [1, 0, 2, 3], np.array([0.3, 0.6, 0.05, 0.05]), 64),
                KeypointEstimate(replace(res, pose=turned @ twin, rms_px=0.8), [1, 0, 2, 3], np.array([0.25, 0.7, 0.03, 0.02]), 64)]
    else:
        ests = [KeypointEstimate(replace(res, pose=near, rms_px=1.5), [0, 1, 2, 3], np.array([0.97, 0.01, 0.01, 0.01]), 64),
                KeypointEstimate(replace(res, pose=turned, rms_px=0.8), [1, 0, 2, 3], np.array([0.1, 0.4, 0.3, 0.2]), 64)]
    reg.passes.estimate_in = lambda image, cam, seen, sun_turn=0.0: ests[0]
    reg.expert.passes.estimate_in = lambda image, cam, seen, sun_turn=0.0: ests[1]
    # brute force: every candidate fitted and scored
    best, best_score = None, -np.inf
    for est in ests:
        pose, order, prob, _ = est[0].pose, est[1], est[2], est[3]
        starts = reg.twin_choice.starts(pose, order)
        head = [prob[k] for k in order]
        ver = reg.verifier.probabilities(frame.image, camera.K, starts)
        for j, start in enumerate(starts):
            fit = edges.fit_edges(reg.twin_check.view, frame, start, search_px=REFINE_SEARCH_PX)
            score = (twin_scores([head[j]], [0.0 if fit is None else fit.quality], edge_weight=VERIFIER_EDGE_WEIGHT,
                                 verifier_prob=[ver[j]])[0] + np.log(pnp_quality(est) + 1e-3))
            if score > best_score:
                out = fit.pose if fit is not None and fit.quality >= REFINE_MIN_QUALITY else start
                best, best_score = (out, pnp_quality(est) * head[j]), score
    fits = []
    real_fit = edges.fit_edges
    monkeypatch.setattr(edges, "fit_edges", lambda *a, **k: fits.append(1) or real_fit(*a, **k))
    m = reg.predict(frame, roi=(200, 150, 240, 180))
    assert m.pose.allclose(best[0], atol=1e-9)
    assert m.quality == pytest.approx(best[1])
    assert (2 if wrong_first else 1) <= len(fits) < 8
    if wrong_first:
        assert rotation_error_deg(m.pose, near) < 5.0, "the edges overrule both heads' wrong twin"


def test_pooled_unsure_pools_only_where_a_twin_head_is_unsure(tiny_checkpoint, truss, camera):
    """expert_rule="pooled-unsure": both heads sure (≥ VERIFIER_SURE) → the quality rule's measurement;
    either unsure → the pooled rule's. The cases are ones where the two rules return different
    measurements, so each comparison can fail."""
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from hybridpose.regressors.twin_choice import VERIFIER_SURE

    near, frame, res = _near_edge_on_view(truss, camera, Rotation.from_euler("x", 84, degrees=True).as_matrix())
    turned = Pose(Rotation.from_rotvec([0.0, 0.0, 0.06]).as_matrix(), np.zeros(3)) @ near
    twin = CheckpointRegressor(tiny_checkpoint).twin_check.twins[0]
    # the second estimate's sure head favours the end-for-end twin; the first head is sure, then unsure
    for first_prob, pooled in ((np.array([0.98, 0.01, 0.005, 0.005]), False), (np.array([0.93, 0.04, 0.02, 0.01]), True)):
        assert (first_prob.max() < VERIFIER_SURE) == pooled
        ests = [KeypointEstimate(replace(res, pose=near, rms_px=1.5), [0, 1, 2, 3], first_prob, 64),
                KeypointEstimate(replace(res, pose=turned @ twin, rms_px=0.8), [1, 0, 2, 3], np.array([0.01, 0.98, 0.005, 0.005]), 64)]
        out = {}
        for rule in ("pooled-unsure", "pooled", "quality"):
            reg = CheckpointRegressor(tiny_checkpoint, edge_on_expert=tiny_checkpoint, expert_below_deg=90.0,
                                      expert_rule=rule)
            reg.passes.estimate_in = lambda image, cam, seen, sun_turn=0.0: ests[0]
            reg.expert.passes.estimate_in = lambda image, cam, seen, sun_turn=0.0: ests[1]
            out[rule] = reg.predict(frame, roi=(200, 150, 240, 180))
        assert out["pooled"].quality != pytest.approx(out["quality"].quality)
        same = out["pooled" if pooled else "quality"]
        assert out["pooled-unsure"].pose.allclose(same.pose, atol=1e-12)
        assert out["pooled-unsure"].quality == same.quality


def test_options_are_one_checked_frozen_object(tiny_checkpoint):
    import dataclasses

    from hybridpose.regressors.options import KeypointOptions

    opts = KeypointOptions(passes="2", turn_pnp_outliers=None, pnp_outliers="ransac")
    assert opts.passes == 2 and opts.turn_pnp_outliers == "ransac"  # normalised once
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.passes = 1
    for bad, match in ((dict(passes=3), "passes"), (dict(turns="sometimes"), "turns"),
                       (dict(expert_below_deg=120), "expert_below_deg"), (dict(max_depth_m=-1.0), "max_depth_m"),
                       (dict(detection="sonar"), "detection")):
        with pytest.raises(ValueError, match=match):
            KeypointOptions(**bad)
    # the regressor takes the object, keyword overrides of it, or both
    reg = CheckpointRegressor(tiny_checkpoint, options=opts, turns="off")
    assert reg.options == dataclasses.replace(opts, turns="off")
    with pytest.raises(TypeError, match="pases: not an option"):
        CheckpointRegressor(tiny_checkpoint, pases=2)
    with pytest.raises(ValueError, match="verifier: decided when the checkpoint is loaded"):
        reg.configure(verifier=None)
    reg.configure(max_depth_m="auto")
    assert reg.options.max_depth_m == "auto" and reg.max_depth_m is not None  # resolved on the checkpoint


def test_eval_scores_a_symmetric_part_against_its_nearest_equivalent_pose(tmp_path, truss):
    import trimesh

    from hybridpose.metrics import add, adds
    from hybridpose.objects import load_object
    from hybridpose.training.evaluate import pose_errors

    path = tmp_path / "box.obj"
    trimesh.creation.box(extents=(0.2, 0.12, 0.08)).export(path)
    box = load_object(path)
    assert box.symmetric
    truth = Pose.from_rotvec_t([0.3, -0.2, 0.5], [0.02, -0.01, 0.8])
    half_turn = box.symmetries[0]
    est = (truth @ half_turn).retract(np.r_[np.radians(2.0), 0, 0, 0.001, 0, 0])
    pts = box.sample_surface(300, rng=0)
    e = pose_errors(est, truth, box, pts)
    assert e["rot_deg"] == pytest.approx(2.0, abs=0.01) and e["trans_m"] < 0.002   # the look-alike, not 180° off
    assert e["add_m"] == pytest.approx(adds(est, truth, pts)) and e["add_m"] < 0.01
    # an asymmetric object is scored against the truth itself, with ADD
    far = pose_errors(truth @ Pose.from_rotvec_t([0, 0, np.pi], [0, 0, 0]), truth, truss, truss.sample_surface(300, rng=0))
    assert far["rot_deg"] == pytest.approx(180.0, abs=1e-6)
    assert far["add_m"] == pytest.approx(add(truth @ Pose.from_rotvec_t([0, 0, np.pi], [0, 0, 0]), truth,
                                             truss.sample_surface(300, rng=0)))


def test_a_checkpoint_of_a_mesh_named_like_a_built_in_does_not_get_the_built_in():
    from hybridpose.objects import load_builtin
    from hybridpose.regressors.checkpoint_checks import builtin_object

    cube = load_builtin("cube")
    assert builtin_object({"object": "cube", "diameter_m": cube.diameter}).name == "cube"
    assert builtin_object({"object": "cube", "diameter_m": 0.14636}) is None  # ViSP's 8.45-cm cube.obj
    assert builtin_object({"object": "my_part", "diameter_m": 0.2}) is None
