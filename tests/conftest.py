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
