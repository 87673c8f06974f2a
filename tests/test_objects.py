import warnings

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from hybridpose import registry
from hybridpose.objects import ObjectModel, load_builtin, load_object


def test_truss_dimensions_and_mesh(truss):
    np.testing.assert_allclose(truss.extents, [0.38, 0.20, 0.05], atol=1e-9)
    assert truss.mesh.is_watertight
    assert 0.42 < truss.diameter < 0.44
    np.testing.assert_allclose(truss.center, 0, atol=1e-12)
    assert truss.keypoints.shape == (12, 3)
    assert len(truss.sharp_edges) > 100 and truss.sharp_edges.shape[1:] == (2, 3)
    assert not truss.symmetric


def test_truss_is_asymmetric(truss):
    """No proper rotation about the centre maps the truss onto itself: every candidate symmetry of a
    box-like shape (the 24 axis permutations) and random rotations leave ≥ 5 mm Chamfer distance."""
    pts = truss.sample_surface(4000, rng=0) - truss.center
    tree = cKDTree(pts)
    candidates = [r for r in Rotation.create_group("O").as_matrix() if not np.allclose(r, np.eye(3))]
    candidates += list(Rotation.random(200, random_state=0).as_matrix())
    def chamfer_capped(moved):  # each distance capped at 2 cm: the search stops there, and only ≤ 5 mm matters
        return np.minimum(tree.query(moved, distance_upper_bound=0.02)[0], 0.02).mean()

    for R in candidates:
        # the symmetric Chamfer distance: the moved points to the surface, and the surface to the moved
        # points — the latter is the points turned back (Rᵀ) to the surface, so one tree serves both
        d = 0.5 * (chamfer_capped(pts @ R.T) + chamfer_capped(pts @ R))
        assert d > 0.005, f"near-symmetry under rotation {Rotation.from_matrix(R).as_rotvec()}"


def test_registry_lists_truss():
    assert "truss" in registry.available("object")
    with pytest.raises(ValueError, match="unknown object 'nope'; available: box, cube, truss"):
        registry.create("object", "nope")


def test_load_builtin_only_for_registered_names(truss, tmp_path):
    assert load_builtin("truss").diameter == pytest.approx(truss.diameter)
    # a user's mesh is recorded by its file name: not a built-in, even when the file exists
    truss.mesh.export(tmp_path / "truss.ply")
    for name in ("nope", None, str(tmp_path / "truss.ply")):
        assert load_builtin(name) is None


@pytest.mark.parametrize("ext", ["obj", "ply", "stl"])
def test_load_object_from_file(tmp_path, truss, ext):
    path = tmp_path / f"part.{ext}"
    truss.mesh.export(path)
    m = load_object(path)
    assert m.name == "part"
    assert abs(m.diameter - truss.diameter) < 1e-6


def test_load_object_in_mm_warns_and_scale_fixes(tmp_path, truss):
    mesh = truss.mesh.copy()
    mesh.apply_scale(1000.0)
    path = tmp_path / "mm.stl"
    mesh.export(path)
    with pytest.warns(UserWarning, match="scale=0.001"):
        load_object(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = load_object(path, scale=0.001)
    assert abs(m.diameter - truss.diameter) < 1e-6


def test_load_object_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="neither a built-in object"):
        load_object(tmp_path / "missing.obj")
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat garbage\n\x00\x01")
    with pytest.raises(ValueError, match="bad.ply"):
        load_object(bad)
    with pytest.raises(ValueError, match="scale"):
        load_object("truss", scale=0)
    with pytest.raises(ValueError, match="mesh"):
        ObjectModel("empty", trimesh.Trimesh())


def _printed_cube_files(folder, with_material=True):
    """A cube OBJ whose +z face is mapped onto the whole of a four-colour image (OBJ + MTL + PNG)."""
    import cv2

    mesh = trimesh.creation.box((0.08, 0.08, 0.08))
    uv = np.c_[(mesh.vertices[:, 0] + 0.04) / 0.08, (mesh.vertices[:, 1] + 0.04) / 0.08]
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv)
    image = np.zeros((64, 64, 3), np.uint8)
    image[:32, :32], image[:32, 32:], image[32:, :32], image[32:, 32:] = (255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0)
    lines = ["mtllib print.mtl", "usemtl print"] + [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv] + [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in mesh.faces + 1]
    (folder / "cube.obj").write_text("\n".join(lines) + "\n")
    if with_material:
        (folder / "print.mtl").write_text("newmtl print\nKd 1 1 1\nmap_Kd print.png\n")
        cv2.imwrite(str(folder / "print.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    return folder / "cube.obj", image


def test_a_mesh_file_with_its_image_loads_as_a_printed_part(tmp_path):
    path, image = _printed_cube_files(tmp_path)
    cube = load_object(path)
    assert np.array_equal(cube.texture, image)
    assert cube.face_uv.shape == (len(cube.faces), 3, 2) and not cube.texture.flags.writeable
    assert len(cube.symmetries) == 23  # the shape's: the fit's network finds it up to them (its print is the tracker's)
    # each face corner keeps the coordinates it has in the file
    corners = cube.vertices[cube.faces]
    assert np.allclose(cube.face_uv, (corners[..., :2] + 0.04) / 0.08, atol=1e-5)


def test_a_mesh_file_whose_material_is_missing_is_a_plain_part(tmp_path):
    path, _ = _printed_cube_files(tmp_path, with_material=False)  # trimesh stands a grey 2 × 2 image in
    cube = load_object(path)
    assert cube.texture is None and cube.face_uv is None and len(cube.symmetries) == 23


def test_a_print_needs_its_coordinates(tmp_path):
    mesh = trimesh.creation.box((0.08, 0.08, 0.08))
    with pytest.raises(ValueError, match="texture, face_uv"):
        ObjectModel("cube", mesh, texture=np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(ValueError, match="face_uv"):
        ObjectModel("cube", mesh, texture=np.zeros((4, 4, 3), np.uint8), face_uv=np.zeros((3, 3, 2)))
    with pytest.raises(ValueError, match="texture: expected an"):
        ObjectModel("cube", mesh, texture=np.zeros((4, 4)), face_uv=np.zeros((len(mesh.faces), 3, 2)))
