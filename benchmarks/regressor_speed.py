"""CPU inference cost of the paper's models: ms per image at 1 and 2 threads, parameter count.

Usage: python benchmarks/regressor_speed.py [--size 224] [--repeats 3]
Writes benchmarks/results/regressor_speed.json and the "regressor-speed" section of RESULTS.md.
"""
from __future__ import annotations

import argparse
import time

import torch

from _common import environment, update_results_md, write_json
from hybridpose.regressors import available_models, build_model


def ms_per_image(model, size: int, threads: int, repeats: int) -> float:
    torch.set_num_threads(threads)
    x = torch.rand(1, 3, size, size)
    args = (x, x) if model.__class__.__name__ == "ParallelVGG19" else (x,)
    with torch.inference_mode():
        model(*args)  # warm-up
        t0 = time.perf_counter()
        for _ in range(repeats):
            model(*args)
    return (time.perf_counter() - t0) / repeats * 1000.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=224)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    rows = []
    for name in available_models():
        kw = {"image_size": args.size} if name in ("branched-vgg19", "parallel-vgg19") else {}
        model = build_model(name, **kw).eval()
        rows.append({"model": name, "params_M": sum(p.numel() for p in model.parameters()) / 1e6,
                     "ms_1_thread": ms_per_image(model, args.size, 1, args.repeats),
                     "ms_2_threads": ms_per_image(model, args.size, 2, args.repeats)})
        del model
    env = environment()
    write_json("regressor_speed", {"env": env, "size": args.size, "repeats": args.repeats, "results": rows})
    lines = [
        "## CNN inference cost on this CPU (`python benchmarks/regressor_speed.py`)",
        "",
        f"{args.size}×{args.size} input, batch 1, float32, torch {torch.__version__}, mean of {args.repeats} runs after a warm-up, "
        f"git {env['git']}, {env['cpus']} CPU cores. Target for the shipped `default`: ≤ 20 ms on 1 thread.",
        "",
        "| model | parameters (M) | ms/image, 1 thread | ms/image, 2 threads |",
        "|---|---|---|---|",
    ]
    lines += [f"| {r['model']} | {r['params_M']:.1f} | {r['ms_1_thread']:.0f} | {r['ms_2_threads']:.0f} |" for r in rows]
    update_results_md("regressor-speed", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
