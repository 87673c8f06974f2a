"""Geometry against independent oracles: scipy Rotation, gtsam Pose3, cv2.projectPoints."""
import cv2
import gtsam
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from hybridpose.metrics import rotation_error_deg
from hybridpose.geometry import (
    Camera, Pose, matrix_to_quat_wxyz, matrix_to_rotvec, mirrored_tilt, quat_angle_between, quat_multiply, quat_slerp,
    quat_wxyz_to_matrix, random_quat, rotvec_to_matrix, rotvec_to_quat, se3_exp, se3_log,
)

N = 3000


def xyzw_to_wxyz(q):
    return np.concatenate([q[..., 3:], q[..., :3]], -1)


def edge_case_rotvecs(rng):
    """Random axes at angles ≈ 0, tiny, ≈ π and exactly π, plus uniform ones."""
    axes = rng.normal(size=(N, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([
        np.zeros(50), rng.uniform(0, 1e-7, 200), rng.uniform(1e-7, 1e-3, 200),
        np.pi - rng.uniform(0, 1e-6, 200), np.full(50, np.pi), rng.uniform(0, np.pi, N - 700),
    ])
    return axes * angles[:, None]


def test_quat_to_matrix_matches_scipy(rng):
    q = random_quat(N, rng)
    q[: N // 2] *= -1  # w < 0 half of the time: same rotation
    ours = quat_wxyz_to_matrix(q)
    ref = Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], 1)).as_matrix()
    np.testing.assert_allclose(ours, ref, atol=1e-12)


