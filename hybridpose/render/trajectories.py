"""Object motion relative to the camera: random poses and smooth, seeded trajectories.

Every trajectory maps a time (s) to ``T_cam_obj``; all are registered under the role
``"trajectory"`` (``hybridpose.registry.available("trajectory")``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import Camera, Pose, quat_wxyz_to_matrix, random_quat, rotvec_to_matrix
from ..objects import ObjectModel, view_elevation_deg
from ..registry import register

ARM_REACH_M = (0.3, 1.2)  # distances (m) of the arm's grasp approach


def random_poses(
    count: int,
    camera: Camera,
    distance_range_m: tuple[float, float] = ARM_REACH_M,
    rng: np.random.Generator | int | None = None,
    in_view_points: np.ndarray | None = None,
    max_tries: int = 200,
    elevation_range_deg: tuple[float, float] | None = None,
    obj: ObjectModel | None = None,
    log_depth: bool = False,
) -> list[Pose]:
    """Poses within arm's reach with the object centre inside the image (so at least partly in view).

    Depth uniform in ``distance_range_m`` (metres along the optical axis; ``log_depth``: its logarithm
    uniform, as many views between 0.3 and 0.6 m as between 1.2 and 2.4 m), object centre uniform
    over the image, orientation uniform on SO(3). With ``in_view_points`` ((N, 3) metres, e.g. the
    bounding-box corners) orientation and centre are redrawn (up to ``max_tries`` per depth) until
    all of them project inside the image: the object is wholly in view, as when the CNN
    initialises a tracker; depths where it cannot fit at all are skipped.

    ``elevation_range_deg`` (low, high), with ``obj``, keeps only views whose elevation
    (:func:`~hybridpose.objects.view_elevation_deg`: 0° edge-on, 90° face-on) lies in it, the rest
    of the distribution unchanged: to render more of the views a flat object is hardest in.
    """
    lo, hi = distance_range_m
    if not 0 < lo <= hi:
        raise ValueError(f"distance_range_m: expected 0 < near ≤ far metres, got {distance_range_m}")
    if count < 0:
        raise ValueError(f"count: expected ≥ 0, got {count}")
    if elevation_range_deg is not None:
        e_lo, e_hi = elevation_range_deg
        if not 0 <= e_lo < e_hi <= 90:
            raise ValueError(f"elevation_range_deg: expected 0 ≤ low < high ≤ 90 degrees, got {elevation_range_deg}")
        if obj is None:
            raise ValueError("obj: the object model is needed to measure view elevation (elevation_range_deg given)")
    rng = np.random.default_rng(rng)

    def depth(n=None):
        return np.exp(rng.uniform(np.log(lo), np.log(hi), n)) if log_depth else rng.uniform(lo, hi, n)

    if in_view_points is None and elevation_range_deg is None:
        z = depth(count)
        u = rng.uniform(-0.5, camera.width - 0.5, count)
        v = rng.uniform(-0.5, camera.height - 0.5, count)
        q = random_quat(count, rng)
        return [_pose_at_pixel(q[i], u[i], v[i], z[i], camera) for i in range(count)]
    # depth first, then orientation and centre until the view is accepted: depth stays ~uniform
    # over the distances where the object can fit at all
    pts = None if in_view_points is None else np.asarray(in_view_points, dtype=np.float64)
    poses: list[Pose] = []
    while len(poses) < count:
        z = depth()
        for _ in range(max_tries):
            pose = _pose_at_pixel(random_quat(None, rng), rng.uniform(-0.5, camera.width - 0.5),
                                  rng.uniform(-0.5, camera.height - 0.5), z, camera)
            if pts is not None and not _all_in_image(pose @ pts, camera):
                continue
            if elevation_range_deg is not None and not e_lo <= view_elevation_deg(pose, obj) <= e_hi:
                continue
            poses.append(pose)
            break
    return poses


def _all_in_image(points_cam: np.ndarray, camera: Camera) -> bool:
    p = points_cam @ camera.K.T
    if not np.all(p[:, 2] > 0):
        return False
    uv = p[:, :2] / p[:, 2:3]
    return bool(np.all(uv >= -0.5) and np.all(uv[:, 0] <= camera.width - 0.5)
                and np.all(uv[:, 1] <= camera.height - 0.5))


def _pose_at_pixel(q, u: float, v: float, z: float, camera: Camera) -> Pose:
    return Pose.from_quat_t(q, [(u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z])


def smoothstep(x: np.ndarray | float) -> np.ndarray | float:
    """0 → 1 ease-in/out on [0, 1] (zero slope at both ends), clamped outside."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def _random_axis(rng: np.random.Generator) -> np.ndarray:
    a = rng.normal(size=3)
    return a / np.linalg.norm(a)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """``T_cam_obj(t) = Pose(R_spin(t) · R0, centre(t))`` with a constant body-frame spin.

    Attributes:
        R0: (3, 3) orientation at t = 0.
        omega_body: (3,) constant angular velocity in the object frame, rad/s.
        waypoints_m: (K, 3) object-centre waypoints in the camera frame, passed through with
            smooth (ease-in/out) timing over ``duration_s``; one row = fixed centre.
        orbit_rate: rad/s of an additional rotation of the object about the camera's y axis
            through its centre (a fly-around seen from the camera).
        duration_s: length of the trajectory, seconds.
    """

    R0: np.ndarray
    omega_body: np.ndarray
    waypoints_m: np.ndarray
    duration_s: float
    orbit_rate: float = 0.0

    def pose_at(self, t: float) -> Pose:
        """``T_cam_obj`` at time ``t`` seconds (clamped to [0, duration_s])."""
        t = float(np.clip(t, 0.0, self.duration_s))
        R = rotvec_to_matrix(np.array([0.0, self.orbit_rate * t, 0.0])) @ self.R0 @ rotvec_to_matrix(self.omega_body * t)
        wp = self.waypoints_m
        if len(wp) == 1:
            centre = wp[0]
        else:
            # equal time per leg, eased in and out so the centre stops at each waypoint
            x = t / self.duration_s * (len(wp) - 1)
            i = min(int(x), len(wp) - 2)
            centre = wp[i] + smoothstep(x - i) * (wp[i + 1] - wp[i])
        return Pose(R, centre)

    def poses(self, timestamps) -> list[Pose]:
        return [self.pose_at(t) for t in timestamps]


