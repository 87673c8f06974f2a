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
