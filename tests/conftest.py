import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest

from hybridpose.geometry import Camera
from hybridpose.objects import load_object


@pytest.fixture(scope="session")
def truss():
    return load_object("truss")


@pytest.fixture(scope="session")
def camera():
    return Camera.default()


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture(scope="session")
def tiny_checkpoint(truss, tmp_path_factory):
    """A `default`-architecture model trained for a few batches (mechanics, not accuracy), and the
    24 views (160×120) it was trained on, in ``.parent.parent / "ds"``."""
    from hybridpose.datasets import render_random_dataset
    from hybridpose.regressors.train import TrainConfig, train

    root = tmp_path_factory.mktemp("kp")
    render_random_dataset(root / "ds", truss, Camera.default().scaled(160), count=24, seed=0)
    cfg = TrainConfig(model="default", data=str(root / "ds"), out=str(root / "run"), epochs=1, batch=8,
                      lr=1e-3, image_size=64, patience=0, schedule="cosine")
    train(cfg, progress=False)
    return root / "run" / "best.pt"
