"""Boundary validation: every public function checks its inputs here and says what it wanted.

Errors name the argument, the expected shape/unit and what was received, so a user never meets a
crash deep inside OpenCV or a silent NaN.
"""
from __future__ import annotations

import numba
import numpy as np

ROTATION_ATOL = 1e-5  # ‖RᵀR − I‖ accepted as a rotation (values read from float32 files)
QUAT_NORM_ATOL = 1e-4  # |‖q‖ − 1| accepted as a unit quaternion (a float32 quaternion from a file)
ORTHONORMAL_ROUNDING = 1e-13  # a rotation this close is kept as given, not re-orthonormalised


def _describe(x: np.ndarray) -> str:
    return f"shape {tuple(x.shape)} dtype {x.dtype}"


def as_array(x, name: str, shape: tuple, dtype=np.float64) -> np.ndarray:
    """Convert ``x`` to an array and check its shape; ``None`` in ``shape`` matches any length.

    Raises:
        ValueError: naming ``name`` when the shape differs or values are not finite.
    """
    try:
        arr = np.asarray(x, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected a numeric array of shape {_fmt_shape(shape)}, got {type(x).__name__}") from exc
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        raise ValueError(f"{name}: expected shape {_fmt_shape(shape)}, got {tuple(arr.shape)}")
    # (the dtype's kind and the array's own ``all``: NumPy's module-level helpers cost more than the test
    # on the small arrays every projection checks)
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise ValueError(f"{name}: contains NaN or inf")
    return arr


def read_only(a) -> np.ndarray:
    """A float64 copy of ``a`` that cannot be written to (the fields of immutable types: a pose's R and t,
    an object's box)."""
    a = np.array(a, dtype=np.float64, copy=True)
    a.flags.writeable = False
    return a


def _fmt_shape(shape: tuple) -> str:
    return "(" + ", ".join("N" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def as_rgb_image(image, name: str = "image") -> np.ndarray:
    """``image`` as an (H, W, 3) uint8 RGB array with at least one pixel."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or img.size == 0:
        raise ValueError(f"{name}: expected (H, W, 3) uint8 RGB, got shape {img.shape} dtype {img.dtype}")
    return img


def as_points3d(x, name: str) -> np.ndarray:
    """(N, 3) float64 array of 3D points."""
    return as_array(x, name, (None, 3))


def as_vector(x, name: str, n: int) -> np.ndarray:
    """(n,) float64 vector."""
    return as_array(x, name, (n,))


def as_rotation_matrix(R, name: str = "R", atol: float = ROTATION_ATOL) -> np.ndarray:
    """(3, 3) float64 proper rotation, re-orthonormalised (SVD) after the check unless it already is
    one to float rounding (max |RᵀR − I| ≤ ``ORTHONORMAL_ROUNDING``).

    Raises:
        ValueError: when ``R`` is not orthonormal within ``atol`` or its determinant is not +1.
    """
    R = as_array(R, name, (3, 3))
    err, det = _orthonormality(np.ascontiguousarray(R))
    if err > atol:
        raise ValueError(f"{name}: not a rotation matrix (max |RᵀR − I| = {err:.3g} > {atol:g})")
    if det < 0:
        raise ValueError(f"{name}: a reflection, not a rotation (det = {det:.3f}, expected +1)")
    if err <= ORTHONORMAL_ROUNDING:  # a rotation to float rounding already (Rodrigues, products): the SVD would not change it
        return R.copy()
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


@numba.njit(cache=True, nogil=True)
def _orthonormality(R: np.ndarray) -> tuple[float, float]:
    """(max |RᵀR − I|, det R) of a (3, 3) float64 matrix, compiled: NumPy's three calls on a 3 × 3 cost
    ≈ 30 µs, and a pose is checked at every PnP solve and edge fit."""
    err = 0.0
    for i in range(3):
        for j in range(3):
            dot = R[0, i] * R[0, j] + R[1, i] * R[1, j] + R[2, i] * R[2, j]
            err = max(err, abs(dot - (1.0 if i == j else 0.0)))
    det = (R[0, 0] * (R[1, 1] * R[2, 2] - R[1, 2] * R[2, 1]) - R[0, 1] * (R[1, 0] * R[2, 2] - R[1, 2] * R[2, 0])
           + R[0, 2] * (R[1, 0] * R[2, 1] - R[1, 1] * R[2, 0]))
    return err, det


def as_unit_direction(d, name: str, meaning: str = "") -> np.ndarray:
    """(3,) float64 unit vector from a non-zero, finite direction of any length; ``meaning`` (e.g.
    what the direction is and its frame) is added to the error message."""
    try:
        arr = np.asarray(d, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.zeros(0)  # not numeric: the same error as any other bad direction
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or np.linalg.norm(arr) < 1e-9:
        raise ValueError(f"{name}: expected a non-zero, finite (3,) direction{' ' + meaning if meaning else ''}, got {d!r}")
    return arr / np.linalg.norm(arr)


def as_unit_quat(q, name: str = "q", atol: float = QUAT_NORM_ATOL) -> np.ndarray:
    """(4,) or (N, 4) quaternion (w, x, y, z), normalised after checking ‖q‖ = 1 within ``atol``."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1:] != (4,) or q.ndim > 2:
        raise ValueError(f"{name}: expected a quaternion (w, x, y, z) of shape (4,) or (N, 4), got {tuple(q.shape)}")
    if not np.all(np.isfinite(q)):
        raise ValueError(f"{name}: contains NaN or inf")
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    bad = np.abs(norm - 1.0) > atol
    if np.any(bad):
        raise ValueError(f"{name}: not a unit quaternion (‖q‖ = {float(norm[bad][0]):.6g}, expected 1 ± {atol:g})")
    return q / norm
