"""The shipped regressor on each inference engine: ms per view and accuracy, interleaved in one run.

Usage: python benchmarks/inference_engines.py --data data/truss_test100 [--limit 1000] [--configs C [C ...]]

A configuration is an engine, optionally with cheaper settings after slashes: ``torch``,
``onnxruntime-int8/no-expert`` (``edge_on_expert=None``), ``onnxruntime/no-turns`` (``turns="off"``).
The first is the reference the others are paired with (default: torch, onnxruntime, onnxruntime-int8).
Writes benchmarks/results/inference_engines.json and the "inference-engines" section of RESULTS.md
(``--section NAME``: results/NAME.json, with dashes as underscores, and that section).

Every view is predicted by each engine, in blocks of 50 views that each engine runs in turn (the order
rotating from block to block), on one thread, so a load that comes and goes on a shared machine falls
on all engines alike: the ms ratios are what
to read, the absolute ms belong to this CPU (its bare torch network call is recorded beside them). The
accuracy of each configuration is paired with the reference's on the same views (:func:`paired_comparison`: bootstrap
95 % interval of the mean difference, McNemar on the views > 30° off).
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from _common import PAIRED_HEADER, environment, paired_cells, publish, test_views, weights_tag
from hybridpose.machine import cpu_label
from hybridpose.metrics import rotation_error_deg, translation_error_m
from hybridpose.training.compare import paired_comparison
from hybridpose.training.eval_report import GROSS_ERROR_DEG
from hybridpose.training.evaluate import FAILED_ROT_DEG, network_call_ms
from hybridpose.regressors.predictor import CheckpointRegressor
from hybridpose.regressors.checkpoints import shipped_checkpoint
from hybridpose.training.quantize import int8_path

ENGINES = ("torch", "onnxruntime", "onnxruntime-int8")
SETTINGS = {"no-expert": {"edge_on_expert": None}, "no-turns": {"turns": "off"}}


def regressor_options(config: str) -> dict:
    """``CheckpointRegressor`` keyword arguments of a configuration such as ``onnxruntime-int8/no-expert``."""
    engine, *settings = config.split("/")
    options = {"engine": engine}
    for s in settings:
        if s not in SETTINGS:
            raise ValueError(f"--configs: unknown setting {s!r} in {config!r} (known: {', '.join(SETTINGS)})")
        options.update(SETTINGS[s])
    return options


def measure(regs: dict, views, block: int = 50) -> dict:
    """Per engine: seconds per view, rotation error (°; a lost view FAILED_ROT_DEG) and translation
    error (m; NaN where lost). The views go in blocks of ``block``; each engine runs a whole block in
    turn, the order rotating from block to block: a load that comes and goes falls on all engines
    alike, and each runs with its own weights warm in the caches, as it would alone (one engine per
    view in turn thrashed them: every engine 10–20 % slower)."""
    names = list(regs)
    out = {n: {"seconds": [], "rot_deg": [], "trans_m": []} for n in names}
    views = list(views)
    for reg in regs.values():
        reg.predict(views[0][0])  # warm-up: sessions, caches
    for b, start in enumerate(range(0, len(views), max(1, int(block)))):
        chunk = views[start:start + max(1, int(block))]
        for n in names[b % len(names):] + names[:b % len(names)]:
            for frame, gt in chunk:
                t0 = time.perf_counter()
                m = regs[n].predict(frame)
                out[n]["seconds"].append(time.perf_counter() - t0)
                lost = m.pose is None
                out[n]["rot_deg"].append(FAILED_ROT_DEG if lost else rotation_error_deg(m.pose, gt.pose))
                out[n]["trans_m"].append(float("nan") if lost else translation_error_m(m.pose, gt.pose))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", required=True)
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--limit", type=int, default=1000)
    ap.add_argument("--block", type=int, default=50, help="views each engine runs in turn")
    ap.add_argument("--section", default="inference-engines", help="RESULTS.md section (and results JSON name)")
    ap.add_argument("--configs", nargs="+", default=None, help="engine[/no-expert][/no-turns] …; the first is the "
                                                              "reference (default: the three engines)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    names = args.configs or [e for e in ENGINES if e != "onnxruntime-int8" or int8_path(args.checkpoint).is_file()]
    regs = {c: CheckpointRegressor(args.checkpoint, **regressor_options(c)) for c in names}
    ref = names[0]
    rows = measure(regs, test_views(args.data, args.limit), args.block)
    bare = {e: network_call_ms(reg) for e, reg in regs.items()}
    env = environment()
    summary = {}
    for e in names:
        r = rows[e]
        summary[e] = {"ms_per_view": 1e3 * float(np.mean(r["seconds"])), "bare_network_ms": bare[e],
                      "rot_mean_deg": float(np.mean(r["rot_deg"])), "rot_median_deg": float(np.median(r["rot_deg"])),
                      "trans_mean_m": float(np.nanmean(r["trans_m"])), "lost": int(np.isnan(r["trans_m"]).sum()),
                      "vs_reference": None if e == ref else paired_comparison(rows[ref]["rot_deg"], r["rot_deg"])}
    int8 = any(c.startswith("onnxruntime-int8") for c in names)
    payload = {"env": env, "data": args.data, "checkpoint": args.checkpoint, "views": len(rows[ref]["seconds"]),
               "reference": ref, "weights": weights_tag(args.checkpoint, *[int8_path(args.checkpoint)] * int8),
               "engines": summary, "per_view": {e: {k: v for k, v in rows[e].items()} for e in names}}
    base = summary[ref]["ms_per_view"]
    lines = [
        "## Inference engines (`python benchmarks/inference_engines.py`)",
        "",
        f"`{args.data}`, {payload['views']} views, the shipped `default` (with its twin verifier, and its edge-on expert but where `no-expert`) "
        f"in each configuration in turn ({args.block} views each, the order rotating), 1 thread, one run; {cpu_label(env)}, git {env['git']}, weights {payload['weights']}. "
        "ms/view is the whole `predict` path; the bare call is one batch-1 network call on that engine.",
        "",
        f"| configuration | ms/view | × {ref} | bare network call ms | mean rot ° | median rot ° | mean trans m | lost | "
        + PAIRED_HEADER.format(gross=GROSS_ERROR_DEG).replace("without", ref).replace("with", "this") + " |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for e, s in summary.items():
        paired = paired_cells(s["vs_reference"]) if s["vs_reference"] else "– | – | – | – | –"
        lines.append(f"| {e} | {s['ms_per_view']:.1f} | {s['ms_per_view'] / base:.2f} | {s['bare_network_ms']:.1f} | "
                     f"{s['rot_mean_deg']:.2f} | {s['rot_median_deg']:.2f} | {s['trans_mean_m']:.3f} | {s['lost']} | {paired} |")
    if args.section != "inference-engines":
        lines[0] = (f"## Configurations {', '.join(names)} (`python benchmarks/inference_engines.py --configs "
                    f"{' '.join(names)} --section {args.section}`)")
    publish(args.section.replace("-", "_"), args.section, payload, lines)


if __name__ == "__main__":
    main()
