"""Run the modes over many rendered sequences (in worker processes) and summarise over seeds."""
from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..estimator import HybridConfig
from .modes import load_sequence, run_cnn, run_hybrid, run_tracker, sequence_stats

MODES = ("tracker", "cnn", "hybrid")


@dataclass(frozen=True)
class RunSpec:
    """What to run on each sequence: modes, backends (registry names) and the hybrid's config."""

    modes: tuple[str, ...] = MODES
    tracker: str = "edges"
    regressor: str = "default"
    fusion: str = "ukf"
    object: str = "truss"
    config: HybridConfig = field(default_factory=HybridConfig)
    threads: int = 1  # CPU threads per worker (torch / ONNX Runtime)


_parts: dict = {}


def _backends(spec: RunSpec):
    """One tracker, regressor and estimator per process and spec (loading a CNN takes seconds)."""
    key = (spec.tracker, spec.regressor, spec.fusion, spec.object, spec.config, spec.threads)
    if key not in _parts:
        from ..estimator import HybridEstimator
        from ..objects import load_object
        from ..registry import create

        obj = load_object(spec.object)
        regressor = create("regressor", spec.regressor, object=obj, threads=spec.threads)
        tracker = create("tracker", spec.tracker, object=obj)
        hybrid = HybridEstimator(create("tracker", spec.tracker, object=obj), regressor,
                                 create("fusion", spec.fusion), config=spec.config)
        _parts.clear()
        _parts[key] = (tracker, regressor, hybrid)
    return _parts[key]


def run_sequence(name: str, scene_dir: str, spec: RunSpec) -> list[dict]:
    """One row per mode for the sequence ``name`` stored in ``scene_dir``."""
    os.environ.setdefault("OMP_NUM_THREADS", str(spec.threads))
    import cv2

    cv2.setNumThreads(spec.threads)
    tracker, regressor, hybrid = _backends(spec)
    seq = load_sequence(scene_dir)
    rows = []
    for mode in spec.modes:
        if mode == "tracker":
            tracker.reset()
            records = run_tracker(seq, tracker)
        elif mode == "cnn":
            records = run_cnn(seq, regressor)
        elif mode == "hybrid":
            records = run_hybrid(seq, hybrid)
        else:
            raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
        rows.append({"sequence": name, "mode": mode, "tracker": spec.tracker if mode != "cnn" else "",
                     "regressor": spec.regressor if mode != "tracker" else "",
                     "fusion": spec.fusion if mode == "hybrid" else "", **sequence_stats(seq, records),
                     "statuses": [r.status for r in records] if mode == "hybrid" else None})
    return rows


def run_all(scenes: dict[str, Path], spec: RunSpec, workers: int = 1,
            progress: Callable[[str], None] | None = None) -> list[dict]:
    """:func:`run_sequence` over ``{name: scene_dir}``, in ``workers`` processes; rows in name order."""
    rows: list[dict] = []
    items = sorted(scenes.items())
    if workers <= 1:
        for name, d in items:
            rows += run_sequence(name, str(d), spec)
            if progress:
                progress(name)
        return rows
    with ProcessPoolExecutor(workers) as pool:
        futures = {name: pool.submit(run_sequence, name, str(d), spec) for name, d in items}
        for name, fut in futures.items():
            rows += fut.result()
            if progress:
                progress(name)
    return rows


def summarise(rows: list[dict], group: Callable[[dict], str] = lambda r: r["mode"]) -> dict[str, dict]:
    """Spread over sequences per group (default: per mode): median / p90 / worst of each sequence's
    mean and median rotation error, pooled means, totals of silent failures and covered frames
    tracked > 10° off, worst recovery, cost."""
    out = {}
    for key in sorted({group(r) for r in rows}):
        rs = [r for r in rows if group(r) == key]
        mean_rot = np.array([r["rot_mean_deg"] for r in rs])
        med_rot = np.array([r["rot_median_deg"] for r in rs])
        rec = [n for r in rs for n in r["recover_frames"]]
        finite = mean_rot[np.isfinite(mean_rot)]
        out[key] = {
            "sequences": len(rs),
            "rot_mean_deg": float(np.mean(finite)) if finite.size else float("nan"),
            "seq_rot_mean_median_deg": float(np.nanmedian(mean_rot)),
            "seq_rot_mean_p90_deg": float(np.nanpercentile(mean_rot, 90)),
            "seq_rot_mean_worst_deg": float(np.nanmax(mean_rot)),
            "seq_rot_median_median_deg": float(np.nanmedian(med_rot)),
            "trans_mean_pct": float(np.nanmean([r["trans_mean_pct"] for r in rs])),
            "trans_mean_m": float(np.nanmean([r["trans_mean_m"] for r in rs])),
            "coverage": float(np.mean([r["coverage"] for r in rs])),
            "silent_failures": int(sum(r["silent_failures"] for r in rs)),
            "frames": int(sum(r["frames"] for r in rs)),
            "covered_tracking_10deg": int(sum(r["covered_tracking_10deg"] for r in rs)),
            "recoveries": len(rec),
            "recover_never": sum(n is None for n in rec),
            "recover_frames_max": max((n for n in rec if n is not None), default=None),
            "ms_per_frame": float(np.mean([r["ms_per_frame"] for r in rs])),
            "cnn_calls_per_100": float(np.mean([r["cnn_calls_per_100"] for r in rs])),
        }
    return out


def spec_dict(spec: RunSpec) -> dict:
    d = asdict(spec)
    d["modes"] = list(spec.modes)
    return d
