"""The paper's models in plain torch (no torchvision): VGG-16/19 baselines, Branched and Parallel VGG-19.

Layer names follow torchvision's VGG (``features.N``, ``classifier.0/3/6``) so that a local
torchvision-format ImageNet state dict loads with :func:`load_imagenet_weights`.
"""
from __future__ import annotations

import logging
from pathlib import Path

import torch
from torch import nn


log = logging.getLogger(__name__)

QUAT_NORM_EPS = 1e-7  # a raw quaternion output this short is not scaled up further


def normalize_quat(q: torch.Tensor) -> torch.Tensor:
    """(B, 4) → unit quaternions (w, x, y, z); the network's raw output is normalised here."""
    if q.ndim != 2 or q.shape[1] != 4:
        raise ValueError(f"q: expected (B, 4) quaternions (w, x, y, z), got {tuple(q.shape)}")
    return q / q.norm(dim=1, keepdim=True).clamp_min(QUAT_NORM_EPS)


CFG = {
    "vgg16": [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M"],
    "vgg19": [64, 64, "M", 128, 128, "M", 256, 256, 256, 256, "M", 512, 512, 512, 512, "M", 512, 512, 512, 512, "M"],
}
FEATURE_DIM = 512 * 7 * 7  # VGG's last pooled features at 224 × 224
BRANCH_DIM = 1024  # hidden width of the branched heads
# how a VGG model's weights start: "torchvision" (init_vgg_weights, the default) or
# "torch-default" (torch's per-layer defaults, which the models had before: to reproduce those runs)
VGG_INITS = ("torchvision", "torch-default")


def make_features(cfg: list) -> nn.Sequential:
    layers: list[nn.Module] = []
    c = 3
    for v in cfg:
        if v == "M":
            layers.append(nn.MaxPool2d(2, 2))
        else:
            layers += [nn.Conv2d(c, v, 3, padding=1), nn.ReLU(inplace=True)]
            c = v
    return nn.Sequential(*layers)


def _check_init(init: str) -> None:
    if init not in VGG_INITS:
        raise ValueError(f"init: expected one of {', '.join(VGG_INITS)}, got {init!r}")


def init_vgg_weights(module: nn.Module) -> None:
    """torchvision's VGG initialisation: convolutions He-normal (fan-out, ReLU gain) with zero bias,
    linear layers N(0, 0.01²) with zero bias.

    Why not torch's layer defaults: they scale each ReLU layer's output variance by about 1/6, so after
    VGG-19's 16 convolutions the features hold little but the biases — at initialisation the outputs
    of different views differ by ~1e-8 m, the gradient carries almost no image, and training from
    scratch can sit at the constant pose: one batch is not fitted in 40 steps, a parallel model's
    translation stream stayed there for 100 epochs, the VGG-16/19 rotation for 10 (docs/decisions.md).
    """
    for m in module.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            nn.init.zeros_(m.bias)
        elif isinstance(m, nn.Linear):
            nn.init.normal_(m.weight, 0.0, 0.01)
            nn.init.zeros_(m.bias)


def _classifier(in_dim: int, out_dim: int, dropout: float) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(in_dim, 4096), nn.ReLU(True), nn.Dropout(dropout),
        nn.Linear(4096, 4096), nn.ReLU(True), nn.Dropout(dropout),
        nn.Linear(4096, out_dim),
    )


def _check_image(x: torch.Tensor, name: str = "image") -> None:
    if x.ndim != 4 or x.shape[1] != 3:
        raise ValueError(f"{name}: expected (B, 3, H, W) float images, got {tuple(x.shape)}")
    if x.shape[2] < 32 or x.shape[3] < 32:
        raise ValueError(f"{name}: VGG needs at least 32×32 pixels (five 2× poolings), got {x.shape[2]}×{x.shape[3]}")


class VGGPose(nn.Module):
    """VGG baseline: features → 7×7 average pool → FC-4096 → FC-4096 → ``out_dim``.

    ``out_dim`` = 7 gives (t (B, 3) metres, q (B, 4) unit); 3 or 4 give one of them (used by the
    parallel model). ``freeze_features`` trains the head only, as the paper's baselines did. ``init``:
    how the weights start (``VGG_INITS``; :func:`init_vgg_weights` by default).
    """

    def __init__(self, arch: str = "vgg19", out_dim: int = 7, dropout: float = 0.5, freeze_features: bool = False,
                 init: str = "torchvision", extra_dim: int = 0) -> None:
        super().__init__()
        if arch not in CFG:
            raise ValueError(f"arch: expected one of {sorted(CFG)}, got {arch!r}")
        _check_init(init)
        self.arch, self.out_dim = arch, out_dim
        self.features = make_features(CFG[arch])
        self.avgpool = nn.AdaptiveAvgPool2d((7, 7))
        # extra_dim: features a subclass concatenates before the first FC (the branched model's branch), so
        # its classifier is built once at its final size (not built, initialised and replaced: 100 M weights)
        self.classifier = _classifier(FEATURE_DIM + int(extra_dim), out_dim, dropout)
        if init == "torchvision":
            init_vgg_weights(self)
        if freeze_features:
            self.features.requires_grad_(False)

    def embed(self, x: torch.Tensor) -> torch.Tensor:
        return torch.flatten(self.avgpool(self.features(x)), 1)

    def forward(self, x: torch.Tensor):
        _check_image(x)
        return split_output(self.classifier(self.embed(x)), self.out_dim)