def test_matrix_to_quat_matches_scipy_including_pi(rng):
    rv = edge_case_rotvecs(rng)
    R = Rotation.from_rotvec(rv).as_matrix()
    ours = matrix_to_quat_wxyz(R)
    ref = xyzw_to_wxyz(Rotation.from_matrix(R).as_quat())
    # q and -q are the same rotation; ours is canonical w >= 0
    dots = np.abs(np.sum(ours * ref, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)
    assert np.all(ours[:, 0] >= 0)
    np.testing.assert_allclose(quat_wxyz_to_matrix(ours), R, atol=1e-12)


def test_rotvec_exp_log_match_scipy(rng):
    rv = edge_case_rotvecs(rng)
    np.testing.assert_allclose(rotvec_to_matrix(rv), Rotation.from_rotvec(rv).as_matrix(), atol=1e-12)
    back = matrix_to_rotvec(rotvec_to_matrix(rv))
    angle = np.linalg.norm(rv, axis=1)
    ok = angle < np.pi - 1e-5  # at π the axis sign is ambiguous: compare rotations instead
    np.testing.assert_allclose(back[ok], rv[ok], atol=1e-9)
    np.testing.assert_allclose(rotvec_to_matrix(back), rotvec_to_matrix(rv), atol=1e-9)
    q = rotvec_to_quat(rv)
    np.testing.assert_allclose(np.abs(np.sum(q * xyzw_to_wxyz(Rotation.from_rotvec(rv).as_quat()), 1)), 1, atol=1e-12)


def test_rotvec_to_matrix_of_one_vector_matches_batch_and_cv2(rng):
    """The compiled one-vector path (PnP's) against scipy, cv2.Rodrigues and the batched NumPy path, on
    both sides of the series switch (θ = 1e-4) and near π."""
    import cv2

    for rv in [*edge_case_rotvecs(rng), [1e-4 * (1 - 1e-9), 0, 0], [1e-4 * (1 + 1e-9), 0, 0], [0, 0, 1e-12]]:
        rv = np.asarray(rv, dtype=np.float64)
        one = rotvec_to_matrix(rv)
        assert one.shape == (3, 3)
        np.testing.assert_allclose(one, Rotation.from_rotvec(rv).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(one, cv2.Rodrigues(rv)[0], atol=1e-12)
        np.testing.assert_allclose(one, rotvec_to_matrix(rv[None])[0], atol=1e-15)


def test_pose_reorthonormalises_only_what_is_not_a_rotation_to_rounding(rng):
    """A rotation to float rounding is kept bit for bit (no SVD); one off by 1e-8 (inside the check's
    tolerance, e.g. float32 from a file) comes back orthonormal to rounding; the checks still reject."""
    R = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    assert np.array_equal(Pose(R, np.zeros(3)).R, R)
    off = R + 1e-8 * rng.normal(size=(3, 3))
    fixed = Pose(off, np.zeros(3)).R
    assert np.abs(fixed.T @ fixed - np.eye(3)).max() < 1e-14 and np.abs(fixed - R).max() < 1e-7
    with pytest.raises(ValueError, match="not a rotation"):
        Pose(R + 1e-3, np.zeros(3))
    with pytest.raises(ValueError, match="reflection"):
        Pose(-R, np.zeros(3))


def test_quat_multiply_and_angle_match_scipy(rng):
    a, b = random_quat(N, rng), random_quat(N, rng)
    ref = Rotation.from_quat(np.roll(a, -1, 1)) * Rotation.from_quat(np.roll(b, -1, 1))
    np.testing.assert_allclose(quat_wxyz_to_matrix(quat_multiply(a, b)), ref.as_matrix(), atol=1e-12)
    ang = (Rotation.from_quat(np.roll(a, -1, 1)).inv() * Rotation.from_quat(np.roll(b, -1, 1))).magnitude()
    np.testing.assert_allclose(quat_angle_between(a, b), ang, atol=1e-9)
    np.testing.assert_allclose(quat_angle_between(a, -a), 0.0, atol=1e-12)  # sign does not matter


def test_slerp_matches_scipy(rng):
    from scipy.spatial.transform import Slerp

    for _ in range(50):
        q0, q1 = random_quat(None, rng), random_quat(None, rng)
        alpha = rng.uniform()
        ref = Slerp([0, 1], Rotation.from_quat(np.roll(np.stack([q0, q1]), -1, 1)))([alpha]).as_matrix()[0]
        np.testing.assert_allclose(quat_wxyz_to_matrix(quat_slerp(q0, q1, alpha)), ref, atol=1e-10)


def test_se3_exp_log_match_gtsam(rng):
    edge = edge_case_rotvecs(rng)[::10]
    xis = np.concatenate([rng.normal(size=(300, 6)), np.hstack([edge, rng.normal(size=edge.shape)])])
    for xi in xis:
        R, t = se3_exp(xi)
        ref = gtsam.Pose3.Expmap(xi)
        np.testing.assert_allclose(R, ref.rotation().matrix(), atol=1e-9)
        np.testing.assert_allclose(t, ref.translation(), atol=1e-9)
        if np.linalg.norm(xi[:3]) < np.pi - 1e-3:
            np.testing.assert_allclose(se3_log(R, t), gtsam.Pose3.Logmap(ref), atol=1e-8)


def test_se3_exp_batched_matches_one_at_a_time(rng):
    """The one-vector fast path and the batched path are the same function."""
    xis = np.concatenate([rng.normal(size=(50, 6)), 1e-6 * rng.normal(size=(10, 6)), np.zeros((1, 6))])
    R, t = se3_exp(xis)
    for k, xi in enumerate(xis):
        R1, t1 = se3_exp(xi)
        np.testing.assert_allclose(R1, R[k], atol=1e-14)
        np.testing.assert_allclose(t1, t[k], atol=1e-14)


def test_pose_algebra(rng):
    for _ in range(200):
        a = Pose.from_quat_t(random_quat(None, rng), rng.normal(size=3))
        b = Pose.from_quat_t(random_quat(None, rng), rng.normal(size=3))
        np.testing.assert_allclose((a @ b).matrix, a.matrix @ b.matrix, atol=1e-12)
        np.testing.assert_allclose((a @ a.inverse()).matrix, np.eye(4), atol=1e-12)
        p = rng.normal(size=(5, 3))
        np.testing.assert_allclose(a @ p, (a.matrix[:3, :3] @ p.T).T + a.t, atol=1e-12)
        xi = a.local(b)
        assert a.retract(xi).allclose(b, atol=1e-9)
        assert Pose.exp(a.log()).allclose(a, atol=1e-9)
        assert a.interpolate(b, 0.0).allclose(a, atol=1e-12) and a.interpolate(b, 1.0).allclose(b, atol=1e-9)


def test_covariance_in_camera_matches_sampled_errors_of_r_and_t(rng):
    """Errors sampled on the right perturbation, measured as scipy sees R'·Rᵀ and as t' − t, spread
    as the camera-frame covariance says."""
    pose = Pose.from_rotvec_t(rng.normal(size=3), [0.1, -0.05, 0.8])
    L = rng.normal(size=(6, 6)) * np.r_[[0.01] * 3, [0.002] * 3][:, None]
    cov = L @ L.T
    xi = rng.multivariate_normal(np.zeros(6), cov, size=20000)
    moved = [pose.retract(x) for x in xi]
    d_theta = Rotation.from_matrix(np.array([m.R @ pose.R.T for m in moved])).as_rotvec()
    d_t = np.array([m.t - pose.t for m in moved])
    sampled = np.cov(np.c_[d_theta, d_t].T)
    want = pose.covariance_in_camera(cov)
    assert np.allclose(sampled, want, atol=0.03 * np.abs(want).max())
    with pytest.raises(ValueError, match="covariance"):
        pose.covariance_in_camera(np.eye(3))


def test_pose_is_immutable():
    p = Pose.identity()
    with pytest.raises(ValueError):
        p.t[0] = 1.0
    with pytest.raises(Exception):
        p.R = np.eye(3)
    composed = Pose.from_rotvec_t([0.1, 0.2, 0.3], [0.0, 0.0, 1.0]) @ p
    for pose in (composed, composed.inverse()):
        with pytest.raises(ValueError):
            pose.R[0, 0] = 2.0
        with pytest.raises(ValueError):
            pose.t[0] = 2.0


def test_long_compositions_stay_rotations(rng):
    """Composition skips the re-orthonormalisation: 20 000 steps (a tracker's pose @ delta over a
    long run) must stay a rotation far inside the checks' tolerance."""
    pose = Pose.identity()
    steps = [Pose.exp(np.r_[rng.normal(0, 0.05, 3), rng.normal(0, 0.01, 3)]) for _ in range(50)]
    for k in range(20000):
        pose = pose @ steps[k % 50]
    assert np.abs(pose.R.T @ pose.R - np.eye(3)).max() < 1e-10
    Pose(pose.R, pose.t)  # passes the checks of a pose from outside


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 1e-3),
       st.lists(st.floats(-5, 5, allow_nan=False), min_size=3, max_size=3))
