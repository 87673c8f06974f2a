"""The paper's loss against hand-computed values; the VGG family's shapes and ImageNet key mapping."""
import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from hybridpose.regressors import (
    BranchedVGG19, ParallelVGG19, VGGPose, available_models, build_model, load_imagenet_weights,
)
from hybridpose.training.losses import pose_loss, quat_geodesic_angle

torch.manual_seed(0)


def test_loss_hand_computed():
    t_true = torch.tensor([[0.0, 0.0, 1.1]])
    t_pred = torch.tensor([[0.0, 0.0, 1.0]])
    q_true = torch.tensor([[math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]])  # 90° about z
    q_pred = torch.tensor([[2.0, 0.0, 0.0, 0.0]])  # identity, not normalised
    assert pose_loss(t_pred, q_pred, t_true, q_true).item() == pytest.approx(0.1 + 10 * math.pi / 2, rel=1e-6)
    assert pose_loss(t_pred, q_pred, t_true, -q_true, beta=1.0).item() == pytest.approx(0.1 + math.pi / 2, rel=1e-6)
    # 350° one way is 10° the other: the shorter way round
    q350 = torch.tensor([[math.cos(math.radians(175)), math.sin(math.radians(175)), 0.0, 0.0]])
    assert quat_geodesic_angle(q350, torch.tensor([[1.0, 0, 0, 0]])).item() == pytest.approx(math.radians(10), abs=1e-5)


def test_geodesic_angle_matches_scipy_and_has_finite_gradient():
    rng = np.random.default_rng(0)
    a, b = Rotation.random(64, random_state=1), Rotation.random(64, random_state=2)
    qa = torch.tensor(np.roll(a.as_quat(), 1, 1)) * torch.tensor(rng.choice([-1.0, 1.0], (64, 1)))
    qb = torch.tensor(np.roll(b.as_quat(), 1, 1))
    np.testing.assert_allclose(quat_geodesic_angle(qa, qb).numpy(), (a.inv() * b).magnitude(), atol=1e-6)
    q = torch.tensor([[1.0, 0.0, 0.0, 0.0]], requires_grad=True)
    pose_loss(torch.zeros(1, 3), q, torch.zeros(1, 3), torch.tensor([[1.0, 0.0, 0.0, 0.0]])).backward()
    assert torch.isfinite(q.grad).all()


def test_loss_bad_shapes():
    with pytest.raises(ValueError, match="q: expected \\(B, 4\\)"):
        pose_loss(torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(2, 4))
    with pytest.raises(ValueError, match="t_pred: expected \\(B, 3\\)"):
        pose_loss(torch.zeros(2, 4), torch.ones(2, 4), torch.zeros(2, 3), torch.ones(2, 4))


def test_model_registry():
    assert available_models() == ["branched-vgg19", "default", "keypoints", "parallel-vgg19", "vgg16", "vgg19"]
    with pytest.raises(ValueError, match="unknown 'resnet'"):
        build_model("resnet")


@pytest.mark.slow  # tens of seconds on a 2-core CPU: CI runs it in its slow step
@torch.no_grad()
def test_vgg_shapes_and_unit_quaternions():
    x = torch.rand(2, 3, 64, 64)
    for arch, n_conv in (("vgg16", 13), ("vgg19", 16)):
        m = VGGPose(arch).eval()
        assert sum(isinstance(l, torch.nn.Conv2d) for l in m.features) == n_conv
        t, q = m(x)
        assert t.shape == (2, 3) and q.shape == (2, 4)
        torch.testing.assert_close(q.norm(dim=1), torch.ones(2))
    b = BranchedVGG19(image_size=64).eval()
    assert b.branch[2].in_features == 128 * 8 * 8  # 2nd max-pool at S/4, then 2×2 max-pool
    t, q = b(x)
    assert t.shape == (2, 3) and q.shape == (2, 4)
    with pytest.raises(ValueError, match="expected 64×64"):
        b(torch.rand(1, 3, 96, 96))
    p = ParallelVGG19(image_size=64).eval()
    t, q = p(x, x)
    assert t.shape == (2, 3) and q.shape == (2, 4)
    with pytest.raises(ValueError, match="crop"):
        p(x)
    with pytest.raises(ValueError, match="image: expected \\(B, 3, H, W\\)"):
        VGGPose("vgg16")(torch.rand(3, 64, 64))


