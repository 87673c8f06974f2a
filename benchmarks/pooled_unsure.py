"""The pooled twin choice only where a twin head is unsure (``expert_rule="pooled-unsure"``) against the
quality rule (``"quality"``), on the shipped keypoint regressor's whole path.

Usage:
    common="--object truss --kind random --size 640x480 --in-view --sun-range 0.7,1.3 --workers 2 --count 1000"
    hybridpose render $common --sun-cone 40 --seed 162 --out data/truss_test162                      # and so on
    python benchmarks/pooled_unsure.py --cone data/truss_test162 ... [--wide ...] [--side ...]

The pooled rule (``benchmarks/pooled_twins.py``) chose better among both estimates' twins on every lighting
but cost ≈ 1 ms more a view than the quality rule, mostly its twin-verifier batch on views where both twin
heads are sure (there the quality rule asks no verifier). Pooling only where a head is unsure keeps most of
its gain on the recorded candidates (replayed exactly) at the quality rule's cost. Every view runs through
both paths in one process, turn about (which goes first alternates), so the times compare on a shared
machine. A = quality, B = pooled-unsure; lost views count 180°.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from _common import (PAIRED_HEADER, add_lighting_groups, concat_sets, environment, lighting_groups, paired_cells, publish, set_names,
                     test_views)
from hybridpose.metrics import rotation_error_deg
from hybridpose.regressors.evaluate import FAILED_ROT_DEG, GROSS_ERROR_DEG, paired_comparison
from hybridpose.regressors.predictor import CheckpointRegressor, shipped_checkpoint


def measure(data: str, regs: dict, limit=None) -> dict:
    """Per view of ``data`` and per regressor in ``regs`` (name → regressor): rotation error (°) and the
    seconds its ``predict`` took."""
    rows = {f"{k}_{n}": [] for k in ("rot", "seconds") for n in regs}
    with torch.no_grad():
        for i, (frame, gt) in enumerate(test_views(data, limit)):
            names = list(regs) if i % 2 == 0 else list(regs)[::-1]
            for name in names:
                t0 = time.perf_counter()
                m = regs[name].predict(frame)
                rows[f"seconds_{name}"].append(time.perf_counter() - t0)
                rows[f"rot_{name}"].append(FAILED_ROT_DEG if m.lost else rotation_error_deg(m.pose, gt.pose))
    return {k: np.asarray(v) for k, v in rows.items()}


def main() -> None:
    ap = argparse.ArgumentParser()
    add_lighting_groups(ap)
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args()
    groups = lighting_groups(ap, args)
    torch.set_num_threads(1)
    regs = {rule: CheckpointRegressor(args.checkpoint, threads=1, expert_rule=rule) for rule in ("quality", "pooled-unsure")}
    out = {"env": environment(), "checkpoint": args.checkpoint, "sets": groups, "groups": {}}
    lines = ["## Pooled twin choice where a head is unsure (`benchmarks/pooled_unsure.py`)", "",
             "A = `expert_rule=\"quality\"` (the default before session 26), B = `\"pooled-unsure\"` (the default since); whole `predict` path, 1 thread, "
             "both per view turn about in one process.", "",
             f"| sets | views | ms/view A → B | {PAIRED_HEADER.format(gross=GROSS_ERROR_DEG)} |",
             "|---|---|---|---|---|---|---|---|"]

    def compare(label: str, m: dict) -> dict:
        """The paired comparison and times of the views ``m``, its table row appended to ``lines``."""
        c = paired_comparison(m["rot_quality"], m["rot_pooled-unsure"])
        ms = [1000 * float(m[f"seconds_{n}"].mean()) for n in regs]
        lines.append(f"| {label} | {len(m['rot_quality'])} | {ms[0]:.1f} → {ms[1]:.1f} | {paired_cells(c)} |")
        return {"views": len(m["rot_quality"]), "ms_per_view": ms, "rotation": c}

    every = []
    for g, dirs in groups.items():
        m = concat_sets([measure(d, regs, args.limit) for d in dirs])
        every.append(m)
        out["groups"][g] = {**compare(f"{g} ({set_names(dirs)})", m), "per_view": {k: v.tolist() for k, v in m.items()}}
    if len(every) > 1:
        out["all"] = compare("all", concat_sets(every))
    publish("pooled_unsure", "pooled-unsure", out, lines)


if __name__ == "__main__":
    main()
