"""The shipped default against the paper's best model on fresh test sets, with 95 % bootstrap intervals.

Usage (``--engine onnxruntime-int8 --no-expert``: the fast settings, a regressor built with those options):
    for s in 180 181 182 183 184 185 186 187; do
      hybridpose render --object truss --kind random --count 1000 --size 640x480 --seed $s --in-view \
                        --sun-cone 40 --sun-range 0.7,1.3 --workers 2 --out data/truss_test$s
    done
    python benchmarks/paper_check.py --data data/truss_test18{0..7} [--reports reports/paper_check] [--workers 2]

The sets are rendered as the held-out test set (seed 100, ``benchmarks/regressor_accuracy.py``) with seeds
no earlier benchmark used, so no rule of the shipped path was chosen on them. Each set runs the whole
``hybridpose eval`` path (``evaluate_checkpoint``: no roi, every shipped default; a lost view counts 180°
and 1 m) into ``--reports``/<set> (kept: a re-run reuses a set whose report is there), ``--workers`` sets
at a time, one torch thread each. The pooled views give the paper's three numbers (mean and median
rotation, mean translation) with percentile-bootstrap 95 % intervals over views (``--resamples``,
seeded). *Below the paper* means the interval's upper end is below the paper's number; *level* that the
interval holds it. Writes benchmarks/results/paper_check.json and the "paper-check" section of RESULTS.md.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from _common import environment, publish, set_names, weights_tag
from hybridpose.machine import cpu_label
from hybridpose.training.eval_report import GROSS_ERROR_DEG, PAPER
from hybridpose.regressors.checkpoints import shipped_checkpoint

PAPER_BEST = "Parallel VGG-19"


def evaluate_set(job) -> str:
    """Run ``hybridpose eval``'s path on one set (in a worker process); returns its report.json path."""
    checkpoint, data, out, limit, options = job
    report = Path(out) / "report.json"
    if not report.is_file():
        import torch

        from hybridpose.training.evaluate import evaluate_checkpoint

        torch.set_num_threads(1)
        evaluate_checkpoint(checkpoint, data, out, limit=limit, gradcam_count=0, timing_images=20, **options)
    return str(report)


def verifier_tag() -> str:
    """The shipped twin verifier's file and :func:`weights_tag` (the part of the path that ships changed most
    often: the table says which one it measured)."""
    from hybridpose.regressors.checkpoints import WEIGHTS_DIR

    return f"`twin_verifier.pt` {weights_tag(WEIGHTS_DIR / 'twin_verifier.pt')}"


def bootstrap(values: np.ndarray, stat, resamples: int, rng) -> dict:
    """``stat`` of ``values`` with its percentile-bootstrap 95 % interval (views resampled)."""
    idx = rng.integers(0, len(values), size=(resamples, len(values)))
    boot = stat(values[idx], axis=1)
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return {"estimate": float(stat(values)), "ci95": [float(lo), float(hi)]}


