"""Pinhole camera with optional OpenCV distortion. Pixel centres at integer coordinates."""
from __future__ import annotations

import functools
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numba
import numpy as np

from .checks import as_array, as_points3d, as_rgb_image
from .pose import Pose
from .rotations import rotvec_to_matrix

_MIN_DEPTH_M = 1e-6  # points nearer the camera plane project to infinity: refused


def parse_size(size) -> tuple[int, int]:
    """``224`` / ``"224"`` → (224, 224); ``"640x480"`` / ``(640, 480)`` → (640, 480) as (W, H)."""
    if isinstance(size, str):
        parts = size.lower().replace("×", "x").split("x")
        try:
            vals = [int(p) for p in parts]
        except ValueError:
            raise ValueError(f"size: expected 'N' or 'WxH' (e.g. 224 or 640x480), got {size!r}") from None
        size = vals[0] if len(vals) == 1 else tuple(vals)
    if isinstance(size, (int, np.integer)):
        size = (int(size), int(size))
    if len(size) != 2 or any(int(s) <= 0 for s in size):
        raise ValueError(f"size: expected positive (W, H), got {size!r}")
    return int(size[0]), int(size[1])


@dataclass(frozen=True)
class Camera:
    """Intrinsics of a pinhole camera (OpenCV model).

    Attributes:
        width, height: image size in pixels.
        fx, fy: focal lengths in pixels.
        cx, cy: principal point in pixels (origin at the centre of the top-left pixel).
        dist: OpenCV distortion coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]); empty = none.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = field(default=())

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if int(v) != v or v <= 0:
                raise ValueError(f"{name}: expected a positive integer number of pixels, got {v!r}")
            object.__setattr__(self, name, int(v))
        for name in ("fx", "fy"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name}: expected a positive focal length in pixels, got {v!r}")
            object.__setattr__(self, name, v)
        for name in ("cx", "cy"):
            v = float(getattr(self, name))
            if not math.isfinite(v):
                raise ValueError(f"{name}: expected a finite principal point in pixels, got {v!r}")
            object.__setattr__(self, name, v)
        dist = tuple(float(d) for d in np.asarray(self.dist, dtype=np.float64).ravel())
        if len(dist) not in (0, 4, 5, 8, 12, 14):
            raise ValueError(f"dist: expected 0, 4, 5, 8, 12 or 14 OpenCV coefficients, got {len(dist)}")
        if all(d == 0.0 for d in dist):
            dist = ()
        object.__setattr__(self, "dist", dist)

    # --- constructors ---------------------------------------------------------------------------
    @classmethod
    def default(cls) -> "Camera":
        """640×480, fx = fy = 600 px (≈ 56° horizontal FOV), centred principal point, no distortion."""
        return cls(640, 480, 600.0, 600.0, 319.5, 239.5)

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> "Camera":
        """Square pixels, centred principal point, horizontal field of view in degrees."""
        if not 0 < hfov_deg < 180:
            raise ValueError(f"hfov_deg: expected a field of view in (0, 180) degrees, got {hfov_deg}")
        f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
        return cls(width, height, f, f, width / 2 - 0.5, height / 2 - 0.5)

    @classmethod
    def from_K(cls, K, width: int, height: int, dist=()) -> "Camera":
        """From a (3, 3) matrix or BOP's flat 9-list ``cam_K`` (pixels)."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape == (9,):
            K = K.reshape(3, 3)
        K = as_array(K, "K", (3, 3))
        if abs(K[0, 1]) > 1e-9 or np.any(np.abs(K[2] - [0, 0, 1]) > 1e-9) or abs(K[1, 0]) > 1e-9:
            raise ValueError(f"K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
        return cls(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], tuple(dist))

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        """From ``{"width", "height", "K" | fx/fy/cx/cy, "dist"?}`` (the camera file format)."""
        try:
            if "K" in d:
                return cls.from_K(d["K"], d["width"], d["height"], d.get("dist", ()))
            return cls(d["width"], d["height"], d["fx"], d["fy"], d["cx"], d["cy"], tuple(d.get("dist", ())))
        except KeyError as exc:
            raise ValueError(f"camera: missing key {exc.args[0]!r}; expected width, height and K (or fx, fy, cx, cy)") from None

    def to_dict(self) -> dict:
        d = asdict(self)
        d["dist"] = list(self.dist)
        return d

    # --- derived ---------------------------------------------------------------------------------
    def pinhole(self) -> "Camera":
        """The same intrinsics without distortion: the camera of :meth:`undistort`'s images."""
        return Camera(self.width, self.height, self.fx, self.fy, self.cx, self.cy)

    def distort_pixels(self, uv_pinhole) -> np.ndarray:
        """(N, 2) pixels of :meth:`pinhole`'s image → where they lie in this camera's own image (its
        lens distortion applied); unchanged without distortion."""
        uv = np.asarray(uv_pinhole, dtype=np.float64).reshape(-1, 2)
        if not self.dist:
            return uv
        out = np.full_like(uv, np.nan)  # NaN rows (no point) stay NaN
        ok = np.all(np.isfinite(uv), axis=1)
        if ok.any():
            rays = np.c_[(uv[ok, 0] - self.cx) / self.fx, (uv[ok, 1] - self.cy) / self.fy, np.ones(int(ok.sum()))]
            out[ok] = self.project_cam(rays)
        return out

    def undistort(self, image: np.ndarray) -> np.ndarray:
        """``image`` (H, W[, C]) of this camera as :meth:`pinhole` would see it: the lens distortion
        removed with the same K (no rectification: a pose in this camera's frame holds in both). The
        image itself where there is no distortion; the remap tables are made once per camera."""
        if not self.dist:
            return image
        import cv2

        map1, map2 = _undistort_maps(self)
        return cv2.remap(image, map1, map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix in pixels."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def size(self) -> tuple[int, int]:
        """(W, H) in pixels."""
        return self.width, self.height

    @property
    def hfov_deg(self) -> float:
        return math.degrees(2 * math.atan2(self.width / 2, self.fx))

    @property
    def vfov_deg(self) -> float:
        return math.degrees(2 * math.atan2(self.height / 2, self.fy))

    def scaled(self, size) -> "Camera":
        """The same camera resampled to a new pixel grid ``size`` (N or (W, H) or "WxH").

        The field of view is unchanged; a change of aspect ratio gives non-square pixels, as when
        the paper squeezed 1280×720 renders to 224×224.
        """
        w, h = parse_size(size)
        sx, sy = w / self.width, h / self.height
        return Camera(w, h, self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, self.dist)

    # --- projection ------------------------------------------------------------------------------
    def project(self, points_obj, T_cam_obj: Pose) -> np.ndarray:
        """Project object-frame points to pixels.

        Args:
            points_obj: (N, 3) float, metres, object frame.
            T_cam_obj: object → camera pose.
        Returns:
            (N, 2) float64 pixel coordinates (OpenCV convention).
        Raises:
            ValueError: if a point lies at or behind the camera plane (z ≤ 0).
        """
        points_obj = as_points3d(points_obj, "points_obj")
        return self._project(T_cam_obj @ points_obj)

    @staticmethod
    def in_front(points_cam) -> np.ndarray:
        """(N,) bool: which of the (N, 3) camera-frame points (metres) :meth:`project_cam` can project
        (in front of the camera plane)."""
        return as_points3d(points_cam, "points_cam")[:, 2] > _MIN_DEPTH_M

    def image_box(self, points_obj, T_cam_obj: Pose) -> tuple[float, float, float, float] | None:
        """Box (x0, y0, x1, y1) px, not clipped to the image, of the (N, 3) object-frame points
        (metres) projected at ``T_cam_obj``; None where one of them is not in front of the camera
        (an object reaching behind the camera has no image box)."""
        points_cam = T_cam_obj @ as_points3d(points_obj, "points_obj")
        if not (points_cam[:, 2] > _MIN_DEPTH_M).all():
            return None
        uv = self._project(points_cam)
        (x0, y0), (x1, y1) = uv.min(0), uv.max(0)
        return float(x0), float(y0), float(x1), float(y1)

    def project_cam(self, points_cam) -> np.ndarray:
        """Project (N, 3) camera-frame points (metres) to (N, 2) pixels; z must be > 0."""
        return self._project(as_points3d(points_cam, "points_cam"))

    def _project(self, p: np.ndarray) -> np.ndarray:
        """:meth:`project_cam` of points already checked to be a finite (N, 3) float64 array."""
        if not (p[:, 2] > _MIN_DEPTH_M).all():
            raise ValueError(
                f"points: {int((p[:, 2] <= _MIN_DEPTH_M).sum())} of {len(p)} points are behind the camera "
                "(z ≤ 0 in the camera frame); check T_cam_obj (t_z must be positive, in metres)"
            )
        if self.dist:
            import cv2

            uv, _ = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.K, np.array(self.dist))
            return uv.reshape(-1, 2).astype(np.float64)
        x = p[:, 0] / p[:, 2]
        y = p[:, 1] / p[:, 2]
        return np.stack([self.fx * x + self.cx, self.fy * y + self.cy], -1)

    def check_image(self, image, name: str = "image") -> np.ndarray:
        """Validate an RGB image for this camera: (H, W, 3) uint8."""
        img = as_rgb_image(image, name)
        if img.shape[:2] != (self.height, self.width):
            raise ValueError(
                f"{name}: size {img.shape[1]}×{img.shape[0]} does not match the camera ({self.width}×{self.height}); "
                "use Camera.scaled() or resize the image"
            )
        return img


