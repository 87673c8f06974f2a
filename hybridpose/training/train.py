"""Training of the CNN pose regressors: seeded 80/20 split, space-imagery augmentations, atomic
checkpoints every epoch, ``--resume``, early stop on validation, metrics to CSV/JSON. What the run
learns from lives in :mod:`.train_data`, one batch's loss and the validation pass in :mod:`.train_steps`.

``python -m hybridpose.training.train --model vgg19 --data data/truss_random --out runs/vgg19``
(the ``hybridpose train`` command calls :func:`train`).
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import DataLoader

from ..datasets.bop import dataset_object
from ..datasets.torch_dataset import single_threaded_worker
from ..regressors.checkpoints import RESUME_ONLY_KEYS, load_checkpoint
from .losses import DEFAULT_BETA
from ..regressors.verify import box_half_turns
from ..regressors.models import MODEL_DEFAULTS, available_models, build_model, model_kind, torch_device
from .train_data import dataset_info, make_augment, make_datasets
from .checkpoint_io import (calibrate_best, kw_for_checkpoint, load_matching_weights, snapshot, write_checkpoints,
                            write_metrics)
from .precision import channels_last
from .train_steps import batch_loss, evaluate
from ..regressors.unlabelled import symmetry_gauge
from ..regressors.vgg import VGG_INITS, load_imagenet_weights

log = logging.getLogger(__name__)

TWIN_CE_WEIGHT = 0.1  # the twin head's cross-entropy beside the keypoint loss (shipped default.pt)

SCHEDULES = ("constant", "cosine")
# fill_time: the epochs planned at this much slower than the epochs so far took on average (on a 2-core
# CPU later epochs ran 0.7-1.1 x the first; the time limit still stops a run that overruns)
FILL_MARGIN = 1.05
MAX_FILL_EPOCHS = 200  # fill_time never plans more (a tiny set on a fast machine)


@dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a training run (stored in every checkpoint).

    Attributes:
        model: name from :func:`available_models`. data: dataset root (BOP, from ``hybridpose render``).
        out: run directory (``last.pt``: everything ``resume`` needs; ``best.pt``: the best validation
            epoch's weights, calibration and history, no optimizer state; ``metrics.csv``, ``history.json``).
        epochs, batch: epochs and batch size. lr: Adam learning rate. beta: rotation weight of the loss.
        image_size: network input side, pixels. val_fraction, seed: the seeded split.
        patience: epochs without validation improvement before stopping (0 = never).
        augment: photometric augmentations (brightness, contrast, gamma, noise, blur).
        freeze_features: train the FC head only (the paper's baselines).
        vgg_init: how a VGG model's weights start, ``"torchvision"`` (``init_vgg_weights``: He-normal
            convolutions, small linear layers; the default) or ``"torch-default"``
            (torch's per-layer defaults, under which a plain VGG's output hardly depends on the image
            at the start: to reproduce older runs). Keypoint models ignore it.
        imagenet_weights: optional local torchvision-format VGG state dict.
        workers: DataLoader worker processes. device: "auto", "cpu" or "cuda".
        schedule: learning rate over epochs, "constant" (the paper) or "cosine" (to 1 % of lr).
        twin_loss: keypoint models — score each sample against the keypoints of the object and of
            its bounding-box half-turn twins and keep the best (see ``keypoint_loss``); validation
            errors are then measured to the nearest twin, the regressor's twin check resolves
            which one at inference.
        twin_weight: keypoint models with a twin head — weight of the head's cross-entropy (which
            twin the keypoints follow) beside the keypoint loss.
        init_from: start from this checkpoint's weights where names and shapes match (fine-tuning,
            e.g. adding the twin head to a trained model); new layers keep their initialisation.
        amp: bfloat16 autocast for the training forward pass (a GPU, or a CPU with AMX:
            ``precision.fast_bf16``, which ``fit`` asks; the validation, calibration and checkpoints
            stay float32).
        time_limit_min: stop after the epoch that would make the next one end past this many
            minutes of training (best.pt is calibrated as after a normal end); None = no limit.
        fill_time: with ``time_limit_min``, ``epochs`` is a first guess: after each epoch of a fresh run
            the epochs are re-planned to fill the limit at the pace so far (``FILL_MARGIN``), the cosine
            schedule following; the checkpoints keep the count for a resumed run. One process only (not DDP).
        cache_images: a directory where the direct (VGG) models' inputs are decoded and resized (or
            cropped) once and memory-mapped from then on (:meth:`PoseDataset.cache_images`; reused by
            later runs on the same views): 0.7 ms per item instead of 7.7 (1.8 instead of 10.1 for the
            parallel model's two) on a core; the GPU then no longer
            waits for the loaders. Keypoint models train on random crops: their decoded views are
            kept there instead (:meth:`PoseDataset.cache_sources`, 0.9 MB a 640×480 view), and each
            crop is cut from them. None: no cache.
        checkpoint_every: write ``last.pt`` every this many epochs (epoch numbers divisible by it,
            counted from 1), and when the run stops; a better ``best.pt`` found in between is kept
            in host memory and written with it. 1 (default): every epoch. A parallel VGG-19's
            ``last.pt`` is 4.6 GB (weights and Adam's two moments per weight, 22 s to write on a
            2-core VM): on a GPU, where an epoch of 20 000 views takes tens of seconds, writing it
            every epoch would take about as long as the training; an interrupted run then resumes
            from the last written epoch.
        full_view: keypoint models — the share of training crops that show the whole frame instead
            of a crop around the object (:class:`PoseDataset`): > 0 for a regressor that finds the
            object itself on any background (it then detects with ``detection="network"``).
    """

    model: str
    data: str
    out: str
    epochs: int = 100
    batch: int = 32
    lr: float = 1e-4
    beta: float = DEFAULT_BETA
    image_size: int = 224
    val_fraction: float = 0.2
    seed: int = 0
    patience: int = 10
    augment: bool = True
    freeze_features: bool = False
    vgg_init: str = "torchvision"
    imagenet_weights: str | None = None
    workers: int = 0
    device: str = "auto"
    schedule: str = "constant"
    twin_loss: bool = True
    twin_weight: float = TWIN_CE_WEIGHT
    init_from: str | None = None
    amp: bool = False
    time_limit_min: float | None = None
    fill_time: bool = False
    checkpoint_every: int = 1
    cache_images: str | None = None
    full_view: float = 0.0
    max_batches: int | None = field(default=None)  # cap per epoch (smoke runs)

    def __post_init__(self) -> None:
        if self.model not in available_models():
            raise ValueError(f"model: unknown {self.model!r}; available: {', '.join(available_models())}")
        for name in ("epochs", "batch", "image_size", "checkpoint_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected ≥ 1, got {getattr(self, name)}")
        if self.vgg_init not in VGG_INITS:
            raise ValueError(f"vgg_init: expected one of {', '.join(VGG_INITS)}, got {self.vgg_init!r}")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"schedule: expected one of {SCHEDULES}, got {self.schedule!r}")
        if self.lr <= 0 or not math.isfinite(self.lr):
            raise ValueError(f"lr: expected a positive learning rate, got {self.lr}")
        if not (self.twin_weight >= 0 and math.isfinite(self.twin_weight)):
            raise ValueError(f"twin_weight: expected a finite weight ≥ 0, got {self.twin_weight}")
        if not 0.0 <= self.full_view <= 1.0:
            raise ValueError(f"full_view: expected a share of the training crops in [0, 1], got {self.full_view}")
        if self.time_limit_min is not None and not self.time_limit_min > 0:
            raise ValueError(f"time_limit_min: expected a positive number of minutes, got {self.time_limit_min}")


