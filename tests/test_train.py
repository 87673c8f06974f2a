"""Training loop mechanics on a tiny rendered dataset: checkpoints, resume, metrics, early stop, errors."""
import json

import numpy as np
import pytest
import torch
from torch import nn

from hybridpose.datasets import render_random_dataset
from hybridpose.geometry import Camera, Pose
from hybridpose.regressors import models
from hybridpose.regressors.vgg import normalize_quat
from hybridpose.training import train as train_module
from hybridpose.training.train import run_summary, train, TrainConfig
from hybridpose.regressors.checkpoints import load_checkpoint


class TinyPose(nn.Module):
    """A few-thousand-parameter stand-in so the loop runs in a second; the VGGs run in the slow test."""

    def __init__(self, **_):
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(3, 8, 3, stride=2), nn.ReLU(), nn.AdaptiveAvgPool2d(4), nn.Flatten(), nn.Linear(128, 7))

    def forward(self, x):
        y = self.net(x)
        return y[:, :3], normalize_quat(y[:, 3:])


@pytest.fixture(scope="module")
def data(truss, tmp_path_factory):
    out = tmp_path_factory.mktemp("train") / "ds"
    render_random_dataset(out, truss, Camera.default().scaled(64), count=20, seed=0)
    return out


@pytest.fixture
def tiny(monkeypatch):
    monkeypatch.setitem(models.MODELS, "tiny", TinyPose)


def test_train_writes_checkpoints_and_metrics_then_resumes(data, tmp_path, tiny):
    cfg = TrainConfig(model="tiny", data=str(data), out=str(tmp_path / "run"), epochs=2, batch=4, lr=1e-2,
                      image_size=32, patience=0)
    best = train(cfg, progress=False)
    assert set(best) >= {"val_loss", "rot_mean_deg", "rot_median_deg", "trans_mean_m", "epochs_run", "stopped"}
    assert best["stopped"] == "ran all 2 epochs" and best["epochs_run"] == 2 and best["early_stop"] is False
    hist = json.loads((tmp_path / "run" / "history.json").read_text())
    assert [r["epoch"] for r in hist] == [0, 1]
    assert [r["train_images"] for r in hist] == [16, 16]       # 20 views, 4 held out for validation
    # where an epoch's time went: waiting for the loader, training steps, then validation and writes
    assert all(0 <= r["loader_wait_s"] <= r["train_s"] <= r["epoch_s"] for r in hist)
    assert (tmp_path / "run" / "metrics.csv").read_text().startswith("epoch,train_loss,val_loss")
    ck = load_checkpoint(tmp_path / "run" / "last.pt")
    assert ck["epoch"] == 1 and ck["config"]["model"] == "tiny" and "optimizer" in ck
    best_ck = load_checkpoint(tmp_path / "run" / "best.pt")      # weights for eval/export, no resume state
    assert not {"optimizer", "scheduler", "torch_rng", "loader_rng"} & set(best_ck)
    assert {"config", "model", "build", "calibration", "history"} <= set(best_ck)
    # resume continues where it stopped, and matches an uninterrupted run exactly
    train(TrainConfig(**{**cfg.__dict__, "epochs": 3}), resume=True, progress=False)
    straight = TrainConfig(**{**cfg.__dict__, "epochs": 3, "out": str(tmp_path / "straight")})
    train(straight, progress=False)
    a = load_checkpoint(tmp_path / "run" / "last.pt")
    b = load_checkpoint(tmp_path / "straight" / "last.pt")
    assert a["epoch"] == b["epoch"] == 2
    for k in a["model"]:
        torch.testing.assert_close(a["model"][k], b["model"][k])
    assert not list((tmp_path / "run").glob("*.tmp"))


