"""The dim fallback of the shipped keypoint regressor: views it loses without it, and what it makes of them.

Usage:
    common="--object truss --kind random --size 640x480 --in-view --sun-range 0.7,1.3 --workers 2 --count 1000"
    hybridpose render $common --sun-cone 40 --seed 146 --out data/truss_test146                      # and so on
    python benchmarks/dim_fallback.py --data data/truss_test146 data/truss_test147 ...

Under grazing sun the whole truss can sit a few grey levels above black with no glint the bright
detection keeps, and the predictor reports the view lost (counted as ``FAILED_ROT_DEG`` = 180° in the
tables). With ``dim_fallback`` (the default) it then looks for the faintly lit object
(``detect_dim_object``) and estimates on its box; it also does so where the bright box gave no plausible
pose. Only those views can change, so the shipped path runs once without the fallback and again, with
it, on the views it lost. Writes ``results/dim_fallback.json`` and the "dim-fallback" section of
RESULTS.md (lost views, their errors with the fallback, the paired comparison over every view).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from _common import PAIRED_HEADER, environment, paired_cells, test_views, update_results_md, write_json
from hybridpose.metrics import rotation_error_deg
from hybridpose.regressors.evaluate import FAILED_ROT_DEG, GROSS_ERROR_DEG, paired_comparison
from hybridpose.regressors.predictor import CheckpointRegressor, shipped_checkpoint


def measure(data: str, checkpoint: str, limit=None) -> dict:
    """Rotation errors (°) per view of ``data`` without the fallback and with it (``FAILED_ROT_DEG``
    where lost), and the quality of the measurements the fallback made."""
    reg = CheckpointRegressor(checkpoint, threads=1, dim_fallback=False)
    without, rescued_quality = [], []
    with torch.no_grad():
        frames = []
        for frame, gt in test_views(data, limit):
            m = reg.predict(frame)
            without.append(FAILED_ROT_DEG if m.lost else rotation_error_deg(m.pose, gt.pose))
            frames.append((frame, gt.pose) if m.lost else None)
        with_fallback = list(without)
        reg.dim_fallback = True
        for k, item in enumerate(frames):
            if item is None:
                continue
            m = reg.predict(item[0])
            if not m.lost:
                with_fallback[k] = rotation_error_deg(m.pose, item[1])
                rescued_quality.append(m.quality)
    return {"without": np.asarray(without), "with": np.asarray(with_fallback),
            "rescued_quality": np.asarray(rescued_quality)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", nargs="+", required=True, help="test sets (BOP folders)")
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args()
    per_set = {d: measure(d, args.checkpoint, args.limit) for d in args.data}
    without = np.concatenate([m["without"] for m in per_set.values()])
    with_fallback = np.concatenate([m["with"] for m in per_set.values()])
    quality = np.concatenate([m["rescued_quality"] for m in per_set.values()])
    lost = without >= FAILED_ROT_DEG
    found = lost & (with_fallback < FAILED_ROT_DEG)
    c = paired_comparison(without, with_fallback)
    out = {"env": environment(), "checkpoint": args.checkpoint, "sets": args.data, "views": int(len(without)),
           "lost_without": int(lost.sum()), "lost_with": int((with_fallback >= FAILED_ROT_DEG).sum()),
           "found_errors_deg": with_fallback[found].tolist(), "found_quality": quality.tolist(), "comparison": c}
    write_json("dim_fallback", out)
    within = int(np.sum(with_fallback[found] <= GROSS_ERROR_DEG))
    lines = ["## Dim fallback of the shipped keypoint regressor (`benchmarks/dim_fallback.py`)", "",
             f"Sets: {', '.join(f'`{d}`' for d in args.data)} ({len(without)} views), checkpoint "
             f"`{Path(args.checkpoint).name}`. A lost view counts {FAILED_ROT_DEG:g}°. A = without the fallback, B = with "
             "it (the default); only views A lost can differ.", "",
             "| views lost (A) | lost (B) | found ≤ 30° | found > 30° | median error found | quality found (median) |",
             "|---|---|---|---|---|---|",
             f"| {int(lost.sum())} | {out['lost_with']} | {within} | {int(found.sum()) - within} | "
             f"{np.median(with_fallback[found]) if found.any() else float('nan'):.1f}° | "
             f"{np.median(quality) if len(quality) else float('nan'):.2f} |", "",
             f"| {PAIRED_HEADER.format(gross=GROSS_ERROR_DEG)} |", "|---|---|---|---|---|",
             f"| {paired_cells(c)} |"]
    update_results_md("dim-fallback", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
