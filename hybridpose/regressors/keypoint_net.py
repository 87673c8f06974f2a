"""Keypoint heatmap network: an object-centred crop in, the 2D image positions of the object's 3D
keypoints out (integral regression: a soft-argmax over one heatmap per keypoint). The pose then
comes from PnP (:mod:`hybridpose.regressors.keypoint_pnp`), as the winners of the spacecraft pose
challenges did, instead of regressing the rotation directly.

A small residual encoder (stride 32, so every heatmap sees the whole crop and can tell the
near-symmetric ends of the truss apart) and an FPN-style decoder back to stride 4.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

HEATMAP_STRIDE = 4  # heatmap cell = 4 crop pixels (32 × 32 cells on a 128-px crop)
# the unlabelled head's bias at start: every cell at probability 0.1 (CenterNet's prior), so the focal
# loss on a map that is almost all background starts small and stable
PRIOR_BIAS = -2.19


class _Block(nn.Module):
    """ResNet basic block (two 3×3 convolutions + shortcut)."""

    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(c_out)
        self.short = (nn.Identity() if stride == 1 and c_in == c_out else
                      nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride, bias=False), nn.BatchNorm2d(c_out)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)), inplace=True)
        return F.relu(self.bn2(self.conv2(y)) + self.short(x), inplace=True)


def _conv_bn(c_in: int, c_out: int, k: int = 3, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, k, stride, k // 2, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(True))


class KeypointNet(nn.Module):
    """Crop (B, 3, S, S) float in [0, 1] → keypoints (B, N, 2) in crop pixels + spread (B, N) pixels.

    Args:
        keypoints_m: (N, 3) model keypoints, metres, object frame; stored as a buffer so the
            checkpoint carries the exact points the heatmaps were trained for.
        width: channels of the first stage (stages use width × 1, 2, 4, 8).
        image_size: crop side S in pixels (a multiple of 32).
        twin_classes: > 0 adds a head (global pool of the deepest features → linear) that says
            which labelling of the object's near-symmetric twins the keypoints follow (identity
            first); trained with the twin loss, it lets inference undo the flip without guessing.

    Pixel convention: integer coordinates are pixel centres (OpenCV); ``spread`` is the standard
    deviation of each heatmap's distribution, a per-keypoint confidence (small = sharp peak).
    """

    kind = "keypoints"

    def __init__(self, keypoints_m, width: int = 32, image_size: int = 128, twin_classes: int = 0) -> None:
        super().__init__()
        kp = torch.tensor(np.array(keypoints_m, dtype=np.float32))
        if kp.ndim != 2 or kp.shape[1] != 3 or len(kp) < 4:
            raise ValueError(f"keypoints_m: expected (N ≥ 4, 3) metres, got {tuple(kp.shape)}")
        if image_size % 32:
            raise ValueError(f"image_size: expected a multiple of 32 pixels, got {image_size}")
        self.register_buffer("keypoints_m", kp)
        self.image_size, self.width = int(image_size), int(width)
        w = self.width
        self.stem = _conv_bn(3, w, 3, 2)                                  # /2
        self.layer1 = _Block(w, w, 2)                                     # /4
        self.layer2 = _Block(w, 2 * w, 2)                                 # /8
        self.layer3 = _Block(2 * w, 4 * w, 2)                             # /16
        self.layer4 = nn.Sequential(_Block(4 * w, 8 * w, 2), _Block(8 * w, 8 * w, 1))  # /32
        d = 2 * w
        self.lat4, self.lat3 = nn.Conv2d(8 * w, d, 1), nn.Conv2d(4 * w, d, 1)
        self.lat2, self.lat1 = nn.Conv2d(2 * w, d, 1), nn.Conv2d(w, d, 1)
        self.smooth3, self.smooth2, self.smooth1 = _conv_bn(d, d), _conv_bn(d, d), _conv_bn(d, d)
        self.head = nn.Conv2d(d, len(kp), 1)
        self.twin_head = nn.Linear(8 * w, int(twin_classes)) if twin_classes else None

    @property
    def num_keypoints(self) -> int:
        return int(self.keypoints_m.shape[0])

    def heatmaps(self, x: torch.Tensor) -> torch.Tensor:
        """(B, 3, S, S) → (B, N, S/4, S/4) logits."""
        return self._run(x)[0]

    def _run(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if x.ndim != 4 or x.shape[1] != 3:
            raise ValueError(f"image: expected (B, 3, H, W) float crops, got {tuple(x.shape)}")
        if x.shape[2] != self.image_size or x.shape[3] != self.image_size:
            raise ValueError(f"image: expected {self.image_size}×{self.image_size} crops, got {x.shape[2]}×{x.shape[3]}")
        c1 = self.layer1(self.stem(x))
        c2 = self.layer2(c1)
        c3 = self.layer3(c2)
        c4 = self.layer4(c3)
        p = self.lat4(c4)
        p = self.smooth3(self.lat3(c3) + F.interpolate(p, scale_factor=2.0, mode="nearest"))
        p = self.smooth2(self.lat2(c2) + F.interpolate(p, scale_factor=2.0, mode="nearest"))
        p = self.smooth1(self.lat1(c1) + F.interpolate(p, scale_factor=2.0, mode="nearest"))
        return self.head(p), c4

    def forward(self, x: torch.Tensor, with_twin: bool = False):
        """(uv (B, N, 2), spread (B, N)); with ``with_twin`` also the twin logits (B, T) or None."""
        logits, c4 = self._run(x)
        uv, spread = soft_argmax(logits, HEATMAP_STRIDE)
        if not with_twin:
            return uv, spread
        twin = self.twin_head(c4.mean((2, 3))) if self.twin_head is not None else None
        return uv, spread, twin


class UnlabelledKeypointNet(KeypointNet):
    """Crop (B, 3, S, S) → the N strongest peaks of one heatmap of all keypoints, without saying which
    keypoint each is: uv (B, N, 2) crop pixels, score (B, N) probabilities, strongest first.

    For objects with symmetries (:mod:`hybridpose.regressors.unlabelled`): the same encoder and
    decoder as :class:`KeypointNet`, one output channel; PnP tries the labellings.

    Args:
        keypoints_m, width, image_size: as :class:`KeypointNet`.
        gauge: the keypoints the first detection may be (:func:`~.unlabelled.symmetry_gauge`);
            None: any. Stored with the keypoints' hull planes (:func:`~.unlabelled.hull_planes`),
            so a checkpoint carries everything its PnP needs.
    """

    unlabelled = True

    def __init__(self, keypoints_m, width: int = 32, image_size: int = 128, gauge=None) -> None:
        from .unlabelled import hull_planes

        super().__init__(keypoints_m, width, image_size, 0)
        self.head = nn.Conv2d(self.head.in_channels, 1, 1)
        nn.init.constant_(self.head.bias, PRIOR_BIAS)
        n = self.num_keypoints
        gauge = list(range(n)) if gauge is None else [int(g) for g in gauge]
        if not gauge or min(gauge) < 0 or max(gauge) >= n:
            raise ValueError(f"gauge: expected keypoint indices in [0, {n}), got {gauge}")
        self.register_buffer("gauge", torch.tensor(gauge, dtype=torch.long))
        self.register_buffer("planes", torch.tensor(hull_planes(np.array(keypoints_m, dtype=np.float64))))

    def pnp_geometry(self) -> tuple[np.ndarray, list[int]]:
        """(hull planes (N, F, 4) float32, gauge) on the CPU: what its PnP needs besides the keypoints."""
        return self.planes.cpu().numpy(), [int(g) for g in self.gauge.cpu()]

    def forward(self, x: torch.Tensor, with_twin: bool = False, heatmaps: bool = False):
        """(uv (B, N, 2), score (B, N)); with ``with_twin`` a third output, None (no twin head);
        with ``heatmaps`` the (B, 1, S/4, S/4) logits instead (what training needs)."""
        logits, _ = self._run(x)
        if heatmaps:
            return logits
        uv, score = heatmap_peaks(logits, self.num_keypoints, HEATMAP_STRIDE)
        return (uv, score, None) if with_twin else (uv, score)


def heatmap_peaks(logits: torch.Tensor, k: int, stride: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` strongest local maxima (3×3) of one-channel heatmaps: (B, 1, h, w) logits → uv (B, k, 2)
    input pixels (the probability-weighted mean of the peak's 3×3 cells), score (B, k) probabilities,
    strongest first. Exported to ONNX as it is (max-pool, top-k, gather)."""
    prob = torch.sigmoid(logits[:, :1].float())                        # (B, 1, h, w)
    b, _, h, w = prob.shape
    peak = prob * (F.max_pool2d(prob, 3, 1, 1) == prob).to(prob.dtype)
    score, index = peak.reshape(b, h * w).topk(k, dim=1)
    xs = torch.arange(w, dtype=prob.dtype, device=prob.device).reshape(1, 1, 1, w).expand(1, 1, h, w)
    ys = torch.arange(h, dtype=prob.dtype, device=prob.device).reshape(1, 1, h, 1).expand(1, 1, h, w)
    mass = F.avg_pool2d(prob, 3, 1, 1)
    mx = (F.avg_pool2d(prob * xs, 3, 1, 1) / mass.clamp_min(1e-12)).reshape(b, h * w)
    my = (F.avg_pool2d(prob * ys, 3, 1, 1) / mass.clamp_min(1e-12)).reshape(b, h * w)
    uv = torch.stack([mx.gather(1, index), my.gather(1, index)], -1) * stride + (stride - 1) / 2
    return uv, score