def _check_duration(duration_s: float) -> float:
    if not np.isfinite(duration_s) or duration_s <= 0:
        raise ValueError(f"duration_s: expected a positive duration in seconds, got {duration_s}")
    return float(duration_s)


@register("trajectory", "tumble")
def tumble(duration_s: float, rng=None, distance_m: float = 0.6, rate_deg_s: float = 20.0) -> Trajectory:
    """Object held at ``distance_m`` spinning at a constant ``rate_deg_s`` about a random body axis."""
    rng = np.random.default_rng(rng)
    R0 = quat_wxyz_to_matrix(random_quat(None, rng))
    centre = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), distance_m])
    return Trajectory(R0, _random_axis(rng) * np.radians(rate_deg_s), centre[None], _check_duration(duration_s))


@register("trajectory", "approach")
def approach(duration_s: float, rng=None, start_m: float = 1.15, end_m: float = 0.4, rate_deg_s: float = 5.0) -> Trajectory:
    """Closing in from ``start_m`` to ``end_m`` along the optical axis, slowly rotating (a grasp approach)."""
    rng = np.random.default_rng(rng)
    R0 = quat_wxyz_to_matrix(random_quat(None, rng))
    off = rng.uniform(-0.05, 0.05, 2)
    wp = np.array([[off[0], off[1], start_m], [0.3 * off[0], 0.3 * off[1], end_m]])
    return Trajectory(R0, _random_axis(rng) * np.radians(rate_deg_s), wp, _check_duration(duration_s))


@register("trajectory", "fly-around")
def fly_around(duration_s: float, rng=None, distance_m: float = 0.65, rate_deg_s: float = 15.0) -> Trajectory:
    """The camera circles the object at ``distance_m``: the object turns about the camera's y axis."""
    rng = np.random.default_rng(rng)
    R0 = quat_wxyz_to_matrix(random_quat(None, rng))
    centre = np.array([0.0, rng.uniform(-0.03, 0.03), distance_m])
    return Trajectory(R0, np.zeros(3), centre[None], _check_duration(duration_s), orbit_rate=np.radians(rate_deg_s))


@register("trajectory", "distance-sweep")
def distance_sweep(duration_s: float, rng=None, near_m: float = 0.35, far_m: float = 1.15, rate_deg_s: float = 8.0) -> Trajectory:
    """Out from ``near_m`` to ``far_m`` and back, slowly rotating: error versus distance."""
    rng = np.random.default_rng(rng)
    R0 = quat_wxyz_to_matrix(random_quat(None, rng))
    wp = np.array([[0.0, 0.0, near_m], [0.0, 0.0, far_m], [0.0, 0.0, near_m]])
    return Trajectory(R0, _random_axis(rng) * np.radians(rate_deg_s), wp, _check_duration(duration_s))
