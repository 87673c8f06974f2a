"""Where the shipped regressor's time goes: ms per view of each stage of ``predict``, 1 thread.

Usage: python benchmarks/predict_stages.py --data data/truss_test100 [--limit 400] [--checkpoint CK] [--engine E]
Writes benchmarks/results/predict_stages.json and the "predict-stages" section of RESULTS.md.

Each stage's function is timed where ``predict`` calls it (a stage called inside another is counted in
the outer one): the keypoint network (every pass of the engine that runs it, torch or ONNX Runtime:
first crop, the turned-crop batch, the second pass, the edge-on expert's), PnP, the edge fits (twin choice and refinement), the object detection and the
twin verifier; *other* is the rest of ``predict`` (crops, twin candidates, covariance). Views are split
by the network time they needed: *one pass* (one batch-1 call) and *more* (turned crops, second pass,
expert). The bare network call (batch 1, :func:`hybridpose.training.evaluate.network_call_ms`) and the
CPU are recorded: the same code ran the whole path in 17.9 ms/view on one host and 31 ms on another
whose network call was 1.9× slower (:mod:`hybridpose.machine`), so compare the shares, or timings
from one run.
"""
from __future__ import annotations

import argparse
import time
from collections import defaultdict
from contextlib import contextmanager

import numpy as np
import torch

from _common import environment, publish, test_views
from hybridpose.machine import cpu_label
from hybridpose.regressors import engines, keypoint_passes, network_detection, predictor, twin_verifier
from hybridpose.regressors.checkpoints import shipped_checkpoint
from hybridpose.regressors.predictor import CheckpointRegressor
from hybridpose.training.evaluate import network_call_ms
from hybridpose.edges import fit as edge_fit

# (owner, attribute, stage): where predict looks each stage up when it runs (module globals are read at
# call time, fit_edges is imported inside the methods that use it)
ENGINE_CALLS = ((engines.TorchEngine, "__call__"), (engines.OnnxRuntimeEngine, "__call__"))
STAGES = (*((owner, attr, "network") for owner, attr in ENGINE_CALLS), (keypoint_passes, "solve_pnp", "PnP"),
          (edge_fit, "fit_edges", "edge fits"), (network_detection, "detect_bright_object", "detection"),
          (predictor, "detect_dim_object", "detection"),
          (twin_verifier.TwinVerifier, "probabilities", "verifier"),
          (twin_verifier.TwinVerifier, "probabilities_of_sets", "verifier"))
STAGE_NAMES = ("network", "PnP", "edge fits", "detection", "verifier")


@contextmanager
def stage_timers():
    """Wrap every stage of :data:`STAGES` with a timer while in the block; yields (seconds, calls) dicts
    by stage name, outermost calls only."""
    seconds, calls, depth = defaultdict(float), defaultdict(int), [0]
    saved = [(owner, attr, getattr(owner, attr)) for owner, attr, _ in STAGES]

    def timed(fn, stage):
        def wrapper(*args, **kwargs):
            if depth[0]:
                return fn(*args, **kwargs)
            depth[0] += 1
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                depth[0] -= 1
                seconds[stage] += time.perf_counter() - t0
                calls[stage] += 1
        return wrapper

    try:
        for (owner, attr, fn), (_, _, stage) in zip(saved, STAGES):
            setattr(owner, attr, timed(fn, stage))
        yield seconds, calls
    finally:
        for owner, attr, fn in saved:
            setattr(owner, attr, fn)


def measure(reg: CheckpointRegressor, frames) -> list[dict]:
    """Per view: total and per-stage seconds, network calls and images through the network."""
    images_per_call = []
    engine_calls = [(owner, attr, getattr(owner, attr)) for owner, attr in ENGINE_CALLS]

    def counting(call):
        def run(self, x):
            images_per_call.append(int(x.shape[0]))
            return call(self, x)
        return run

    rows = []
    for owner, attr, call in engine_calls:
        setattr(owner, attr, counting(call))
    try:
        with stage_timers() as (seconds, calls):
            reg.predict(frames[0])  # warm-up
            for frame in frames:
                before, n_before = dict(seconds), len(images_per_call)
                t0 = time.perf_counter()
                reg.predict(frame)
                row = {"total": time.perf_counter() - t0}
                row.update({s: seconds[s] - before.get(s, 0.0) for s in STAGE_NAMES})
                row["network_calls"] = len(images_per_call) - n_before
                row["network_images"] = sum(images_per_call[n_before:])
                rows.append(row)
    finally:
        for owner, attr, call in engine_calls:
            setattr(owner, attr, call)
    return rows


