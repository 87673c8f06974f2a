"""Name → network builder for the CNN pose regressors (``hybridpose train --model NAME``)."""
from __future__ import annotations

from typing import Callable

from torch import nn

from .vgg import BranchedVGG19, ParallelVGG19, VGGPose

MODELS: dict[str, Callable[..., nn.Module]] = {
    "vgg16": lambda **kw: VGGPose("vgg16", 7, **kw),
    "vgg19": lambda **kw: VGGPose("vgg19", 7, **kw),
    "branched-vgg19": lambda image_size=224, **kw: BranchedVGG19(7, image_size, **kw),
    "parallel-vgg19": lambda image_size=224, **kw: ParallelVGG19(image_size, **kw),
}


def available_models() -> list[str]:
    return sorted(MODELS)


def build_model(name: str, **kwargs) -> nn.Module:
    """Build an untrained network; kwargs: ``dropout``, ``freeze_features``, ``image_size`` (branched/parallel)."""
    try:
        factory = MODELS[name]
    except KeyError:
        raise ValueError(f"model: unknown {name!r}; available: {', '.join(available_models())}") from None
    return factory(**kwargs)
