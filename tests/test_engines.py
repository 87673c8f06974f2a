"""Inference engines: ONNX Runtime must compute what torch does, follow torch's thread count, and be
refused or replaced with a clear reason where it cannot run."""
import logging
import sys

import pytest
import torch

from hybridpose.regressors.engines import ENGINES, OnnxRuntimeEngine, TorchEngine, keypoint_engine
from hybridpose.regressors.keypoint_net import KeypointNet
from hybridpose.regressors.models import fold_batch_norm
from hybridpose.regressors.predictor import CheckpointRegressor, shipped_checkpoint

pytest.importorskip("onnxruntime")


def _net(truss, twin_classes=4):
    torch.manual_seed(0)
    net = KeypointNet(truss.keypoints, width=8, image_size=64, twin_classes=twin_classes)
    for m in net.modules():  # batch-norm statistics a trained net would have (not 0/1)
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.2, 0.2)
            m.running_var.uniform_(0.5, 2.0)
    return fold_batch_norm(net.eval())


@pytest.mark.parametrize("twin_classes", [4, 0])
@pytest.mark.parametrize("batch", [1, 5])
def test_onnxruntime_engine_computes_what_torch_does(truss, twin_classes, batch):
    net = _net(truss, twin_classes)
    x = torch.rand(batch, 3, 64, 64, generator=torch.Generator().manual_seed(batch))
    uv_t, spread_t, twin_t = TorchEngine(net, torch.device("cpu"))(x)
    uv_o, spread_o, twin_o = OnnxRuntimeEngine(net, 64)(x)
    assert uv_o.shape == (batch, net.num_keypoints, 2) and uv_o.dtype == torch.float32
    torch.testing.assert_close(uv_o, uv_t, atol=1e-3, rtol=0)        # crop pixels
    torch.testing.assert_close(spread_o, spread_t, atol=1e-3, rtol=0)
    if twin_classes:
        torch.testing.assert_close(twin_o, twin_t, atol=1e-4, rtol=1e-4)
    else:
        assert twin_o is None and twin_t is None


def test_onnxruntime_sessions_follow_torchs_thread_count(truss):
    engine = OnnxRuntimeEngine(_net(truss), 64)
    before = torch.get_num_threads()
    try:
        for n in (1, 2, 1):
            torch.set_num_threads(n)
            engine(torch.rand(1, 3, 64, 64))
    finally:
        torch.set_num_threads(before)
    assert sorted(engine._sessions) == [1, 2]


def test_auto_engine_is_onnxruntime_on_the_cpu_and_falls_back_to_torch(truss, monkeypatch, caplog):
    net = _net(truss)
    assert keypoint_engine("auto", net, torch.device("cpu"), 64).name == "onnxruntime"
    assert keypoint_engine("torch", net, torch.device("cpu"), 64).name == "torch"
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # as if not installed
    with caplog.at_level(logging.INFO, logger="hybridpose.regressors.engines"):
        assert keypoint_engine("auto", net, torch.device("cpu"), 64).name == "torch"
    assert "needs the onnxruntime package" in caplog.text
    with pytest.raises(RuntimeError, match="pip install onnxruntime"):
        keypoint_engine("onnxruntime", net, torch.device("cpu"), 64)


def test_engine_bad_input(truss, tmp_path):
    net = _net(truss)
    with pytest.raises(ValueError, match="engine: expected one of"):
        keypoint_engine("tensorrt", net, torch.device("cpu"), 64)
    with pytest.raises(ValueError, match="runs on the CPU"):
        keypoint_engine("onnxruntime", net, torch.device("meta"), 64)
    with pytest.raises(ValueError, match="engine: expected one of"):
        CheckpointRegressor(shipped_checkpoint("default"), engine="fast")
    assert set(ENGINES) == {"auto", "torch", "onnxruntime", "onnxruntime-int8"}


def test_shipped_default_gives_the_same_pose_on_either_engine(truss):
    """The exact speed-up: both engines, one rendered view, the same measurement to float rounding."""
    from hybridpose.core import Frame
    from hybridpose.geometry import Camera, Pose
    from hybridpose.render import Renderer

    camera = Camera.default().scaled((320, 240))
    with Renderer(truss, camera) as r:
        frame = Frame(r.render(Pose.from_rotvec_t([0.5, -0.4, 0.3], [0.02, 0.01, 0.7])).rgb, camera, 0.0)
    m = {e: CheckpointRegressor(shipped_checkpoint("default"), engine=e).predict(frame) for e in ("torch", "onnxruntime")}
    assert m["onnxruntime"].pose is not None and m["torch"].pose is not None
    assert m["onnxruntime"].pose.allclose(m["torch"].pose, atol=1e-4)
    assert m["onnxruntime"].quality == pytest.approx(m["torch"].quality, abs=1e-4)
