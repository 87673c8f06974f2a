"""Another twin verifier in the shipped predictor's place, compared view by view on the same candidates.

Usage:
    python benchmarks/verifier_swap.py --verifier runs/tv4/best.pt --cone data/truss_test154 ... \
        [--wide data/truss_wide222 ...] [--side data/truss_side244 ...] --cache runs/twin_cache

The twin verifier only weighs the box twins the predictor has already made (``benchmarks/pooled_twins.py``
records every one: head, verifier, edge fit, PnP quality, true error), so swapping it changes nothing else.
Per set this takes the recorded candidates once and the candidate verifier's probabilities of the same
candidates (:func:`pooled_twins.verifier_column`), and replays each ``expert_rule``'s twin and estimate
choice with each verifier: the quality rule (exactly what ``predict`` returns: 0 differences on 23 000 views,
session 25; the default until session 26), the pooled rule and pooled-unsure (the default since). A = the shipped verifier, B = the candidate; McNemar on the views > 30° off, paired bootstrap of
the mean rotation error. Same network size, so the same cost per call.
"""
from __future__ import annotations

import argparse

import numpy as np

from _common import (PAIRED_HEADER, add_lighting_groups, concat_sets, environment, lighting_groups, paired_cells, publish,
                     set_names)
from hybridpose.regressors.evaluate import GROSS_ERROR_DEG, paired_comparison
from hybridpose.regressors.predictor import shipped_checkpoint
from pooled_twins import cached, errors_of, pooled_choice, pooled_unsure_choice, quality_choice

RULES = (("quality", quality_choice), ("pooled", pooled_choice), ("pooled-unsure (shipped)", pooled_unsure_choice))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--verifier", required=True, help="candidate twin-verifier checkpoint (train-verifier best.pt)")
    add_lighting_groups(ap)
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--expert", default="auto", help="edge-on expert checkpoint (default: the shipped one)")
    ap.add_argument("--limit", type=int, default=None)
    ap.add_argument("--cache", default=None, help="folder keeping each set's per-view numbers (reused when present)")
    ap.add_argument("--section", default="verifier-swap", help="RESULTS.md section to (re)write")
    args = ap.parse_args()
    groups = lighting_groups(ap, args)
    out = {"env": environment(), "checkpoint": args.checkpoint, "expert": args.expert, "verifier": args.verifier,
           "sets": groups, "groups": {}}
    lines = [f"## Twin verifier `{args.verifier}` in the shipped one's place (`benchmarks/verifier_swap.py`)", "",
             "A = shipped `twin_verifier.pt`, B = the candidate, on the same recorded candidates (everything but the "
             "verifier's probabilities unchanged); rule = the predictor's twin and estimate choice replayed.", "",
             f"| sets | views | rule | {PAIRED_HEADER.format(gross=GROSS_ERROR_DEG)} |", "|---|---|---|---|---|---|---|---|"]
    per_view = {rule: [] for rule, _ in RULES}
    for g, dirs in groups.items():
        a = concat_sets([cached(args.cache, d, args.checkpoint, args.expert, args.limit) for d in dirs])
        b = dict(a, **concat_sets([cached(args.cache, d, args.checkpoint, args.expert, args.limit, verifier=args.verifier)
                                   for d in dirs]))
        out["groups"][g] = {"views": len(a["n_est"])}
        for rule, choose in RULES:
            ea, eb = errors_of(a, *choose(a)), errors_of(b, *choose(b))
            per_view[rule].append((ea, eb))
            c = paired_comparison(ea, eb)
            out["groups"][g][rule] = c
            lines.append(f"| {g} ({set_names(dirs)}) | {len(ea)} | {rule} | "
                         f"{paired_cells(c)} |")
    if len(groups) > 1:
        for rule, pairs in per_view.items():
            ea, eb = (np.concatenate([p[i] for p in pairs]) for i in (0, 1))
            c = paired_comparison(ea, eb)
            out[f"all {rule}"] = c
            lines.append(f"| all | {len(ea)} | {rule} | {paired_cells(c)} |")
    publish(args.section.replace("-", "_"), args.section, out, lines)


if __name__ == "__main__":
    main()