@functools.lru_cache(maxsize=8)
def _undistort_maps(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    # the fixed-point tables cv2.undistort makes on every call, kept: a frame's remap then costs ~1 ms
    import cv2

    return cv2.initUndistortRectifyMap(camera.K, np.asarray(camera.dist), None, camera.K, camera.size, cv2.CV_16SC2)


def shifted_in_image(pose: Pose, camera: Camera, dx_px: float, dy_px: float) -> Pose:
    """``pose`` turned about the camera centre so that its projection moves by about (dx, dy) pixels:
    the same view of the object, elsewhere in the image."""
    K = camera.K
    return Pose.from_rotvec_t([-dy_px / K[1, 1], dx_px / K[0, 0], 0.0], np.zeros(3)) @ pose


def turned_about(pose: Pose, rotvec, centre_obj) -> Pose:
    """``pose`` turned by ``rotvec`` (3,) rad about the camera's axes through the object's point
    ``centre_obj`` (3,) m, which stays where it was in the camera frame (and so in the image)."""
    centre_obj = np.asarray(centre_obj, np.float64)
    centre_cam = pose.R @ centre_obj + pose.t
    R = rotvec_to_matrix(np.asarray(rotvec, np.float64)) @ pose.R
    return Pose(R, centre_cam - R @ centre_obj)


def mirrored_tilt(pose: Pose, normal_obj, centre_obj) -> Pose:
    """The other pose of the planar ambiguity: ``pose`` turned about the object's point ``centre_obj``
    (3,) m so that the plane with normal ``normal_obj`` (3,) (object frame) tilts as far from the line of
    sight to that point, mirrored about it. A face seen near head-on shows almost the same outline
    either way (the two solutions of planar pose estimation, e.g. OpenCV's ``SOLVEPNP_IPPE``): the
    centre's image stays put and the two poses differ by twice the face's tilt. ``pose`` itself where
    the face is seen exactly head-on or edge-on."""
    centre_cam = pose.R @ np.asarray(centre_obj, np.float64) + pose.t
    sight = centre_cam / np.linalg.norm(centre_cam)
    n = pose.R @ np.asarray(normal_obj, np.float64)
    n = n / np.linalg.norm(n)
    mirrored = 2.0 * float(n @ sight) * sight - n
    axis = np.cross(n, mirrored)
    sin, cos = float(np.linalg.norm(axis)), float(n @ mirrored)
    if sin < 1e-9:
        return pose
    return turned_about(pose, axis / sin * math.atan2(sin, cos), centre_obj)


def sphere_directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5 ** 0.5) * k
    r = np.sqrt(1 - z ** 2)
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


