"""The same contract over every registered regressor (the Measurement rules every fusion relies on):
a Measurement from the regressor's own source at the frame's time; ``lost == (pose is None)``; a pose
that is a rotation and a finite, positive semi-definite covariance; no NaN on a black frame; a bad
roi or frame refused with a clear error. The shipped `default` is also held to being right on an
in-view render; the others run untrained (a few batches, or fresh weights): the contract, not accuracy."""
import numpy as np
import pytest
import torch

from hybridpose.core import Frame, Measurement
from hybridpose.geometry import Camera, Pose
from hybridpose.metrics import rotation_error_deg
from hybridpose.registry import available, create

REGRESSORS = available("regressor")
DIRECT = ("vgg16", "vgg19", "branched-vgg19", "parallel-vgg19")


@pytest.fixture(scope="module")
def view(truss):
    from hybridpose.render import Renderer

    camera = Camera.default()
    pose = Pose.from_rotvec_t([0.6, -0.4, 0.3], [0.01, -0.01, 0.7])
    with Renderer(truss, camera) as r:
        image = r.render(pose, rng=0).rgb
    return Frame(image, camera, 0.25, 3), pose


@pytest.fixture(scope="module")
def tiny_keypoints(truss, tmp_path_factory):
    from hybridpose.datasets import render_random_dataset
    from hybridpose.training.train import TrainConfig, train

    root = tmp_path_factory.mktemp("kp48")
    render_random_dataset(root / "ds", truss, Camera.default().scaled(160), count=16, seed=1)
    train(TrainConfig(model="keypoints", data=str(root / "ds"), out=str(root / "run"), epochs=1, batch=8, lr=1e-3,
                      image_size=64, patience=0, schedule="cosine"), progress=False)
    return root / "run" / "best.pt"


def _regressor(name, truss, tmp_path, tiny_keypoints):
    if name == "default":
        return create("regressor", "default", object=truss, threads=1)
    if name == "keypoints":
        return create("regressor", "keypoints", checkpoint=tiny_keypoints, object=truss, threads=1)
    if name == "none":
        return create("regressor", "none", object=truss)
    from hybridpose.regressors.models import build_model
    from hybridpose.regressors.checkpoints import save_checkpoint

    torch.manual_seed(0)
    build = {} if name in ("vgg16", "vgg19") else {"image_size": 64}
    save_checkpoint(tmp_path / "ck.pt", {"config": {"model": name, "image_size": 64}, "build": build,
                                         "model": build_model(name, **build).state_dict()})
    return create("regressor", name, checkpoint=tmp_path / "ck.pt", object=truss, threads=1)


def _check(m: Measurement, name: str, frame: Frame) -> None:
    assert isinstance(m, Measurement) and m.source == f"regressor:{name}" and m.timestamp == frame.timestamp
    assert m.lost == (m.pose is None) and 0.0 <= m.quality <= 1.0
    assert np.all(np.isfinite(m.covariance)) and np.linalg.eigvalsh(m.covariance).min() >= -1e-12
    if m.pose is not None:
        assert np.allclose(m.pose.R @ m.pose.R.T, np.eye(3), atol=1e-6) and np.all(np.isfinite(m.pose.t))


def test_expected_backends_are_registered():
    assert set(DIRECT) | {"default", "keypoints"} <= set(REGRESSORS)


@pytest.mark.parametrize("name", REGRESSORS)
def test_every_regressor_keeps_the_measurement_contract(name, truss, view, tmp_path, tiny_keypoints):
    from hybridpose.contracts import check_backend

    reg = _regressor(name, truss, tmp_path, tiny_keypoints)
    check_backend("regressor", reg)
    frame, truth = view
    m = reg.predict(frame)
    _check(m, name, frame)
    _check(reg.predict(frame, roi=(160, 80, 320, 320)), name, frame)
    black = Frame(np.zeros_like(frame.image), frame.camera, 0.5, 4)
    _check(reg.predict(black), name, black)
    if name == "default":
        assert not m.lost and rotation_error_deg(m.pose, truth) < 5.0
    if name == "none":
        assert m.lost  # no network: the hybrid's keypoint memory alone finds the part
    for bad in ((0, 0, -5, 10), (1000, 1000, 10, 10), (np.nan, 0, 10, 10)):
        with pytest.raises(ValueError, match="roi"):
            reg.predict(frame, roi=bad)
    # a start's candidates: predict's measurement first, then at most `limit` more, each a measurement
    found = reg.candidates(frame, None, 3)
    assert 1 <= len(found) <= 4 and (found[0].pose is None) == m.lost
    if not m.lost:
        assert rotation_error_deg(found[0].pose, m.pose) < 1e-6
    for c in found:
        _check(c, name, frame)
    # where the regressor's other looks at the frame saw the object: poses, or None where it does not say
    assert found.sightings is None or all(isinstance(p, Pose) for p in found.sightings)
    if name == "default":
        assert isinstance(found.sightings, tuple)  # a keypoint network's passes
    assert len(reg.candidates(frame, None, 0)) == 1 and len(reg.candidates(frame, (160, 80, 320, 320), 3)) == 1
