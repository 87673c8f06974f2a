"""Training precision and layout: bfloat16 only where the device computes it fast; the plan's timing
trains the way the training will."""
import pytest
import torch

from hybridpose.training import precision
from hybridpose.training.precision import channels_last, fast_bf16


@pytest.mark.parametrize("amx", [True, False])
def test_a_cpu_trains_in_bf16_only_with_amx(monkeypatch, amx):
    monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: amx, raising=False)
    assert fast_bf16(torch.device("cpu")) is amx


def test_a_torch_without_the_cpu_probe_trains_in_float32(monkeypatch):
    monkeypatch.delattr(torch.cpu, "_is_amx_tile_supported", raising=False)
    assert fast_bf16(torch.device("cpu")) is False
    assert fast_bf16(torch.device("meta")) is False


def test_channels_last_keeps_the_values_and_moves_the_layout():
    conv = torch.nn.Conv2d(3, 8, 3)
    before = conv.weight.detach().clone()
    assert channels_last(conv) is conv
    assert conv.weight.is_contiguous(memory_format=torch.channels_last) and not conv.weight.is_contiguous()
    assert torch.equal(conv.weight, before)


@pytest.mark.parametrize("amx", [True, False])
def test_the_plans_training_speed_is_timed_in_the_trainings_precision(monkeypatch, truss, amx):
    """measure_train_speed times the steps the fit's training will run: on its device, NHWC weights, and
    bf16 activations exactly where fast_bf16 turns the training's autocast on for that device."""
    import hybridpose.regressors.models as models
    from hybridpose.fit_plan import measure_train_speed

    asked = []
    monkeypatch.setattr(precision, "fast_bf16", lambda device: asked.append(device) or amx)
    seen = []
    real_build = models.build_model

    def spied_build(*a, **kw):
        net = real_build(*a, **kw)
        for m in net.modules():
            if isinstance(m, torch.nn.Conv2d):
                m.register_forward_hook(lambda mod, inp, out: seen.append(
                    (out.dtype, mod.weight.is_contiguous(memory_format=torch.channels_last))))
                break
        return net

    monkeypatch.setattr(models, "build_model", spied_build)
    assert measure_train_speed(truss) > 0
    assert seen and set(seen) == {(torch.bfloat16 if amx else torch.float32, True)}
    assert asked == [models.torch_device("auto")]  # the device the fit's training takes (TrainConfig.device)


def test_the_plans_training_speed_names_a_device_it_cannot_reach(truss):
    from hybridpose.fit_plan import measure_train_speed

    with pytest.raises(ValueError, match="device"):
        measure_train_speed(truss, device="tpu")