def facing_pose(direction_obj, distance_m: float) -> Pose:
    """``T_cam_obj`` of a camera ``distance_m`` metres from the object's origin along the unit vector
    ``direction_obj`` (3,) (object frame), looking at the origin (which projects to the principal point)."""
    z = -np.asarray(direction_obj, np.float64)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])  # rows: the camera's axes in the object frame
    return Pose(R, np.array([0.0, 0.0, float(distance_m)]))


def save_camera(camera: Camera, path) -> None:
    Path(path).write_text(json.dumps(camera.to_dict(), indent=2))


def line_jacobian(pose: Pose, points_m: np.ndarray, K: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projections (S, 2) and the Jacobian (S, 6) of each one's component along its image
    ``normals`` (S, 2) w.r.t. the right perturbation ``ξ = [ω, v]``: the rows of the moving-edge
    (point-to-line) least squares, ``n · ∂p/∂ξ`` of :func:`projection_jacobian` without forming the
    (S, 2, 6) tensor; object points ``points_m`` (S, 3) in metres, K (3, 3), no distortion."""
    points_m = np.ascontiguousarray(points_m, dtype=np.float64)
    uv, J = np.empty((len(points_m), 2)), np.empty((len(points_m), 6))
    line_rows(pose.R, pose.t, points_m, np.asarray(K, dtype=np.float64),
              np.ascontiguousarray(normals, dtype=np.float64), uv, J)
    return uv, J


@numba.njit(cache=True, nogil=True)
def line_rows(R, t, points_m, K, normals, uv, J):
    """:func:`line_jacobian` into ``uv`` (S, 2) and ``J`` (S, 6), compiled (the edge fit's Gauss–Newton
    kernel calls it every step). With ``b = Rᵀ (∂π/∂X_c)ᵀ n`` the row is ``[X × b, b]`` (since
    ``−bᵀ [X]× = (X × b)ᵀ``)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    for s in range(points_m.shape[0]):
        p0, p1, p2 = points_m[s, 0], points_m[s, 1], points_m[s, 2]
        x = R[0, 0] * p0 + R[0, 1] * p1 + R[0, 2] * p2 + t[0]
        y = R[1, 0] * p0 + R[1, 1] * p1 + R[1, 2] * p2 + t[1]
        z = R[2, 0] * p0 + R[2, 1] * p1 + R[2, 2] * p2 + t[2]
        inv_z = 1.0 / z
        u, v = fx * x * inv_z, fy * y * inv_z
        uv[s, 0], uv[s, 1] = u + cx, v + cy
        nu, nv = normals[s, 0] * inv_z, normals[s, 1] * inv_z
        a0, a1, a2 = fx * nu, fy * nv, -(nu * u + nv * v)          # (∂π/∂X_c)ᵀ n, camera frame
        b0 = a0 * R[0, 0] + a1 * R[1, 0] + a2 * R[2, 0]             # in the object frame
        b1 = a0 * R[0, 1] + a1 * R[1, 1] + a2 * R[2, 1]
        b2 = a0 * R[0, 2] + a1 * R[1, 2] + a2 * R[2, 2]
        J[s, 0] = p1 * b2 - p2 * b1
        J[s, 1] = p2 * b0 - p0 * b2
        J[s, 2] = p0 * b1 - p1 * b0
        J[s, 3], J[s, 4], J[s, 5] = b0, b1, b2


def projection_jacobian(pose: Pose, points_m: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projections (S, 2) and their Jacobian (S, 2, 6) w.r.t. the right perturbation
    ``ξ = [ω, v]`` in ``pose.retract(ξ)``: ``∂p/∂ξ = [−R [X]×, R]`` chained with the pinhole
    (no distortion: undistort the measurements first). Shared by PnP and the edge trackers."""
    R = pose.R
    Xc = points_m @ R.T + pose.t
    x, y, z = Xc[:, 0], Xc[:, 1], Xc[:, 2]
    fx, fy = K[0, 0], K[1, 1]
    uv = np.stack([fx * x / z + K[0, 2], fy * y / z + K[1, 2]], 1)
    dpi = np.zeros((len(Xc), 2, 3))
    dpi[:, 0, 0] = fx / z
    dpi[:, 0, 2] = -fx * x / z**2
    dpi[:, 1, 1] = fy / z
    dpi[:, 1, 2] = -fy * y / z**2
    # d(R (X + ω×X + v))/dω = −R [X]×  ;  /dv = R
    Xs = points_m
    skew = np.zeros((len(Xs), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2] = -Xs[:, 2], Xs[:, 1]
    skew[:, 1, 0], skew[:, 1, 2] = Xs[:, 2], -Xs[:, 0]
    skew[:, 2, 0], skew[:, 2, 1] = -Xs[:, 1], Xs[:, 0]
    dX = np.concatenate([-R @ skew, np.broadcast_to(R, (len(Xs), 3, 3))], axis=2)  # (S, 3, 6)
    return uv, dpi @ dX