def test_checkpoints_every_n_epochs_hold_the_best_until_written(data, tmp_path, tiny, monkeypatch):
    """checkpoint_every=2: last.pt at epochs 2, 4 and the last; a better best.pt found in between is kept in host
    memory and written with it — the same files as writing every epoch (the runs are identical otherwise)."""
    import hybridpose.training.checkpoint_io as checkpoint_io

    writes = []
    real = checkpoint_io.save_checkpoint
    monkeypatch.setattr(checkpoint_io, "save_checkpoint", lambda path, payload: writes.append((path.name, payload["epoch"]))
                        or real(path, payload))
    base = dict(model="tiny", data=str(data), epochs=5, batch=4, lr=1e-2, image_size=32, patience=0, augment=False)
    train(TrainConfig(**base, out=str(tmp_path / "every"), checkpoint_every=1), progress=False)
    writes.clear()
    train(TrainConfig(**base, out=str(tmp_path / "sparse"), checkpoint_every=2), progress=False)
    assert [w for w in writes if w[0] == "last.pt"] == [("last.pt", 1), ("last.pt", 3), ("last.pt", 4)]
    # best.pt only just before a last.pt, holding an epoch no later than it (then once more: its calibration)
    assert writes[-1][0] == "best.pt" and all(writes[i + 1][0] == "last.pt" and epoch <= writes[i + 1][1]
                                              for i, (name, epoch) in enumerate(writes[:-1]) if name == "best.pt")
    for name in ("best.pt", "last.pt"):
        a, b = load_checkpoint(tmp_path / "every" / name), load_checkpoint(tmp_path / "sparse" / name)
        assert a["epoch"] == b["epoch"] and len(a["history"]) == len(b["history"])
        for k in a["model"]:
            torch.testing.assert_close(a["model"][k], b["model"][k], rtol=0, atol=0)
    # a run stopped by its time limit writes what it has, due or not
    writes.clear()
    train(TrainConfig(**base, out=str(tmp_path / "tl"), checkpoint_every=3, time_limit_min=1e-6), progress=False)
    assert writes == [("best.pt", 0), ("last.pt", 0), ("best.pt", 0)]
    # the image cache changes nothing but where the pixels come from
    train(TrainConfig(**base, out=str(tmp_path / "cached"), checkpoint_every=1, cache_images=str(tmp_path / "cache")),
          progress=False)
    assert list((tmp_path / "cache").glob("full_32x32.npy"))
    a, b = load_checkpoint(tmp_path / "every" / "last.pt"), load_checkpoint(tmp_path / "cached" / "last.pt")
    for k in a["model"]:
        torch.testing.assert_close(a["model"][k], b["model"][k], rtol=0, atol=0)
    with pytest.raises(ValueError, match="checkpoint_every"):
        TrainConfig(**base, out=str(tmp_path), checkpoint_every=0)


