"""Unlabelled keypoints for symmetric objects: hull visibility against ray casting, the symmetry gauge,
PnP without correspondences against the true pose (up to the symmetries), the training target, the
heatmap peaks, and the network on both engines."""
import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from hybridpose.geometry import Pose
from hybridpose.objects import ObjectModel
from hybridpose.regressors.keypoint_net import UnlabelledKeypointNet, heatmap_peaks
from hybridpose.regressors.unlabelled import (focal_loss, heatmap_targets, hull_planes, solve_pnp_unlabelled,
                                              symmetry_gauge, visible_keypoints)

K = np.array([[300.0, 0, 63.5], [0, 300.0, 63.5], [0, 0, 1]])


@pytest.fixture(scope="module")
def box():
    return ObjectModel("box", trimesh.creation.box(extents=(0.18, 0.11, 0.07)))


def _look(seed: int, distance: float = 1.0) -> Pose:
    """A random orientation at ``distance`` metres on the optical axis."""
    return Pose(Rotation.random(random_state=seed).as_matrix(), np.array([0.0, 0.0, distance]))


def _project(points, pose: Pose) -> np.ndarray:
    p = (points @ pose.R.T + pose.t) @ K.T
    return p[:, :2] / p[:, 2:]


def _first_hit(origin, direction, triangles) -> float:
    """Smallest ray parameter s > 0 at which ``origin + s·direction`` meets a triangle (Möller–Trumbore), ∞ if none."""
    v0, v1, v2 = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = origin - v0
    u = np.einsum("ij,ij->i", tvec, p) * inv
    q = np.cross(tvec, e1)
    v = np.einsum("j,ij->i", direction, q) * inv
    s = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9) & (s > 1e-9)
    return float(s[hit].min()) if hit.any() else np.inf


def test_hull_visibility_agrees_with_ray_casting(box):
    planes = hull_planes(box.keypoints)
    triangles = box.mesh.vertices[box.mesh.faces]
    for seed in range(30):
        pose = _look(seed, 0.6)
        centre = -pose.R.T @ pose.t  # camera centre, object frame
        seen = visible_keypoints(planes, pose.R, pose.t)
        for k, point in enumerate(box.keypoints):
            # the keypoint is seen where no triangle crosses the ray before it (nudged off the corner)
            first = _first_hit(centre, point - centre, triangles)
            assert seen[k] == (first > 1 - 1e-6), (seed, k)
    # between three and seven corners of a box are in view from outside it
    counts = [visible_keypoints(planes, _look(s).R, _look(s).t).sum() for s in range(100)]
    assert 3 <= min(counts) and max(counts) <= 7


def test_the_gauge_holds_one_keypoint_per_orbit(box):
    assert len(box.symmetries) == 3
    assert len(symmetry_gauge(box.keypoints, box.symmetries)) == 2   # the corners' two chiralities
    cube = ObjectModel("cube", trimesh.creation.box(extents=(0.1, 0.1, 0.1)))
    assert symmetry_gauge(cube.keypoints, cube.symmetries) == [0]
    assert symmetry_gauge(box.keypoints, ()) == list(range(8))


@pytest.mark.parametrize("spurious", [False, True])
def test_pnp_without_correspondences_finds_the_pose_up_to_symmetry(box, spurious):
    planes, gauge = hull_planes(box.keypoints), symmetry_gauge(box.keypoints, box.symmetries)
    rng = np.random.default_rng(0)
    for seed in range(25):
        truth = _look(seed)
        seen = visible_keypoints(planes, truth.R, truth.t)
        det = _project(box.keypoints, truth)[seen] + rng.normal(0.0, 0.3, (seen.sum(), 2))
        det = det[rng.permutation(len(det))]
        if spurious:  # a detection on the background, as confident as the rest
            det = np.vstack([det[:2], [[5.0, 120.0]], det[2:]])
        res = solve_pnp_unlabelled(det, box.keypoints, planes, gauge, K, threshold_px=4.0)
        if seen.sum() < 4:
            continue
        assert res is not None, seed
        errors = [Rotation.from_matrix(truth.R.T @ (res.pose @ S).R).magnitude() for S in (Pose.identity(), *box.symmetries)]
        assert np.degrees(min(errors)) < 3.0, seed
        assert np.linalg.norm(res.pose.t - truth.t) < 0.03 * np.linalg.norm(truth.t)
        assert res.inliers.sum() == seen.sum() and res.inlier_ratio == pytest.approx(1.0)
    assert solve_pnp_unlabelled(det[:3], box.keypoints, planes, gauge, K, 4.0) is None


