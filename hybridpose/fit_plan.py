"""How ``hybridpose fit`` spends its budget on this machine: views to render and epochs to train,
from speeds measured here (rendering before anything else, training again just before it starts).
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .geometry import Camera
from .objects import ObjectModel

# of the budget: training and test views. A quarter while training decoded every view's PNG each epoch;
# with the decoded views kept (cache_fits) an epoch takes half as long, and a quarter would have bought
# a 60-minute box fit 25 epochs of 9 000 views, where no fit gained past 8 (docs/decisions.md)
RENDER_SHARE = 0.35
TRAIN_SHARE = 0.55    # the training run; the rest: calibration, evaluation, margins
MAX_TRAIN_VIEWS = 40_000  # training views rendered at most: beyond, a budget goes to epochs
TEST_VIEWS = (60, 300)  # held-out views: at least, at most (half calibrate the covariance, half evaluate)
IMAGE_SIZE = 128  # the shipped keypoint network's crop side: a part's fit starts from its weights
TRAIN_BATCH = 32  # images a training step (also how a fit times one, to plan its budget)
# a training epoch's wall time over its bare forward + backward steps (augmentation, the loader cutting
# crops beside them, validation): three 60-minute box fits' epochs from decoded views took 1.07–1.49 × the
# float32 steps timed before them (the timing swings by a fifth from run to run: the training re-plans its
# epochs after each one, TrainConfig.fill_time). In bf16 (precision.fast_bf16) the steps shrink and the
# rest does not: a 60-minute box fit's epochs took 2.6 × its timed steps (7.1 ms an image against 2.7), so
# its first count was high (22 epochs planned, 13 run) until the first epoch's re-plan
TRAIN_OVERHEAD = 1.35  # with REPLAN_MARGIN, the slowest of those float32 epochs still fits the time planned
PLAN_MARGIN = 1.3  # the machine is rarely all ours: plan for this much slower than measured
# the training re-planned from its speed measured just before it starts: a 60-minute box fit planned at
# PLAN_MARGIN trained its 16 epochs in 32 of its 43 minutes
REPLAN_MARGIN = 1.1
CACHE_DISK_SHARE = 0.5  # of the free disk a fit's decoded training views may take (else decoded every epoch)
EVAL_RESERVE_MIN = 2.0  # kept after training for calibration and evaluation (under a minute for 300 views here)


@dataclass(frozen=True)
class FitPlan:
    """What ``fit`` will do within ``budget_min`` minutes on this machine.

    Attributes:
        budget_min: the budget. train_views, test_views: rendered views. epochs: training epochs
            planned (the run also stops at ``train_min``). train_min: the training run's time limit.
        render_s_per_view, train_s_per_view: measured on this machine before planning (rendering: wall
            seconds a view on the fit's render processes together).
        distance_range_m: the part's distances in the training views (metres, near, far).
    """

    budget_min: float
    train_views: int
    test_views: int
    epochs: int
    train_min: float
    render_s_per_view: float
    train_s_per_view: float
    distance_range_m: tuple[float, float]


def parse_budget(text) -> float:
    """``"60m"``, ``"1h"``, ``"1h30m"``, ``"90s"`` or a number of minutes → minutes (float)."""
    s = str(text).strip().lower()
    try:
        return float(s)
    except ValueError:
        pass
    parts = re.fullmatch(r"(?:(\d+(?:\.\d+)?)h)?(?:(\d+(?:\.\d+)?)m(?:in)?)?(?:(\d+(?:\.\d+)?)s)?", s)
    if not s or parts is None or not any(parts.groups()):
        raise ValueError(f"budget: expected a time like 60m, 1h, 1h30m or 90s, got {text!r}")
    h, m, sec = (float(g) if g else 0.0 for g in parts.groups())
    return 60 * h + m + sec / 60


NEAR_FILL, FAR_FILL = 1.0, 0.12  # the part's diameter as a share of the image's shorter side, near and far


def working_distances(obj: ObjectModel, camera: Camera) -> tuple[float, float]:
    """(near, far) metres at which the part's diameter spans the image's shorter side (``NEAR_FILL``:
    a part held up to the camera fills the frame) and ≈ 12 % of it — the range a CNN initialisation is
    asked to cover (the truss, 0.43 m across, with the default 640×480 camera: 0.54–4.5 m). A near end
    of 70 % of the side left ViSP's tea box 0.45 m from its camera (0.2 m across, 839-px focal length:
    77 % of the side) outside its own fit's range."""
    f = min(camera.fx, camera.fy)
    side = min(camera.width, camera.height)
    return float(f * obj.diameter / (NEAR_FILL * side)), float(f * obj.diameter / (FAR_FILL * side))