def test_loader_workers_start_after_this_process_used_opencv_threads(data, tmp_path):
    """A loader worker forked while OpenCV's thread pool was up hung setting its thread count (the image cache
    is built in this process): train() runs OpenCV single-threaded while its workers run, and puts it back.
    In a subprocess, so that a hang fails the test instead of stalling the suite."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(f"""
        import cv2, numpy as np, torch
        from torch import nn
        from hybridpose.regressors import models
        from hybridpose.regressors.vgg import normalize_quat
        from hybridpose.training.train import TrainConfig, train

        class Tiny(nn.Module):
            def __init__(self, **_):
                super().__init__()
                self.net = nn.Sequential(nn.Conv2d(3, 4, 3, stride=2), nn.AdaptiveAvgPool2d(2), nn.Flatten(), nn.Linear(16, 7))

            def forward(self, x):
                y = self.net(x)
                return y[:, :3], normalize_quat(y[:, 3:])

        models.MODELS["tiny"] = Tiny
        cv2.resize(np.zeros((2000, 2000, 3), np.uint8), (500, 500), interpolation=cv2.INTER_AREA)  # the pool is up
        threads = cv2.getNumThreads()
        train(TrainConfig(model="tiny", data={str(data)!r}, out={str(tmp_path / "run")!r}, epochs=1, batch=4,
                          image_size=32, workers=2, patience=0, cache_images={str(tmp_path / "cache")!r}), progress=False)
        assert cv2.getNumThreads() == threads
        print("trained")
    """)
    import os
    import signal

    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=240)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the hung loader workers too
        proc.communicate()
        pytest.fail("training with loader workers hung after OpenCV's thread pool ran")
    assert proc.returncode == 0 and "trained" in out, err[-2000:]


def test_metrics_of_a_run_resumed_across_versions_keep_every_column(tmp_path):
    """A run resumed by a version whose rows carry a new column still writes its CSV (blank where absent)."""
    from hybridpose.training.checkpoint_io import write_metrics

    write_metrics(tmp_path, [{"epoch": 0, "val_loss": 2.0}, {"epoch": 1, "val_loss": 1.5, "train_images": 16}])
    assert (tmp_path / "metrics.csv").read_text().splitlines() == ["epoch,val_loss,train_images", "0,2.0,", "1,1.5,16"]
    assert json.loads((tmp_path / "history.json").read_text())[1]["train_images"] == 16


def test_early_stop(data, tmp_path, tiny):
    cfg = TrainConfig(model="tiny", data=str(data), out=str(tmp_path / "es"), epochs=50, batch=4, lr=1e-12,
                      image_size=32, patience=2, augment=False)
    best = train(cfg, progress=False)
    ran = len(json.loads((tmp_path / "es" / "history.json").read_text()))
    assert ran < 50 and best["epochs_run"] == ran
    assert best["stopped"] == f"early stop after epoch {ran - 1}: no validation improvement for 2 epochs (--patience)"
    assert best["early_stop"] is True
    line = run_summary(best, tmp_path / "es")
    assert line.startswith(f"train: {ran} epochs recorded (early stop after epoch {ran - 1}") and "best.pt" in line
    assert run_summary({"epochs_run": 0, "stopped": "ran all 3 epochs"}, "r").startswith("train: no epoch ran")
    one = {**best, "epoch": 0, "epochs_run": 1, "stopped": "ran all 1 epoch"}
    assert run_summary(one, "r").startswith("train: 1 epoch recorded (ran all 1 epoch); best validation epoch 0")


def test_time_limit_stops_cleanly_and_amp_trains(data, tmp_path, tiny, caplog):
    cfg = TrainConfig(model="tiny", data=str(data), out=str(tmp_path / "tl"), epochs=5, batch=4, lr=1e-2,
                      image_size=32, patience=0, amp=True, time_limit_min=1e-6)
    with caplog.at_level("INFO", logger="hybridpose.training.train"):
        best = train(cfg, progress=False)
    assert "time limit: stopping after epoch 0 of 5" in caplog.text
    assert best["epochs_run"] == 1 and best["stopped"].startswith("time limit after epoch 0 of 5") and not best["early_stop"]
    hist = json.loads((tmp_path / "tl" / "history.json").read_text())
    assert len(hist) == 1 and all(map(torch.isfinite, torch.tensor([hist[0]["train_loss"], best["val_loss"]])))
    ck = load_checkpoint(tmp_path / "tl" / "best.pt")
    assert ck["config"]["amp"] and all(v.dtype == torch.float32 for v in ck["model"].values() if v.is_floating_point())
    with pytest.raises(ValueError, match="time_limit_min"):
        TrainConfig(model="tiny", data=str(data), out=str(tmp_path), time_limit_min=0)


def test_fill_time_replans_the_epochs_after_the_first_and_a_resume_keeps_them(data, tmp_path, tiny, monkeypatch):
    """fill_time: one epoch planned, a limit far beyond it: the run takes as many as the cap allows, the
    cosine schedule decays over them, the checkpoint records the count and a resume given the first guess keeps it."""
    monkeypatch.setattr(train_module, "MAX_FILL_EPOCHS", 3)
    cfg = TrainConfig(model="tiny", data=str(data), out=str(tmp_path / "fill"), epochs=1, batch=4, lr=1e-2,
                      image_size=32, patience=0, schedule="cosine", time_limit_min=10.0, fill_time=True)
    best = train(cfg, progress=False)
    assert best["epochs_run"] == 3 and best["stopped"] == "ran all 3 epochs"
    ck = load_checkpoint(tmp_path / "fill" / "last.pt")
    assert ck["config"]["epochs"] == 3 and ck["scheduler"]["T_max"] == 3
    lrs = [r["lr"] for r in json.loads((tmp_path / "fill" / "history.json").read_text())]
    assert lrs[0] == pytest.approx(1e-2) and lrs[0] > lrs[1] > lrs[2] > 1e-4
    again = train(cfg, resume=True, progress=False)
    assert again["epochs_run"] == 3 and again["stopped"] == "ran all 3 epochs"


def test_fill_time_shrinks_a_plan_the_first_epoch_shows_too_long():
    cfg = TrainConfig(model="default", data="d", out="o", epochs=50,
                      time_limit_min=2.0, fill_time=True)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(torch.optim.SGD([nn.Parameter(torch.zeros(1))], lr=1.0), 50)
    shorter = train_module._filled(cfg, 0.5, sched, None)
    assert shorter.epochs == 3 and sched.T_max == 3      # 2 min / (1.05 x 0.5 min)
    assert train_module._filled(cfg, 1e-9, None, None).epochs == train_module.MAX_FILL_EPOCHS
    assert train_module._filled(cfg, 0.5, None, None, done=5).epochs == 5  # never fewer than those run


def test_fill_time_replans_after_every_epoch_of_a_fresh_run_at_the_pace_so_far(data, tmp_path, tiny, monkeypatch):
    """A first epoch that also builds caches is slower than the rest: planned from it alone, 20-minute fits
    ended 2-4 minutes early. Each epoch of a fresh run re-plans from the mean pace so far."""
    seen = []

    def spy(cfg, epoch_min, sched, bar, done=1):
        seen.append(done)
        return cfg

    monkeypatch.setattr(train_module, "_filled", spy)
    cfg = TrainConfig(model="tiny", data=str(data), out=str(tmp_path / "each"), epochs=3, batch=4, image_size=32,
                      patience=0, time_limit_min=10.0, fill_time=True)
    train(cfg, progress=False)
    assert seen == [1, 2, 3]


def test_train_errors(data, tmp_path, tiny):
    with pytest.raises(ValueError, match="model: unknown 'resnet'"):
        TrainConfig(model="resnet", data=str(data), out=str(tmp_path))
    with pytest.raises(FileNotFoundError, match="dataset not found"):
        train(TrainConfig(model="tiny", data=str(tmp_path / "none"), out=str(tmp_path / "r")), progress=False)
    (tmp_path / "bad.pt").write_bytes(b"\x00" * 10)
    with pytest.raises(ValueError, match="bad.pt: corrupt or truncated checkpoint"):
        load_checkpoint(tmp_path / "bad.pt")


@pytest.mark.slow
def test_vgg16_one_step_on_cpu(data, tmp_path):
    cfg = TrainConfig(model="vgg16", data=str(data), out=str(tmp_path / "v"), epochs=1, batch=4, image_size=32,
                      freeze_features=True, max_batches=1)
    best = train(cfg, progress=False)
    assert np.isfinite(best["val_loss"])
    # the checkpoint it wrote is a working regressor
    from hybridpose.core import Camera, Frame
    from hybridpose.regressors.predictor import CheckpointRegressor

    from hybridpose.io import read_image

    reg = CheckpointRegressor(tmp_path / "v" / "best.pt")
    assert (reg.model_name, reg.image_size) == ("vgg16", 32)
    cam = Camera.default().scaled(64)
    image = read_image(next((data / "train").rglob("*.png")))
    m = reg.predict(Frame(image, cam, 0.0))   # after one step its answer may lie outside the image: then lost
    assert m.lost or (np.isfinite(m.pose.t).all() and np.isfinite(m.covariance).all())


@pytest.mark.slow  # tens of seconds on a 2-core CPU: CI runs it in its slow step
def test_ddp_two_cpu_processes_with_gloo(data, tmp_path):
    """`torchrun --nproc_per_node 2 -m hybridpose.training.train`: both ranks train, rank 0 writes."""
    import subprocess
    import sys

    out = tmp_path / "ddp"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--master_port", "29517",
           "-m", "hybridpose.training.train", "--model", "default", "--data", str(data), "--out", str(out),
           "--epochs", "2", "--batch", "4", "--image-size", "64", "--max-batches", "2", "--device", "cpu"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "DDP: rank 0 of 2" in res.stderr and "DDP: rank 1 of 2" in res.stderr
    ck = load_checkpoint(out / "last.pt")
    assert ck["epoch"] == 1 and not any(k.startswith("module.") for k in ck["model"])
    hist = json.loads((out / "history.json").read_text())
    assert [r["epoch"] for r in hist] == [0, 1]
    assert [r["train_images"] for r in hist] == [16, 16]     # both ranks' shards of the 16 training views


def test_init_from_copies_matching_weights_and_adds_new_layers(data, tmp_path):
    base = TrainConfig(model="default", data=str(data), out=str(tmp_path / "a"), epochs=1, batch=4, lr=1e-3,
                       image_size=64, patience=0, twin_loss=False, max_batches=2)
    train(base, progress=False)
    src = load_checkpoint(tmp_path / "a" / "last.pt")["model"]
    assert not any(k.startswith("twin_head") for k in src)
    tuned = TrainConfig(**{**base.__dict__, "out": str(tmp_path / "b"), "twin_loss": True, "max_batches": 0,
                           "init_from": str(tmp_path / "a" / "last.pt")})
    train(tuned, progress=False)  # no training step: the weights are the copied ones
    got = load_checkpoint(tmp_path / "b" / "last.pt")["model"]
    assert {k for k in got if k.startswith("twin_head")} == {"twin_head.weight", "twin_head.bias"}
    for k, v in src.items():
        torch.testing.assert_close(got[k], v)
    with pytest.raises(FileNotFoundError):
        train(TrainConfig(**{**tuned.__dict__, "init_from": str(tmp_path / "none.pt")}), progress=False)


def test_init_from_a_narrower_keypoint_net_widens_it(data, tmp_path, caplog):
    """`keypoints` (width 48) from a `default` (width 32) checkpoint: Net2WiderNet, not a fresh start."""
    from hybridpose.regressors.keypoint_net import widen_state_dict
    from hybridpose.training.checkpoint_io import WIDEN_NOISE

    base = TrainConfig(model="default", data=str(data), out=str(tmp_path / "a"), epochs=1, batch=4, lr=1e-3,
                       image_size=64, patience=0, twin_loss=False, max_batches=2)
    train(base, progress=False)
    src = load_checkpoint(tmp_path / "a" / "last.pt")["model"]
    wide = TrainConfig(**{**base.__dict__, "model": "keypoints", "out": str(tmp_path / "b"), "twin_loss": True,
                          "max_batches": 0, "init_from": str(tmp_path / "a" / "last.pt")})
    train(wide, progress=False)  # no training step: the weights are the widened ones
    got = load_checkpoint(tmp_path / "b" / "last.pt")["model"]
    assert got["stem.0.weight"].shape[0] == 48 and got["layer4.1.conv2.weight"].shape[:2] == (384, 384)
    want = widen_state_dict(src, {k: got[k] for k in src}, noise=WIDEN_NOISE, seed=0)
    for k, v in want.items():
        torch.testing.assert_close(got[k], v)
    torch.testing.assert_close(got["stem.0.weight"][:32], src["stem.0.weight"])
    assert {k for k in got if k.startswith("twin_head")} == {"twin_head.weight", "twin_head.bias"}
    with caplog.at_level("WARNING", logger="hybridpose.training.train"):
        train(TrainConfig(**{**wide.__dict__, "out": str(tmp_path / "c"), "image_size": 96}), progress=False)
    assert "trained on 64 px crops, this run uses 96 px (--image-size 64 keeps its scale)" in caplog.text


def test_twin_weight_scales_the_twin_cross_entropy(data, tmp_path):
    """loss(w) = keypoint loss + w · CE(twin logits, best labelling); checked against the two terms."""
    from hybridpose.regressors.keypoint_net import KeypointNet, keypoint_loss
    from hybridpose.training.train_steps import batch_loss

    torch.manual_seed(0)
    net = KeypointNet(torch.rand(6, 3).numpy(), width=8, image_size=64, twin_classes=3).eval()
    batch = {"image": torch.rand(4, 3, 64, 64), "kp2d": torch.rand(4, 3, 6, 2) * 63}
    with torch.no_grad():
        uv, spread, twin = net(batch["image"], with_twin=True)
        kp, best = keypoint_loss(uv, spread, batch["kp2d"], 64, return_best=True)
        ce = torch.nn.functional.cross_entropy(twin, best)
        for w in (0.0, 0.1, 2.5):
            torch.testing.assert_close(batch_loss(net, batch, "cpu", 10.0, w), kp + w * ce)
    with pytest.raises(ValueError, match="twin_weight: expected a finite weight ≥ 0, got -1"):
        TrainConfig(model="default", data=str(data), out=str(tmp_path), twin_weight=-1)


def test_cli_options_reach_the_config():
    import argparse

    from hybridpose.training.train import TWIN_CE_WEIGHT, add_train_arguments, config_from_args

    p = argparse.ArgumentParser()
    add_train_arguments(p)
    cfg = config_from_args(p.parse_args(["--model", "default", "--data", "d", "--out", "o", "--twin-weight", "1.5",
                                         "--time-limit", "30"]))
    assert (cfg.twin_weight, cfg.time_limit_min, cfg.image_size, cfg.lr) == (1.5, 30.0, 128, 1e-3)
    default = config_from_args(p.parse_args(["--model", "vgg16", "--data", "d", "--out", "o"]))
    assert (default.twin_weight, default.image_size, default.lr, default.schedule) == (TWIN_CE_WEIGHT, 224, 1e-4, "constant")
    assert default.vgg_init == "torchvision"
    old = config_from_args(p.parse_args(["--model", "vgg16", "--data", "d", "--out", "o", "--vgg-init", "torch-default"]))
    assert old.vgg_init == "torch-default"
    with pytest.raises(ValueError, match="vgg_init: expected one of torchvision, torch-default"):
        TrainConfig(model="vgg16", data="d", out="o", vgg_init="kaiming")


def test_validation_errors_of_a_symmetric_part_go_to_the_nearest_equivalent_pose():
    """What no image can tell apart is not an error: the truth is replaced by the equivalent pose
    nearest the prediction (a box's half-turns), and left alone for an asymmetric part."""
    import trimesh
    import torch

    from hybridpose.objects import ObjectModel
    from hybridpose.training.losses import quat_geodesic_angle
    from hybridpose.training.train_steps import nearest_twin

    box = ObjectModel("box", trimesh.creation.box(extents=(0.2, 0.12, 0.08)))
    truth = Pose.from_rotvec_t([0.3, -0.2, 0.1], [0.05, 0.0, 0.8])
    turned = truth @ box.symmetries[0]
    t_true = torch.tensor([truth.t], dtype=torch.float32)
    q_true = torch.tensor([truth.quat_wxyz], dtype=torch.float32)
    t_pred = torch.tensor([turned.t], dtype=torch.float32)
    q_pred = torch.tensor([turned.quat_wxyz], dtype=torch.float32)
    assert float(quat_geodesic_angle(q_pred, q_true)) > 3.0
    t_eq, q_eq = nearest_twin(t_pred, q_pred, t_true, q_true, box.symmetries)
    assert float(quat_geodesic_angle(q_pred, q_eq)) < 1e-3 and float((t_pred - t_eq).norm()) < 1e-5
    t_same, q_same = nearest_twin(t_pred, q_pred, t_true, q_true, ())
    assert torch.equal(q_same, q_true)
