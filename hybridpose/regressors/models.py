"""Name → network builder for the CNN pose regressors (``hybridpose train --model NAME``)."""
from __future__ import annotations

from typing import Callable

import torch
from torch import nn

from .keypoint_net import KeypointNet
from .vgg import BranchedVGG19, ParallelVGG19, VGGPose

MODELS: dict[str, Callable[..., nn.Module]] = {
    "vgg16": lambda **kw: VGGPose("vgg16", 7, **kw),
    "vgg19": lambda **kw: VGGPose("vgg19", 7, **kw),
    "branched-vgg19": lambda image_size=224, **kw: BranchedVGG19(7, image_size, **kw),
    "parallel-vgg19": lambda image_size=224, **kw: ParallelVGG19(image_size, **kw),
    # CPU models: keypoint heatmaps on the object-centred crop, pose by PnP (see keypoint_net.py).
    # "default" is the one we ship trained (chosen by accuracy per ms, benchmarks/RESULTS.md);
    # "keypoints" the wider variant for when a few more ms buy accuracy.
    "default": lambda keypoints_m, image_size=128, twin_classes=0, **kw: KeypointNet(keypoints_m, 32, image_size, twin_classes),
    "keypoints": lambda keypoints_m, image_size=160, twin_classes=0, **kw: KeypointNet(keypoints_m, 48, image_size, twin_classes),
}

KEYPOINT_MODELS = ("default", "keypoints")

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
    """Build an untrained network; kwargs: ``dropout``, ``freeze_features``, ``image_size`` (branched/parallel)."""
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