def test_quat_pose_round_trip(qv, t):
    q = np.asarray(qv) / np.linalg.norm(qv)
    p = Pose.from_quat_t(q, t)
    q2 = p.quat_wxyz
    assert abs(abs(np.dot(q, q2)) - 1) < 1e-9 and q2[0] >= 0
    assert Pose.from_quat_t(q2, p.t).allclose(p, atol=1e-12)
    assert Pose.exp(p.log()).allclose(p, atol=1e-8)


@pytest.mark.parametrize("dist", [(), (0.1, -0.05, 0.001, -0.002, 0.01)])
def test_camera_project_matches_cv2(rng, dist):
    cam = Camera(640, 480, 610.0, 590.0, 322.3, 237.9, dist)
    for _ in range(100):
        pose = Pose.from_quat_t(random_quat(None, rng), [rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(0.4, 1.2)])
        pts = rng.uniform(-0.2, 0.2, size=(20, 3))
        ref, _ = cv2.projectPoints(pts, cv2.Rodrigues(pose.R)[0], pose.t, cam.K, np.array(dist) if dist else None)
        np.testing.assert_allclose(cam.project(pts, pose), ref.reshape(-1, 2), atol=1e-6)


def test_undistortion_matches_cv2_and_distort_pixels_inverts_it(rng):
    """Camera.undistort against cv2.undistort; distort_pixels against cv2.undistortPoints; a frame of
    a pinhole camera is its own undistorted frame."""
    from hybridpose.core import Frame

    lens = Camera(320, 240, 300.0, 302.0, 161.0, 118.5, (-0.3, 0.1, 0.001, -0.002, 0.0))
    image = rng.integers(0, 255, size=(240, 320, 3), dtype=np.uint8)
    ours = lens.undistort(image).astype(int)
    ref = cv2.undistort(image, lens.K, np.asarray(lens.dist)).astype(int)
    assert np.mean(np.abs(ours - ref) <= 1) > 0.99
    raw = rng.uniform([20, 20], [300, 220], size=(50, 2))
    pinhole_px = cv2.undistortPoints(raw.reshape(-1, 1, 2), lens.K, np.asarray(lens.dist), P=lens.K).reshape(-1, 2)
    np.testing.assert_allclose(lens.distort_pixels(pinhole_px), raw, atol=0.01)  # undistortPoints iterates
    assert np.all(np.isnan(lens.distort_pixels([[np.nan, np.nan]])))
    frame = Frame(image, lens, 0.0)
    assert frame.undistorted().camera == lens.pinhole() and not frame.undistorted().camera.dist
    plain = Frame(image, lens.pinhole(), 0.0)
    assert plain.undistorted() is plain


