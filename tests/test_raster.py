"""Painter's raster shared by the trackers' facet ids and the twin verifier's drawings."""
import numpy as np
import trimesh

from hybridpose.geometry import Camera, Pose
from hybridpose.geometry.raster import fill_triangles, front_faces_far_first


def test_a_cube_seen_head_on_shows_only_its_near_face():
    box = trimesh.creation.box((0.2, 0.2, 0.2))
    tri = np.asarray(box.vertices)[np.asarray(box.faces)]
    pose = Pose.from_quat_t([1, 0, 0, 0], [0, 0, 1.0])
    tri_cam, facing, order = front_faces_far_first(tri, np.asarray(box.face_normals), pose)
    # the face at z = -0.1 (object) faces the camera squarely; the four sides are seen edge-on
    near = np.flatnonzero(np.isclose(box.face_normals[:, 2], -1))
    assert set(order.tolist()) == set(near.tolist())
    np.testing.assert_allclose(facing[near], 1.0, atol=0.02)  # cos of the small off-axis angle
    assert np.all(facing[np.isclose(box.face_normals[:, 2], 1)] < 0)
    np.testing.assert_allclose(tri_cam[near, :, 2], 0.9)


def test_nearer_triangles_paint_over_farther_ones():
    cam = Camera(64, 48, 50.0, 50.0, 31.5, 23.5)
    far = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0, 0.5, 0]])
    tri = np.stack([far, far * 0.3 + [0, 0, -0.5]])        # the small one 0.5 m nearer the camera
    normals = np.array([[0, 0, -1.0], [0, 0, -1.0]])
    pose = Pose.from_quat_t([1, 0, 0, 0], [0, 0, 2.0])
    # given in near-first order: the raster must still paint the far one first
    tri_cam, _, order = front_faces_far_first(tri[::-1], normals, pose)
    assert order.tolist() == [1, 0]
    p = tri_cam[order] @ cam.K.T
    img = fill_triangles(np.zeros((cam.height, cam.width), np.uint8), p[..., :2] / p[..., 2:3], [10, 20])
    assert img[23, 31] == 20 and img[40, 12] == 0 and (img == 10).sum() > (img == 20).sum() > 20


def _zbuffer(tri, normals, values, pose, cam, scale=1.0):
    from hybridpose.geometry.raster import zbuffer_front_faces

    h, w = int(round(cam.height * scale)), int(round(cam.width * scale))
    return zbuffer_front_faces(np.asarray(tri, float), np.asarray(normals, float), np.asarray(values, np.int64),
                               pose.R, pose.t, cam.K, scale, h, w)


def test_zbuffer_shows_the_nearer_triangle_in_any_order():
    cam = Camera(64, 48, 50.0, 50.0, 31.5, 23.5)
    far = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0, 0.5, 0]])
    tri = np.stack([far, far * 0.3 + [0, 0, -0.5]])
    normals = np.array([[0, 0, -1.0], [0, 0, -1.0]])
    pose = Pose.from_quat_t([1, 0, 0, 0], [0, 0, 2.0])
    for order in ([0, 1], [1, 0]):
        img = _zbuffer(tri[order], normals[order], np.array([10, 20])[order], pose, cam)
        assert img[23, 31] == 20 and img[40, 12] == 0 and (img == 10).sum() > (img == 20).sum() > 20
    # a back face is not drawn
    assert not _zbuffer(tri, -normals, [10, 20], pose, cam).any()


def test_zbuffer_orders_long_triangles_the_painter_misorders():
    """A long triangle reaching from 1.2 m to 3 m crosses in front of a small one at 2 m: painted by
    farthest vertex the small one goes on top everywhere; per pixel the long one is in front."""
    cam = Camera(64, 48, 50.0, 50.0, 31.5, 23.5)
    long_tri = np.array([[-0.2, -0.3, 1.2], [0.2, -0.3, 1.2], [0.0, 0.3, 3.0]])   # camera frame = object frame
    small = np.array([[-0.3, -0.5, 2.0], [0.3, -0.5, 2.0], [0.0, 0.1, 2.0]])
    tri = np.stack([long_tri, small])
    normals = np.array([np.cross(t[1] - t[0], t[2] - t[0]) for t in tri])
    normals *= -np.sign(normals[:, 2:])                                           # towards the camera
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    pose = Pose.identity()
    img = _zbuffer(tri, normals, [1, 2], pose, cam)
    u, v = 31, 12  # the long triangle's point (0, −0.28, 1.26) m, inside the small one's image
    assert img[v, u] == 1
    tri_cam, _, order = front_faces_far_first(tri, normals, pose)
    p = tri_cam[order] @ cam.K.T
    painted = fill_triangles(np.zeros((cam.height, cam.width), np.uint8), p[..., :2] / p[..., 2:3],
                             np.array([1, 2])[order])
    assert painted[v, u] == 2  # what the painter's order gets wrong