def verdict(ci: dict, paper: float) -> str:
    lo, hi = ci["ci95"]
    return "below" if hi < paper else ("above" if lo > paper else "level")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", nargs="+", required=True, help="fresh test sets (BOP folders)")
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--reports", default="reports/paper_check", help="one hybridpose eval report per set (kept)")
    ap.add_argument("--workers", type=int, default=2, help="sets evaluated at once (one torch thread each)")
    ap.add_argument("--resamples", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--limit", type=int, default=None, help="views per set (a smoke run; the table says how many)")
    ap.add_argument("--section", default="paper-check", help="RESULTS.md section (and results JSON name) to (re)write")
    ap.add_argument("--engine", default="auto", help="the regressor's engine (auto, torch, onnxruntime, onnxruntime-int8)")
    ap.add_argument("--no-expert", action="store_true", help="without the edge-on expert (edge_on_expert=None)")
    args = ap.parse_args()
    options = {"engine": args.engine, **({"edge_on_expert": None} if args.no_expert else {})}
    label = "default" + "".join(f", {x}" for x in ([args.engine] if args.engine != "auto" else []) + ["no expert"] * args.no_expert)
    jobs = [(args.checkpoint, d, str(Path(args.reports) / Path(d).name), args.limit, options) for d in args.data]
    if args.workers > 1 and len(jobs) > 1:
        from hybridpose.workers import spawn_executor

        with spawn_executor(min(args.workers, len(jobs))) as pool:
            reports = list(pool.map(evaluate_set, jobs))
    else:
        reports = [evaluate_set(j) for j in jobs]
    per_set, rot_all, trans_all = [], [], []
    for d, path in zip(args.data, reports):
        rows = json.loads(Path(path).read_text())["per_image"]
        rot = np.array([r["rot_deg"] for r in rows])
        trans = np.array([r["trans_m"] for r in rows])
        per_set.append({"set": d, "views": len(rows), "rot_mean_deg": float(rot.mean()),
                        "rot_median_deg": float(np.median(rot)), "trans_mean_m": float(trans.mean()),
                        "gross_share": float(np.mean(rot > GROSS_ERROR_DEG)),
                        "lost": int(sum(r["lost"] for r in rows))})
        rot_all.append(rot)
        trans_all.append(trans)
    rot, trans = np.concatenate(rot_all), np.concatenate(trans_all)
    rng = np.random.default_rng(args.seed)
    pooled = {"views": len(rot), "rot_mean_deg": bootstrap(rot, np.mean, args.resamples, rng),
              "rot_median_deg": bootstrap(rot, np.median, args.resamples, rng),
              "trans_mean_m": bootstrap(trans, np.mean, args.resamples, rng),
              "gross_share": float(np.mean(rot > GROSS_ERROR_DEG)), "lost": int(sum(s["lost"] for s in per_set))}
    paper = dict(zip(("rot_mean_deg", "rot_median_deg", "trans_mean_m"), PAPER[PAPER_BEST]))
    pooled["verdict"] = {k: verdict(pooled[k], paper[k]) for k in paper}
    env = environment()
    payload = {"env": env, "checkpoint": args.checkpoint, "options": options, "verifier": verifier_tag(), "sets": args.data,
               "resamples": args.resamples,
               "seed": args.seed, "paper": {PAPER_BEST: paper}, "per_set": per_set, "pooled": pooled}

    def cell(c, fmt):
        return f"{c['estimate']:{fmt}} ({c['ci95'][0]:{fmt}}–{c['ci95'][1]:{fmt}})"

    lines = [
        f"## The shipped {label} against the paper on fresh sets (`python benchmarks/paper_check.py`, twin verifier "
        f"{verifier_tag()})",
        "",
        f"{len(args.data)} fresh sets ({set_names(args.data)}) of {per_set[0]['views']} rendered 640×480 views each, rendered as the "
        "held-out test set (truss wholly in view, 0.4–1.2 m, sun within 40° of the default, ×0.7–1.3) with seeds "
        "no rule of the shipped path was chosen on. Whole `hybridpose eval` path, no roi; a lost view counts 180° / "
        f"1 m. Pooled: percentile-bootstrap 95 % intervals over the {len(rot)} views ({args.resamples} resamples). "
        f"git {env['git']}, {cpu_label(env)}.",
        "",
        "| model | views | mean rot ° | median rot ° | mean trans m | > 30° | lost |",
        "|---|---|---|---|---|---|---|",
        f"| paper: {PAPER_BEST} (their data, GPU, 100 epochs) | – | {paper['rot_mean_deg']:.2f} | "
        f"{paper['rot_median_deg']:.2f} | {paper['trans_mean_m']:.2f} | – | – |",
    ]
    for s in per_set:
        lines.append(f"| {label}, {Path(s['set']).name} | {s['views']} | {s['rot_mean_deg']:.2f} | {s['rot_median_deg']:.2f} | "
                     f"{s['trans_mean_m']:.3f} | {s['gross_share']:.2%} | {s['lost']} |")
    lines.append(f"| **{label}, pooled** | {len(rot)} | **{cell(pooled['rot_mean_deg'], '.2f')}** | "
                 f"**{cell(pooled['rot_median_deg'], '.2f')}** | **{cell(pooled['trans_mean_m'], '.3f')}** | "
                 f"{pooled['gross_share']:.2%} | {pooled['lost']} |")
    v = pooled["verdict"]
    lines += ["", f"Against the paper's {PAPER_BEST}: mean rotation **{v['rot_mean_deg']}**, median rotation "
              f"**{v['rot_median_deg']}**, mean translation **{v['trans_mean_m']}** (below: the whole interval under "
              "the paper's number; level: the interval holds it)."]
    publish(args.section.replace("-", "_"), args.section, payload, lines)


if __name__ == "__main__":
    main()
