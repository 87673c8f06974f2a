"""The edge-on expert of the shipped keypoint regressor: its rule and gate chosen on some sets, confirmed on others.

Usage:
    common="--object truss --kind random --size 640x480 --in-view --sun-range 0.7,1.3 --workers 2 --count 1000"
    hybridpose render $common --sun-cone 40 --seed 142 --out data/truss_test142                      # and so on
    python benchmarks/edge_on_expert.py --expert hybridpose/regressors/weights/edge_on_expert.pt \
        --tune data/truss_test128 ... --confirm data/truss_test142 ... [--wide data/truss_wide216 ...] \
        [--side data/truss_side240 ...] [--cache runs/expert_cache]

Most of the regressor's views > 30° off are seen within a few degrees of edge-on
(benchmarks/RESULTS.md, "error vs view elevation"). The edge-on expert is a second keypoint network
trained on near edge-on views only, run where the first estimate's view elevation is below a gate.
For every view: the full path without the expert (``edge_on_expert=None``), the first estimate's
elevation, and (below the largest gate) the full path on the expert's estimate
(``expert_rule="replace"``, gate 90°), with each measurement's quality. Every gate in ``GATES_DEG`` is
replayed on those numbers under both rules: ``replace`` (the expert's measurement) and ``quality``
(the one of higher measurement quality, the first on a tie: what the shipped predictor does). The
rule and gate are chosen on ``--tune`` (lowest mean rotation error), then compared with no expert on
``--confirm``, ``--wide`` and ``--side`` (sets that took no part in choosing them; McNemar on the
> 30° views, paired bootstrap of the mean). ``--cache`` keeps each set's numbers. Writes
``results/edge_on_expert.json`` and the "edge-on-expert" section of RESULTS.md.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from _common import PAIRED_HEADER, cached_npz, concat_sets, environment, paired_cells, test_views, update_results_md, write_json
from hybridpose.metrics import rotation_error_deg
from hybridpose.objects import view_elevation_deg
from hybridpose.regressors.evaluate import FAILED_ROT_DEG, GROSS_ERROR_DEG, paired_comparison
from hybridpose.regressors.predictor import EXPERT_BELOW_DEG, CheckpointRegressor, shipped_checkpoint

GATES_DEG = (0.0, 8.0, 12.0, 16.0, 20.0, 25.0)
RULES = ("replace", "quality")


def measure(data: str, checkpoint: str, expert: str, limit=None) -> dict:
    """Per view of ``data``: rotation error without the expert (``base``), the first estimate's view
    elevation (° ; 90 where nothing was found), the error with the expert where that elevation is below
    the largest gate (``expert``; ``base`` elsewhere) and the seconds each full path took."""
    plain = CheckpointRegressor(checkpoint, threads=1, edge_on_expert=None)
    # gate 90°: the expert runs wherever it is asked to; the replay applies the gates
    with_expert = CheckpointRegressor(checkpoint, threads=1, edge_on_expert=expert, expert_below_deg=90.0,
                                      expert_rule="replace")
    obj = with_expert.expert_object
    rows = {"base": [], "elevation": [], "expert": [], "seconds_base": [], "seconds_expert": [],
            "quality_base": [], "quality_expert": []}
    with torch.no_grad():
        for frame, gt in test_views(data, limit):
            t0 = time.perf_counter()
            m = plain.predict(frame)
            rows["seconds_base"].append(time.perf_counter() - t0)
            err = FAILED_ROT_DEG if m.lost else rotation_error_deg(m.pose, gt.pose)
            est = plain._keypoint_estimate(frame.image, frame.camera, None)
            elevation = 90.0 if est is None else view_elevation_deg(est[0].pose, obj)
            rows["base"].append(err), rows["elevation"].append(elevation), rows["quality_base"].append(m.quality)
            if elevation >= max(GATES_DEG):
                rows["expert"].append(err), rows["seconds_expert"].append(rows["seconds_base"][-1])
                rows["quality_expert"].append(m.quality)
                continue
            t0 = time.perf_counter()
            e = with_expert.predict(frame)
            rows["seconds_expert"].append(time.perf_counter() - t0)
            rows["expert"].append(FAILED_ROT_DEG if e.lost else rotation_error_deg(e.pose, gt.pose))
            rows["quality_expert"].append(e.quality)
    return {k: np.asarray(v, dtype=float) for k, v in rows.items()}


def cached(folder, data: str, checkpoint: str, expert: str, limit=None) -> dict:
    """:func:`measure`, kept in ``folder`` (one .npz per set, checkpoint, expert and limit) when given."""
    key = f"{Path(data).name}__{Path(checkpoint).stem}__{Path(expert).stem}__{limit}"
    return cached_npz(folder, key, lambda: measure(data, checkpoint, expert, limit))


def replay(m: dict, gate_deg: float, rule: str = "replace") -> tuple[np.ndarray, np.ndarray]:
    """(rotation errors (°) with the expert below ``gate_deg``, which views it ran on). ``rule``:
    ``"replace"`` (its result is returned, as the predictor does) or ``"quality"`` (the result of higher
    measurement quality is returned)."""
    ran = m["elevation"] < gate_deg
    use = ran if rule == "replace" else ran & (m["quality_expert"] > m["quality_base"])
    return np.where(use, m["expert"], m["base"]), ran


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--expert", required=True, help="edge-on expert checkpoint")
    ap.add_argument("--tune", nargs="+", required=True, help="sets that choose the gate")
    ap.add_argument("--confirm", nargs="+", required=True, help="fresh sets lit like the training data")
    ap.add_argument("--wide", nargs="*", default=[], help="fresh sets lit from within 85° of the optical axis")
    ap.add_argument("--side", nargs="*", default=[], help="fresh sets lit from within 120° (side- and back-light)")
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--limit", type=int, default=None)
    ap.add_argument("--cache", default=None, help="folder keeping each set's per-view numbers (reused when present)")
    args = ap.parse_args()
    CheckpointRegressor(args.checkpoint, edge_on_expert=args.expert)  # fail early on a wrong expert
    groups = {"tune": args.tune, "confirm": args.confirm, "wide": args.wide, "side": args.side}
    measured = {g: [cached(args.cache, d, args.checkpoint, args.expert, args.limit) for d in dirs]
                for g, dirs in groups.items() if dirs}
    tune = concat_sets(measured["tune"])
    variants = [("replace", 0.0)] + [(rule, g) for rule in RULES for g in GATES_DEG if g > 0]
    chosen = min(variants, key=lambda v: (replay(tune, v[1], v[0])[0].mean(), v[1]))
    rows, out = [], {"env": environment(), "checkpoint": args.checkpoint, "expert": args.expert, "sets": groups,
                     "chosen": {"rule": chosen[0], "gate_deg": chosen[1]}, "shipped_gate_deg": EXPERT_BELOW_DEG,
                     "groups": {}}
    for g, sets in measured.items():
        m = concat_sets(sets)
        group = {"views": len(m["base"]), "variants": {}}
        for rule, gate in variants:
            err, ran = replay(m, gate, rule)
            c = paired_comparison(m["base"], err)
            # the quality rule runs both full paths where the expert runs
            seconds = np.where(ran, m["seconds_expert"] + (m["seconds_base"] if rule == "quality" else 0), m["seconds_base"])
            group["variants"][f"{rule} {gate:g}"] = {"ran": int(ran.sum()), "ms_per_view": float(1e3 * seconds.mean()), **c}
            rows.append((g, (rule, gate), c, int(ran.sum()), float(1e3 * seconds.mean())))
        out["groups"][g] = group
    write_json("edge_on_expert", out)
    lines = ["## Edge-on expert of the shipped keypoint regressor (`benchmarks/edge_on_expert.py`)", "",
             f"Checkpoint `{args.checkpoint.split('/')[-1]}`, expert `{args.expert.split('/')[-1]}`. Full inference "
             "path without the expert, and with it where the first estimate is seen within *gate* of edge-on (the "
             "expert's network passes and PnP replace the first ones; gate 0: never): *replace* returns the expert's "
             "result, *quality* the one of higher measurement quality (both paths run). *tune* "
             f"({', '.join(args.tune)}) chose {chosen[0]} at {chosen[1]:.0f}° (lowest mean); *confirm* ({', '.join(args.confirm)})"
             + (f", *wide* ({', '.join(args.wide)}, sun within 85° of the optical axis)" if args.wide else "")
             + (f", *side* ({', '.join(args.side)}, within 120°)" if args.side else "")
             + " took no part in choosing it. *only without / only with*: views > "
             f"{GROSS_ERROR_DEG:.0f}° off only without the expert / only with it (McNemar p); Δ mean: with − without, "
             "paired bootstrap 95 % interval; ms/view: mean of the whole path, one thread, timed inside this "
             f"benchmark (compare within a row group only). git {out['env']['git']}.", "",
             f"| sets | rule, gate ° | views it ran on | {PAIRED_HEADER.format(gross=GROSS_ERROR_DEG)} | ms/view |",
             "|---|---|---|---|---|---|---|---|---|"]
    for g, (rule, gate), c, n, ms in rows:
        bold = "**" if (rule, gate) == chosen else ""
        lines.append(f"| {g} | {bold}{rule if gate else 'none'}{f', {gate:.0f}' if gate else ''}{bold} | {n} | "
                     f"{paired_cells(c)} | {ms:.1f} |")
    update_results_md("edge-on-expert", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
