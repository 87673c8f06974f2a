import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest
import trimesh

from hybridpose.geometry import Camera
from hybridpose.objects import ObjectModel, load_object


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
    from hybridpose.training.train import TrainConfig, train

    root = tmp_path_factory.mktemp("kp")
    render_random_dataset(root / "ds", truss, Camera.default().scaled(160), count=24, seed=0)
    cfg = TrainConfig(model="default", data=str(root / "ds"), out=str(root / "run"), epochs=1, batch=8,
                      lr=1e-3, image_size=64, patience=0, schedule="cosine")
    train(cfg, progress=False)
    return root / "run" / "best.pt"


@pytest.fixture(scope="session")
def truss_depth_views(truss, camera):
    """Six random views of the truss (0.6–1.0 m, seed 7) and MuJoCo's depth of each: [(pose, (H, W)
    float32 metres)], the oracle of the rasters' visibility tests."""
    from hybridpose.geometry import Pose
    from hybridpose.render import Renderer

    rng = np.random.default_rng(7)
    views = []
    with Renderer(truss, camera) as r:
        for _ in range(6):
            pose = Pose.from_rotvec_t(rng.normal(size=3), np.r_[rng.uniform(-0.05, 0.05, 2), rng.uniform(0.6, 1.0)])
            views.append((pose, r.render(pose, rng=0).depth))
    return views


@pytest.fixture(scope="session")
def print_on_cube():
    """A function: the 6-cm cube with ``image`` ((h, w, 3) uint8 RGB) printed on it, each face one cell
    of the image's 3 × 2 grid; keyword arguments go to :class:`~hybridpose.objects.ObjectModel`."""
    def make(image, **kw):
        mesh = trimesh.creation.box((0.06, 0.06, 0.06))
        uv = np.zeros((len(mesh.faces), 3, 2))
        for k, normal in enumerate(np.asarray(mesh.face_normals)):
            axis = int(np.argmax(np.abs(normal)))
            cell = 2 * axis + (normal[axis] > 0)
            a, b = [i for i in range(3) if i != axis]
            local = (mesh.vertices[mesh.faces[k]][:, [a, b]] + 0.03) / 0.06          # 0..1 across the face
            uv[k] = (np.c_[(cell % 3 + local[:, 0]) / 3, (cell // 3 + local[:, 1]) / 2]) * 0.98 + 0.01
        return ObjectModel("printed-cube", mesh, texture=image, face_uv=uv, **kw)

    return make