def measure_speeds(obj: ObjectModel, camera: Camera, views: int = 32, workers: int = 1,
                   **render_kw) -> tuple[float, float]:
    """(render s/view, training s/view) on this machine: the longer of two timed runs renders ``views``
    views more (on several ``workers``: one work unit a process more) and writes them as the training
    set will be (``render_kw``: the fit's own :func:`~hybridpose.datasets.render_random_dataset`
    settings — its photos, lights, shares — on its ``workers`` processes, so the render time is wall
    time a view with all of them: a software GL renderer already spreads one process over the cores,
    and a 2-process truss fit planned as twice one process's rate rendered at 1.1 times it; image,
    depth and masks in BOP files; the per-call start-up cancelled out by a shorter run, after an
    untimed one), and forward + backward
    passes of the ``default`` network on 128-px crops. Measured on six views without the fit's photos
    and sun range, a 60-minute box fit planned 0.024 s a view and rendered at 0.044–0.059: its quarter
    of the budget became half. Timed from the process's first render call, the GL and mesh set-up fell
    in the shorter run only: a truss fit measured 0.018 s a view and rendered at 0.05–0.06."""
    import tempfile

    from .datasets import render_random_dataset
    from .datasets.generate import CHECKPOINT_EVERY
    from .render import AppearanceSpec

    workers = max(1, int(workers))
    render_kw = {"appearance": AppearanceSpec("random"), "distance_range_m": working_distances(obj, camera),
                 "in_view": True, **render_kw, "workers": workers}
    # Several processes render only a job of more than one work unit, each process starting (an
    # interpreter, GL, the mesh) within the timed run: on a pool both runs give every process whole
    # units, the longer one twice as many, so that the start-ups cancel out (a 2-process box fit that
    # timed 2 views on one process against 34 on two planned 0.138 s a view and rendered at 0.042).
    counts = (2, 2 + views) if workers == 1 else (CHECKPOINT_EVERY * workers, 2 * CHECKPOINT_EVERY * workers)
    with tempfile.TemporaryDirectory() as tmp:
        render_random_dataset(Path(tmp) / "warm", obj, camera, 1, seed=0, **render_kw)
        spent = []
        for n in counts:
            t0 = time.perf_counter()
            render_random_dataset(Path(tmp) / f"n{n}", obj, camera, n, seed=0, **render_kw)
            spent.append(time.perf_counter() - t0)
    render_s = max(spent[1] - spent[0], 1e-3) / (counts[1] - counts[0])
    return render_s, measure_train_speed(obj)


