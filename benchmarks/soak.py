"""Soak test: the hybrid over 10 000 frames in one process, as a long run on a robot would use it.

    python benchmarks/soak.py                  # rewrites the `soak` block of RESULTS.md
    python benchmarks/soak.py --frames 2000    # a shorter run: prints, touches nothing

The frames: a 300-frame rendered sequence of the truss (tumble, the arm passing in front partly then
wholly; seed 3, a seed no default was tuned on) played forwards, then backwards, then forwards again
— the motion turns at each end, as a hand or an arm that stops and comes back — with timestamps that
keep going (30 fps). The estimator is built once and never reset. Checked on every frame: no NaN in
the pose, covariance or twist, the covariance symmetric positive definite; per block of 1 000 frames:
the memory the process holds (resident set), the cost per frame (median, p99) and the statuses; and
the rotation error on the frames where the truss is at least half visible, against the truth.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import environment, publish  # noqa: E402

SEQUENCE_FRAMES, SEED, BLOCK = 300, 3, 1000


def resident_mib() -> float:
    """This process's resident memory, MiB (Linux ``/proc/self/status``; NaN elsewhere)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def ping_pong(count: int, length: int) -> list[int]:
    """Frame indices 0, 1, …, length−1, length−2, …, 1, 0, 1, … ``count`` long."""
    period = 2 * (length - 1)
    return [k % period if k % period < length else period - k % period for k in range(count)]


def run(frames: int, cache: Path) -> dict:
    from dataclasses import replace

    from hybridpose import HybridEstimator, warm_up
    from hybridpose.bench.modes import HALF_VISIBLE, load_sequence
    from hybridpose.datasets import render_sequence_dataset
    from hybridpose.geometry import Camera
    from hybridpose.metrics import rotation_error_deg
    from hybridpose.objects import load_object
    from hybridpose.render.sequences import SequenceSpec

    obj = load_object("truss")
    spec = SequenceSpec(trajectory="tumble", frames=SEQUENCE_FRAMES, fps=30.0, occlusion="arm", seed=SEED)
    seq = load_sequence(render_sequence_dataset(cache / f"soak_tumble_arm_s{SEED}", obj, Camera.default(), spec))
    est = HybridEstimator.from_names(object=obj)
    warm_up(trackers=("edges",), fusions=("isam2",))
    blocks, bad, not_pd, start_mib = [], [], 0, resident_mib()
    ms, statuses, errors = [], [], []
    for k, i in enumerate(ping_pong(frames, len(seq))):
        s = seq[i]
        frame = replace(s.frame, timestamp=k / 30.0, index=k)
        t0 = time.perf_counter()
        e = est.step(frame)
        ms.append(1000 * (time.perf_counter() - t0))
        statuses.append(e.status)
        values = [e.covariance, e.velocity] + ([e.pose.R, e.pose.t] if e.pose is not None else [])
        if not all(np.all(np.isfinite(v)) for v in values if v is not None):
            bad.append(k)
        if e.covariance is not None and np.linalg.eigvalsh(0.5 * (e.covariance + e.covariance.T)).min() <= 0:
            not_pd += 1
        if e.pose is not None and e.status != "lost" and s.visible >= HALF_VISIBLE:
            errors.append(rotation_error_deg(e.pose, s.truth))
        if (k + 1) % BLOCK == 0 or k + 1 == frames:
            counts = {st: statuses.count(st) for st in ("tracking", "reinit", "lost", "init")}
            blocks.append({"frames": f"{k + 2 - len(ms)}–{k + 1}", "rss_mib": round(resident_mib(), 1),
                           "ms_median": round(float(np.median(ms)), 2), "ms_p99": round(float(np.percentile(ms, 99)), 1),
                           "rot_median_deg": round(float(np.median(errors)), 3) if errors else None,
                           "rot_p99_deg": round(float(np.percentile(errors, 99)), 2) if errors else None, **counts})
            print(blocks[-1], flush=True)
            ms, statuses, errors = [], [], []
    return {"frames": frames, "start_rss_mib": round(start_mib, 1), "blocks": blocks, "nan_frames": bad,
            "covariance_not_pd": not_pd, "cnn_calls": est.regressor_calls}


def summary_lines(r: dict) -> list[str]:
    lines = ["| frames | resident MiB at the end | ms/frame median | p99 | median rotation error ° | p99 | tracking | re-init | lost |",
             "|---|---|---|---|---|---|---|---|---|"]
    for b in r["blocks"]:
        lines.append(f"| {b['frames']} | {b['rss_mib']:.0f} | {b['ms_median']:.1f} | {b['ms_p99']:.0f} | "
                     f"{b['rot_median_deg']} | {b['rot_p99_deg']} | {b['tracking']} | {b['reinit']} | {b['lost']} |")
    return lines


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=10_000)
    ap.add_argument("--cache", default="runs/bench_cache", help="where the 300-frame sequence is rendered (reused)")
    args = ap.parse_args(argv)
    r = run(args.frames, Path(args.cache))
    first, last = r["blocks"][0], r["blocks"][-1]
    head = [f"The hybrid (`edges` + `default` + `isam2`, its defaults, one thread) over {r['frames']} frames in one process "
            f"(`python benchmarks/soak.py`, commit `{environment()['git']}`): a 300-frame truss tumble with the arm "
            f"passing in front (seed {SEED}, untuned) played forwards and backwards, timestamps running on, never "
            f"reset. Resident memory {r['start_rss_mib']:.0f} MiB after the warm-up, {first['rss_mib']:.0f} MiB "
            f"after the first {BLOCK} frames, {last['rss_mib']:.0f} MiB at the end; frames with a NaN: {len(r['nan_frames'])}; "
            f"covariances not positive definite: {r['covariance_not_pd']}; CNN calls: {r['cnn_calls']}. Per block "
            "of frames (errors on the frames where the truss is at least half visible, trusted):", ""]
    if args.frames != 10_000:
        print("\n".join(head + summary_lines(r)))
        return
    publish("soak", "soak", {"environment": environment(), **r}, head + summary_lines(r))


if __name__ == "__main__":
    main()
