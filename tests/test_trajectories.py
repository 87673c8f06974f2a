import numpy as np
import pytest

from hybridpose import registry
from hybridpose.geometry import Camera
from hybridpose.metrics import rotation_error_deg
from hybridpose.render import random_poses
from hybridpose.render.sequences import SequenceSpec, make_sequence, occlusion_schedule, sun_schedule


def test_random_poses_in_reach_and_in_view():
    cam = Camera.default()
    poses = random_poses(2000, cam, (0.3, 1.2), rng=0)
    z = np.array([p.t[2] for p in poses])
    assert z.min() >= 0.3 and z.max() <= 1.2 and z.std() > 0.2
    uv = np.array([cam.project_cam(p.t[None])[0] for p in poses])
    assert np.all((uv > -0.5) & (uv < [cam.width - 0.5, cam.height - 0.5]))
    again = random_poses(2000, cam, (0.3, 1.2), rng=0)
    assert all(a.allclose(b) for a, b in zip(again, poses))


@pytest.mark.parametrize("in_view", [False, True])
def test_random_poses_log_depth_spreads_views_evenly_over_scale(truss, in_view):
    """Log-uniform depth: as many views in each doubling of the distance, against a uniform draw that
    puts twice as many in the far doubling as in the near one."""
    cam = Camera.default()
    kw = {"in_view_points": truss.bbox_corners} if in_view else {}
    rng_range = (1.0, 4.0)  # the truss fits in view all the way (0.54 m is its near end with this lens)
    z = np.array([p.t[2] for p in random_poses(2000, cam, rng_range, rng=4, log_depth=True, **kw)])
    near, far = np.sum(z < 2.0), np.sum(z >= 2.0)
    assert z.min() >= 1.0 and z.max() <= 4.0 and abs(near - far) < 200
    u = np.array([p.t[2] for p in random_poses(2000, cam, rng_range, rng=4, **kw)])
    assert np.sum(u >= 2.0) > 1.7 * np.sum(u < 2.0)


def test_random_poses_with_the_whole_object_in_view(truss):
    cam = Camera.default()
    poses = random_poses(300, cam, (0.3, 1.2), rng=2, in_view_points=truss.bbox_corners)
    for p in poses:
        uv = cam.project(truss.bbox_corners, p)
        assert np.all(uv >= -0.5) and np.all(uv <= [cam.width - 0.5, cam.height - 0.5])
    z = np.array([p.t[2] for p in poses])
    # depth stays spread over the distances where the truss fits (it cannot at 0.3 m with this lens)
    assert z.max() > 1.1 and z.min() < 0.5 and np.histogram(z, bins=4, range=(0.45, 1.2))[0].min() > 40


def test_random_poses_within_an_elevation_band(truss):
    from hybridpose.objects import view_elevation_deg

    cam = Camera.default()
    poses = random_poses(400, cam, (0.3, 1.2), rng=5, in_view_points=truss.bbox_corners,
                         elevation_range_deg=(0.0, 20.0), obj=truss)
    elev = np.array([view_elevation_deg(p, truss) for p in poses])
    assert elev.max() <= 20.0 and elev.min() >= 0.0
    # orientation stays uniform inside the band: sin(elevation) is uniform, so below 10° ≈ sin10/sin20
    assert abs(np.mean(elev < 10.0) - np.sin(np.radians(10)) / np.sin(np.radians(20))) < 0.07
    for p in poses[:50]:
        uv = cam.project(truss.bbox_corners, p)
        assert np.all(uv >= -0.5) and np.all(uv <= [cam.width - 0.5, cam.height - 0.5])
    # the band check draws nothing: a band that admits every view gives the unfiltered poses
    whole = random_poses(40, cam, (0.3, 1.2), rng=5, in_view_points=truss.bbox_corners,
                         elevation_range_deg=(0.0, 90.0), obj=truss)
    plain = random_poses(40, cam, (0.3, 1.2), rng=5, in_view_points=truss.bbox_corners)
    assert all(a.allclose(b) for a, b in zip(whole, plain))


def test_random_poses_elevation_errors_name_the_argument(truss):
    cam = Camera.default()
    with pytest.raises(ValueError, match="elevation_range_deg"):
        random_poses(3, cam, elevation_range_deg=(30.0, 10.0), obj=truss)
    with pytest.raises(ValueError, match="obj"):
        random_poses(3, cam, elevation_range_deg=(0.0, 10.0))


