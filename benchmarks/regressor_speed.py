"""CPU inference cost of every regressor network: ms per image at 1 and 2 threads, parameter count.

The paper's VGGs at ``--size`` (224); the keypoint models at their own crop size, and ``default`` also at
160 px, the shipped edge-on expert's (network only — ``hybridpose eval`` times the whole ``predict``
path: detection, passes, PnP, edge fits).

Usage: python benchmarks/regressor_speed.py [--size 224] [--repeats 3]
Writes benchmarks/results/regressor_speed.json and the "regressor-speed" section of RESULTS.md.
"""
from __future__ import annotations

import argparse
import time

import torch

from _common import environment, update_results_md, write_json
from hybridpose.machine import cpu_label
from hybridpose.objects import load_object
from hybridpose.regressors import available_models, build_model
from hybridpose.regressors.models import MODEL_DEFAULTS, fold_batch_norm, model_kind


EXTRA_KEYPOINT_SIZES = {"default": (160,)}


def ms_per_image(model, size: int, threads: int, repeats: int) -> float:
    torch.set_num_threads(threads)
    x = torch.rand(1, 3, size, size).contiguous(memory_format=torch.channels_last)
    args = (x, x) if model.__class__.__name__ == "ParallelVGG19" else (x,)
    with torch.inference_mode():
        model(*args)  # warm-up
        t0 = time.perf_counter()
        for _ in range(repeats):
            model(*args)
    return (time.perf_counter() - t0) / repeats * 1000.0


def onnxruntime_ms(model, size: int, repeats: int) -> dict:
    """ms per batch-1 call of a keypoint net on ONNX Runtime (``engine="onnxruntime"``) at 1 and 2 threads;
    {} where onnxruntime is not installed."""
    from hybridpose.regressors.engines import OnnxRuntimeEngine, call_ms

    try:
        engine = OnnxRuntimeEngine(model, size)
    except RuntimeError:
        return {}
    out = {}
    for threads in (1, 2):
        torch.set_num_threads(threads)
        out[f"ort_ms_{threads}_thread{'s' if threads > 1 else ''}"] = call_ms(engine, torch.rand(1, 3, size, size),
                                                                              calls=repeats, repeats=1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=224)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--models", default=None, help="comma-separated subset (default: all)")
    args = ap.parse_args()
    rows = []
    keypoints = load_object("truss").keypoints
    names = args.models.split(",") if args.models else available_models()
    # the shipped default's edge-on expert is the same network at a larger crop
    runs = [(name, None) for name in names] + [(name, size) for name in names for size in EXTRA_KEYPOINT_SIZES.get(name, ())]
    for name, own_size in runs:
        size = args.size
        kw = {"image_size": args.size} if name in ("branched-vgg19", "parallel-vgg19") else {}
        if model_kind(name) == "keypoints":
            size = own_size or MODEL_DEFAULTS[name]["image_size"]
            kw = {"keypoints_m": keypoints, "image_size": size}
        model = build_model(name, **kw).eval()
        params = sum(p.numel() for p in model.parameters()) / 1e6
        # as CheckpointRegressor runs it on the CPU: batch norm folded, channels-last
        model = fold_batch_norm(model).to(memory_format=torch.channels_last)
        repeats = args.repeats if model_kind(name) == "direct" else max(args.repeats, 30)  # ms-scale nets: more runs
        row = {"model": name, "input_px": size, "params_M": params,
               "ms_1_thread": ms_per_image(model, size, 1, repeats),
               "ms_2_threads": ms_per_image(model, size, 2, repeats)}
        if model_kind(name) == "keypoints":
            row.update(onnxruntime_ms(model, size, repeats))
        rows.append(row)
        del model
    env = environment()
    write_json("regressor_speed", {"env": env, "size": args.size, "repeats": args.repeats, "results": rows})
    lines = [
        "## CNN inference cost on this CPU (`python benchmarks/regressor_speed.py`)",
        "",
        f"Square input of the given side, batch 1, float32, channels-last, batch norm folded (as the regressor runs them), "
        f"torch {torch.__version__}, mean of {args.repeats} runs (30 for the keypoint nets) after a warm-up, "
        f"git {env['git']}, {cpu_label(env)}. Target for the shipped `default`: ≤ 20 ms on 1 thread. ONNX Runtime "
        "(`engine=\"onnxruntime\"`, keypoint nets only): the same nets exported to ONNX, mean of as many calls.",
        "",
        "| model | input px | parameters (M) | ms/image, 1 thread | ms/image, 2 threads | ONNX Runtime, 1 thread | 2 threads |",
        "|---|---|---|---|---|---|---|",
    ]

    def ort(r, key):
        return f"{r[key]:.1f}" if key in r else "–"

    lines += [f"| {r['model']} | {r['input_px']} | {r['params_M']:.1f} | {r['ms_1_thread']:.1f} | {r['ms_2_threads']:.1f} | "
              f"{ort(r, 'ort_ms_1_thread')} | {ort(r, 'ort_ms_2_threads')} |" for r in rows]
    update_results_md("regressor-speed", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
