"""CNN pose regressors at predict time: the contract (:class:`PoseRegressor`), the networks (the paper's VGG
family and the keypoint models) and trained checkpoints as backends (:mod:`.predictor`). Training,
evaluation, calibration fitting and the paper's loss live in :mod:`hybridpose.training`."""
from .base import PoseRegressor
from .models import available_models, build_model
from .vgg import BranchedVGG19, ParallelVGG19, VGGPose, load_imagenet_weights, normalize_quat

__all__ = [
    "BranchedVGG19", "ParallelVGG19", "PoseRegressor", "VGGPose", "available_models", "build_model",
    "load_imagenet_weights", "normalize_quat",
]