def test_zbuffer_agrees_with_mujoco_depth(truss, truss_depth_views):
    """Where the z-buffer shows a facet of the truss, MuJoCo's depth buffer sees the object at that
    facet's depth (the ray meets its plane there), and it shows nothing where MuJoCo sees nothing."""
    from hybridpose.edges import ModelView

    cam = Camera.default()
    view = ModelView(truss)
    rng = np.random.default_rng(3)
    agree, background = [], []
    for pose, depth in truss_depth_views:
        depth = depth.astype(float)
        ids = view.facet_ids(pose, cam, scale=1.0)
        v, u = np.nonzero(ids)
        pick = rng.choice(len(u), 3000, replace=False)
        u, v = u[pick], v[pick]
        _, lam, ok = view.ray_plane_depths(pose, cam, np.c_[u, v], ids[v, u])
        agree.extend(np.abs(lam[ok] - depth[v[ok], u[ok]]) < 0.002)
        background.append(np.mean(depth[ids == 0] == 0))
    assert np.mean(agree) > 0.97 and min(background) > 0.97


def _zbuffer_oracle(tri, normals, values, pose, cam):
    """Every pixel of every front face's box tested, in numpy: the raster before its row spans."""
    h, w = cam.height, cam.width
    ids, inv_depth = np.zeros((h, w), np.uint16), np.zeros((h, w))
    P = tri @ pose.R.T + pose.t
    for f in range(len(tri)):
        p = P[f]
        if np.any(p[:, 2] <= 1e-3) or (normals[f] @ pose.R.T) @ p.sum(0) >= 0:
            continue
        uv = np.c_[(cam.fx * p[:, 0] / p[:, 2] + cam.cx + 0.5) * 1.0 - 0.5,
                   (cam.fy * p[:, 1] / p[:, 2] + cam.cy + 0.5) * 1.0 - 0.5]
        area = (uv[1, 0] - uv[0, 0]) * (uv[2, 1] - uv[0, 1]) - (uv[2, 0] - uv[0, 0]) * (uv[1, 1] - uv[0, 1])
        if abs(area) < 1e-12:
            continue
        x0, x1 = max(int(np.ceil(uv[:, 0].min())), 0), min(int(np.floor(uv[:, 0].max())), w - 1)
        y0, y1 = max(int(np.ceil(uv[:, 1].min())), 0), min(int(np.floor(uv[:, 1].max())), h - 1)
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                b0 = ((uv[1, 0] - x) * (uv[2, 1] - y) - (uv[2, 0] - x) * (uv[1, 1] - y)) / area
                b1 = ((uv[2, 0] - x) * (uv[0, 1] - y) - (uv[0, 0] - x) * (uv[2, 1] - y)) / area
                b2 = 1.0 - b0 - b1
                if min(b0, b1, b2) < 0:
                    continue
                iz = b0 * (1.0 / p[0, 2]) + b1 * (1.0 / p[1, 2]) + b2 * (1.0 / p[2, 2])
                if iz > inv_depth[y, x]:
                    inv_depth[y, x], ids[y, x] = iz, values[f]
    return ids


def test_zbuffer_matches_a_test_of_every_pixel_in_each_box(truss):
    """The raster narrows each row of a triangle's box to where its edges cross the row: on random
    truss views (some running out of the image) it must give exactly what testing every pixel gives."""
    from scipy.spatial.transform import Rotation

    cam = Camera(96, 72, 80.0, 80.0, 47.5, 35.5)
    tri = np.asarray(truss.mesh.vertices)[np.asarray(truss.mesh.faces)]
    normals = np.asarray(truss.mesh.face_normals)
    values = np.arange(1, len(tri) + 1)
    for k, R in enumerate(Rotation.random(6, random_state=5).as_matrix()):
        pose = Pose(R, np.array([0.05 * (k - 3), 0.0, 0.5 + 0.25 * k]))
        img = _zbuffer(tri, normals, values, pose, cam)
        assert img.any()
        np.testing.assert_array_equal(img, _zbuffer_oracle(tri, normals, values, pose, cam))


def test_a_densely_tessellated_part_is_rasterised_from_its_facets_alone():
    """A textured export tessellates its flat faces densely; the facet-id raster draws each convex
    facet as a fan of its corners instead: the same ids at every pixel, from a handful of triangles."""
    import trimesh

    from hybridpose.edges import ModelView
    from hybridpose.geometry import Camera, Pose
    from hybridpose.geometry.raster import zbuffer_front_faces
    from hybridpose.objects import ObjectModel

    mesh = trimesh.creation.box((0.08, 0.06, 0.05)).subdivide().subdivide().subdivide()
    view = ModelView(ObjectModel("dense-box", mesh))
    camera = Camera.default()
    rng = np.random.default_rng(5)
    for _ in range(10):
        pose = Pose.from_rotvec_t(rng.normal(size=3), [rng.uniform(-0.03, 0.03), 0.01, 0.3])
        full = zbuffer_front_faces(view.triangles, view.face_normals, view.facet_of, pose.R, pose.t, camera.K,
                                   0.5, 240, 320)
        assert np.array_equal(view.facet_ids(pose, camera), full)
    assert len(view.triangles) == 768 and len(view.raster_mesh[0]) == 12
