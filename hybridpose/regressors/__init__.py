"""CNN pose regressors at predict time: the contract (:class:`PoseRegressor`), the networks (the paper's VGG
family and the keypoint models) and trained checkpoints as backends (:mod:`.predictor`). Training,
evaluation, calibration fitting and the paper's loss live in :mod:`hybridpose.training`.

The networks' names are imported on first use (PEP 562): they need torch, whose import costs about three
seconds, and the tracker, the estimator and the keypoint memory, which live beside them, do not."""
from __future__ import annotations

import importlib

from .base import PoseRegressor

_LAZY = {
    "available_models": ".models", "build_model": ".models",
    "BranchedVGG19": ".vgg", "ParallelVGG19": ".vgg", "VGGPose": ".vgg", "load_imagenet_weights": ".vgg",
    "normalize_quat": ".vgg",
}

__all__ = [
    "BranchedVGG19", "ParallelVGG19", "PoseRegressor", "VGGPose", "available_models", "build_model",
    "load_imagenet_weights", "normalize_quat",
]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