@pytest.mark.slow  # tens of seconds on a 2-core CPU: CI runs it in its slow step
@torch.no_grad()
def test_every_vgg_stream_sees_the_image_at_initialisation():
    # With torch's layer defaults the plain VGG streams' outputs differed across images by ~1e-9 m: no
    # image in the gradient, and training from scratch sat at the constant pose (experiment `vgg_init`)
    torch.manual_seed(0)
    x = torch.rand(4, 3, 64, 64)
    models = {"vgg16": VGGPose("vgg16"), "vgg19": VGGPose("vgg19"), "branched": BranchedVGG19(image_size=64),
              "parallel": ParallelVGG19(image_size=64)}
    for name, m in models.items():
        t, q = m.eval()(x, x) if name == "parallel" else m.eval()(x)
        assert t.std(0).max() > 1e-4 and q.std(0).max() > 1e-3, name
    conv = models["vgg19"].features[2]
    assert conv.bias.abs().max() == 0 and conv.weight.std() == pytest.approx((2 / (64 * 9)) ** 0.5, rel=0.05)  # He, fan-out
    # the branched model's classifier (built once at its final width) and branch start as torchvision's FCs do
    branched = models["branched"]
    for fc in (branched.classifier[0], branched.classifier[3], branched.branch[2]):
        assert fc.bias.abs().max() == 0 and fc.weight.std() == pytest.approx(0.01, rel=0.05)
    # the older start (`hybridpose train --vgg-init torch-default`): the image is all but lost
    t, _ = build_model("parallel-vgg19", image_size=64, init="torch-default").eval()(x, x)
    assert t.std(0).max() < 1e-6
    with pytest.raises(ValueError, match="init: expected one of torchvision, torch-default"):
        VGGPose("vgg16", init="he")


def test_paper_branch_size_at_224():
    b = BranchedVGG19(image_size=224)
    assert b.branch[2].in_features == 100352 and b.classifier[0].in_features == 25088 + 1024


def test_freeze_features_trains_head_only():
    m = VGGPose("vgg16", freeze_features=True)
    assert not any(p.requires_grad for p in m.features.parameters())
    assert all(p.requires_grad for p in m.classifier.parameters())