def test_camera_scaled_keeps_fov_and_pixel_centres():
    cam = Camera.default()
    assert abs(cam.hfov_deg - 56.14) < 0.01
    s = cam.scaled(224)
    assert (s.width, s.height) == (224, 224)
    assert abs(s.hfov_deg - cam.hfov_deg) < 1e-9 and abs(s.vfov_deg - cam.vfov_deg) < 1e-9
    assert (s.cx, s.cy) == (111.5, 111.5)
    # a point projects to the same relative image position at both resolutions
    pose = Pose.from_rotvec_t([0.1, 0.2, 0.3], [0.05, -0.02, 0.7])
    uv, uv_s = cam.project([[0.1, 0.0, 0.0]], pose), s.project([[0.1, 0.0, 0.0]], pose)
    np.testing.assert_allclose((uv_s + 0.5) / [224, 224], (uv + 0.5) / [640, 480], atol=1e-12)
    assert cam.scaled("1280x960").fx == 1200
    assert Camera.from_fov(640, 480, cam.hfov_deg).fx == pytest.approx(600.0)
    assert Camera.from_K(cam.K.ravel().tolist(), 640, 480) == cam
    assert Camera.from_dict(cam.to_dict()) == cam


@pytest.mark.parametrize("call, match", [
    (lambda: Pose(np.diag([1.0, 1.0, -1.0]), np.zeros(3)), "reflection"),
    (lambda: Pose(np.ones((3, 3)), np.zeros(3)), "not a rotation"),
    (lambda: Pose(np.eye(3), [0, 0]), r"t: expected shape \(3,\)"),
    (lambda: Pose(np.eye(3), [0, np.nan, 1]), "NaN"),
    (lambda: Pose.from_quat_t([1, 0.1, 0, 0], [0, 0, 1]), "not a unit quaternion"),
    (lambda: Camera(640, 480, 0.0, 600, 319.5, 239.5), "fx: expected a positive focal length"),
    (lambda: Camera(640, 0, 600, 600, 319.5, 239.5), "height"),
    (lambda: Camera.default().project([[0, 0, 0.1]], Pose.from_rotvec_t([0, 0, 0], [0, 0, -1])), "behind the camera"),
    (lambda: Camera.default().project(np.zeros(3), Pose.identity()), r"points_obj: expected shape \(N, 3\)"),
    (lambda: Camera.default().scaled("abc"), "size"),
])
def test_bad_input_names_the_argument(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_unit_direction_check_normalises_and_names_the_argument():
    from hybridpose.geometry import as_unit_direction

    np.testing.assert_allclose(as_unit_direction([0.0, 3.0, 4.0], "d"), [0.0, 0.6, 0.8])
    for bad in ([0.0, 0.0], [0.0, 0.0, 0.0], [1.0, np.nan, 0.0], "up"):
        with pytest.raises(ValueError, match=r"sun: expected a non-zero, finite \(3,\) direction it travels, got"):
            as_unit_direction(bad, "sun", "it travels")


def test_in_front_says_which_points_project_cam_takes():
    cam = Camera.default()
    pts = np.array([[0.0, 0.0, 0.5], [0.1, 0.0, 1e-7], [0.0, 0.1, -0.2]])
    assert cam.in_front(pts).tolist() == [True, False, False]
    cam.project_cam(pts[cam.in_front(pts)])
    for p in pts[~cam.in_front(pts)]:
        with pytest.raises(ValueError, match="behind the camera"):
            cam.project_cam(p[None])


def test_image_box_bounds_cv2_projections_and_refuses_points_behind_the_camera(rng):
    cam = Camera(640, 480, 610.0, 590.0, 322.3, 237.9)
    pts = rng.uniform(-0.2, 0.2, size=(30, 3))
    pose = Pose.from_rotvec_t([0.3, -0.2, 0.5], [0.05, -0.02, 0.8])
    ref, _ = cv2.projectPoints(pts, cv2.Rodrigues(pose.R)[0], pose.t, cam.K, None)
    ref = ref.reshape(-1, 2)
    np.testing.assert_allclose(cam.image_box(pts, pose), [*ref.min(0), *ref.max(0)], atol=1e-6)
    # the box is not clipped to the image, and a point at or behind the camera plane gives none
    assert cam.image_box(pts, Pose(np.eye(3), [3.0, 0.0, 0.8]))[0] > cam.width
    assert cam.image_box(pts, Pose(np.eye(3), [0.0, 0.0, 0.1])) is None


@settings(max_examples=25, deadline=None)
@given(st.floats(5.0, 30.0), st.floats(0.0, 2 * np.pi), st.floats(-0.1, 0.1), st.floats(-0.1, 0.1))
def test_mirrored_tilt_is_the_other_solution_of_planar_pose(tilt_deg, azimuth, x_m, y_m):
    """Oracle: OpenCV's IPPE, which returns both poses of a square seen through its four corners."""
    K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
    square = np.array([[-0.05, -0.05, 0], [0.05, -0.05, 0], [0.05, 0.05, 0], [-0.05, 0.05, 0]])
    axis = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    truth = Pose.from_rotvec_t(np.radians(tilt_deg) * axis, [x_m, y_m, 1.0])
    uv = cv2.projectPoints(square, cv2.Rodrigues(truth.R)[0], truth.t, K, None)[0]
    _, rvecs, tvecs, _ = cv2.solvePnPGeneric(square, uv, K, None, flags=cv2.SOLVEPNP_IPPE)
    solutions = [Pose(cv2.Rodrigues(r)[0], t.ravel()) for r, t in zip(rvecs, tvecs)]
    other = max(solutions, key=lambda p: rotation_error_deg(p, truth))
    mirrored = mirrored_tilt(truth, [0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    assert rotation_error_deg(mirrored, other) < 0.05
    sight = truth.t / np.linalg.norm(truth.t)
    tilt_from_sight = np.degrees(np.arccos(-(truth.R @ [0.0, 0.0, -1.0]) @ sight))
    assert rotation_error_deg(mirrored, truth) == pytest.approx(2 * tilt_from_sight, abs=1e-6)
    # the centre stays put; IPPE moves it along the line of sight by the perspective's share
    np.testing.assert_allclose(mirrored.t, truth.t, atol=1e-12)
    assert np.linalg.norm(other.t - truth.t) < 0.01


def test_mirrored_tilt_of_a_face_seen_head_on_is_the_pose_itself():
    head_on = Pose.from_rotvec_t([0.0, 0.0, 0.3], [0.0, 0.0, 1.0])
    assert mirrored_tilt(head_on, [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]).allclose(head_on, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=9, max_size=9))
def test_a_pose_turned_about_an_object_point_keeps_that_point_in_place(v):
    """Oracle: scipy's rotation of the camera-frame points about the point's camera position."""
    from hybridpose.geometry import turned_about

    pose = Pose.from_rotvec_t(v[:3], [0.1 * v[3], 0.1 * v[4], 0.5 + 0.2 * abs(v[5])])
    centre, rotvec = 0.05 * np.array(v[6:]), 0.3 * np.array(v[:3][::-1])
    got = turned_about(pose, rotvec, centre)
    turn = Rotation.from_rotvec(rotvec)
    c_cam = pose.R @ centre + pose.t
    points = np.array([[0.03, -0.02, 0.01], [-0.04, 0.05, 0.02], centre])
    expected = turn.apply((points @ pose.R.T + pose.t) - c_cam) + c_cam
    np.testing.assert_allclose(points @ got.R.T + got.t, expected, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).filter(lambda v: np.linalg.norm(v) > 0.1),
       st.floats(0.1, 5.0))
def test_a_facing_pose_looks_at_the_object_from_its_direction(v, distance):
    """Oracle: cv2.projectPoints puts the object's origin on the principal point; the camera centre
    lies ``distance`` along ``direction`` (object frame); the rotation is proper."""
    from hybridpose.geometry import facing_pose

    direction = np.asarray(v) / np.linalg.norm(v)
    pose = facing_pose(direction, distance)
    K = Camera.default().K
    uv, _ = cv2.projectPoints(np.zeros((1, 3)), cv2.Rodrigues(pose.R)[0], pose.t, K, None)
    np.testing.assert_allclose(uv.ravel(), K[:2, 2], atol=1e-9)
    np.testing.assert_allclose(-pose.R.T @ pose.t, distance * direction, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(pose.R), 1.0, atol=1e-12)


def test_sphere_directions_are_unit_and_spread():
    from hybridpose.geometry import sphere_directions

    d = sphere_directions(26)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    cos = d @ d.T - 2 * np.eye(26)
    nearest_deg = np.degrees(np.arccos(cos.max(1)))
    assert 25 < nearest_deg.min() and nearest_deg.max() < 50   # evenly spread: no two close, no gap
    assert np.linalg.norm(d.mean(0)) < 0.05
