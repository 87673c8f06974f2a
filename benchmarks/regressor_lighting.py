"""Regressors under lighting they were or were not trained for: where the sun may be.

Usage:
    common="--object truss --kind random --size 640x480 --in-view --sun-range 0.7,1.3 --workers 2 --count 1000"
    hybridpose render $common --sun-cone 40 --seed 128 --out data/truss_test128                        # trained cone
    hybridpose render $common --sun-dir 0,0,1 --sun-cone 85 --seed 210 --out data/truss_wide210        # any side
    python benchmarks/regressor_lighting.py --data cone=data/truss_test128 --data wide=data/truss_wide210 \\
        [--checkpoint NAME=PATH ...] [--sun-known NAME ...]

The ``default`` up to stage 7 was trained with the sun within 40° of one direction (0.6, 0.4, 0.7):
light from behind the camera's upper left; stage 9 (session 22) also on light from any side. In orbit
the sun can be anywhere. The *wide* sets draw it
anywhere within 85° of the optical axis (phase angle 0–85°, light from any side of the image).
Runs ``hybridpose eval`` (full inference path, no roi) of each checkpoint on each set — and, for the
checkpoints named by ``--sun-known``, again with each image's sun given to the regressor (its crop
turned so the light crosses it as in training: ``predict(..., sun_direction_cam=...)``) — compares the
first row with each other one on the same views (McNemar on the > 30° views, paired bootstrap of the
mean), and tabulates the errors pooled over the sets against the angle between each image's
sun and the shipped default's training direction, and against the phase angle. Writes
``results/regressor_lighting.json`` and the "regressor-lighting" section of RESULTS.md.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from _common import environment, update_results_md, write_json
from hybridpose.machine import cpu_label
from hybridpose.regressors.evaluate import PHASE_BINS_DEG, compare_reports, error_in_bins, evaluate_checkpoint
from hybridpose.regressors.predictor import shipped_checkpoint
from hybridpose.render import SpaceLighting

# the training sun of the default up to stage 7: the default direction, ±40°
TRAINED_SUN = np.asarray(SpaceLighting().sun_direction_cam)
TRAINED_CONE_DEG = 40.0
FROM_TRAINED_BINS_DEG = np.array([0.0, 20.0, 40.0, 60.0, 80.0, 100.0, 180.0])


def angle_from_trained_deg(rows) -> None:
    """Adds ``sun_from_trained_deg`` to each row with a recorded sun (in place)."""
    for r in rows:
        if "sun_direction_cam" in r:
            d = np.asarray(r["sun_direction_cam"], dtype=float)
            r["sun_from_trained_deg"] = float(np.degrees(np.arccos(np.clip(d @ TRAINED_SUN / np.linalg.norm(d), -1, 1))))


def table(bins_by_model: dict, label: str) -> list[str]:
    names = list(bins_by_model)
    lines = [f"| {label} | n | " + " | ".join(f"{n}: mean ° / median ° / > 30°" for n in names) + " |",
             "|---|---|" + "---|" * len(names)]
    first = bins_by_model[names[0]]
    for k, b in enumerate(first):
        cells = []
        for n in names:
            c = bins_by_model[n][k]
            cells.append(f"{c['rot_mean_deg']:.2f} / {c['rot_median_deg']:.2f} / {c['gross_error_share']:.1%}")
        lines.append(f"| {b['lo_deg']:.0f}–{b['hi_deg']:.0f} | {b['n']} | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", action="append", required=True, help="NAME=DIR, a rendered set (repeat)")
    ap.add_argument("--checkpoint", action="append", default=[], help="NAME=PATH (default: the shipped default); "
                    "the first is the reference of the paired comparisons")
    ap.add_argument("--sun-known", action="append", default=[], metavar="NAME",
                    help="also evaluate checkpoint NAME with each image's sun given (row 'NAME, sun given')")
    ap.add_argument("--limit", type=int, default=None)
    ap.add_argument("--reports", default=None, help="keep the eval reports in this folder (default: a temp folder)")
    args = ap.parse_args()
    sets = [d.split("=", 1) for d in args.data]
    checkpoints = [c.split("=", 1) for c in args.checkpoint] or [["default", str(shipped_checkpoint("default"))]]
    unknown = set(args.sun_known) - {n for n, _ in checkpoints}
    if unknown:
        raise SystemExit(f"--sun-known: no checkpoint named {', '.join(sorted(unknown))}")
    # rows: (name, checkpoint path, sun given), each checkpoint's sun-given row right after it
    models = [row for n, p in checkpoints for row in [(n, p, False)] + ([(f"{n}, sun given", p, True)]
                                                                          if n in args.sun_known else [])]
    root = Path(args.reports or tempfile.mkdtemp())
    summaries, reports = {}, {}
    for model, path, sun_known in models:
        for name, data in sets:
            out = root / f"{model.replace(', ', '_').replace(' ', '-')}_{name}"
            s = evaluate_checkpoint(path, data, out, limit=args.limit, timing_images=20, gradcam_count=0,
                                    sun_known=sun_known)
            summaries[(model, name)], reports[(model, name)] = s, out / "report.json"
            print(f"{model} on {name}: {s['rot_mean_deg']:.2f}° mean, {s['rot_median_deg']:.2f}° median, "
                  f"{s['gross_error_share']:.1%} > 30°, {s['trans_mean_m']:.3f} m")
    pooled = {}
    for model, _, _ in models:
        rows = []
        for name, _ in sets:
            rows += json.loads(reports[(model, name)].read_text())["per_image"]
        angle_from_trained_deg(rows)
        pooled[model] = {"from_trained": error_in_bins(rows, "sun_from_trained_deg", FROM_TRAINED_BINS_DEG),
                         "phase": error_in_bins(rows, "sun_phase_deg", PHASE_BINS_DEG)}
    comparisons = {}
    ref = models[0][0]
    for model, _, _ in models[1:]:
        for label, names in [(n, [n]) for n, _ in sets] + ([("all", [n for n, _ in sets])] if len(sets) > 1 else []):
            comparisons[f"{model} vs {ref} on {label}"] = compare_reports([reports[(ref, n)] for n in names],
                                                                          [reports[(model, n)] for n in names])
    env = environment()
    write_json("regressor_lighting", {
        "env": env, "sets": dict(sets), "checkpoints": dict(checkpoints), "sun_known": args.sun_known,
        "summaries": {f"{m} on {n}": s for (m, n), s in summaries.items()},
        "pooled_bins": pooled, "comparisons": comparisons})

    lines = [
        "## CNN regressors under other lighting (`python benchmarks/regressor_lighting.py`)",
        "",
        "Where the sun may be. The `default` up to stage 7 (session 14) was trained with the sun within 40° of one "
        "direction (0.6, 0.4, 0.7) in the camera frame — light from behind the camera's upper left, phase angle ≈ 6–86°; "
        "stage 9 (session 22) also with the sun anywhere within 85° of the optical axis. "
        "Sets: " + "; ".join(f"*{n}* `{d}`" for n, d in sets) + " (1000 rendered 640×480 views each, truss wholly in "
        "view, random pose 0.4–1.2 m; the sets' commands are in the script's docstring). Full inference path, no roi; "
        f"> 30°: share of views off by more than 30° in rotation. git {env['git']}, {cpu_label(env)}.",
        "",
        "| checkpoint | set | mean rot ° | median rot ° | mean trans m | SPEED | ADD-0.1d | > 30° | failures |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for (model, name), s in summaries.items():
        lines.append(f"| {model} | {name} | {s['rot_mean_deg']:.2f} | {s['rot_median_deg']:.2f} | {s['trans_mean_m']:.3f} | "
                     f"{s['speed_score']:.3f} | {s['add_0.1d_recall']:.2f} | {s['gross_error_share']:.1%} | {s['failures']} |")
    lines += ["", f"Pooled over the sets, by the angle between each image's sun and (0.6, 0.4, 0.7), the training sun "
              f"up to stage 7 (its cone: 0–{TRAINED_CONE_DEG:.0f}°):", ""]
    lines += table({m: b["from_trained"] for m, b in pooled.items()}, "sun from trained °")
    lines += ["", "Pooled over the sets, by sun phase angle (at the object, between the directions to the sun and to the "
              "camera: 0° sun behind the camera, 90° side-lit):", ""]
    lines += table({m: b["phase"] for m, b in pooled.items()}, "phase °")
    if comparisons:
        lines += ["", "Paired, same views (`hybridpose compare`): gross = > 30°; B − A of the mean with its 95 % paired "
                  "bootstrap interval.", "",
                  "| B vs A, set | gross only A / only B / both | McNemar p | mean B − A ° (95 %) |", "|---|---|---|---|"]
        for label, c in comparisons.items():
            m = c["rot_mean_diff_deg"]
            lines.append(f"| {label} | {c['gross_only_a']} / {c['gross_only_b']} / {c['gross_both']} | "
                         f"{c['mcnemar_p']:.3g} | {m['estimate']:+.2f} ({m['ci95'][0]:+.2f} … {m['ci95'][1]:+.2f}) |")
    update_results_md("regressor-lighting", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
