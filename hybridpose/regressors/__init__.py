"""CNN pose regressors: the paper's VGG family, its loss; training and the shipped default follow."""
from .losses import DEFAULT_BETA, normalize_quat, pose_loss, quat_geodesic_angle
from .models import available_models, build_model
from .vgg import BranchedVGG19, ParallelVGG19, VGGPose, load_imagenet_weights

__all__ = [
    "DEFAULT_BETA", "BranchedVGG19", "ParallelVGG19", "VGGPose", "available_models", "build_model",
    "load_imagenet_weights", "normalize_quat", "pose_loss", "quat_geodesic_angle",
]