def summarise(rows: list[dict]) -> dict:
    n = len(rows)
    total_ms = 1e3 * np.array([r["total"] for r in rows])
    out = {"views": n, "ms_total": float(total_ms.mean()), "ms_p95": float(np.percentile(total_ms, 95)),
           "ms_max": float(total_ms.max()),
           "network_calls": float(np.mean([r["network_calls"] for r in rows])),
           "network_images": float(np.mean([r["network_images"] for r in rows]))}
    for s in STAGE_NAMES:
        out[f"ms_{s}"] = 1e3 * float(np.mean([r[s] for r in rows]))
    out["ms_other"] = out["ms_total"] - sum(out[f"ms_{s}"] for s in STAGE_NAMES)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", required=True)
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--limit", type=int, default=400)
    ap.add_argument("--engine", default="auto", choices=engines.ENGINES)
    args = ap.parse_args()
    torch.set_num_threads(1)
    reg = CheckpointRegressor(args.checkpoint, engine=args.engine)
    frames = [frame for frame, _ in test_views(args.data, args.limit)]
    rows = measure(reg, frames)
    one_pass = [r for r in rows if r["network_calls"] == 1 and r["network_images"] == 1]
    more = [r for r in rows if not (r["network_calls"] == 1 and r["network_images"] == 1)]
    groups = {"all views": summarise(rows)}
    if one_pass:
        groups["one network pass"] = summarise(one_pass)
    if more:
        groups["more passes (turns, second pass, expert)"] = summarise(more)
    env = environment()
    bare_ms, engine_ms = network_call_ms(reg, on_torch=True), network_call_ms(reg)
    payload = {"env": env, "data": args.data, "checkpoint": args.checkpoint, "engine": reg.engine.name,
               "bare_network_ms": bare_ms, "engine_network_ms": engine_ms,
               "groups": groups, "per_view_ms": {k: [1e3 * r[k] for r in rows] for k in ("total",) + STAGE_NAMES}}
    total = groups["all views"]["ms_total"]
    lines = [
        "## Where the shipped regressor's time goes (`python benchmarks/predict_stages.py`)",
        "",
        f"`{args.data}`, first {len(rows)} views, whole `predict` path (no roi), the network on {reg.engine.name}, "
        "1 thread, one run; "
        f"{cpu_label(env)}, git {env['git']}. One bare network call (batch 1, {reg.image_size} px, torch) takes "
        f"**{bare_ms:.1f} ms** on this CPU: timings from hosts whose bare call differs are not comparable (the "
        f"same code ran the path in 17.9 ms/view where the call took ≈ 3.5 ms); on {reg.engine.name} it takes "
        f"{engine_ms:.1f} ms. ms per view of each stage; "
        "*other*: crops, twin candidates, covariance, Python.",
        "",
        "| views | share | ms/view | 95th pct. ms | largest ms | network | PnP | edge fits | detection | verifier | other | "
        "network calls | images through it |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, g in groups.items():
        lines.append(f"| {name} | {g['views'] / len(rows):.0%} | {g['ms_total']:.1f} | {g['ms_p95']:.1f} | {g['ms_max']:.1f} | "
                     + " | ".join(f"{g[f'ms_{s}']:.1f}" for s in STAGE_NAMES)
                     + f" | {g['ms_other']:.1f} | {g['network_calls']:.2f} | {g['network_images']:.2f} |")
    if more:
        lines += ["", f"The views that need more than one pass take {sum(r['total'] for r in more) / sum(r['total'] for r in rows):.0%} "
                  f"of the time; of all the time, the network takes {groups['all views']['ms_network'] / total:.0%}."]
    publish("predict_stages", "predict-stages", payload, lines)


if __name__ == "__main__":
    main()