def _distributed(device: torch.device) -> tuple[int, int, torch.device]:
    """(rank, world size, device) — under ``torchrun`` (``WORLD_SIZE`` > 1) joins the process group:
    NCCL with one GPU per process, gloo on CPU."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1, device
    import torch.distributed as dist

    if device.type == "cuda":
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    return dist.get_rank(), world, device


def train(cfg: TrainConfig, resume: bool = False, progress: bool = True) -> dict:
    """Train ``cfg.model`` on ``cfg.data``; returns the best validation epoch's metrics with
    ``epochs_run``, ``stopped`` (why the run ended, in words) and ``early_stop`` (True where
    ``cfg.patience`` ended it).

    Under ``torchrun --nproc_per_node N`` the run is data-parallel (DDP): each process trains on
    its shard of every epoch with ``cfg.batch`` images per step (global batch N × batch); rank 0
    validates, writes checkpoints and metrics, and decides early stopping for all.
    """
    threads = cv2.getNumThreads()
    if cfg.workers > 0:
        # OpenCV single-threaded in this process before the loader workers fork: a worker forked while
        # OpenCV's thread pool was up (this process had resized or cropped images, e.g. building
        # --cache-images) hangs when it sets its own thread count
        cv2.setNumThreads(1)
    try:
        return _train(cfg, resume, progress)
    finally:
        cv2.setNumThreads(threads)


def _train(cfg: TrainConfig, resume: bool, progress: bool) -> dict:
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    rank, world, device = _distributed(torch_device(cfg.device))
    main_process = rank == 0
    torch.manual_seed(cfg.seed)
    kw = {"freeze_features": cfg.freeze_features, "init": cfg.vgg_init}
    if cfg.model in ("branched-vgg19", "parallel-vgg19"):
        kw["image_size"] = cfg.image_size
    obj, twins, label_sets = None, [], None
    if model_kind(cfg.model) == "keypoints":
        obj = dataset_object(cfg.data)
        kw = {"keypoints_m": obj.keypoints, "image_size": cfg.image_size}
        if obj.symmetries:
            # no image says which of a symmetric object's look-alike keypoints is which: one heatmap
            # of them all, and PnP tries the labellings (unlabelled.py); no twins to learn
            kw["gauge"] = symmetry_gauge(obj.keypoints, obj.symmetries)
            label_sets = obj.keypoints
        else:
            twins = box_half_turns(obj) if cfg.twin_loss else []
            label_sets = np.stack([obj.keypoints] + [S @ obj.keypoints for S in twins])
            if twins:
                kw["twin_classes"] = len(label_sets)
    model = build_model(cfg.model, **kw)
    train_ds, val_ds = make_datasets(cfg, keypoints_m=label_sets)
    gen = torch.Generator().manual_seed(cfg.seed)
    sampler = None
    if world > 1:
        from torch.utils.data.distributed import DistributedSampler

        sampler = DistributedSampler(train_ds, num_replicas=world, rank=rank, shuffle=True, seed=cfg.seed)
    train_loader = DataLoader(train_ds, batch_size=cfg.batch, shuffle=sampler is None, sampler=sampler,
                              generator=gen if sampler is None else None, num_workers=cfg.workers,
                              drop_last=len(train_ds) > cfg.batch * world, pin_memory=device.type == "cuda",
                              worker_init_fn=single_threaded_worker, persistent_workers=cfg.workers > 0)
    val_loader = DataLoader(val_ds, batch_size=cfg.batch, num_workers=cfg.workers, worker_init_fn=single_threaded_worker,
                            persistent_workers=cfg.workers > 0)

    if cfg.init_from:
        load_matching_weights(model, cfg.init_from)
    if cfg.imagenet_weights:
        load_imagenet_weights(model, cfg.imagenet_weights)
    elif obj is None and not cfg.init_from:
        log.warning("no --imagenet-weights given: training %s from scratch (nothing is downloaded)", cfg.model)
    model.to(device)
    if device.type == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = True
        # Fixed input sizes: cuDNN times its convolution algorithms once and keeps the fastest.
        torch.backends.cudnn.benchmark = True
    channels_last(model)
    net = model
    if world > 1:
        from torch.nn.parallel import DistributedDataParallel

        net = DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)
        log.info("DDP: rank %d of %d processes on %s", rank, world, device)
    optim = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=cfg.lr)
    augment = make_augment().to(device) if cfg.augment else None
    sched = (torch.optim.lr_scheduler.CosineAnnealingLR(optim, cfg.epochs, eta_min=0.01 * cfg.lr)
             if cfg.schedule == "cosine" else None)

    start_epoch, best, history, stale = 0, math.inf, [], 0
    last_path = out / "last.pt"
    if resume and last_path.exists():
        ck = load_checkpoint(last_path)
        if ck["config"]["model"] != cfg.model:
            raise ValueError(f"{last_path}: checkpoint is for model {ck['config']['model']!r}, not {cfg.model!r}")
        model.load_state_dict(ck["model"])
        optim.load_state_dict(ck["optimizer"])
        if sched is not None and ck.get("scheduler"):
            sched.load_state_dict(ck["scheduler"])
        torch.set_rng_state(ck["torch_rng"])
        gen.set_state(ck["loader_rng"])
        start_epoch, best, history, stale = ck["epoch"] + 1, ck["best"], ck["history"], ck["stale"]
        if cfg.fill_time:  # the count its first epoch planned (the scheduler's state holds its length)
            cfg = replace(cfg, epochs=ck["config"]["epochs"])
        log.info("resumed %s at epoch %d", last_path, start_epoch)

    bar = None
    if progress and main_process:
        from tqdm import tqdm

        bar = tqdm(total=cfg.epochs, initial=start_epoch, desc=f"train {cfg.model}", unit="epoch")
    run_start = time.perf_counter()
    best_payload = None  # a best.pt not written yet (checkpoint_every > 1)
    stopped, early_stop = None, False  # why the run ended, for the caller's summary
    epoch = start_epoch - 1
    while (epoch := epoch + 1) < cfg.epochs:  # fill_time may re-plan cfg.epochs after each
        if sampler is not None:
            sampler.set_epoch(epoch)
        net.train()
        t0, total, n, lr_used = time.perf_counter(), 0.0, 0, optim.param_groups[0]["lr"]
        # time spent waiting for the loader: whether its workers or the device set the pace (loss.item()
        # below waits for the device every step, so the rest of the loop is the step itself)
        loader_wait_s, ready = 0.0, time.perf_counter()
        for b, batch in enumerate(train_loader):
            loader_wait_s += time.perf_counter() - ready
            if cfg.max_batches is not None and b >= cfg.max_batches:
                break
            if augment is not None:
                batch["image"] = augment(batch["image"].to(device))
                if "crop_image" in batch:
                    batch["crop_image"] = augment(batch["crop_image"].to(device))
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=cfg.amp):
                loss = batch_loss(net, batch, device, cfg.beta, cfg.twin_weight)
            if not torch.isfinite(loss):
                raise FloatingPointError(f"epoch {epoch} batch {b}: loss is {loss.item()}; lower --lr")
            optim.zero_grad(set_to_none=True)
            loss.backward()
            optim.step()
            total, n = total + loss.item() * len(batch["index"]), n + len(batch["index"])
            ready = time.perf_counter()
        train_s = time.perf_counter() - t0
        if sched is not None:
            sched.step()
        if world > 1:
            # Every rank trained on its own shard: the epoch's loss and image count are the sums.
            import torch.distributed as dist

            sums = torch.tensor([total, float(n)], dtype=torch.float64, device=device)
            dist.all_reduce(sums)
            total, n = sums[0].item(), int(sums[1].item())
        if not main_process:
            if _stop_signal(None):
                break
            continue
        row = {"epoch": epoch, "train_loss": total / max(n, 1), **evaluate(model, val_loader, device, cfg.beta, twins,
                                                                           obj.symmetries if obj is not None else ()),
               "lr": lr_used, "epoch_s": time.perf_counter() - t0, "train_images": n, "train_s": train_s,
               "loader_wait_s": loader_wait_s}
        history.append(row)
        if cfg.fill_time and cfg.time_limit_min and start_epoch == 0 and world == 1:
            cfg = _filled(cfg, (time.perf_counter() - run_start) / 60 / (epoch + 1), sched, bar, done=epoch + 1)
        improved = row["val_loss"] < best
        best, stale = (row["val_loss"], 0) if improved else (best, stale + 1)
        payload = {"config": asdict(cfg), "model": model.state_dict(), "build": kw_for_checkpoint(kw),
                   "dataset": dataset_info(cfg.data, obj), "twins": [S.matrix.tolist() for S in twins], "optimizer": optim.state_dict(),
                   "scheduler": sched.state_dict() if sched is not None else None,
                   "epoch": epoch, "best": best, "history": history, "stale": stale,
                   "torch_rng": torch.get_rng_state(), "loader_rng": gen.get_state()}
        if improved:
            # best.pt is what eval, export and --init-from read; resuming reads last.pt. Without the
            # optimizer's moments a VGG-19's best.pt is 3x smaller (Adam keeps two per weight:
            # 1.6 GB -> 0.55 GB), and a run writes it every improving epoch.
            best_payload = {k: v for k, v in payload.items() if k not in RESUME_ONLY_KEYS}
            if cfg.checkpoint_every > 1:  # held until the next write: later steps must not change it
                best_payload = snapshot(best_payload)
        if bar:
            bar.update(1)
            bar.set_postfix(val_loss=f"{row['val_loss']:.3f}", rot=f"{row['rot_mean_deg']:.1f}°", t=f"{row['trans_mean_m']:.3f}m")
        stop = bool(cfg.patience and stale >= cfg.patience)
        if stop:
            log.info("early stop at epoch %d: no validation improvement for %d epochs", epoch, stale)
            stopped = f"early stop after epoch {epoch}: no validation improvement for {stale} epochs (--patience)"
            early_stop = True
        written = stop or epoch + 1 == cfg.epochs or (epoch + 1) % cfg.checkpoint_every == 0
        if written:  # before the time limit is judged: the writes are part of an epoch's time
            write_checkpoints(out, best_payload, payload)
            best_payload = None
        write_metrics(out, history)
        elapsed_min = (time.perf_counter() - run_start) / 60
        if cfg.time_limit_min and epoch + 1 < cfg.epochs and elapsed_min * (epoch + 2 - start_epoch) / (epoch + 1 - start_epoch) > cfg.time_limit_min:
            log.info("time limit: stopping after epoch %d of %d (%.1f of %.1f min used)",
                     epoch, cfg.epochs, elapsed_min, cfg.time_limit_min)
            stopped = (f"time limit after epoch {epoch} of {cfg.epochs}: {elapsed_min:.1f} of {cfg.time_limit_min:g} "
                       "min used (--time-limit; --resume continues)")
            stop = True
            if not written:
                write_checkpoints(out, best_payload, payload)
        if world > 1:
            _stop_signal(stop)
        if stop:
            break
    if bar:
        bar.close()
    best_path = out / "best.pt"
    if main_process and best_path.exists():
        # a symmetric object's errors count to its nearest equivalent pose (no image tells them apart)
        calibrate_best(best_path, model, val_loader, device, twins or (obj.symmetries if obj is not None else ()))
    if world > 1:
        import torch.distributed as dist

        dist.barrier()
        dist.destroy_process_group()
    best_row = min(history, key=lambda r: r["val_loss"]) if history else {}
    return {**best_row, "epochs_run": len(history), "stopped": stopped or f"ran all {_epochs(cfg.epochs)}",
            "early_stop": early_stop}


def _filled(cfg: TrainConfig, epoch_min: float, sched, bar, done: int = 1) -> TrainConfig:
    """``cfg`` with its epochs re-planned (``fill_time``) after ``done`` epochs of ``epoch_min`` minutes on
    average (never fewer than ``done``); the cosine ``sched`` and the progress ``bar`` (None: none) follow."""
    epochs = int(np.clip(cfg.time_limit_min / (FILL_MARGIN * max(epoch_min, 1e-6)), done, MAX_FILL_EPOCHS))
    if epochs == cfg.epochs:
        return cfg
    log.info("fill_time: %d epochs, not %d (%.2f min an epoch of %g)", epochs, cfg.epochs, epoch_min, cfg.time_limit_min)
    if sched is not None:  # its rate now as the new length has it; the chainable cosine goes on from there
        for group, base in zip(sched.optimizer.param_groups, sched.base_lrs):
            group["lr"] = sched.eta_min + (base - sched.eta_min) * (1 + math.cos(math.pi * sched.last_epoch / epochs)) / 2
        sched.T_max = epochs
    if bar is not None:
        bar.total = epochs
        bar.refresh()
    return replace(cfg, epochs=epochs)


def _stop_signal(stop: bool | None) -> bool:
    """Rank 0 broadcasts its early-stop decision after validating; the other ranks receive it."""
    import torch.distributed as dist

    box = [stop]
    dist.broadcast_object_list(box, src=0)
    return bool(box[0])


def add_train_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, choices=available_models())
    p.add_argument("--data", required=True, help="dataset root from `hybridpose render --kind random`")
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument("--epochs", type=int, default=100)
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--lr", type=float, default=None, help="Adam learning rate (default: 1e-4; 1e-3 for default/keypoints)")
    p.add_argument("--beta", type=float, default=DEFAULT_BETA)
    p.add_argument("--image-size", type=int, default=None, help="network input side, px (default: 224; 128 default, 160 keypoints)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--patience", type=int, default=10)
    p.add_argument("--no-augment", action="store_true")
    p.add_argument("--freeze-features", action="store_true")
    p.add_argument("--vgg-init", choices=VGG_INITS, default="torchvision",
                   help="VGG models: how the weights start (torch-default: torch's per-layer defaults, for older runs)")
    p.add_argument("--imagenet-weights", default=None, help="local torchvision-format VGG state dict")
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--schedule", choices=SCHEDULES, default=None, help="lr schedule (default: constant; cosine for default/keypoints)")
    p.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    p.add_argument("--max-batches", type=int, default=None, help="cap batches per epoch (smoke runs)")
    p.add_argument("--no-twin-loss", action="store_true",
                   help="keypoint models: score against the true keypoints only (not also the box-symmetric twins)")
    p.add_argument("--twin-weight", type=float, default=TWIN_CE_WEIGHT,
                   help=f"keypoint models: weight of the twin head's cross-entropy (default {TWIN_CE_WEIGHT})")
    p.add_argument("--init-from", default=None, help="start from a checkpoint's matching weights (fine-tuning)")
    p.add_argument("--val-fraction", type=float, default=0.2, help="share of the data held out for validation")
    p.add_argument("--amp", action="store_true", help="bfloat16 autocast for training (a GPU or a CPU with AMX: about 1.5x faster there)")
    p.add_argument("--time-limit", type=float, default=None, metavar="MIN",
                   help="stop cleanly before the next epoch would end past MIN minutes")
    p.add_argument("--resume", action="store_true", help="continue from <out>/last.pt")
    p.add_argument("--cache-images", default=None, metavar="DIR",
                   help="decode every view once into DIR and memory-map it (reused by later runs on the same "
                        "views): VGG models' resized inputs (≈ 150 KB a view at 224 px), keypoint models' "
                        "whole views (0.9 MB at 640×480; their random crops are cut from them)")
    p.add_argument("--full-view", type=float, default=0.0, metavar="SHARE",
                   help="keypoint models: share of training crops showing the whole frame, so that the network "
                        "finds the object itself on any background (e.g. 0.3; default 0: found by detection)")
    p.add_argument("--checkpoint-every", type=int, default=1, metavar="N",
                   help="write last.pt (and a better best.pt) every N epochs and when the run stops (default 1: every "
                        "epoch; the VGG models' multi-GB checkpoints take as long to write as a GPU epoch takes)")


def config_from_args(args) -> TrainConfig:
    defaults = {"image_size": 224, "lr": 1e-4, **MODEL_DEFAULTS.get(args.model, {})}
    lr = defaults["lr"] if args.lr is None else args.lr
    image_size = defaults["image_size"] if args.image_size is None else args.image_size
    schedule = defaults.get("schedule", "constant") if args.schedule is None else args.schedule
    return TrainConfig(model=args.model, data=args.data, out=args.out, epochs=args.epochs, batch=args.batch,
                       lr=lr, beta=args.beta, image_size=image_size, seed=args.seed,
                       patience=args.patience, augment=not args.no_augment, freeze_features=args.freeze_features,
                       vgg_init=args.vgg_init, imagenet_weights=args.imagenet_weights, workers=args.workers, device=args.device,
                       max_batches=args.max_batches, schedule=schedule, twin_loss=not args.no_twin_loss,
                       twin_weight=args.twin_weight,
                       init_from=args.init_from, val_fraction=args.val_fraction, amp=args.amp,
                       time_limit_min=args.time_limit,
                       checkpoint_every=args.checkpoint_every, cache_images=args.cache_images,
                       full_view=args.full_view)


def run(args: argparse.Namespace) -> int:
    """Train from parsed :func:`add_train_arguments` options and print the best validation metrics."""
    best = train(config_from_args(args), resume=args.resume)
    if int(os.environ.get("RANK", "0")) == 0:
        print(run_summary(best, args.out))
        print(json.dumps(best, indent=2))
    return 0


def _epochs(n: int) -> str:
    return f"{n} epoch" + ("" if n == 1 else "s")


def run_summary(best: dict, out) -> str:
    """One line for the end of ``hybridpose train``: why the run stopped, its best validation epoch
    (whose weights are ``out``/best.pt) and that epoch's metrics."""
    if "epoch" not in best:
        return f"train: no epoch ran ({best.get('stopped', 'nothing to do')}); nothing written to {out}"
    return (f"train: {_epochs(best['epochs_run'])} recorded ({best['stopped']}); best validation epoch "
            f"{best['epoch']} (loss {best['val_loss']:.3f}, rotation {best['rot_mean_deg']:.2f}° mean / "
            f"{best['rot_median_deg']:.2f}° median, translation {best['trans_mean_m']:.3f} m) → "
            f"{Path(out) / 'best.pt'}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hybridpose.training.train")
    add_train_arguments(p)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