def test_the_target_peaks_at_the_visible_keypoints_only():
    kp = torch.tensor([[[10.3, 20.0], [60.0, 61.5], [100.0, 5.0]]])
    seen = torch.tensor([[True, True, False]])
    target = heatmap_targets(kp, seen, 128, 4)
    assert target.shape == (1, 1, 32, 32)
    ones = torch.nonzero(target[0, 0] == 1.0).tolist()
    assert sorted(ones) == sorted([[round((20.0 - 1.5) / 4), round((10.3 - 1.5) / 4)], [round(60 / 4 - 0.375), round(58.5 / 4)]])
    assert target[0, 0, 1, 24] < 0.01  # the hidden keypoint leaves no trace
    # the focal loss is small where the logits agree with the target and large where they do not
    good = torch.logit(target.clamp(1e-3, 1 - 1e-3))
    assert focal_loss(good, target) < 0.1 * focal_loss(-good, target)


def test_heatmap_peaks_find_sub_cell_positions_strongest_first():
    h = 32
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(h, dtype=torch.float32), indexing="ij")
    centres = [(5.3, 7.6, 0.9), (20.0, 25.2, 0.6), (28.4, 3.0, 0.3)]
    prob = torch.zeros(h, h)
    for x, y, peak in centres:
        prob = torch.maximum(prob, peak * torch.exp(-((xs - x) ** 2 + (ys - y) ** 2) / 2))
    uv, score = heatmap_peaks(torch.logit(prob.clamp(1e-6, 1 - 1e-6))[None, None], 3, 4)
    assert torch.all(score[0, :-1] >= score[0, 1:])
    expected = torch.tensor([[4 * x + 1.5, 4 * y + 1.5] for x, y, _ in centres])
    assert torch.allclose(uv[0], expected, atol=1.0)   # within a quarter of a cell
    # the score is the peak cell's probability
    at_cell = [p * np.exp(-((x - round(x)) ** 2 + (y - round(y)) ** 2) / 2) for x, y, p in centres]
    assert torch.allclose(score[0], torch.tensor(at_cell, dtype=torch.float32), atol=1e-3)


def test_the_unlabelled_network_runs_alike_on_torch_and_onnxruntime(box):
    pytest.importorskip("onnxruntime")
    from hybridpose.regressors.engines import OnnxRuntimeEngine, TorchEngine
    from hybridpose.regressors.models import build_model, fold_batch_norm

    torch.manual_seed(0)
    net = fold_batch_norm(build_model("default", keypoints_m=box.keypoints, gauge=[0, 1]).eval())
    assert isinstance(net, UnlabelledKeypointNet) and net.twin_head is None
    x = torch.rand(2, 3, 128, 128)
    a, b = TorchEngine(net, torch.device("cpu"))(x), OnnxRuntimeEngine(net, 128)(x)
    assert a[0].shape == (2, 8, 2) and a[1].shape == (2, 8) and a[2] is None and b[2] is None
    assert torch.allclose(a[1], b[1], atol=1e-4) and torch.allclose(a[0], b[0], atol=1e-2)
    with pytest.raises(ValueError, match="gauge"):
        UnlabelledKeypointNet(box.keypoints, gauge=[9])
    with pytest.raises(ValueError, match="twin"):
        build_model("default", keypoints_m=box.keypoints, gauge=[0], twin_classes=4)


def test_the_linked_cluster_keeps_the_chain_from_the_strongest_detection():
    from hybridpose.regressors.network_detection import linked_cluster

    points = np.array([[10.0, 10.0], [100.0, 100.0], [14.0, 12.0], [18.0, 15.0], [21.0, 30.0], [104.0, 99.0]])
    assert linked_cluster(points, 6.0).tolist() == [[10.0, 10.0], [14.0, 12.0], [18.0, 15.0]]
    assert len(linked_cluster(points, 20.0)) == 4 and len(linked_cluster(points, 200.0)) == 6