def soft_argmax(logits: torch.Tensor, stride: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Expected position under each heatmap's softmax: (B, N, h, w) → (B, N, 2) input pixels, (B, N) spread.

    Heatmap cell (i, j) covers input pixels ``stride·j … stride·j + stride − 1``; its centre is
    input pixel ``stride·j + (stride − 1)/2``.
    """
    b, n, h, w = logits.shape
    prob = torch.softmax(logits.reshape(b, n, h * w).float(), dim=-1).reshape(b, n, h, w)
    xs = torch.arange(w, dtype=prob.dtype, device=prob.device) * stride + (stride - 1) / 2
    ys = torch.arange(h, dtype=prob.dtype, device=prob.device) * stride + (stride - 1) / 2
    px, py = prob.sum(2), prob.sum(3)  # marginals (B, N, w), (B, N, h)
    x = (px * xs).sum(-1)
    y = (py * ys).sum(-1)
    var = (px * xs**2).sum(-1) - x**2 + (py * ys**2).sum(-1) - y**2
    return torch.stack([x, y], -1), var.clamp_min(1e-6).sqrt()


def keypoint_loss(pred_px: torch.Tensor, spread_px: torch.Tensor, true_px: torch.Tensor, image_size: int,
                  spread_weight: float = 0.05, return_best: bool = False):
    """Mean L1 keypoint error as a fraction of the crop side, plus a small term for sharp heatmaps.

    ``true_px`` is (B, N, 2), or (B, T, N, 2) for T equally valid labellings (the keypoints under
    the object's near-symmetries): each sample then counts its best-matching labelling, so the
    network is not pushed to the average of the ends it cannot yet tell apart (the regressor's
    twin check picks the right one on the image). Keypoints whose label lies outside the crop are
    not counted (a soft-argmax cannot reach them). ``return_best`` also returns each sample's
    best labelling index (B,) (the twin head's target).
    """
    if true_px.ndim == 3:
        true_px = true_px[:, None]
    inside = ((true_px >= 0) & (true_px <= image_size - 1)).all(-1).float()   # (B, T, N)
    err = (pred_px[:, None] - true_px).abs().sum(-1) / image_size            # (B, T, N)
    spread = (spread_px[:, None] / image_size * inside).sum(-1)
    count = inside.sum(-1).clamp_min(1.0)
    per = (err * inside).sum(-1) / count + spread_weight * spread / count      # (B, T)
    best, index = per.min(dim=1)
    return (best.mean(), index) if return_best else best.mean()


def widen_state_dict(state: dict, target: dict, noise: float = 0.01, seed: int = 0) -> dict:
    """A trained :class:`KeypointNet` state dict rewritten for a wider one (Net2WiderNet, Chen et al. 2016).

    Every feature map of ``C`` channels that has ``C' > C`` in ``target`` keeps its ``C`` channels
    first; each extra channel copies a seeded random old one (the same choice for every tensor of
    ``C`` channels, so residual and FPN sums still add like to like), and the consumers of a copied
    channel share its weight among the copies. With ``noise = 0`` the wider net computes exactly
    what the narrow one did (eval mode: the batch-norm statistics are copied too); ``noise`` (a
    fraction of each weight tensor's standard deviation, added to the copies' incoming weights only)
    lets the copies drift apart in training — without it they would stay identical for good (Adam's
    step does not see how the outgoing weight was shared).

    Written here because no maintained library widens a trained network; it lets the wider
    ``keypoints`` model start from the shipped ``default`` instead of from scratch (days on a CPU).

    Args:
        state: the trained net's ``state_dict()``.
        target: the wider net's ``state_dict()`` (only names and shapes are used); same layers.
        noise: relative noise on the copied channels' incoming weights (finite, ≥ 0).
        seed: seeds which old channels are copied and the noise.
    Returns:
        a state dict with ``target``'s shapes, loadable into the wider net.
    """
    if set(state) != set(target):
        raise ValueError("state: not the same layers as the target net "
                         f"(differ: {', '.join(sorted(set(state) ^ set(target))[:4])} …)")
    if not (noise >= 0 and math.isfinite(noise)):
        raise ValueError(f"noise: expected a finite fraction ≥ 0, got {noise}")
    gen = torch.Generator().manual_seed(seed)
    maps: dict[tuple[int, int], torch.Tensor] = {}

    def mapping(c_old: int, c_new: int) -> torch.Tensor:
        if c_new < c_old:
            raise ValueError(f"target: {c_new} channels where the trained net has {c_old}; it can only widen")
        if (c_old, c_new) not in maps:
            n = c_new - c_old   # distinct channels copied while there are enough, so no channel is split thrice
            extra = torch.randperm(c_old, generator=gen)[:n] if n <= c_old else torch.randint(c_old, (n,), generator=gen)
            maps[c_old, c_new] = torch.cat([torch.arange(c_old), extra])
        return maps[c_old, c_new]

    out = {}
    for key, value in state.items():
        shape = tuple(target[key].shape)
        v = value.clone()
        if v.ndim != len(shape):
            raise ValueError(f"target: {key} has shape {shape}, the trained net {tuple(v.shape)}")
        if v.ndim >= 1 and shape[0] != v.shape[0]:               # output channels (also BN vectors, biases)
            g = mapping(v.shape[0], shape[0])
            copied = torch.arange(len(g)) >= v.shape[0]
            v = v[g]
            if v.ndim >= 2 and noise > 0:
                v[copied] += noise * float(value.std()) * torch.randn(v[copied].shape, generator=gen)
        if v.ndim >= 2 and shape[1] != v.shape[1]:                # input channels: share among the copies
            g = mapping(v.shape[1], shape[1])
            counts = torch.bincount(g, minlength=v.shape[1]).to(v.dtype)
            v = v[:, g] / counts[g].reshape(1, -1, *([1] * (v.ndim - 2)))
        if tuple(v.shape) != shape:
            raise ValueError(f"target: {key} has shape {shape}, cannot widen {tuple(value.shape)} to it")
        out[key] = v
    return out
