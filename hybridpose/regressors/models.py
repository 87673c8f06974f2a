"""Name → network builder for the CNN pose regressors (``hybridpose train --model NAME``)."""
from __future__ import annotations

from typing import Callable

import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from .keypoint_net import KeypointNet, UnlabelledKeypointNet
from .vgg import BranchedVGG19, ParallelVGG19, VGGPose

MODELS: dict[str, Callable[..., nn.Module]] = {
    "vgg16": lambda **kw: VGGPose("vgg16", 7, **kw),
    "vgg19": lambda **kw: VGGPose("vgg19", 7, **kw),
    "branched-vgg19": lambda image_size=224, **kw: BranchedVGG19(7, image_size, **kw),
    "parallel-vgg19": lambda image_size=224, **kw: ParallelVGG19(image_size, **kw),
    # CPU models: keypoint heatmaps on the object-centred crop, pose by PnP (see keypoint_net.py).
    # "default" is the one we ship trained (chosen by accuracy per ms, benchmarks/RESULTS.md);
    # "keypoints" the wider variant for when a few more ms buy accuracy.
    # An object with symmetries gets the unlabelled variant (``gauge`` given: unlabelled.py).
    "default": lambda keypoints_m, image_size=128, twin_classes=0, gauge=None, **kw: _keypoint_net(
        keypoints_m, 32, image_size, twin_classes, gauge),
    "keypoints": lambda keypoints_m, image_size=160, twin_classes=0, gauge=None, **kw: _keypoint_net(
        keypoints_m, 48, image_size, twin_classes, gauge),
}

KEYPOINT_MODELS = ("default", "keypoints")


def _keypoint_net(keypoints_m, width: int, image_size: int, twin_classes: int, gauge) -> nn.Module:
    if gauge is None:
        return KeypointNet(keypoints_m, width, image_size, twin_classes)
    if twin_classes:
        raise ValueError("twin_classes: an unlabelled keypoint net (gauge given) has no twin head")
    return UnlabelledKeypointNet(keypoints_m, width, image_size, gauge)

# training settings that differ from TrainConfig's (paper) defaults: the keypoint nets train from
# scratch with batch norm, where the paper's lr = 1e-4 for ImageNet-initialised VGGs is too slow
MODEL_DEFAULTS: dict[str, dict] = {
    "default": {"image_size": 128, "lr": 1e-3, "schedule": "cosine"},
    "keypoints": {"image_size": 160, "lr": 1e-3, "schedule": "cosine"},
}


def model_kind(name: str) -> str:
    """``"keypoints"`` (heatmaps + PnP) or ``"direct"`` (regresses t and q)."""
    return "keypoints" if name in KEYPOINT_MODELS else "direct"


def available_models() -> list[str]:
    return sorted(MODELS)


def build_model(name: str, **kwargs) -> nn.Module:
    """Build an untrained network; kwargs: ``dropout``, ``freeze_features``, ``init`` (VGG models: ``VGG_INITS``),
    ``image_size`` (branched/parallel)."""
    try:
        factory = MODELS[name]
    except KeyError:
        raise ValueError(f"model: unknown {name!r}; available: {', '.join(available_models())}") from None
    return factory(**kwargs)


def torch_device(device="auto") -> torch.device:
    """``device`` ("auto", "cpu", "cuda", "cuda:N" or a torch.device) checked against what torch can reach.

    "auto" is the first CUDA GPU when torch sees one, else the CPU. Training and inference both
    pick their device here, so a bad name gets the same error from either.
    """
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise ValueError(f"device: expected 'auto', 'cpu', 'cuda' or 'cuda:N', got {device!r}") from exc
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device: {device!r} asked for, but torch sees no CUDA GPU here; use 'cpu'")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"device: {device!r} asked for, but torch sees {torch.cuda.device_count()} CUDA GPU(s)")
    elif dev.type != "cpu":
        raise ValueError(f"device: expected 'auto', 'cpu', 'cuda' or 'cuda:N', got {device!r}")
    return dev


def fold_batch_norm(net: nn.Module) -> nn.Module:
    """Fold every batch norm that follows a convolution into it, in place, for inference only.

    Eval-mode batch norm is an affine map per channel, so ``conv → bn`` is one convolution with
    rescaled weights and a bias (torch's ``fuse_conv_bn_eval`` does the arithmetic); the network
    then computes the same outputs (to float rounding) with a third fewer layers, ≈ 0.5 ms of the
    ≈ 5 ms a 128 px keypoint pass takes on one CPU thread. Pairs are a ``Conv2d`` directly followed
    by a ``BatchNorm2d`` in an ``nn.Sequential``, and sibling attributes ``convX`` / ``bnX`` (the
    residual blocks). The folded network must not be trained again (the statistics are gone).

    Args:
        net: a network in eval mode.
    Returns:
        ``net``, folded.
    """
    if net.training:
        raise ValueError("net: batch norm folds only in eval mode (call net.eval() first)")
    for module in list(net.modules()):
        if isinstance(module, nn.Sequential):
            for i in range(len(module) - 1):
                if isinstance(module[i], nn.Conv2d) and isinstance(module[i + 1], nn.BatchNorm2d):
                    module[i], module[i + 1] = fuse_conv_bn_eval(module[i], module[i + 1]), nn.Identity()
        for name, child in list(module.named_children()):
            conv_name = "conv" + name[2:]
            if name.startswith("bn") and isinstance(child, nn.BatchNorm2d) and isinstance(getattr(module, conv_name, None), nn.Conv2d):
                setattr(module, conv_name, fuse_conv_bn_eval(getattr(module, conv_name), child))
                setattr(module, name, nn.Identity())
    return net
