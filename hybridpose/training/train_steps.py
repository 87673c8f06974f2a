"""One training batch's loss and a validation pass, the same for direct (VGG) and keypoint models:
the paper's pose loss, the keypoint loss with the twin head's cross-entropy, and the validation
errors through PnP for keypoint models."""
from __future__ import annotations

import numpy as np
import torch

from ..geometry import Pose, quat_wxyz_to_matrix
from .calibrate import keypoint_pnp_batch
from ..regressors.keypoint_net import HEATMAP_STRIDE, keypoint_loss
from ..regressors.unlabelled import focal_loss, heatmap_targets, visible_keypoints
from .losses import pose_loss, quat_geodesic_angle


def _unwrap(model):
    """The network inside a DistributedDataParallel wrapper (or the network itself)."""
    return getattr(model, "module", model)


def is_keypoint_model(model) -> bool:
    return getattr(_unwrap(model), "kind", "direct") == "keypoints"


def forward(model, batch, device):
    """The network's raw output on ``batch`` (the parallel model also gets the crops)."""
    x = batch["image"].to(device, non_blocking=True)
    if "crop_image" in batch:
        return model(x, batch["crop_image"].to(device, non_blocking=True))
    return model(x)


def batch_loss(model, batch, device, beta: float, twin_weight: float) -> torch.Tensor:
    if is_keypoint_model(model):
        net = _unwrap(model)
        labels = batch["kp2d"].to(device)
        if getattr(net, "unlabelled", False):
            R = quat_wxyz_to_matrix(batch["q"].numpy())
            seen = visible_keypoints(net.planes.cpu().numpy(), R, batch["t"].numpy().astype(np.float64))
            target = heatmap_targets(labels, torch.from_numpy(seen).to(device), net.image_size, HEATMAP_STRIDE)
            return focal_loss(model(batch["image"].to(device, non_blocking=True), heatmaps=True), target)
        if net.twin_head is not None and labels.ndim == 4:
            pred, spread, twin = model(batch["image"].to(device, non_blocking=True), with_twin=True)
            loss, best = keypoint_loss(pred, spread, labels, net.image_size, return_best=True)
            return loss + twin_weight * torch.nn.functional.cross_entropy(twin, best)
        pred, spread = model(batch["image"].to(device, non_blocking=True))
        return keypoint_loss(pred, spread, labels, net.image_size)
    t, q = forward(model, batch, device)
    return pose_loss(t, q, batch["t"].to(device), batch["q"].to(device), beta)


def predict_batch(model, batch, device, twins=()) -> tuple[torch.Tensor, torch.Tensor]:
    """(t (B, 3) m, q (B, 4)) for a batch; keypoint models go through PnP with the batch's ``K``.

    A keypoint prediction PnP cannot explain gets the pose at the crop centre, 1 m away, identity
    rotation — a counted failure, not a skipped sample. A model with a twin head has its
    predicted twin undone (``pose @ S``, the half-turns are their own inverses).
    """
    if not is_keypoint_model(model):
        return forward(model, batch, device)
    results, twin = keypoint_pnp_batch(model, batch, device)
    which = twin.argmax(1).cpu().numpy() if twin is not None and twins else np.zeros(len(results), int)
    ts, qs = [], []
    for res, K, k in zip(results, batch["K"].numpy().astype(np.float64), which):
        pose = res.pose if res is not None else Pose.from_quat_t([1, 0, 0, 0], np.linalg.solve(K, [model.image_size / 2, model.image_size / 2, 1.0]))
        if k > 0:
            pose = pose @ twins[k - 1]
        ts.append(pose.t)
        qs.append(pose.quat_wxyz)
    return (torch.tensor(np.array(ts), dtype=torch.float32, device=device),
            torch.tensor(np.array(qs), dtype=torch.float32, device=device))


def nearest_twin(t_pred, q_pred, t_true, q_true, twins) -> tuple[torch.Tensor, torch.Tensor]:
    """Ground truth replaced, per sample, by the twin pose (``gt @ S``) closest to the prediction."""
    best_t, best_q = t_true.clone(), q_true.clone()
    best = quat_geodesic_angle(q_pred, q_true) + (t_pred - t_true).norm(dim=1)
    for S in twins:
        tt, qq = [], []
        for t, q in zip(t_true.cpu().numpy(), q_true.cpu().numpy()):
            g = Pose.from_quat_t(q / np.linalg.norm(q), t) @ S
            tt.append(g.t)
            qq.append(g.quat_wxyz)
        tt = torch.tensor(np.array(tt), dtype=t_true.dtype, device=t_true.device)
        qq = torch.tensor(np.array(qq), dtype=q_true.dtype, device=q_true.device)
        score = quat_geodesic_angle(q_pred, qq) + (t_pred - tt).norm(dim=1)
        closer = score < best
        best = torch.where(closer, score, best)
        best_t[closer], best_q[closer] = tt[closer], qq[closer]
    return best_t, best_q


def evaluate(model, loader, device, beta: float, twins=(), symmetries=()) -> dict:
    """Paper loss of the predicted poses, mean/median rotation error (°) and mean translation error
    (m) over ``loader`` (the same numbers for direct and keypoint models); with ``twins`` the error
    is to the nearest twin of the ground truth where the model has no twin head to choose one; with
    the object's ``symmetries`` always to the nearest equivalent pose (no image tells those apart)."""
    model.eval()
    losses, rot, trans = [], [], []
    with torch.no_grad():
        for batch in loader:
            t, q = predict_batch(model, batch, device, twins)
            t_true, q_true = batch["t"].to(device), batch["q"].to(device)
            if twins and getattr(_unwrap(model), "twin_head", None) is None:
                t_true, q_true = nearest_twin(t, q, t_true, q_true, twins)
            if symmetries:
                t_true, q_true = nearest_twin(t, q, t_true, q_true, symmetries)
            losses.append(pose_loss(t, q, t_true, q_true, beta).item() * len(t))
            rot.append(torch.rad2deg(quat_geodesic_angle(q, q_true)).cpu())
            trans.append((t - t_true).norm(dim=1).cpu())
    rot_all, trans_all = torch.cat(rot).numpy(), torch.cat(trans).numpy()
    return {"val_loss": float(np.sum(losses) / len(rot_all)), "rot_mean_deg": float(rot_all.mean()),
            "rot_median_deg": float(np.median(rot_all)), "trans_mean_m": float(trans_all.mean())}
