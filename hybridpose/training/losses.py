"""The paper's loss: ``L = ‖t − t̂‖₂ + β·L_R`` with ``L_R`` the geodesic angle between quaternions."""
from __future__ import annotations

import torch

from ..regressors.vgg import normalize_quat

DEFAULT_BETA = 10.0  # the paper's β: rotation (rad) weighed against translation (m)
_EPS = 1e-7  # keeps arccos' gradient finite at |⟨q, q̂⟩| = 1


def quat_geodesic_angle(q_pred: torch.Tensor, q_true: torch.Tensor) -> torch.Tensor:
    """(B,) angle in radians between rotations, the shorter way round: ``2·acos(|⟨q̂, q⟩|)``.

    ``q_pred`` is normalised first (the paper normalises in the loss); the sign of either
    quaternion does not matter. The dot product is clamped just below 1 so the gradient of acos
    stays finite when the prediction is exact.
    """
    q_pred = normalize_quat(q_pred)
    q_true = normalize_quat(q_true)
    dot = (q_pred * q_true).sum(dim=1).abs().clamp(max=1.0 - _EPS)
    return 2.0 * torch.acos(dot)


def pose_loss(t_pred: torch.Tensor, q_pred: torch.Tensor, t_true: torch.Tensor, q_true: torch.Tensor,
              beta: float = DEFAULT_BETA) -> torch.Tensor:
    """Mean over the batch of ``‖t − t̂‖₂ + β·L_R`` (translation in metres, angle in radians).

    Args:
        t_pred, t_true: (B, 3) metres. q_pred, q_true: (B, 4) (w, x, y, z); q_pred need not be unit.
        beta: weight of the rotation term (the paper's β = 10).
    """
    for name, x, n in (("t_pred", t_pred, 3), ("t_true", t_true, 3)):
        if x.ndim != 2 or x.shape[1] != n:
            raise ValueError(f"{name}: expected (B, {n}), got {tuple(x.shape)}")
    trans = (t_pred - t_true).norm(dim=1)
    return (trans + beta * quat_geodesic_angle(q_pred, q_true)).mean()
