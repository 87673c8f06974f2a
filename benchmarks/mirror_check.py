"""The edge-on mirror check of the shipped keypoint regressor: chosen on some sets, confirmed on others.

Usage:
    common="--object truss --kind random --size 640x480 --in-view --sun-range 0.7,1.3 --workers 2 --count 1000"
    hybridpose render $common --sun-cone 40 --seed 134 --out data/truss_test134                      # and so on
    python benchmarks/mirror_check.py --tune data/truss_test128 ... --confirm data/truss_test134 ... \\
        [--wide data/truss_wide216 ...] [--mirror-verifier PATH]

Seen within a few degrees of edge-on, the truss's image hardly says whether its long axis leans
towards the camera or away from it (:func:`hybridpose.regressors.verify.edge_on_mirror`): most of the
regressor's views > 30° off are such a mirror, or a box twin of it. The mirror check (a verifier
trained with ``hybridpose train-verifier --mirrors``) scores a pose estimated within
``MIRROR_BELOW_DEG`` of edge-on against its twins and their mirrors and switches to the one it
believes with p ≥ ``MIRROR_SWITCH_P``. For every view: the full inference path without the check
(``mirror_verifier=None``), then the check on its pose (the verifier's belief, and the error of its
favourite candidate after the edge fit, as the predictor would return it). The threshold is replayed
on those numbers: chosen on ``--tune`` (lowest mean rotation error), then compared with no check on
``--confirm`` and ``--wide`` (sets that took no part in choosing; McNemar on the > 30° views, paired
bootstrap of the mean). Writes ``results/mirror_check.json`` and the "mirror-check" section of
RESULTS.md.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from _common import PAIRED_HEADER, concat_sets, environment, paired_cells, test_views, update_results_md, write_json
from hybridpose.metrics import rotation_error_deg
from hybridpose.objects import view_elevation_deg
from hybridpose.regressors.evaluate import FAILED_ROT_DEG, GROSS_ERROR_DEG, paired_comparison
from hybridpose.regressors.predictor import MIRROR_SWITCH_P, WEIGHTS_DIR, CheckpointRegressor, shipped_checkpoint
from hybridpose.regressors.twin_verifier import TwinVerifier
from hybridpose.regressors.verify import MIRROR_BELOW_DEG

THRESHOLDS = (0.5, 0.7, 0.8, 0.9, 0.95)


def measure(data: str, checkpoint: str, mirror_verifier: str, limit=None) -> dict:
    """Per view of ``data``: rotation error without the check, the verifier's top probability and
    candidate (0 = the pose itself; -1 where the check does not run), the error after switching to it,
    and the seconds the check took."""
    reg = CheckpointRegressor(checkpoint, threads=1, mirror_verifier=None)
    checker = CheckpointRegressor(checkpoint, threads=1, mirror_verifier=mirror_verifier)
    # every threshold is replayed from one check at p ≥ 0 (the favourite and its probability)
    base, switched, p_top, top, seconds = [], [], [], [], []
    obj = checker.twin_check.view.object
    with torch.no_grad():
        for frame, gt in test_views(data, limit):
            m = reg.predict(frame)
            err = FAILED_ROT_DEG if m.lost else rotation_error_deg(m.pose, gt.pose)
            base.append(err)
            if m.lost or view_elevation_deg(m.pose, obj) >= MIRROR_BELOW_DEG:
                switched.append(err), p_top.append(0.0), top.append(-1), seconds.append(0.0)
                continue
            t0 = time.perf_counter()
            pose, p, k = checker._mirror_check(frame, m.pose, switch_p=0.0)
            seconds.append(time.perf_counter() - t0)
            switched.append(rotation_error_deg(pose, gt.pose) if k else err)
            p_top.append(p), top.append(k)
    return {k: np.asarray(v, dtype=float) for k, v in
            {"base": base, "switched": switched, "p_top": p_top, "top": top, "seconds": seconds}.items()}


def replay(m: dict, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(rotation errors (°) with the check switching at ``threshold``, which views it switches)."""
    switch = (m["top"] > 0) & (m["p_top"] >= threshold)
    return np.where(switch, m["switched"], m["base"]), switch


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tune", nargs="+", required=True, help="sets that choose the threshold")
    ap.add_argument("--confirm", nargs="+", required=True, help="fresh sets lit like the training data")
    ap.add_argument("--wide", nargs="*", default=[], help="fresh sets lit from any side")
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--mirror-verifier", default=str(WEIGHTS_DIR / "mirror_verifier.pt"))
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args()
    TwinVerifier(args.mirror_verifier, CheckpointRegressor(args.checkpoint).twin_check.view.object)  # fail early
    groups = {"tune": args.tune, "confirm": args.confirm, "wide": args.wide}
    measured = {g: [measure(d, args.checkpoint, args.mirror_verifier, args.limit) for d in dirs]
                for g, dirs in groups.items() if dirs}
    tune = concat_sets(measured["tune"])
    by_threshold = {t: replay(tune, t)[0] for t in THRESHOLDS}
    chosen = min(THRESHOLDS, key=lambda t: (by_threshold[t].mean(), -t))
    rows, out = [], {"env": environment(), "checkpoint": args.checkpoint, "mirror_verifier": args.mirror_verifier,
                     "sets": groups, "below_elevation_deg": MIRROR_BELOW_DEG, "chosen_threshold": chosen,
                     "shipped_threshold": MIRROR_SWITCH_P, "groups": {}}
    for g, sets in measured.items():
        m = concat_sets(sets)
        checked = m["top"] >= 0
        group = {"views": len(m["base"]), "checked_share": float(checked.mean()),
                 "check_ms_per_checked_view": float(1e3 * m["seconds"][checked].mean()) if checked.any() else 0.0,
                 "check_ms_per_view": float(1e3 * m["seconds"].mean()),
                 "thresholds": {}}
        for t in THRESHOLDS:
            err, switch = replay(m, t)
            c = paired_comparison(m["base"], err)
            group["thresholds"][str(t)] = {"switched": int(switch.sum()), **c}
            rows.append((g, t, c, int(switch.sum())))
        out["groups"][g] = group
    write_json("mirror_check", out)
    lines = ["## Edge-on mirror check of the shipped keypoint regressor (`benchmarks/mirror_check.py`)", "",
             f"Checkpoint `{args.checkpoint.split('/')[-1]}`, mirror verifier `{args.mirror_verifier.split('/')[-1]}`. "
             f"Full inference path without the check, then the check on views whose pose is within "
             f"{MIRROR_BELOW_DEG:.0f}° of edge-on: the pose is replaced by the twin or edge-on mirror the verifier "
             f"believes with p ≥ threshold (edge-fitted). *tune* ({', '.join(args.tune)}) chose the threshold "
             f"({chosen}, lowest mean); *confirm* ({', '.join(args.confirm)})"
             + (f" and *wide* ({', '.join(args.wide)}, sun anywhere within 85° of the optical axis)" if args.wide else "")
             + " took no part in choosing it. *only without / only with*: views > "
             f"{GROSS_ERROR_DEG:.0f}° off only without the check / only with it (McNemar p); Δ mean: with − without, "
             "paired bootstrap 95 % interval. "
             + "; ".join(f"*{g}*: the check runs on {100 * v['checked_share']:.0f} % of the views, "
                         f"{v['check_ms_per_checked_view']:.1f} ms each ({v['check_ms_per_view']:.1f} ms a view on average, "
                         "one thread)" for g, v in out["groups"].items())
             + f". git {out['env']['git']}.", "",
             f"| sets | threshold | views switched | {PAIRED_HEADER.format(gross=GROSS_ERROR_DEG)} |",
             "|---|---|---|---|---|---|---|---|"]
    for g, t, c, n in rows:
        bold = "**" if t == chosen else ""
        lines.append(f"| {g} | {bold}{t}{bold} | {n} | {paired_cells(c)} |")
    update_results_md("mirror-check", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
