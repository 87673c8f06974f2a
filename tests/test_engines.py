"""Inference engines: ONNX Runtime must compute what torch does, follow torch's thread count, and be
refused or replaced with a clear reason where it cannot run."""
import logging
import sys
import time

import numpy as np
import pytest
import torch

from hybridpose.core import Frame
from hybridpose.geometry import Camera

from hybridpose.regressors.engines import ENGINES, OnnxRuntimeEngine, TorchEngine, keypoint_engine
from hybridpose.regressors.keypoint_net import KeypointNet
from hybridpose.regressors.models import fold_batch_norm
from hybridpose.regressors.predictor import CheckpointRegressor
from hybridpose.regressors.checkpoints import shipped_checkpoint

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
    assert sorted(engine.onnx.sessions) == [1, 2]
    # no spinning threads: a regressor's several sessions would fight over the cores (2 threads took 2x 1 thread's time)
    for session in engine.onnx.sessions.values():
        assert session.get_session_options().get_session_config_entry("session.intra_op.allow_spinning") == "0"


def test_auto_engine_is_onnxruntime_on_the_cpu_and_falls_back_to_torch(truss, monkeypatch, caplog):
    import hybridpose.regressors.engines as engines

    net = _net(truss)
    assert keypoint_engine("torch", net, torch.device("cpu"), 64).name == "torch"
    assert keypoint_engine("auto", net, torch.device("cpu"), 64).name == "onnxruntime"
    shipped = CheckpointRegressor(shipped_checkpoint("default"))     # the default: its 8-bit models
    assert shipped.engine.name == "onnxruntime-int8" and shipped.expert.engine.name == "onnxruntime-int8"
    runs = []

    def slow(x):  # an engine whose every call takes at least 2 ms
        runs.append(x.shape)
        time.sleep(0.002)

    assert engines.call_ms(slow, torch.zeros(1, 3, 64, 64), calls=2, repeats=2) >= 2.0
    assert len(runs) == 1 + 2 * 2, "one warm-up call, then repeats × calls"
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
    with pytest.raises(RuntimeError, match="ONNX Runtime cannot run the network"):
        OnnxRuntimeEngine(net, 64, model=b"not an onnx model")
    assert set(ENGINES) == {"auto", "torch", "onnxruntime", "onnxruntime-int8"}


def test_shipped_default_gives_the_same_pose_on_either_engine(truss):
    """The exact speed-up: both engines, one rendered view, the same measurement to float rounding."""
    from hybridpose.geometry import Pose
    from hybridpose.render import Renderer

    camera = Camera.default().scaled((320, 240))
    with Renderer(truss, camera) as r:
        frame = Frame(r.render(Pose.from_rotvec_t([0.5, -0.4, 0.3], [0.02, 0.01, 0.7])).rgb, camera, 0.0)
    m = {e: CheckpointRegressor(shipped_checkpoint("default"), engine=e).predict(frame) for e in ("torch", "onnxruntime")}
    assert m["onnxruntime"].pose is not None and m["torch"].pose is not None
    assert m["onnxruntime"].pose.allclose(m["torch"].pose, atol=1e-4)
    assert m["onnxruntime"].quality == pytest.approx(m["torch"].quality, abs=1e-4)


def test_quantize_writes_an_8bit_model_the_int8_engine_runs(tiny_checkpoint, tmp_path):
    from hybridpose.training.quantize import int8_path, quantize_checkpoint, read_record

    ck = tmp_path / "net.pt"
    ck.write_bytes(tiny_checkpoint.read_bytes())
    data = tiny_checkpoint.parent.parent / "ds"
    rec = quantize_checkpoint(ck, data, crops=12)
    out = int8_path(ck)
    assert out == tmp_path / "net.int8.onnx" and rec["path"] == str(out) and out.is_file()
    assert not list(tmp_path.glob("*.tmp")) and (out.stat().st_mode & 0o044) == 0o044  # renamed, readable
    assert read_record(out)["crops"] == rec["crops"] == 12 and len(rec["checkpoint_sha256"]) == 64
    f32 = CheckpointRegressor(ck, engine="onnxruntime")
    i8 = CheckpointRegressor(ck, engine="onnxruntime-int8")
    assert i8.engine.name == "onnxruntime-int8" and len(out.read_bytes()) < 0.5 * len(f32.engine.model)
    x = torch.rand(3, 3, f32.image_size, f32.image_size, generator=torch.Generator().manual_seed(0))
    (uv8, spread8, twin8), (uv, spread, twin) = i8.engine(x), f32.engine(x)
    assert uv8.shape == uv.shape and spread8.shape == spread.shape and twin8.shape == twin.shape
    assert torch.isfinite(uv8).all() and torch.isfinite(spread8).all()
    assert (uv8 - uv).abs().mean() < 0.05 * f32.image_size   # 8-bit noise, not another network
    cam = Camera.default().scaled(160)
    m = i8.predict(Frame(np.zeros((cam.height, cam.width, 3), np.uint8), cam, 0.0))
    assert m.lost  # the whole path runs on it (nothing in a black frame)


