"""Metrics against independent computations (scipy Rotation, brute force, numerical integration)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hybridpose.geometry import Pose, random_quat
from hybridpose.metrics import (add, add_recall, adds, auc, pose_errors, rotation_error_deg, speed_score,
                                translation_error_m)


def random_pose(rng):
    return Pose.from_quat_t(random_quat(None, rng), rng.uniform(-0.3, 0.3, 3) + [0, 0, 0.8])


def test_rotation_error_matches_scipy(rng):
    for _ in range(500):
        a, b = random_pose(rng), random_pose(rng)
        ref = np.degrees((Rotation.from_matrix(a.R).inv() * Rotation.from_matrix(b.R)).magnitude())
        assert rotation_error_deg(a, b) == pytest.approx(ref, abs=1e-8)
    p = random_pose(rng)
    assert rotation_error_deg(p, p) == 0.0
    small = p.retract([1e-7, 0, 0, 0, 0, 0])
    assert rotation_error_deg(p, small) == pytest.approx(np.degrees(1e-7), rel=1e-6)


def test_translation_and_speed(rng):
    a = Pose.from_rotvec_t([0, 0, 0], [0.0, 0.0, 1.0])
    b = Pose.from_rotvec_t([0, 0, np.radians(10)], [0.03, 0.04, 1.0])
    assert translation_error_m(b, a) == pytest.approx(0.05)
    assert speed_score(b, a) == pytest.approx(np.radians(10) + 0.05 / 1.0)


def test_add_and_adds_against_brute_force(rng, truss):
    pts = truss.sample_surface(300, rng=1)
    for _ in range(20):
        est, gt = random_pose(rng), random_pose(rng)
        pe, pg = pts @ est.R.T + est.t, pts @ gt.R.T + gt.t
        assert add(est, gt, pts) == pytest.approx(np.linalg.norm(pe - pg, axis=1).mean())
        # every pair's distance, (300, 300): no nearest-neighbour structure to share a bug with
        brute = np.linalg.norm(pg[:, None] - pe[None], axis=2).min(1).mean()
        assert adds(est, gt, pts) == pytest.approx(brute)
        assert adds(est, gt, pts) <= add(est, gt, pts) + 1e-12


def test_pose_errors_score_the_nearest_symmetric_equivalent(rng):
    """A box's half-turn about its own axis looks the same: an estimate of the turned pose has zero
    error to the nearest equivalent (ADD-S ≈ 0) and the half-turn's 180° without the symmetry (ADD > 0)."""
    half_turn = Pose(Rotation.from_euler("z", 180, degrees=True).as_matrix(), np.zeros(3))
    # points of a box symmetric under that half-turn
    pts = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.05, 0.05) for z in (-0.02, 0.02)])
    for _ in range(10):
        gt = random_pose(rng)
        est = (gt @ half_turn).retract([0.01, 0.0, 0.0, 0.002, 0.0, 0.0])   # ≈ 0.57° and 2 mm off the turned pose
        sym = pose_errors(est, gt, [half_turn], pts, symmetric=True)
        assert sym["rot_deg"] == pytest.approx(rotation_error_deg(est, gt @ half_turn))
        assert sym["rot_deg"] < 1.0 and sym["trans_m"] == pytest.approx(translation_error_m(est, gt))
        assert sym["speed"] == pytest.approx(speed_score(est, gt @ half_turn))
        assert sym["add_m"] == pytest.approx(adds(est, gt, pts)) and sym["nearest"].allclose(gt @ half_turn)
        plain = pose_errors(est, gt, (), pts)
        assert plain["rot_deg"] > 179.0 and plain["add_m"] == pytest.approx(add(est, gt, pts))
        assert "add_m" not in pose_errors(est, gt)


def test_auc_matches_numerical_integration(rng):
    e = rng.exponential(0.03, 200)
    thr = np.linspace(0, 0.1, 200001)
    acc = (e[None, :] <= thr[:, None]).mean(1)
    assert auc(e, 0.1) == pytest.approx(np.trapezoid(acc, thr) / 0.1, abs=1e-4)
    assert auc([0.0, 0.0], 0.1) == 1.0 and auc([0.2], 0.1) == 0.0
    assert add_recall([0.01, 0.05, 0.03], diameter_m=0.4) == pytest.approx(2 / 3)


def test_metric_bad_input():
    with pytest.raises(ValueError, match="est: expected a Pose or a"):
        rotation_error_deg(np.eye(4), np.eye(3))
    with pytest.raises(ValueError, match="errors: empty"):
        auc([], 0.1)
    with pytest.raises(ValueError, match="points_obj"):
        add(Pose.identity(), Pose.identity(), np.zeros(3))
