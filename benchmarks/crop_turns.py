"""Which test-time in-plane turns of the crop the shipped keypoint regressor should try (``turns="auto"``).

Usage:
    python benchmarks/crop_turns.py --data data/truss_test100 data/truss_test105 data/truss_test106

For every held-out view, the first crop (around the detected object) is passed through the network
turned by each of ``ANGLES_DEG`` (:meth:`CheckpointRegressor._solve_turned`: the keypoints are
mapped back to the unturned crop, then PnP) and per turn the PnP inlier share, RMS reprojection
error and rotation error are kept: of the twin the head picks, and of the nearest box twin (what a
perfect twin choice would leave: the keypoints' own quality). Rules are then replayed on those
numbers: each turn alone, and sets of turns where the pass whose PnP keeps the most keypoints (then
the lowest RMS) wins, tried on every view or only where the unturned pass keeps fewer than a share
of its keypoints. Before any edge fit or twin verifier, so the figures are the keypoints' and
the head's alone; the full inference path with and without the shipped rule is measured by
``hybridpose eval --turns off|auto`` (benchmarks/RESULTS.md, notes). Writes
``results/crop_turns.json`` and the "crop-turns" section of RESULTS.md.
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

from _common import environment, update_results_md, write_json
from hybridpose.datasets.bop import BopScene, find_scenes
from hybridpose.datasets.torch_dataset import crop_box
from hybridpose.geometry import Pose
from hybridpose.metrics import rotation_error_deg
from hybridpose.regressors.evaluate import GROSS_ERROR_DEG
from hybridpose.regressors.predictor import (CROP_MARGIN, TURNS_BELOW_INLIERS, TURNS_DEG, CheckpointRegressor,
                                             detect_bright_object, shipped_checkpoint)

ANGLES_DEG = (0.0, 20.0, -20.0, 40.0, -40.0, 90.0, -90.0, 180.0)
SETS = {"0, ±20": (0.0, 20.0, -20.0), "0, ±20, ±40": (0.0, *TURNS_DEG), "0, ±90, 180": (0.0, 90.0, -90.0, 180.0),
        "all eight": ANGLES_DEG}
GATES = tuple(sorted({0.8, 0.9, TURNS_BELOW_INLIERS, 1.0})) + (None,)  # turns where the unturned pass keeps < this share; None: always


def measure(reg: CheckpointRegressor, data_dirs, limit=None) -> dict:
    """Per view × turn: inlier share, RMS px, rotation error (°) of the head's twin and of the nearest twin."""
    S = [Pose.identity(), *reg.twins]
    items = [(s, i) for d in data_dirs for s in map(BopScene, find_scenes(d)) for i in s.image_ids][:limit]
    inl, rms, err_head, err_best = [], [], [], []
    miss = [0.0, 99.0, 180.0, 180.0]
    with torch.no_grad():
        for scene, im_id in items:
            gt = scene.image(im_id)
            image = scene.rgb(im_id)
            box = detect_bright_object(image)
            rows = [miss] * len(ANGLES_DEG)
            if box is not None:
                crop, K_crop = reg._crop(image, gt.camera.K, *crop_box(box, CROP_MARGIN))
                rows = [miss if res is None else
                        [res.inlier_ratio, res.rms_px, rotation_error_deg(res.pose, gt.pose),
                         min(rotation_error_deg(res.pose @ s, gt.pose) for s in S)]
                        for res, *_ in reg._solve_turned(crop, K_crop, ANGLES_DEG)]
            a = np.asarray(rows, dtype=float)
            inl.append(a[:, 0]); rms.append(a[:, 1]); err_head.append(a[:, 2]); err_best.append(a[:, 3])
    return {k: np.array(v) for k, v in
            {"inliers": inl, "rms_px": rms, "err_head": err_head, "err_best_twin": err_best}.items()}


def replay(m: dict, angles, gate) -> dict:
    """The pass chosen per view among ``angles`` (most inliers, then lowest RMS), tried only where the
    unturned pass keeps fewer than ``gate`` of the keypoints (always with None)."""
    cols = [ANGLES_DEG.index(a) for a in angles]
    n = len(m["inliers"])
    turned = np.ones(n, bool) if gate is None else m["inliers"][:, 0] < gate
    pick = np.zeros(n, int)
    for i in np.flatnonzero(turned):
        order = np.lexsort((m["rms_px"][i, cols], -m["inliers"][i, cols]))
        pick[i] = cols[order[0]]
    rows = np.arange(n)
    head, best = m["err_head"][rows, pick], m["err_best_twin"][rows, pick]
    return {"gross_share_head_twin": float(np.mean(head > GROSS_ERROR_DEG)), "rot_mean_deg_head_twin": float(head.mean()),
            "gross_share_best_twin": float(np.mean(best > GROSS_ERROR_DEG)), "rot_mean_deg_best_twin": float(best.mean()),
            "rot_median_deg_best_twin": float(np.median(best)), "turned_share": float(turned.mean()),
            "passes_per_view": float(1 + turned.mean() * (len(angles) - 1))}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", nargs="+", required=True, help="held-out test sets (hybridpose render --seed …)")
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)  # the thread count changes a few borderline views: fix it
    m = measure(CheckpointRegressor(args.checkpoint, verifier=None), args.data, args.limit)
    rules = {f"{a:+g}° alone": replay(m, (a,), None) for a in ANGLES_DEG}
    for name, angles in SETS.items():
        for gate in GATES:
            rules[f"{name}, " + ("always" if gate is None else f"where < {gate:g} kept")] = replay(m, angles, gate)
    shipped = f"0, ±20, ±40, where < {TURNS_BELOW_INLIERS:g} kept"
    n = len(m["inliers"])
    write_json("crop_turns", {"env": environment(), "data": args.data, "checkpoint": args.checkpoint, "views": n,
                              "angles_deg": ANGLES_DEG, "shipped_rule": shipped, "rules": rules})
    lines = ["## Test-time crop turns of the shipped keypoint regressor (`benchmarks/crop_turns.py`)", "",
             f"{', '.join(f'`{d}`' for d in args.data)} ({n} views), checkpoint `{args.checkpoint.split('/')[-1]}`, "
             "first pass (crop around the detected object), PnP, before any edge fit or twin verifier. Per rule: the "
             "pass kept per view (most PnP inliers, then lowest RMS) among the turned crops, tried on every view or "
             "only where the unturned pass keeps fewer than a share of its keypoints. *Head's twin*: the twin the "
             "head picks on the kept pass; *best twin*: the nearest box twin (the keypoints' own quality). "
             f"0° alone is the regressor without turns; **bold**: the shipped `turns=\"auto\"`. git {environment()['git']}.", "",
             f"| rule | > {GROSS_ERROR_DEG:.0f}°, head's twin | mean °, head's twin | > {GROSS_ERROR_DEG:.0f}°, best twin | "
             "mean °, best twin | median °, best twin | views turned | network passes / view |",
             "|---|---|---|---|---|---|---|---|"]
    for name, r in rules.items():
        bold = "**" if name == shipped else ""
        turned = "–" if name.endswith("alone") else f"{100 * r['turned_share']:.0f} %"
        lines.append(f"| {bold}{name}{bold} | {100 * r['gross_share_head_twin']:.1f} % | {r['rot_mean_deg_head_twin']:.2f} | "
                     f"{100 * r['gross_share_best_twin']:.1f} % | {r['rot_mean_deg_best_twin']:.2f} | "
                     f"{r['rot_median_deg_best_twin']:.2f} | {turned} | {r['passes_per_view']:.2f} |")
    update_results_md("crop-turns", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