def measure_train_speed(obj: ObjectModel, device="auto") -> float:
    """Training s/view on this machine now: forward + backward passes of the ``default`` network on
    128-px crops, × ``TRAIN_OVERHEAD`` for augmentation and validation beside the bare steps; on the
    device the training takes (``device``: as :func:`~hybridpose.regressors.models.torch_device` reads
    it; "auto", the fit's, is a CUDA GPU where torch sees one), in its layout and precision
    (:mod:`~hybridpose.training.precision`)."""
    import torch

    from .regressors.models import build_model, torch_device
    from .training.precision import channels_last, fast_bf16

    dev = torch_device(device)
    torch.manual_seed(0)
    net = channels_last(build_model("default", image_size=IMAGE_SIZE, keypoints_m=obj.keypoints)).to(dev)
    opt = torch.optim.Adam(net.parameters(), 1e-4)
    x = torch.rand(TRAIN_BATCH, 3, IMAGE_SIZE, IMAGE_SIZE, device=dev)
    bf16 = fast_bf16(dev)

    def step():
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=bf16):
            out = net(x)
        outs = out.values() if isinstance(out, dict) else out if isinstance(out, (tuple, list)) else [out]
        loss = sum(v.float().mean() for v in outs if isinstance(v, torch.Tensor))
        opt.zero_grad()
        loss.backward()
        opt.step()

    def synchronised():  # a GPU's steps are queued: the clock reads when they are done
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)
        return time.perf_counter()

    step()  # untimed: the first step allocates (timed with the others, it read 0.021 s a view, not 0.015)
    steps = 3
    t0 = synchronised()
    for _ in range(steps):
        step()
    return TRAIN_OVERHEAD * (synchronised() - t0) / (steps * TRAIN_BATCH)


def cache_fits(views: int, camera: Camera, folder) -> bool:
    """Whether ``views`` decoded training views (H × W × 3 bytes each) fit in ``CACHE_DISK_SHARE`` of the
    free disk under ``folder``: the fit's training then cuts its random crops from them
    (:meth:`~hybridpose.datasets.torch_dataset.PoseDataset.cache_sources`), which halved a 2-core CPU's epoch
    (65 s instead of 128 for 5 696 box views: decoding each PNG again took 10 ms of a core)."""
    import shutil

    return views * camera.width * camera.height * 3 <= CACHE_DISK_SHARE * shutil.disk_usage(folder).free


def make_plan(budget_min: float, render_s_per_view: float, train_s_per_view: float,
              distance_range_m: tuple[float, float]) -> FitPlan:
    """Views and epochs for ``budget_min``: ``RENDER_SHARE`` of it renders (``render_s_per_view``: wall
    seconds a view on the fit's render processes, :func:`measure_speeds`), ``TRAIN_SHARE`` trains;
    more views while an epoch over them still fits at least twice."""
    render_s = 60 * budget_min * RENDER_SHARE / PLAN_MARGIN
    views = int(render_s / max(render_s_per_view, 1e-4))
    test = int(np.clip(0.1 * views, *TEST_VIEWS))
    train_min = budget_min * TRAIN_SHARE
    # an epoch over the training views must fit at least twice in the training time
    fit_twice = int(60 * train_min / (2 * PLAN_MARGIN * max(train_s_per_view, 1e-4)))
    train = int(max(100, min(views - test, fit_twice, MAX_TRAIN_VIEWS)))
    epochs = max(1, int(60 * train_min / (PLAN_MARGIN * train * train_s_per_view)))
    return FitPlan(budget_min=float(budget_min), train_views=train, test_views=test, epochs=min(epochs, 200),
                   train_min=float(train_min), render_s_per_view=float(render_s_per_view),
                   train_s_per_view=float(train_s_per_view), distance_range_m=tuple(float(d) for d in distance_range_m))


def plan_training(plan: FitPlan, spent_min: float) -> FitPlan:
    """``plan`` with its training run re-planned once the views are rendered: the budget's time left
    after ``spent_min`` minutes (measuring and rendering, as long as they took) less
    ``EVAL_RESERVE_MIN``, and as many epochs as fit in it at ``REPLAN_MARGIN``. Planned up front at its
    fixed share (``TRAIN_SHARE``), the training left both stages' margins unused: a 60-minute box fit
    ended after 44. Never less than half the training time planned up front: a render stage that
    overran makes the fit overrun its budget rather than ship a network barely trained."""
    train_min = max(plan.budget_min - spent_min - EVAL_RESERVE_MIN, 0.5 * plan.train_min)
    epochs = int(60 * train_min / (REPLAN_MARGIN * plan.train_views * max(plan.train_s_per_view, 1e-4)))
    return replace(plan, train_min=float(train_min), epochs=int(np.clip(epochs, 1, 200)))
