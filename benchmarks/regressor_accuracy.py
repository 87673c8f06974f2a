"""Trained regressors on the held-out rendered truss test set, beside the paper's table.

Usage:
    hybridpose render --object truss --kind random --count 1000 --size 640x480 --seed 100 --in-view \
                      --sun-cone 40 --sun-range 0.7,1.3 --out data/truss_test
    python benchmarks/regressor_accuracy.py --data data/truss_test [--checkpoint NAME=PATH ...]

Default checkpoint: the shipped ``default``. Runs ``hybridpose eval`` for each (full inference path,
no roi: detection, a network pass (the crop turned by ±20°/±40° too where PnP drops keypoints, a
second pass where the twin head is unsure), PnP dropping the worst keypoint, twin head + verifier +
edge check), without the crop turns, with RANSAC for PnP's outliers, without the twin verifier, without the
edge-on expert (where one is shipped), with the expert's quality rule (the older default),
without the final edge refinement, with always one and always two passes, with each view's true
object box as ``roi`` (what a tracker on the object passes), with float32 networks instead of the 8-bit
ones ``engine="auto"`` runs, and what a quality gate keeps (accuracy by quality); copies its plots to
``benchmarks/results/`` and writes the "regressor-accuracy" section of RESULTS.md.
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

from _common import BENCH_DIR, environment, update_results_md, write_json
from hybridpose.machine import cpu_label
from hybridpose.training.eval_report import PAPER, covariance_lines, quality_table
from hybridpose.training.evaluate import evaluate_checkpoint
from hybridpose.regressors.checkpoints import shipped_checkpoint, WEIGHTS_DIR


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", required=True)
    ap.add_argument("--checkpoint", action="append", default=[], help="NAME=PATH (default: the shipped default)")
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args()
    pairs = [c.split("=", 1) for c in args.checkpoint] or [["default", str(shipped_checkpoint("default"))]]
    results = {}
    # every row runs the shipped path (evaluate_checkpoint's defaults: twin verifier, crop
    # turns, PnP dropping the worst keypoint, edge refinement, passes "auto") but for what its name says
    variants = [("", {}), (", no crop turns", {"turns": "off"}), (", PnP outliers by RANSAC", {"pnp_outliers": "ransac"}),
                (", no twin verifier", {"verifier": None}),
                (", no edge refinement", {"refine_edges": False}), (", 1 pass", {"passes": 1}),
                (", 2 passes", {"passes": 2}), (", true box as roi", {"roi": "truth"}),
                (", float32 networks (engine onnxruntime)", {"engine": "onnxruntime"})]
    if (WEIGHTS_DIR / "edge_on_expert.pt").is_file():
        variants.insert(4, (", no edge-on expert", {"edge_on_expert": None}))
        variants.insert(5, (", quality rule (the older default)", {"expert_rule": "quality"}))
    runs = [(n + suffix, p, options) for suffix, options in variants for n, p in pairs]
    for name, path, options in runs:
        tmp = Path(tempfile.mkdtemp())
        s = evaluate_checkpoint(path, args.data, tmp, limit=args.limit, **options)
        if name in dict(pairs):  # the plots of the default inference path
            for png in ("error_vs_distance.png", "gradcam.png"):
                if (tmp / png).exists():
                    shutil.copy(tmp / png, BENCH_DIR / "results" / f"regressor_{name}_{png}")
        shutil.rmtree(tmp)
        results[name] = s
        print(name, {k: v for k, v in s.items() if not k.startswith("error_vs")})
    env = environment()
    write_json("regressor_accuracy", {"env": env, "data": args.data, "results": results})
    lines = [
        "## CNN regressors on the held-out test set (`python benchmarks/regressor_accuracy.py`)",
        "",
        f"`{args.data}`: {next(iter(results.values()))['images']} rendered 640×480 views, truss wholly in view, 0.4–1.2 m, "
        "random orientation, sun direction within 40° of the default and intensity ×0.7–1.3 (seed 100; the training "
        f"sets use other seeds, `hybridpose/regressors/weights/README.md`). Full inference path, no roi (but in the row *true box as roi*: "
        "each view's true object box, what a tracker on the object passes; timed without it). Failures count as 180° / 1 m; *> 30°*: share of views off by more "
        f"than 30° in rotation (mostly the truss turned end for end). *ms/img*: lowest of 3 runs of the mean time of the whole `predict` over the "
        f"first 100 views (the extra passes, turns and fits run only on hard views: a median would hide them), on the "
        f"default engine (`{next(iter(results.values()))['engine']}`), 1 or 2 threads. *In 90 % ellipsoid*: share of the views with a pose whose error lies inside the 90 % χ²₆ "
        f"ellipsoid of the reported covariance, around the true pose (around the nearest box twin): ≈ 90 % when the "
        f"covariance is calibrated, far below when over-confident. git {env['git']}, {cpu_label(env)}. "
        "This set has tuned many of the path's choices (the seed-100 views are the tuning set): fresh sets score "
        "higher, e.g. 4.44° mean / 0.51° median / 1.8 % > 30° on 48 000 fresh views (seeds 311–358), still below the paper's 4.61° / 4.41°.",
        "",
        "| model | mean rot ° | median rot ° | mean trans m | median trans m | SPEED | ADD-0.1d | > 30° | failures | "
        "in 90 % ellipsoid (twin) | ms/img 1 thr | ms/img 2 thr |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, (mr, md, mt) in PAPER.items():
        lines.append(f"| paper: {name} (their data, GPU, 100 epochs) | {mr:.2f} | {md:.2f} | {mt:.2f} | – | – | – | – | – | – | – | – |")
    for name, s in results.items():
        ms, c = s["ms_per_image"], s["covariance_check"]
        inside = f"{c['inside_share']:.0%} ({c['inside_share_twin']:.0%})" if c.get("views") else "–"
        lines.append(f"| **{name}** | {s['rot_mean_deg']:.2f} | {s['rot_median_deg']:.2f} | {s['trans_mean_m']:.3f} | "
                     f"{s['trans_median_m']:.3f} | {s['speed_score']:.3f} | {s['add_0.1d_recall']:.2f} | {s['gross_error_share']:.1%} | {s['failures']} | "
                     f"{inside} | {ms['1_thread']:.1f} | {ms['2_threads']:.1f} |")
    for name, s in list(results.items())[:1]:
        lines += ["", f"Error vs distance, `{name}` (mean ± 1σ; plot `results/regressor_{name}_error_vs_distance.png`, "
                      f"Grad-CAM of best/worst `results/regressor_{name}_gradcam.png`):", "",
                  "| distance m | n | rot ° | trans m |", "|---|---|---|---|"]
        lines += [f"| {b['lo_m']:.1f}–{b['hi_m']:.1f} | {b['n']} | {b['rot_mean_deg']:.2f} ± {b['rot_std_deg']:.2f} | "
                  f"{b['trans_mean_m']:.3f} ± {b['trans_std_m']:.3f} |" for b in s["error_vs_distance"]]
        lines += ["", f"Error vs view elevation, `{name}` (the line of sight's angle to the truss's plane: 0° edge-on, "
                      "90° face-on):", "", "| elevation ° | n | mean rot ° | median rot ° | > 30° |", "|---|---|---|---|---|"]
        lines += [f"| {b['lo_deg']:.0f}–{b['hi_deg']:.0f} | {b['n']} | {b['rot_mean_deg']:.2f} | {b['rot_median_deg']:.2f} | "
                  f"{b['gross_error_share']:.1%} |" for b in s["error_vs_elevation"]]
        lines += ["", f"`{name}`: measurement quality = PnP inlier share × exp(−RMS reprojection / 2 % of the crop side) × the twin "
                      "head's probability of the returned twin, so a pose that may be turned end for end scores low. "
                      + quality_table(s["accuracy_by_quality"])]
        lines += covariance_lines(s["covariance_check"], s["checkpoint"])
    update_results_md("regressor-accuracy", "\n".join(lines))


if __name__ == "__main__":
    main()