def test_sun_directions_stay_in_their_cone():
    from hybridpose.datasets.generate import sun_directions_in_cone

    axis = np.array([0.6, 0.4, 0.7]) / np.linalg.norm([0.6, 0.4, 0.7])
    d = sun_directions_in_cone(axis, 40.0, 5000, np.random.default_rng(0))
    ang = np.degrees(np.arccos(np.clip(d @ axis, -1, 1)))
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0) and ang.max() <= 40.0 + 1e-9 and ang.max() > 38.0
    # uniform on the cap: the cap's outer half (in solid angle) holds half the directions
    cos_mid = (1 + np.cos(np.radians(40.0))) / 2
    assert abs(np.mean(d @ axis < cos_mid) - 0.5) < 0.03
    # beyond a hemisphere (back-lit views around the optical axis): still uniform on the cap
    z = np.array([0.0, 0.0, 1.0])
    d = sun_directions_in_cone(z, 150.0, 5000, np.random.default_rng(1))
    ang = np.degrees(np.arccos(np.clip(d[:, 2], -1, 1)))
    assert ang.max() <= 150.0 + 1e-9 and ang.max() > 145.0 and np.mean(ang > 90) == pytest.approx(
        np.cos(np.radians(150.0)) / (np.cos(np.radians(150.0)) - 1), abs=0.03)


@pytest.mark.parametrize("name", ["tumble", "approach", "fly-around", "distance-sweep"])
def test_trajectories_smooth_and_seeded(name):
    fps, dur = 30.0, 6.0
    traj = registry.create("trajectory", name, duration_s=dur, rng=3)
    ts = np.arange(0, dur, 1 / fps)
    poses = traj.poses(ts)
    steps_deg = [rotation_error_deg(a, b) for a, b in zip(poses, poses[1:])]
    steps_m = [np.linalg.norm(a.t - b.t) for a, b in zip(poses, poses[1:])]
    assert max(steps_deg) < 1.0 and max(steps_m) < 0.5 / fps  # < 30 °/s, < 0.5 m/s
    z = np.array([p.t[2] for p in poses])
    assert z.min() >= 0.3 and z.max() <= 1.2
    again = registry.create("trajectory", name, duration_s=dur, rng=3).poses(ts)
    assert all(a.allclose(b) for a, b in zip(poses, again))


def test_tumble_has_constant_angular_velocity():
    traj = registry.create("trajectory", "tumble", duration_s=4.0, rng=1, rate_deg_s=30.0)
    poses = traj.poses(np.arange(0, 4.0, 0.1))
    rel = [np.degrees(a.local(b)[:3]) for a, b in zip(poses, poses[1:])]  # body-frame increments
    np.testing.assert_allclose(rel, np.repeat(rel[:1], len(rel), 0), atol=1e-9)
    assert abs(np.linalg.norm(rel[0]) - 3.0) < 1e-9


def test_sequence_occlusion_schedule(truss):
    spec = SequenceSpec("tumble", frames=90, fps=30, occlusion="arm", seed=0)
    frames = make_sequence(spec, truss, Camera.default())
    kinds = [f.occlusion for f in frames]
    assert kinds[0] == "none" and "partial" in kinds and "full" in kinds
    assert all((f.arm is None) == (f.occlusion == "none") for f in frames)
    assert [f.timestamp for f in frames[:3]] == [0.0, 1 / 30, 2 / 30]
    assert len(occlusion_schedule("arm-long", 10.0)) == 1
    assert sun_schedule("eclipse", 5.0, 10.0) == pytest.approx(0.1) and sun_schedule("eclipse", 0.0, 10.0) == 1.0


@pytest.mark.parametrize("kwargs, match", [
    (dict(trajectory="spiral", frames=10), "unknown trajectory 'spiral'"),
    (dict(trajectory="tumble", frames=0), "frames"),
    (dict(trajectory="tumble", frames=10, occlusion="cloud"), "occlusion"),
    (dict(trajectory="tumble", frames=10, fps=0), "fps"),
])
def test_bad_sequence_spec(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SequenceSpec(**kwargs)