class BranchedVGG19(VGGPose):
    """The paper's Branched VGG-19: after the 2nd max-pool a branch → 2×2 max-pool → FC-1024,
    concatenated with the main stream's features before the first FC.

    ``image_size`` fixes the branch's FC input (128 · (S/8)² for an S×S image; 224 → 100 352).
    """

    def __init__(self, out_dim: int = 7, image_size: int = 224, dropout: float = 0.5, freeze_features: bool = False,
                 init: str = "torchvision") -> None:
        if int(image_size) % 32:
            raise ValueError(f"image_size: expected a multiple of 32 pixels, got {image_size}")
        super().__init__("vgg19", out_dim, dropout, freeze_features, init, extra_dim=BRANCH_DIM)
        self.image_size = int(image_size)
        self._split = 10  # index just after the 2nd max-pool in features
        side = self.image_size // 8
        self.branch = nn.Sequential(nn.MaxPool2d(2, 2), nn.Flatten(), nn.Linear(128 * side * side, BRANCH_DIM), nn.ReLU(True))
        if init == "torchvision":
            init_vgg_weights(self.branch)

    def forward(self, x: torch.Tensor):
        _check_image(x)
        if x.shape[2] != self.image_size or x.shape[3] != self.image_size:
            raise ValueError(f"image: expected {self.image_size}×{self.image_size} (the branch's FC size), got {x.shape[2]}×{x.shape[3]}")
        early = self.features[: self._split](x)
        main = torch.flatten(self.avgpool(self.features[self._split:](early)), 1)
        return split_output(self.classifier(torch.cat([main, self.branch(early)], 1)), self.out_dim)


class ParallelVGG19(nn.Module):
    """The paper's best model: stream 1 (VGG-19, full image) → translation; stream 2 (Branched
    VGG-19, object-centred crop, the "bounded image") → quaternion.

    ``forward(image, crop)`` → (t (B, 3) metres, q (B, 4) unit).
    """

    def __init__(self, image_size: int = 224, dropout: float = 0.5, freeze_features: bool = False,
                 init: str = "torchvision") -> None:
        super().__init__()
        self.translation = VGGPose("vgg19", 3, dropout, freeze_features, init)
        self.rotation = BranchedVGG19(4, image_size, dropout, freeze_features, init)

    def forward(self, image: torch.Tensor, crop: torch.Tensor | None = None):
        if crop is None:
            raise ValueError("crop: the parallel model needs the object-centred crop (the 'bounded image') as second input")
        return self.translation(image), self.rotation(crop)


def split_output(y: torch.Tensor, out_dim: int):
    """Raw head output → (t, q) for 7, t for 3, q (normalised) for 4."""
    if out_dim == 7:
        return y[:, :3], normalize_quat(y[:, 3:])
    if out_dim == 4:
        return normalize_quat(y)
    return y


def load_imagenet_weights(model: nn.Module, path) -> list[str]:
    """Load a local torchvision-format VGG state dict (``features.N.*``, ``classifier.{0,3}.*``).

    Convolutions and the two hidden FC layers are copied; the last FC (1000 classes) is skipped;
    for a branched model, the first FC gets the ImageNet weights in its main-stream columns.
    Applied to every VGG stream of a parallel model. Returns the loaded parameter names.

    Raises:
        FileNotFoundError / ValueError naming ``path`` (missing, unreadable, or not a VGG of the
        model's depth).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: ImageNet weights file not found")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001
        raise ValueError(f"{path}: cannot read a torch state dict ({exc})") from exc
    if isinstance(state, dict) and "state_dict" in state:
        state = state["state_dict"]
    streams = [m for m in model.modules() if isinstance(m, VGGPose)]
    if not streams:
        raise ValueError("model: no VGG stream to load ImageNet weights into")
    loaded: list[str] = []
    with torch.no_grad():
        for prefix, stream in ((n + "." if n else "", m) for n, m in model.named_modules() if isinstance(m, VGGPose)):
            own = stream.state_dict()
            for key, value in state.items():
                if not (key.startswith("features.") or key.startswith("classifier.0.") or key.startswith("classifier.3.")):
                    continue
                if key not in own:
                    raise ValueError(f"{path}: key {key!r} does not exist in {stream.arch} — is it a VGG of another depth?")
                target = own[key]
                if key == "classifier.0.weight" and target.shape[1] > value.shape[1]:
                    target[:, : value.shape[1]].copy_(value)  # branched: main-stream columns
                elif target.shape != value.shape:
                    raise ValueError(f"{path}: {key} has shape {tuple(value.shape)}, the model expects {tuple(target.shape)}")
                else:
                    target.copy_(value)
                loaded.append(prefix + key)
    return loaded