def test_int8_engine_refuses_a_missing_stale_or_foreign_file(tiny_checkpoint, tmp_path, capsys):
    from hybridpose.cli import main
    from hybridpose.training.quantize import int8_path, read_record

    ck = tmp_path / "net.pt"
    ck.write_bytes(tiny_checkpoint.read_bytes())
    with pytest.raises(ValueError, match="no 8-bit model .*hybridpose quantize"):
        CheckpointRegressor(ck, engine="onnxruntime-int8")
    assert main(["quantize", "--checkpoint", str(ck), "--data", str(tiny_checkpoint.parent.parent / "ds"),
                 "--crops", "4"]) == 0
    assert "net.int8.onnx" in capsys.readouterr().out
    from hybridpose.regressors.checkpoints import load_checkpoint, save_checkpoint

    state = load_checkpoint(ck)
    state["model"] = {k: v * 1.01 if v.is_floating_point() else v for k, v in state["model"].items()}
    save_checkpoint(ck, state)                              # retrained since it was quantized
    with pytest.raises(ValueError, match="quantized from another"):
        CheckpointRegressor(ck, engine="onnxruntime-int8")
    int8_path(ck).write_bytes(b"not a model")
    with pytest.raises(ValueError, match="not an ONNX model"):
        read_record(int8_path(ck))
    assert main(["quantize", "--checkpoint", str(ck), "--data", str(tmp_path), "--crops", "0"]) == 2
    assert "crops: expected at least 1" in capsys.readouterr().err
    save_checkpoint(tmp_path / "vgg.pt", {"config": {"model": "vgg16"}, "model": {}, "build": {}})
    assert main(["quantize", "--checkpoint", str(tmp_path / "vgg.pt"), "--data", str(tmp_path)]) == 2
    assert "holds a direct 'vgg16' model; only keypoint models" in capsys.readouterr().err


def test_auto_engine_runs_the_8bit_model_made_from_this_very_checkpoint(tiny_checkpoint, tmp_path, caplog):
    """engine='auto': the 8-bit file beside the checkpoint where it was made from it; float32 where there is
    none, or where the checkpoint changed since (a warning naming the file, not a silent older network)."""
    from hybridpose.training.quantize import quantize_checkpoint
    from hybridpose.regressors.checkpoints import load_checkpoint, save_checkpoint

    ck = tmp_path / "net.pt"
    ck.write_bytes(tiny_checkpoint.read_bytes())
    assert CheckpointRegressor(ck).engine.name == "onnxruntime"                # nothing beside it
    quantize_checkpoint(ck, tiny_checkpoint.parent.parent / "ds", crops=4)
    assert CheckpointRegressor(ck).engine.name == "onnxruntime-int8"
    assert CheckpointRegressor(ck, engine="onnxruntime").engine.name == "onnxruntime"   # asked for: float32
    state = load_checkpoint(ck)
    state["model"] = {k: v * 1.01 if v.is_floating_point() else v for k, v in state["model"].items()}
    save_checkpoint(ck, state)                                                   # retrained since
    with caplog.at_level(logging.WARNING, logger="hybridpose.regressors.engines"):
        assert CheckpointRegressor(ck).engine.name == "onnxruntime"
    assert "net.pt: its 8-bit model is not used" in caplog.text and "quantized from another" in caplog.text


def test_stale_int8_names_an_8bit_file_not_made_from_the_checkpoint(tiny_checkpoint, tmp_path):
    """What `hybridpose calibrate` checks after writing --out (in place, the 8-bit model goes stale)."""
    from hybridpose.training.quantize import int8_path, quantize_checkpoint, stale_int8
    from hybridpose.regressors.checkpoints import load_checkpoint, save_checkpoint

    ck = tmp_path / "net.pt"
    ck.write_bytes(tiny_checkpoint.read_bytes())
    assert stale_int8(ck) is None                                   # none beside it
    quantize_checkpoint(ck, tiny_checkpoint.parent.parent / "ds", crops=4)
    assert stale_int8(ck) is None                                   # made from it
    state = load_checkpoint(ck)
    state["calibration"] = {"scale": 2.0}
    save_checkpoint(ck, state)                                      # re-calibrated in place
    assert stale_int8(ck) == int8_path(ck)
    int8_path(ck).write_bytes(b"not a model")
    assert stale_int8(ck) == int8_path(ck)