def test_imagenet_key_mapping(tmp_path):
    src = VGGPose("vgg16", out_dim=7)
    state = {k: v.clone() for k, v in src.state_dict().items() if not k.startswith("classifier.0.")}
    state["classifier.6.weight"] = torch.zeros(1000, 4096)  # ImageNet head: skipped
    state["classifier.6.bias"] = torch.zeros(1000)
    path = tmp_path / "vgg16_imagenet.pth"
    torch.save(state, path)
    dst = VGGPose("vgg16")
    loaded = load_imagenet_weights(dst, path)
    assert "features.0.weight" in loaded and "classifier.3.weight" in loaded and not any("classifier.6" in k for k in loaded)
    torch.testing.assert_close(dst.features[28].weight, src.features[28].weight)
    assert not torch.equal(dst.classifier[6].weight[:7], torch.zeros(7, 4096))
    vgg19 = {k: v for k, v in VGGPose("vgg19").state_dict().items() if k.startswith("features.")}
    torch.save(vgg19, tmp_path / "vgg19.pth")
    with pytest.raises(ValueError, match="another depth"):
        load_imagenet_weights(VGGPose("vgg16"), tmp_path / "vgg19.pth")
    with pytest.raises(FileNotFoundError, match="missing.pth"):
        load_imagenet_weights(dst, tmp_path / "missing.pth")
    (tmp_path / "bad.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="bad.pth: cannot read"):
        load_imagenet_weights(dst, tmp_path / "bad.pth")


@pytest.mark.slow
def test_imagenet_first_fc_goes_to_main_stream_columns_of_branched(tmp_path):
    src = VGGPose("vgg19")
    torch.save({k: v for k, v in src.state_dict().items() if k.startswith(("features.", "classifier.0."))}, tmp_path / "w.pth")
    p = ParallelVGG19(image_size=64)
    load_imagenet_weights(p, tmp_path / "w.pth")
    torch.testing.assert_close(p.rotation.classifier[0].weight[:, :25088], src.classifier[0].weight)
    torch.testing.assert_close(p.translation.classifier[0].weight, src.classifier[0].weight)


@pytest.mark.slow  # tens of seconds on a 2-core CPU: CI runs it in its slow step
@pytest.mark.parametrize("name", ["vgg16", "branched-vgg19", "parallel-vgg19"])
def test_gradcam_and_timing_of_every_direct_model(name, tmp_path):
    """`hybridpose eval`'s Grad-CAM sheet and bare-call timing work for each direct model (the branched one runs slices
    of its features, which once left a hook on the whole Sequential unfired)."""
    from hybridpose.core import Camera, Frame
    from hybridpose.training.evaluate import network_call_ms
    from hybridpose.training.gradcam import gradcam
    from hybridpose.regressors.predictor import CheckpointRegressor
    from hybridpose.regressors.checkpoints import save_checkpoint

    torch.manual_seed(0)
    build = {} if name == "vgg16" else {"image_size": 64}
    save_checkpoint(tmp_path / "ck.pt", {"config": {"model": name, "image_size": 64}, "build": build,
                                         "model": build_model(name, **build).state_dict()})
    reg = CheckpointRegressor(tmp_path / "ck.pt")
    image = np.random.default_rng(0).integers(0, 255, (96, 128, 3), dtype=np.uint8)
    img, cam = gradcam(reg, Frame(image, Camera.default().scaled("128x96"), 0.0))
    assert img.shape == (64, 64, 3) and cam.shape == (64, 64)
    assert np.isfinite(cam).all() and 0.0 <= cam.min() and cam.max() <= 1.0
    if name == "parallel-vgg19":  # the rotation stream's map (its hooks fired), on its bounded image, not the whole frame
        import cv2

        assert not np.array_equal(img, cv2.resize(image, (64, 64), interpolation=cv2.INTER_AREA))
    # the report's bare-call timing feeds every input the model takes (the parallel one's two streams)
    seen = []
    forward = reg.net.forward
    reg.net.forward = lambda *inputs: seen.append([tuple(x.shape) for x in inputs]) or forward(*inputs)
    network_call_ms(reg, calls=2, repeats=1)
    streams = 2 if name == "parallel-vgg19" else 1
    assert seen == [[(1, 3, 64, 64)] * streams] * 3   # a warm-up call, then the timed ones


@pytest.mark.slow  # tens of seconds on a 2-core CPU: CI runs it in its slow step
@pytest.mark.parametrize("name", ["parallel-vgg19", "default"])  # parallel: both VGG streams and the branch
def test_channels_last_layout_gives_the_same_outputs_and_gradients(name, truss):
    """Training puts the weights in NHWC (precision.channels_last); flattening, the branch and the
    two streams must read the same numbers as in NCHW."""
    from hybridpose.training.precision import channels_last

    torch.manual_seed(0)
    build = {"image_size": 64, **({"keypoints_m": truss.keypoints} if name == "default" else {})}
    ref = build_model(name, **build).eval()
    nhwc = channels_last(build_model(name, **build).eval())
    nhwc.load_state_dict(ref.state_dict())
    assert any(p.dim() == 4 and p.is_contiguous(memory_format=torch.channels_last) and not p.is_contiguous()
               for p in nhwc.parameters())
    x = torch.rand(2, 3, 64, 64)
    args = (x, x.flip(-1)) if name == "parallel-vgg19" else (x,)
    outs = [m(*args) for m in (ref, nhwc)]
    for a, b in zip(*outs):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
    weights = [torch.randn_like(v.float()) for v in outs[0]]  # |q| = 1: a sum of squares has no gradient
    for o in outs:
        sum((v.float() * w).sum() for v, w in zip(o, weights)).backward()
    # (a gradient that is zero by symmetry, e.g. a bias before a softmax, is compared with the largest)
    floor = 1e-3 * max(float(p.grad.norm()) for p in ref.parameters())
    for (n, a), b in zip(ref.named_parameters(), nhwc.parameters()):
        # float32 sums in another order, rounding grown through up to 16 layers: each gradient as a
        # whole within 1 % (a layout mistake moves it by its own size)
        assert (a.grad - b.grad).norm() <= 1e-2 * a.grad.norm() + floor, n


def test_parallel_model_crops_around_the_detected_object_or_else_its_translation(tmp_path, monkeypatch):
    """Without a roi the bounded image is the detected object's box × CROP_MARGIN (as it trained, on the
    true box); with nothing to detect, the projection of its own translation, sized by the diameter."""
    from hybridpose.core import Camera, Frame
    from hybridpose.geometry.crops import crop_box
    from hybridpose.regressors.detection import CROP_MARGIN
    from hybridpose.regressors.predictor import CheckpointRegressor
    from hybridpose.regressors.checkpoints import save_checkpoint

    torch.manual_seed(0)
    save_checkpoint(tmp_path / "ck.pt", {"config": {"model": "parallel-vgg19", "image_size": 64}, "build": {"image_size": 64},
                                         "model": build_model("parallel-vgg19", image_size=64).state_dict()})
    reg = CheckpointRegressor(tmp_path / "ck.pt")
    import hybridpose.regressors.direct as direct

    crops, crop = [], direct.crop_image
    monkeypatch.setattr(direct, "crop_image", lambda image, K, cx, cy, side, size:
                        crops.append((cx, cy, side)) or crop(image, K, cx, cy, side, size))
    t = np.array([0.05, -0.02, 0.8])  # the translation stream's estimate, fixed (an untrained one may point anywhere)
    monkeypatch.setattr(reg.net.translation, "forward", lambda x: torch.tensor(t, dtype=x.dtype)[None])
    cam = Camera.default().scaled("128x96")
    image = np.zeros((96, 128, 3), np.uint8)
    image[30:50, 40:70] = 200                                  # a lit object, 30 × 20 px
    m = reg.predict(Frame(image, cam, 0.0))
    np.testing.assert_allclose(m.pose.t, t, rtol=1e-6)
    np.testing.assert_allclose(crops[-1], crop_box((40, 30, 30, 20), CROP_MARGIN), atol=2.5)  # detection: ±1 px at half size
    reg.predict(Frame(image, cam, 0.0), roi=(10, 10, 20, 20))
    np.testing.assert_allclose(crops[-1], crop_box((10, 10, 20, 20), CROP_MARGIN))
    black = reg.predict(Frame(np.zeros_like(image), cam, 0.0))   # nothing to detect
    assert black.lost and black.pose is None  # zero biases on a black frame: a zero quaternion, lost (not NaN)
    np.testing.assert_allclose(crops[-1][:2], (cam.K @ (t / t[2]))[:2], atol=1e-3)
    assert crops[-1][2] == pytest.approx(CROP_MARGIN * max(cam.fx, cam.fy) * 0.5 / t[2], rel=1e-6)


def test_checkpoint_weights_that_do_not_fit_the_network_name_the_file(tmp_path):
    """The network is built without weights (meta device) and given the checkpoint's: a wrong shape or a missing
    tensor is refused naming the file, and a good checkpoint leaves no tensor without storage."""
    from hybridpose.regressors.predictor import CheckpointRegressor
    from hybridpose.regressors.checkpoints import save_checkpoint

    good = build_model("vgg16").state_dict()
    wrong_shape = {**good, "classifier.6.weight": torch.zeros(5, 4096)}
    missing = {k: v for k, v in good.items() if k != "classifier.6.bias"}
    for name, state, match in (("shape", wrong_shape, "size mismatch"), ("missing", missing, "Missing key")):
        save_checkpoint(tmp_path / f"{name}.pt", {"config": {"model": "vgg16", "image_size": 64}, "build": {}, "model": state})
        with pytest.raises(ValueError, match=f"(?s){name}.pt: weights do not fit the 'vgg16' network .*{match}"):
            CheckpointRegressor(tmp_path / f"{name}.pt")
    save_checkpoint(tmp_path / "good.pt", {"config": {"model": "vgg16", "image_size": 64}, "build": {}, "model": good})
    reg = CheckpointRegressor(tmp_path / "good.pt")
    assert all(not t.is_meta for t in [*reg.net.parameters(), *reg.net.buffers()])
    torch.testing.assert_close(reg.net.classifier[6].weight, good["classifier.6.weight"])
