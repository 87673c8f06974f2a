"""Renderer alignment with cv2 projection, masks, depth, lighting, arm, sensor."""
import cv2
import numpy as np
import pytest

from hybridpose.geometry import Camera, Pose, random_quat
from hybridpose.render import Renderer, SensorModel, SpaceLighting, arm_state, random_poses


def cv2_silhouette(obj, pose, camera, s=8):
    """Independent oracle: cv2.projectPoints + cv2.fillConvexPoly per triangle on an s× finer grid,
    coverage ≥ ½ at each pixel (OpenCV's fill alone includes every touched pixel)."""
    uv, _ = cv2.projectPoints(obj.vertices, cv2.Rodrigues(pose.R)[0], pose.t, camera.K, None)
    uv = (uv.reshape(-1, 2) + 0.5) * s - 0.5
    canvas = np.zeros((camera.height * s, camera.width * s), np.uint8)
    pts = np.round(uv * 16).astype(np.int32)
    for f in obj.faces:
        cv2.fillConvexPoly(canvas, pts[f], 1, cv2.LINE_8, 4)
    return canvas.reshape(camera.height, s, camera.width, s).mean(axis=(1, 3)) >= 0.5


def iou(a, b):
    return (a & b).sum() / max(1, (a | b).sum())


@pytest.fixture(scope="module")
def renderer(truss):
    r = Renderer(truss, Camera.default())
    yield r
    r.close()


def test_alignment_with_projected_mesh(truss, renderer):
    cam = renderer.camera
    poses = random_poses(30, cam, (0.35, 1.2), rng=7)
    ious, centroid_err = [], []
    for pose in poses:
        res = renderer.render(pose)
        sil = cv2_silhouette(truss, pose, cam)
        if sil.sum() < 200:
            continue
        ious.append(iou(sil, res.mask))
        ys, xs = np.nonzero(sil)
        ym, xm = np.nonzero(res.mask)
        centroid_err.append(np.hypot(xs.mean() - xm.mean(), ys.mean() - ym.mean()))
    assert len(ious) >= 20
    assert min(ious) >= 0.98, ious
    assert max(centroid_err) < 0.5


def test_alignment_off_centre_principal_point_and_non_square_pixels(truss):
    cam = Camera(400, 300, 420.0, 380.0, 212.7, 141.2)
    with Renderer(truss, cam) as r:
        for pose in random_poses(6, cam, (0.5, 1.0), rng=3):
            assert iou(cv2_silhouette(truss, pose, cam), r.render(pose).mask) >= 0.98


def test_depth_is_z_in_metres(truss, renderer):
    pose = Pose.from_quat_t(random_quat(None, 5), [0.0, 0.0, 0.7])
    res = renderer.render(pose)
    z = (pose @ truss.vertices)[:, 2]
    d = res.depth[res.mask]
    assert z.min() - 0.002 <= d.min() and d.max() <= z.max() + 0.002
    assert np.all(res.depth[~res.mask] == 0)


def test_space_lighting_black_background_and_eclipse(truss):
    cam = Camera.default().scaled(160)
    pose = Pose.from_rotvec_t([0.3, 0.5, 0.1], [0, 0, 0.6])
    with Renderer(truss, cam) as r:
        lit = r.render(pose)
        near = cv2.dilate(lit.mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        assert np.all(lit.rgb[~near] == 0), "space background must be black (anti-aliased rim aside)"
        assert lit.rgb[lit.mask].max() > 100
        dark = r.render(pose, sun_scale=0.0)
        assert dark.rgb.max() == 0, "no ambient light: an eclipsed object is invisible"
    with Renderer(truss, cam, SpaceLighting(background="earth")) as r:
        earth = r.render(pose, rng=1)
        assert earth.rgb[~earth.mask].mean() > 20


def test_arm_occludes_object(truss, renderer):
    pose = Pose.from_rotvec_t([0.2, 0.1, 0.0], [0.0, 0.0, 0.7])
    centre = pose @ truss.center
    full = renderer.render(pose, arm=arm_state(centre, truss.diameter / 2, 0.5, "full"))
    assert full.visible_fraction < 0.02 and full.mask.sum() > 1000
    partial = renderer.render(pose, arm=arm_state(centre, truss.diameter / 2, 0.5, "partial"))
    assert 0.2 < partial.visible_fraction < 0.98
    parked = renderer.render(pose, arm=arm_state(centre, truss.diameter / 2, 0.0, "full"))
    assert parked.visible_fraction > 0.999
    assert np.array_equal(full.mask, parked.mask)  # the full silhouette ignores the arm


def test_sensor_effects_are_seeded(truss):
    cam = Camera.default().scaled(128)
    pose = Pose.from_rotvec_t([0.3, 0.5, 0.1], [0, 0, 0.6])
    with Renderer(truss, cam, sensor=SensorModel(blur_sigma_px=1.0, noise_std=0.02, gamma=2.2)) as r:
        a, b, c = r.render(pose, rng=1), r.render(pose, rng=1), r.render(pose, rng=2)
    assert np.array_equal(a.rgb, b.rgb) and not np.array_equal(a.rgb, c.rgb)
    assert a.rgb[~a.mask].mean() > 1  # noise lifts the black background


def test_render_bad_input(truss, renderer):
    with pytest.raises(ValueError, match="behind the camera"):
        renderer.render(Pose.from_rotvec_t([0, 0, 0], [0, 0, -0.5]))
    with pytest.raises(TypeError, match="T_cam_obj"):
        renderer.render(np.eye(4))
    with pytest.raises(ValueError, match="sun_direction_cam"):
        SpaceLighting(sun_direction_cam=(0, 0, 0))
    with pytest.raises(ValueError, match="distortion"):
        Renderer(truss, Camera(64, 48, 60, 60, 31.5, 23.5, (0.1, 0, 0, 0)))


def test_a_printed_part_shows_its_print_the_way_up_the_mesh_file_maps_it(tmp_path):
    from test_objects import _printed_cube_files

    from hybridpose.objects import load_object
    from hybridpose.render import Appearance

    path, image = _printed_cube_files(tmp_path)
    cube = load_object(path)
    camera = Camera.default().scaled((320, 240))
    # the +z face towards the camera, the object's +y up in the image (the camera's y points down)
    pose = Pose.from_rotvec_t([np.pi, 0.0, 0.0], [0.0, 0.0, 0.3])
    with Renderer(cube, camera) as r:
        rgb = r.render(pose, appearance=Appearance(ambient=1.0)).rgb
    # object (x, y) quarter → the image quarter it maps to (v counts up from the image's bottom row)
    for (x, y), (row, col) in {(-1, 1): (0, 0), (1, 1): (0, 1), (-1, -1): (1, 0), (1, -1): (1, 1)}.items():
        u, v = camera.project(np.array([[0.02 * x, 0.02 * y, 0.04]]), pose)[0]
        expected = image[16 + 32 * row, 16 + 32 * col].astype(int)
        seen = rgb[int(v), int(u)].astype(int)
        assert np.argmax(seen) == np.argmax(expected) and np.abs(seen - expected).max() < 120, (x, y, seen, expected)
