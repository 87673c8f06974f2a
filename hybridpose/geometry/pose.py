"""The one pose type of hybridpose: ``T_cam_obj``, object frame → OpenCV camera frame, metres."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import as_array, as_rotation_matrix, as_unit_quat, as_vector, read_only
from .rotations import matrix_to_quat_wxyz, quat_slerp, quat_wxyz_to_matrix, rotvec_to_matrix
from .se3 import se3_exp, se3_log


@dataclass(frozen=True, eq=False)
class Pose:
    """Rigid transform ``x_cam = R · x_obj + t``.

    Attributes:
        R: (3, 3) float64 rotation, read-only.
        t: (3,) float64 translation in metres, read-only.

    Immutable: every operation returns a new ``Pose``. Compose with ``@``:
    ``T_cam_obj = T_cam_world @ T_world_obj``; ``T @ points`` transforms (N, 3) points.
    """

    R: np.ndarray
    t: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", read_only(as_rotation_matrix(self.R, "R")))
        object.__setattr__(self, "t", read_only(as_vector(self.t, "t", 3)))

    @classmethod
    def _composed(cls, R: np.ndarray, t: np.ndarray) -> "Pose":
        """A pose from the product of valid ones (composition, inverse): already a rotation to
        float rounding, so the checks and the SVD re-orthonormalisation (≈ 30 µs, a dozen times per
        regressor call) are skipped. Not for data from outside."""
        pose = object.__new__(cls)
        object.__setattr__(pose, "R", read_only(R))
        object.__setattr__(pose, "t", read_only(t))
        return pose

    # --- constructors -------------------------------------------------------------------------
    @classmethod
    def identity(cls) -> "Pose":
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_quat_t(cls, quat_wxyz, t) -> "Pose":
        """From a unit quaternion (w, x, y, z) and a translation (3,) in metres."""
        return cls(quat_wxyz_to_matrix(as_unit_quat(quat_wxyz, "quat_wxyz")), t)

    @classmethod
    def from_rotvec_t(cls, rotvec, t) -> "Pose":
        """From a rotation vector (3,) in radians and a translation (3,) in metres."""
        return cls(rotvec_to_matrix(as_vector(rotvec, "rotvec", 3)), t)

    @classmethod
    def from_matrix(cls, T) -> "Pose":
        """From a (4, 4) homogeneous matrix whose last row is [0, 0, 0, 1]."""
        T = as_array(T, "T", (4, 4))
        if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
            raise ValueError(f"T: last row must be [0, 0, 0, 1], got {T[3].tolist()}")
        return cls(T[:3, :3], T[:3, 3])

    @classmethod
    def exp(cls, xi) -> "Pose":
        """SE(3) exponential of a tangent vector ``[ω (rad), v (m)]`` (6,)."""
        R, t = se3_exp(as_vector(xi, "xi", 6))
        return cls(R, t)

    # --- views ---------------------------------------------------------------------------------
    @property
    def quat_wxyz(self) -> np.ndarray:
        """(4,) canonical unit quaternion (w ≥ 0)."""
        return matrix_to_quat_wxyz(self.R)

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix."""
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.t
        return T

    @property
    def distance_m(self) -> float:
        """Distance from the camera centre to the object origin, metres."""
        return float(np.linalg.norm(self.t))

    # --- algebra -------------------------------------------------------------------------------
    def inverse(self) -> "Pose":
        return Pose._composed(self.R.T, -self.R.T @ self.t)

    def __matmul__(self, other):
        if isinstance(other, Pose):
            return Pose._composed(self.R @ other.R, self.R @ other.t + self.t)
        pts = np.asarray(other, dtype=np.float64)
        if pts.ndim == 2 and pts.shape[1] == 3:
            return pts @ self.R.T + self.t
        if pts.shape == (3,):
            return self.R @ pts + self.t
        raise ValueError(f"Pose @ x: expected a Pose, (3,) or (N, 3) points, got shape {pts.shape}")

    def log(self) -> np.ndarray:
        """(6,) tangent ``[ω, v]`` with ``Pose.exp(T.log()) == T``."""
        return se3_log(self.R, self.t)

    def retract(self, xi) -> "Pose":
        """Right perturbation ``T · Exp(ξ)`` — the convention of every covariance in hybridpose."""
        return self @ Pose.exp(xi)

    def local(self, other: "Pose") -> np.ndarray:
        """(6,) ``ξ`` with ``self.retract(ξ) == other``."""
        return (self.inverse() @ other).log()

    def covariance_in_camera(self, covariance) -> np.ndarray:
        """A (6, 6) covariance over this pose's right perturbation ``[ω, v]`` (the convention of every
        covariance in hybridpose) as that of ``[δθ, δt]`` in the camera frame, with ``R' = Exp(δθ)·R``
        and ``t' = t + δt``: ``B Σ Bᵀ`` with ``B = diag(R, R)`` (first order). ``δt`` (m, camera axes) is
        the error of ``t`` itself and ``δθ`` (rad) a rotation about the camera axes — what a navigation
        filter given ``R`` and ``t`` expects (``hybridpose track`` writes its standard deviations)."""
        cov = as_array(covariance, "covariance", (6, 6))
        B = np.zeros((6, 6))
        B[:3, :3] = B[3:, 3:] = self.R
        return B @ cov @ B.T

    def interpolate(self, other: "Pose", alpha: float) -> "Pose":
        """Slerp on rotation and linear interpolation on translation (alpha 0 → self, 1 → other).

        Decoupled rather than the SE(3) geodesic so that the object centre moves on a straight
        line, which is what trajectory keyframes mean.
        """
        q = quat_slerp(self.quat_wxyz, other.quat_wxyz, alpha)
        return Pose.from_quat_t(q, (1 - alpha) * self.t + alpha * other.t)

    def allclose(self, other: "Pose", atol: float = 1e-9) -> bool:
        return bool(np.allclose(self.R, other.R, atol=atol) and np.allclose(self.t, other.t, atol=atol))

    def __repr__(self) -> str:
        q = np.round(self.quat_wxyz, 5).tolist()
        t = np.round(self.t, 5).tolist()
        return f"Pose(quat_wxyz={q}, t_m={t})"
