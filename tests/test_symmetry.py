"""Discrete symmetries: found on boxes and prisms, not on the truss; written and read the BOP way;
metrics score a symmetric object's estimate against the nearest equivalent of the truth."""
import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from hybridpose.bench.modes import FrameRecord, SequenceFrame, sequence_stats, trusted_errors_deg
from hybridpose.core import Frame
from hybridpose.datasets.bop import read_symmetries, write_models
from hybridpose.geometry import Camera, Pose
from hybridpose.metrics import nearest_equivalent, rotation_error_deg
from hybridpose.objects import ObjectModel
from hybridpose.objects.symmetry import discrete_symmetries


def model(mesh, name="part"):
    return ObjectModel(name, mesh)


@pytest.mark.parametrize("extents, group", [((0.2, 0.12, 0.08), 4), ((0.2, 0.1, 0.1), 8), ((0.1, 0.1, 0.1), 24)])
def test_boxes_have_their_symmetry_groups(extents, group):
    box = trimesh.creation.box(extents=extents).apply_translation([0.3, -0.1, 0.05])  # off the origin
    syms = discrete_symmetries(box)
    assert len(syms) + 1 == group
    # oracle: each maps the surface onto itself, and the set is closed under composition
    pts, _ = trimesh.sample.sample_surface(box, 3000, seed=1)
    tree = cKDTree(trimesh.sample.sample_surface(box, 20000, seed=2)[0])
    for S in syms:
        assert np.percentile(tree.query(S @ pts)[0], 99) < 0.01
    mats = [np.eye(3)] + [S.R for S in syms]
    for a in mats:
        for b in mats:
            assert any(np.allclose(a @ b, c, atol=1e-9) for c in mats)


def test_the_truss_and_a_box_with_a_bump_have_none(truss):
    assert truss.symmetries == () and not truss.symmetric
    assert discrete_symmetries(truss.mesh) == ()
    bumped = trimesh.creation.box(extents=(0.2, 0.12, 0.08)).union(
        trimesh.creation.box(extents=(0.05, 0.05, 0.05)).apply_translation([0.08, 0.04, 0.05]))
    assert model(bumped).symmetries == ()


def test_symmetries_round_trip_through_bop_models_info(tmp_path):
    box = model(trimesh.creation.box(extents=(0.2, 0.12, 0.08)).apply_translation([0.01, 0.02, 0.0]))
    write_models(tmp_path, box)
    back = read_symmetries(tmp_path / "models" / "models_info.json")
    assert len(back) == len(box.symmetries) == 3
    for a, b in zip(box.symmetries, back):
        assert np.allclose(a.matrix, b.matrix, atol=1e-9)
    assert read_symmetries(tmp_path / "missing.json") is None
    with pytest.raises(ValueError, match="symmetries: expected"):
        ObjectModel("bad", box.mesh, symmetries=(np.eye(4),))


def test_metrics_score_a_symmetric_estimate_against_the_nearest_equivalent():
    box = model(trimesh.creation.box(extents=(0.2, 0.12, 0.08)))
    truth = Pose.from_rotvec_t([0.3, 0.2, -0.1], [0.0, 0.0, 0.8])
    twin = truth @ box.symmetries[1]
    assert rotation_error_deg(twin, truth) == pytest.approx(180.0)
    assert rotation_error_deg(twin, nearest_equivalent(twin, truth, box.symmetries)) < 1e-6
    assert nearest_equivalent(twin, truth, ()) is truth

    cam = Camera.default().scaled(64)
    seq = [SequenceFrame(Frame(np.zeros((cam.height, cam.width, 3), np.uint8), cam, k / 30, k), truth, 1.0)
           for k in range(5)]
    records = [FrameRecord(twin, True, 1.0, raw_pose=twin) for _ in seq]
    sym, plain = sequence_stats(seq, records, box), sequence_stats(seq, records)
    assert sym["rot_mean_deg"] < 1e-6 and sym["silent_failures"] == 0 and sym["add_recall"] == 1.0
    assert sym["in_basin"] == 1.0 and sym["edge_px_median"] < 1e-6
    assert plain["rot_mean_deg"] == pytest.approx(180.0) and plain["silent_failures"] == 5
    off = [FrameRecord(truth.retract([0.0, 0.0, 0.0, 0.004, 0.0, 0.0]), True, 1.0) for _ in seq]  # 4 mm aside
    px = sequence_stats(seq, off, box)["edge_px_median"]
    assert px == pytest.approx(cam.fx * 0.004 / 0.8, rel=0.2)  # ≈ f · Δx / z
    assert max(trusted_errors_deg(seq, records, box.symmetries)) < 1e-6
