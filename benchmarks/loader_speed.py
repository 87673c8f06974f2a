"""What one training item of the VGG models costs a DataLoader worker: decoded from the PNG, or read
from the image cache (``hybridpose train --cache-images``), same views, interleaved runs, one thread.

Usage: python benchmarks/loader_speed.py --data data/truss_test100 [--limit 300] [--repeats 3]
Writes benchmarks/results/loader_speed.json and the "loader-speed" section of RESULTS.md.

A loader worker is single-threaded (OpenCV too), so ms per item on one core says how many workers a
model needs to feed a GPU that trains N views a second: N × ms / 1000. The cache is built in a
temporary folder and removed afterwards.
"""
from __future__ import annotations

import argparse
import tempfile
import time

import cv2
import numpy as np

from _common import environment, publish
from hybridpose.regressors.train import TrainConfig, make_datasets


def _ms_per_item(get, n: int) -> float:
    t0 = time.perf_counter()
    for k in range(n):
        get(k)
    return (time.perf_counter() - t0) / n * 1e3


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", required=True)
    ap.add_argument("--limit", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    cv2.setNumThreads(1)  # as in the loader workers
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        for model in ("vgg19", "parallel-vgg19"):
            plain, _ = make_datasets(TrainConfig(model=model, data=args.data, out=cache))
            t0 = time.perf_counter()
            cached, _ = make_datasets(TrainConfig(model=model, data=args.data, out=cache,
                                                  cache_images=f"{cache}/{model}"))  # its own: both inputs built
            views = len(cached.dataset.full.samples) if model == "parallel-vgg19" else len(cached.dataset.samples)
            build_ms = (time.perf_counter() - t0) / views * 1e3
            n = min(args.limit, len(plain))
            ways = {"decoded": plain.__getitem__, "from the cache": cached.__getitem__}
            if model == "parallel-vgg19":  # its two inputs read separately, each decoding the view (before session 31)
                paired = plain.dataset
                ways["decoded once per input (before session 31)"] = lambda k: (
                    paired.full[plain.indices[k]], paired.crop[plain.indices[k]])
            ms = {way: [] for way in ways}
            for _ in range(args.repeats):  # interleaved: a slow spell of the machine hits every way
                for way, get in ways.items():
                    ms[way].append(_ms_per_item(get, n))
            for way in ways:
                rows.append({"model": model, "way": way, "ms_per_item": float(np.median(ms[way])), "items": n,
                             "cache_build_ms_per_view": build_ms if way == "from the cache" else None})
    env = environment()
    payload = {"env": env, "data": args.data, "repeats": args.repeats, "rows": rows}
    lines = [
        "## Training items of the VGG models: decoded or cached (`python benchmarks/loader_speed.py`)",
        "",
        f"`{args.data}`, the first {rows[0]['items']} training items (224 px), one thread as in a loader worker, "
        f"median of {args.repeats} interleaved runs, git {env['git']}, {env.get('cpu_model', 'CPU')}. *from the cache*: "
        "`hybridpose train --cache-images DIR` (built once per set of views, single thread here; the GPU script "
        "builds it with 15 threads). A worker feeds 1000 / (ms per item) views a second.",
        "",
        "| model | item | ms per item | views/s per worker | cache build ms per view |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        build = "–" if r["cache_build_ms_per_view"] is None else f"{r['cache_build_ms_per_view']:.1f}"
        lines.append(f"| {r['model']} | {r['way']} | {r['ms_per_item']:.2f} | {1000 / r['ms_per_item']:.0f} | {build} |")
    publish("loader_speed", "loader-speed", payload, lines)


if __name__ == "__main__":
    main()
