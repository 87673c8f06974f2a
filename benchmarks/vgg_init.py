"""Why the paper's VGG models sat at the constant pose when trained from scratch: their initialisation.

Until session 34 the VGG models kept torch's per-layer defaults, which scale each ReLU layer's output
variance by about 1/6: after VGG-19's 16 convolutions the features hold little but the biases, so every
image gives the same output and the gradient carries no image. On the lent GPUs the plain VGG-16/19 sat
at the constant pose for 10 epochs (session 30) and the parallel model's translation stream for all of
100 (session 34). They now start as torchvision's VGG does (``hybridpose.regressors.vgg.init_vgg_weights``:
He-normal convolutions, N(0, 0.01²) linear layers, zero biases). For each VGG model, both ways:

1. **image signal at initialisation**: on ``--views`` real test views at 224 px (the rotation streams
   fed the crop around the true box, as in training), the spread of the outputs across views: the
   largest per-component standard deviation of the raw translation (m) and of the unit quaternion;
2. **fit one batch**: ``--fit-model`` (default the plain VGG-19, the worst case) trained on ``--views``
   views at ``--fit-size`` px for ``--steps`` Adam steps (lr 1e-4, the paper's loss with β = 10,
   dropout off: the question is whether the gradient reaches the image, not generalisation): the loss
   against the constant-pose loss on the same views (the labels' mean translation and mean rotation),
   which is where a network that ignores the image stays.

Usage:
    python benchmarks/vgg_init.py --data data/truss_test100 [--views 16] [--fit-size 64] [--steps 40]

Writes ``results/vgg_init.json`` and the "vgg-init" section of RESULTS.md.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from torch import nn

from _common import environment, publish
from hybridpose.datasets.torch_dataset import PoseDataset
from hybridpose.regressors.losses import pose_loss
from hybridpose.regressors.models import build_model

INITS = ("torch-default", "torchvision")  # hybridpose.regressors.vgg.VGG_INITS, old start first
MODELS = ("vgg16", "vgg19", "branched-vgg19", "parallel-vgg19")


def build(model: str, init: str, size: int, dropout: float = 0.5) -> nn.Module:
    """``model`` at ``size`` px, its weights started as ``init`` says (``hybridpose train --vgg-init``)."""
    kw = {"image_size": size} if model in ("branched-vgg19", "parallel-vgg19") else {}
    return build_model(model, dropout=dropout, init=init, **kw)


def views(data: str, n: int, size: int) -> dict:
    """The first ``n`` views at ``size`` px: full frames, crops around the true box, labels."""
    full = [PoseDataset(data, size=size)[k] for k in range(n)]
    crops = [PoseDataset(data, size=size, crop=True)[k] for k in range(n)]
    return {"image": torch.stack([v["image"] for v in full]), "crop": torch.stack([v["image"] for v in crops]),
            "t": torch.stack([v["t"] for v in full]), "q": torch.stack([v["q"] for v in full])}


def run(m: nn.Module, model: str, batch: dict):
    return m(batch["image"], batch["crop"]) if model == "parallel-vgg19" else m(batch["crop"] if model == "branched-vgg19" else batch["image"])


@torch.no_grad()
def image_signal(model: str, init: str, batch: dict) -> dict:
    torch.manual_seed(0)
    m = build(model, init, batch["image"].shape[-1]).eval()
    t, q = run(m, model, batch)
    return {"t_spread_m": float(t.std(0).max()), "q_spread": float(q.std(0).max())}


def constant_pose_loss(batch: dict) -> float:
    """The paper's loss of the labels' mean translation and mean rotation on every view: the level of a
    network that ignores the image."""
    # scipy's rotation mean (the chordal one, as benchmarks/short_runs.py's constant pose); its quaternions are (x, y, z, w)
    q_mean = torch.tensor(np.roll(Rotation.from_quat(np.roll(batch["q"].double().numpy(), -1, axis=1)).mean().as_quat(), 1),
                          dtype=torch.float32)
    n = len(batch["q"])
    return float(pose_loss(batch["t"].mean(0).expand(n, 3), q_mean.expand(n, 4), batch["t"], batch["q"]))


def fit_batch(model: str, init: str, batch: dict, steps: int) -> dict:
    torch.manual_seed(0)
    m = build(model, init, batch["image"].shape[-1], dropout=0.0).train()
    opt = torch.optim.Adam(m.parameters(), lr=1e-4)
    losses, t0 = [], time.perf_counter()
    for _ in range(steps):
        t, q = run(m, model, batch)
        loss = pose_loss(t, q, batch["t"], batch["q"])
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    return {"losses": losses, "final_loss": float(np.mean(losses[-5:])), "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True, help="rendered views with labels (e.g. data/truss_test100)")
    ap.add_argument("--views", type=int, default=16)
    ap.add_argument("--fit-model", default="vgg19", choices=MODELS)
    ap.add_argument("--fit-size", type=int, default=64, help="px of the fitted views (a multiple of 32)")
    ap.add_argument("--steps", type=int, default=40)
    args = ap.parse_args()
    torch.set_num_threads(2)

    at_224 = views(args.data, args.views, 224)
    signal = {model: {init: image_signal(model, init, at_224) for init in INITS} for model in MODELS}
    small = views(args.data, args.views, args.fit_size)
    constant = constant_pose_loss(small)
    fits = {init: fit_batch(args.fit_model, init, small, args.steps) for init in INITS}

    payload = {"environment": environment(), "args": vars(args), "image_signal": signal,
               "fit": {"model": args.fit_model, "constant_pose_loss": constant, **fits}}
    lines = [f"## VGG initialisation and the image signal (`python benchmarks/vgg_init.py --data {args.data}`)", "",
             f"{args.views} views of `{args.data}`; *torch-default*: torch's layer initialisation (the VGG models until "
             "session 34), *torchvision*: `init_vgg_weights` (now theirs). Spread: the largest per-component standard "
             "deviation across the views of each output at initialisation (224 px, eval mode; the branched model and "
             "the parallel model's rotation stream fed the crop around the true box).", "",
             "| model | translation spread m: torch-default → torchvision | quaternion spread: torch-default → torchvision |",
             "|---|---|---|"]
    for model in MODELS:
        a, b = signal[model]["torch-default"], signal[model]["torchvision"]
        lines.append(f"| {model} | {a['t_spread_m']:.1e} → {b['t_spread_m']:.1e} | {a['q_spread']:.1e} → {b['q_spread']:.1e} |")
    lines += ["", f"Fitting one batch: `{args.fit_model}` on the same {args.views} views at {args.fit_size} px, "
              f"{args.steps} Adam steps (lr 1e-4, the paper's loss, β = 10, dropout off). A network that ignores the "
              f"image cannot go below the constant-pose loss, **{constant:.3f}** on these views.", "",
              "| initialisation | loss after 1 step | after 10 | after 20 | last 5 steps (mean) | s/step |", "|---|---|---|---|---|---|"]
    for init in INITS:
        f = fits[init]
        lines.append(f"| {init} | {f['losses'][0]:.3f} | {f['losses'][min(9, args.steps - 1)]:.3f} | "
                     f"{f['losses'][min(19, args.steps - 1)]:.3f} | {f['final_loss']:.3f} | {f['seconds'] / args.steps:.2f} |")
    env = payload["environment"]
    lines += ["", f"git {env['git']}, {env['cpu_model']} ({', '.join(env['isa'])}), 2 threads."]
    publish("vgg_init", "vgg-init", payload, lines)


if __name__ == "__main__":
    main()
