"""The depth gate of the shipped keypoint regressor: poses far deeper than anything it was trained on.

Usage:
    common="--object truss --kind random --size 640x480 --in-view --sun-range 0.7,1.3 --workers 2 --count 1000"
    hybridpose render $common --sun-cone 40 --seed 158 --out data/truss_test158                      # and so on
    python benchmarks/depth_gate.py --cone data/truss_test158 ... [--wide ...] [--side ...] [--max-depth 3.6]

An end-on truss close to the camera and the truss lying across the view far away fill the same small
box; PnP on near-collinear keypoints sometimes lands on the far one (18.4 m for a truss at 1.19 m), which
the size check (``size_ratio``) cannot refuse. With ``max_depth_m`` an estimate deeper than the limit is no
plausible pose: the view is reported lost (an edge-on expert's estimate beyond it is dropped and the first
one kept). An option, off by default: rule 13 (session 26) was not met. Every view runs through the
shipped path without the gate (A) and with it (B). Errors as ``hybridpose eval`` counts them: a lost view is
``FAILED_ROT_DEG`` (180°) and ``FAILED_TRANS_M`` (1 m). Also counted: views within 30° without the gate
that it loses (a gate that refuses good poses is too tight).
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

from _common import (PAIRED_HEADER, add_lighting_groups, concat_sets, environment, lighting_groups, paired_cells, publish, set_names,
                     test_views)
from hybridpose.metrics import rotation_error_deg, translation_error_m
from hybridpose.regressors.evaluate import FAILED_ROT_DEG, FAILED_TRANS_M, GROSS_ERROR_DEG, paired_comparison
from hybridpose.regressors.predictor import DEPTH_BEYOND_TRAINED, CheckpointRegressor, shipped_checkpoint

TRAINED_FAR_M = 1.2  # the far end of the shipped default's training depths (weights README)


def errors(m, gt) -> tuple[float, float]:
    """(rotation °, translation m) of one measurement, counted as ``hybridpose eval`` does when lost."""
    if m.lost:
        return FAILED_ROT_DEG, FAILED_TRANS_M
    return rotation_error_deg(m.pose, gt.pose), translation_error_m(m.pose, gt.pose)


def measure(data: str, checkpoint: str, max_depth_m: float, limit=None) -> dict:
    """Per view of ``data``: rotation (°) and translation (m) errors without the gate (``rot_a``,
    ``trans_a``) and with it (``rot_b``, ``trans_b``), and the true depth (m)."""
    a = CheckpointRegressor(checkpoint, threads=1, max_depth_m=None)
    b = CheckpointRegressor(checkpoint, threads=1, max_depth_m=max_depth_m)
    rows = {k: [] for k in ("rot_a", "trans_a", "rot_b", "trans_b", "depth")}
    with torch.no_grad():
        for frame, gt in test_views(data, limit):
            for tag, reg in (("a", a), ("b", b)):
                rot, trans = errors(reg.predict(frame), gt)
                rows[f"rot_{tag}"].append(rot)
                rows[f"trans_{tag}"].append(trans)
            rows["depth"].append(float(gt.pose.t[2]))
    return {k: np.asarray(v) for k, v in rows.items()}


def main() -> None:
    ap = argparse.ArgumentParser()
    add_lighting_groups(ap)
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--max-depth", type=float, default=DEPTH_BEYOND_TRAINED * TRAINED_FAR_M,
                    help="the gate, metres along the optical axis (default: what 'auto' gives the shipped default)")
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args()
    groups = lighting_groups(ap, args)
    out = {"env": environment(), "checkpoint": args.checkpoint, "max_depth_m": args.max_depth, "sets": groups,
           "groups": {}}
    lines = ["## Depth gate of the shipped keypoint regressor (`benchmarks/depth_gate.py`)", "",
             f"A = without the gate, B = estimates deeper than {args.max_depth:g} m refused. A lost view counts "
             f"{FAILED_ROT_DEG:g}° and {FAILED_TRANS_M:g} m (as `hybridpose eval`); good views lost = within "
             f"{GROSS_ERROR_DEG:g}° in A, lost in B.", "",
             f"| sets | views | mean trans m A → B | median trans m | lost A → B | good views lost | "
             f"{PAIRED_HEADER.format(gross=GROSS_ERROR_DEG)} |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for g, dirs in groups.items():
        m = concat_sets([measure(d, args.checkpoint, args.max_depth, args.limit) for d in dirs])
        lost_a, lost_b = m["rot_a"] >= FAILED_ROT_DEG, m["rot_b"] >= FAILED_ROT_DEG
        good_lost = int(np.sum((m["rot_a"] <= GROSS_ERROR_DEG) & lost_b))
        c = paired_comparison(m["rot_a"], m["rot_b"])
        out["groups"][g] = {"views": len(m["rot_a"]), "trans_mean_m": [float(m["trans_a"].mean()), float(m["trans_b"].mean())],
                            "trans_median_m": [float(np.median(m["trans_a"])), float(np.median(m["trans_b"]))],
                            "lost": [int(lost_a.sum()), int(lost_b.sum())], "good_views_lost": good_lost,
                            "changed": int(np.sum(m["rot_a"] != m["rot_b"])), "rotation": c,
                            "per_view": {k: v.tolist() for k, v in m.items()}}
        lines.append(f"| {g} ({set_names(dirs)}) | {len(m['rot_a'])} | "
                     f"{m['trans_a'].mean():.4f} → {m['trans_b'].mean():.4f} | {np.median(m['trans_a']):.4f} → "
                     f"{np.median(m['trans_b']):.4f} | {int(lost_a.sum())} → {int(lost_b.sum())} | {good_lost} | "
                     f"{paired_cells(c)} |")
    publish("depth_gate", "depth-gate", out, lines)


if __name__ == "__main__":
    main()
