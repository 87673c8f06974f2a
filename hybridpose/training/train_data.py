"""What a regressor's training run learns from: the seeded train/validation split of a rendered
dataset (object-centred crops for keypoint models, full images and crops for the parallel model),
the photometric augmentations, and the description of the data a checkpoint records."""
from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import torch
from torch.utils.data import Dataset, Subset

from ..datasets.torch_dataset import PoseDataset, split_indices
from ..workers import usable_cores

if TYPE_CHECKING:  # the config lives with the training loop, which imports this module
    from .train import TrainConfig

log = logging.getLogger("hybridpose.training.train")


class _Paired(Dataset):
    """Full image and object-centred crop of the same sample (the parallel model's two inputs)."""

    def __init__(self, full: PoseDataset, crop: PoseDataset) -> None:
        self.full, self.crop = full, crop

    def __len__(self) -> int:
        return len(self.full)

    def __getitem__(self, k: int) -> dict:
        image = None if self.full.cached and self.crop.cached else self.full.rgb(k)  # decoded once for both inputs
        item = self.full.item(k, image)
        item["crop_image"] = self.crop.item(k, image)["image"]
        return item


def make_datasets(cfg: TrainConfig, keypoints_m=None) -> tuple[Dataset, Dataset]:
    """Seeded (train, val) subsets; for the parallel model each item also carries the crop.

    Keypoint models (``keypoints_m`` given) train on random label-consistent crops (the in-plane
    shift and scale augmentation; see :class:`PoseDataset` ``jitter``) and validate on the
    deterministic object-centred crop.
    """
    if keypoints_m is not None:
        crops = PoseDataset(cfg.data, size=cfg.image_size, crop=True, keypoints_m=keypoints_m, full_view=cfg.full_view)
        if cfg.cache_images:  # the decoded views: random crops differ every epoch and are cut from them
            crops.cache_sources(cfg.cache_images, workers=max(cfg.workers, usable_cores()))
        train_idx, val_idx = split_indices(len(crops), cfg.val_fraction, cfg.seed)
        return crops.subset(train_idx, jitter=cfg.augment), crops.subset(val_idx)
    inputs = [PoseDataset(cfg.data, size=cfg.image_size)]
    if cfg.model == "parallel-vgg19":
        inputs.append(PoseDataset(cfg.data, size=cfg.image_size, crop=True))
    if cfg.cache_images:
        for ds in inputs:
            ds.cache_images(cfg.cache_images, workers=max(1, cfg.workers))
    data: Dataset = _Paired(*inputs) if len(inputs) == 2 else inputs[0]
    train_idx, val_idx = split_indices(len(data), cfg.val_fraction, cfg.seed)
    return Subset(data, train_idx.tolist()), Subset(data, val_idx.tolist())


def make_augment():
    """Photometric augmentations that matter in space imagery (kornia, on (B, 3, H, W) in [0, 1]).

    Geometric ones are left out: a shift or rotation of the image changes the pose label.
    """
    import kornia.augmentation as K

    return torch.nn.Sequential(
        K.ColorJitter(brightness=0.3, contrast=0.3, p=0.8),
        K.RandomGamma(gamma=(0.6, 1.6), p=0.5),
        K.RandomGaussianBlur((5, 5), (0.1, 1.5), p=0.3),
        K.RandomGaussianNoise(mean=0.0, std=0.03, p=0.5),
    )


def dataset_info(root, obj=None) -> dict:
    """What the training data was: object name/diameter and camera (checked again at inference), its
    sun (``lighting``: the direction the light travels, camera frame, and the cone each image's sun
    was drawn in; what a keypoint model's sun turn aligns to) and its depths (``distance_range_m``:
    near, far metres along the optical axis; what the predictor's depth gate scales)."""
    from ..io import read_json

    config = Path(root) / "hybridpose.json"
    info = read_json(config) if config.is_file() else {}
    out = {"object": info.get("object"), "camera": info.get("camera")}
    sun = (info.get("lighting") or {}).get("sun_direction_cam")
    if sun is not None:
        out["lighting"] = {"sun_direction_cam": [float(x) for x in sun], "sun_cone_deg": float(info.get("sun_cone_deg", 0.0))}
    if info.get("distance_range_m") is not None:
        out["distance_range_m"] = [float(x) for x in info["distance_range_m"]]
    if obj is not None:
        out["diameter_m"] = float(obj.diameter)
    return out
