"""What a training run reads and writes besides the network's passes: its checkpoints (the build
arguments, host copies of the weights, ``best.pt`` then ``last.pt``), weights taken over from another
checkpoint (``--init-from``), the best checkpoint's covariance calibration and the metrics files.
"""
from __future__ import annotations

import csv
import io
import logging
from pathlib import Path

import numpy as np

from ..io import atomic_write_json, atomic_write_text
from .calibrate import calibrate
from ..regressors.checkpoints import load_checkpoint, save_checkpoint
from ..regressors.keypoint_net import widen_state_dict
from .train_steps import forward

log = logging.getLogger("hybridpose.training.train")  # the training run's log, where its users look

# noise on the copied channels when --init-from widens a narrower keypoint net: enough to let the
# copies drift apart, small enough to keep the start's keypoints within ≈ 0.1 px on real crops
WIDEN_NOISE = 0.002


def kw_for_checkpoint(kw: dict) -> dict:
    """The :func:`build_model` arguments, as plain lists (a checkpoint rebuilds its own network)."""
    return {k: (np.asarray(v).tolist() if k == "keypoints_m" else v) for k, v in kw.items()}


def snapshot(payload: dict) -> dict:
    """``payload`` with its model weights copied to host memory and its history list copied: what
    training goes on to change in place."""
    out = dict(payload)
    out["model"] = {k: v.detach().to("cpu", copy=True) for k, v in payload["model"].items()}
    out["history"] = list(payload["history"])
    return out


def write_checkpoints(out: Path, best_payload: dict | None, payload: dict) -> None:
    """Write the pending ``best.pt`` (where there is one), then ``last.pt``."""
    if best_payload is not None:
        save_checkpoint(out / "best.pt", best_payload)
    save_checkpoint(out / "last.pt", payload)


OBJECT_BUFFERS = ("keypoints_m",)  # what a network holds of its object, never copied by --init-from


def load_matching_weights(model, path) -> None:
    """Copy the weights of ``path`` whose names and shapes match ``model``'s; log what was left out."""
    src = load_checkpoint(path)
    if "model" not in src:
        raise ValueError(f"{path}: not a hybridpose checkpoint (no 'model')")
    own = model.state_dict()
    weights = src["model"]
    if getattr(model, "kind", None) == "keypoints" and "stem.0.weight" in weights:
        width, own_width = weights["stem.0.weight"].shape[0], own["stem.0.weight"].shape[0]
        if width < own_width:   # e.g. the wider `keypoints` net from the shipped `default`: keep what it learned
            common = [k for k in weights if k in own]   # a head only one of them has stays fresh
            weights = widen_state_dict({k: weights[k] for k in common}, {k: own[k] for k in common},
                                       noise=WIDEN_NOISE, seed=0)
            log.info("widened %s from width %d to %d (Net2WiderNet)", path, width, own_width)
    src_size = (src.get("build") or {}).get("image_size")
    if src_size and getattr(model, "image_size", src_size) != src_size:
        # the keypoint nets are fully convolutional, so this runs, but every feature sees a new scale
        # (a new crop size costs accuracy until the network has re-learned its scales)
        log.warning("%s was trained on %d px crops, this run uses %d px (--image-size %d keeps its scale)",
                    path, src_size, model.image_size, src_size)
    # the object's own keypoints stay: a start from another object's checkpoint (of as many keypoints)
    # would otherwise carry its 3D points into every PnP
    take = {k: v for k, v in weights.items() if k in own and own[k].shape == v.shape and k not in OBJECT_BUFFERS}
    if not take:
        raise ValueError(f"{path}: no weight matches the {type(model).__name__} being trained")
    model.load_state_dict(take, strict=False)
    fresh = sorted(set(own) - set(take))
    log.info("initialised %d tensors from %s; new: %s", len(take), path, ", ".join(fresh) or "none")


def calibrate_best(path: Path, model, val_loader, device, twins=()) -> None:
    """Store the held-out covariance calibration (see calibration.py) in the best checkpoint."""
    ck = load_checkpoint(path)
    model.load_state_dict(ck["model"])
    try:
        ck["calibration"] = calibrate(model, val_loader, lambda m, b: forward(m, b, device), twins, device)
    except ValueError as exc:
        log.warning("%s: not calibrated (%s); its covariances will be conservative defaults", path, exc)
        return
    save_checkpoint(path, ck)
    log.info("calibrated %s: %s", path, {k: v for k, v in ck["calibration"].items() if k != "covariance"})


def write_metrics(out: Path, history: list[dict]) -> None:
    """``out/metrics.csv`` and ``out/history.json``: one row per epoch of ``history`` (a dict of numbers
    each), each written atomically."""
    buf = io.StringIO()
    # the union of the rows' columns: a run resumed across versions may add one
    w = csv.DictWriter(buf, fieldnames=list(dict.fromkeys(k for row in history for k in row)), restval="",
                       lineterminator="\n")
    w.writeheader()
    w.writerows(history)
    atomic_write_text(out / "metrics.csv", buf.getvalue())
    atomic_write_json(out / "history.json", history)
