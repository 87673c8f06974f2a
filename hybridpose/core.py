"""The data that flows between the parts: ``Frame`` in, ``Measurement`` and ``Estimate`` out."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np

from .geometry import Camera, Pose
from .geometry.checks import as_array, as_unit_direction


class Status(str, Enum):
    """An :class:`Estimate`'s status, and the state of the estimator that gave it. A ``str``:
    ``Status.LOST == "lost"``, and it prints and serialises as its value.

    - ``INIT``: no pose yet (the CNN looks for the object, or the first start is on probation);
    - ``TRACKING``: the pose is tracked and trusted;
    - ``LOST``: the object was lost; the pose, where given, is a prediction not to be trusted;
    - ``REINIT``: the track restarted from the CNN on this frame (trusted).
    """

    INIT = "init"
    TRACKING = "tracking"
    LOST = "lost"
    REINIT = "reinit"

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


ESTIMATE_STATUSES = tuple(s.value for s in Status)
# the covariance of a measurement that knows nothing: ±180° rotation, ±1 m translation
LOST_COVARIANCE = np.diag([np.pi**2] * 3 + [1.0] * 3)


def covariance_from_information(information: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """(6, 6) symmetric covariance over ``[ω, v]`` of a fit whose normal equations are ``information``
    (6, 6), each row's variance ``scale`` (e.g. σ² px²): ``(information / scale + LOST_COVARIANCE⁻¹)⁻¹``,
    about ``scale · information⁻¹`` where the fit saw the pose.

    Why not ``scale · pinv(information)``: a direction the fit saw nothing of (a flat part seen face-on
    by the region cue alone, say) has no information, and the pseudo-inverse gives it *zero* variance —
    a certainty that a smoother's noise model cannot even invert. Adding a measurement that knows
    nothing (:data:`LOST_COVARIANCE`) bounds such a direction at ±180°, ±1 m and changes a
    well-observed one by nothing that matters (its information is many orders larger)."""
    H = 0.5 * (information + information.T) / scale + np.linalg.inv(LOST_COVARIANCE)
    cov = np.linalg.inv(H)
    return 0.5 * (cov + cov.T)


def as_covariance6(cov, name: str = "covariance") -> np.ndarray:
    """(6, 6) symmetric positive semi-definite covariance of a tangent ``[ω (rad), v (m)]``."""
    cov = as_array(cov, name, (6, 6))
    # every Measurement and Estimate passes here (several a frame): np.allclose's test written out
    # (|a − aᵀ| ≤ atol + 1e-5·|aᵀ|), at a fifth of its cost
    tol = 1e-9 * max(1.0, float(np.abs(cov).max()))
    if not np.all(np.abs(cov - cov.T) <= tol + 1e-5 * np.abs(cov.T)):
        raise ValueError(f"{name}: expected a symmetric (6, 6) matrix")
    if np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() < -tol:
        raise ValueError(f"{name}: not positive semi-definite")
    cov = np.array(cov, copy=True)
    cov.flags.writeable = False
    return cov


@dataclass(frozen=True, eq=False)
class Frame:
    """One image and what is known about it.

    Attributes:
        image: (H, W, 3) uint8 RGB, size matching ``camera``.
        camera: intrinsics of the image.
        timestamp: seconds.
        index: frame number in its sequence.
        sun_direction_cam: where known (a sun sensor, or ephemeris and attitude) and the sun is the
            only light — black space, no lamp — the (3,) direction the sunlight travels in this
            camera's frame (x right, y down, z forward; stored as a unit vector). The edge fits then
            leave out the model edges the sun cannot show (:meth:`ModelView.sun_shows
            <hybridpose.edges.ModelView.sun_shows>`). None: unknown, or other light too.
    """

    image: np.ndarray
    camera: Camera
    timestamp: float
    index: int = 0
    sun_direction_cam: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.camera.check_image(self.image, "image")
        if not np.isfinite(self.timestamp):
            raise ValueError(f"timestamp: expected finite seconds, got {self.timestamp}")
        if self.sun_direction_cam is not None:
            sun = as_unit_direction(self.sun_direction_cam, "sun_direction_cam",
                                    "the sunlight travels in the camera frame (x right, y down, z forward)")
            sun.flags.writeable = False
            object.__setattr__(self, "sun_direction_cam", sun)

    def undistorted(self) -> "Frame":
        """This frame as a pinhole camera sees it (:meth:`Camera.undistort`: same K, same camera frame,
        so poses and the sun's direction hold); itself where the camera has no distortion. The edge
        fits and the CNN work on pinhole images."""
        if not self.camera.dist:
            return self
        return replace(self, image=self.camera.undistort(self.image), camera=self.camera.pinhole())


@dataclass(frozen=True, eq=False)
class Measurement:
    """What one estimator (a tracker or a regressor) says about one frame.

    One meaning for every backend of every role:

    - ``lost == (pose is None)``: a backend that has lost the object, or never found it, says nothing
      about the pose. ``Measurement(pose=None, ...)`` is lost whatever ``lost`` says; a pose with
      ``lost=True`` is refused.
    - ``covariance`` is what the fusion layer weighs: the backend's own uncertainty of ``pose``.
    - ``quality`` is a 0..1 summary for people, plots and thresholds inside the backend (1: the best
      fit the backend knows, 0: nothing found); each backend documents how it computes it. Fusion
      never uses it as a second uncertainty.

    Attributes:
        pose: ``T_cam_obj`` or None when the estimator has nothing to say.
        covariance: (6, 6) tangent ``[ω, v]`` right-perturbation covariance (rad², m²).
        quality: 0..1, see above.
        source: ``"<role>:<backend>"``, e.g. ``"tracker:edges"`` or ``"regressor:default"``.
        timestamp: seconds.
        lost: True exactly when ``pose`` is None.
    """

    pose: Pose | None
    covariance: np.ndarray
    quality: float
    source: str
    timestamp: float
    lost: bool = False

    def __post_init__(self) -> None:
        if self.pose is not None and not isinstance(self.pose, Pose):
            raise TypeError(f"pose: expected a hybridpose Pose (T_cam_obj) or None, got {type(self.pose).__name__}")
        if self.pose is not None and self.lost:
            raise ValueError("lost: a lost measurement carries no pose (pass pose=None)")
        object.__setattr__(self, "lost", self.pose is None)
        object.__setattr__(self, "covariance", as_covariance6(self.covariance))
        q = float(self.quality)
        if not 0.0 <= q <= 1.0:
            raise ValueError(f"quality: expected a value in [0, 1], got {self.quality}")
        object.__setattr__(self, "quality", q)
        if not np.isfinite(self.timestamp):
            raise ValueError(f"timestamp: expected finite seconds, got {self.timestamp}")


@dataclass(frozen=True, eq=False)
class Estimate:
    """The fused belief at one time.

    Attributes:
        pose: ``T_cam_obj`` or None before initialisation.
        covariance: (6, 6) right-perturbation covariance of ``pose``, tangent ``[ω, v]``.
        velocity: (6,) body-frame twist ``[ω (rad/s), v (m/s)]``.
        status: a :class:`Status` (``"init"``, ``"tracking"``, ``"lost"`` or ``"reinit"``; a str given
            here is turned into one).
        timestamp: seconds.
        sources: the measurements fused into this estimate, e.g. ``("tracker:edges",
            "regressor:default")`` (empty when only predicted).
        timings_ms: milliseconds spent per component on this frame (``"tracker"``, ``"regressor"``,
            ``"fusion"``, ``"total"``).
    """

    pose: Pose | None
    covariance: np.ndarray
    timestamp: float
    status: Status = Status.INIT
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(6))
    sources: tuple[str, ...] = ()
    timings_ms: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.status not in ESTIMATE_STATUSES:
            raise ValueError(f"status: expected one of {ESTIMATE_STATUSES}, got {self.status!r}")
        object.__setattr__(self, "status", Status(self.status))
        object.__setattr__(self, "covariance", as_covariance6(self.covariance))
        object.__setattr__(self, "velocity", as_array(self.velocity, "velocity", (6,)))


def check_next_frame(frame: Frame, camera, last_timestamp: float | None):
    """Check that ``frame`` can follow a sequence's frames so far (taken by ``camera``, the last at
    ``last_timestamp`` seconds; None for both before the first): a :class:`Frame`, the same camera,
    a later timestamp. Returns the sequence's camera. Raises TypeError / ValueError naming the field."""
    if not isinstance(frame, Frame):
        raise TypeError(f"frame: expected a hybridpose Frame, got {type(frame).__name__}")
    if camera is not None and frame.camera != camera:
        raise ValueError(f"frame.camera: {frame.camera} differs from the camera of the first frame ({camera}); "
                         "call reset() to start over with another camera")
    if last_timestamp is not None and not frame.timestamp > last_timestamp:
        raise ValueError(f"frame.timestamp: {frame.timestamp:.6f} s is not after the previous frame's "
                         f"{last_timestamp:.6f} s (timestamps must increase)")
    return frame.camera if camera is None else camera
