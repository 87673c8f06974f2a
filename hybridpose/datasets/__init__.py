"""Datasets: BOP read/write (mm in files, metres in memory), labels.csv, rendering jobs, torch Dataset.

``torch_dataset`` is imported lazily (``from hybridpose.datasets.torch_dataset import PoseDataset``)
so that reading BOP data does not import torch, and the rendering jobs on first use so that neither
reading data nor a regressor's inference imports MuJoCo.
"""
from .bop import BopImage, BopScene, BopSceneWriter, find_scenes, pose_from_bop, pose_to_bop
from .labels import Label, read_labels, write_labels

__all__ = [
    "BopImage", "BopScene", "BopSceneWriter", "Label", "find_scenes", "pose_from_bop", "pose_to_bop",
    "read_labels", "render_random_dataset", "render_sequence_dataset", "write_labels",
]


def __getattr__(name: str):
    if name in ("render_random_dataset", "render_sequence_dataset"):
        from . import generate

        return getattr(generate, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
