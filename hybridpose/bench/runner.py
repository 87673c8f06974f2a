"""Run modes × backends over many sequences — in worker processes or as Ray tasks — and resume.

A :class:`RunSpec` is one mode with its backends; :func:`run_all` runs every spec on every sequence,
one task per sequence (its frames are read once for all specs), and keeps each (sequence, spec) row
in ``OUT/rows/`` as it finishes, so an interrupted run resumes where it stopped. A kept row holds the
fingerprint of the code that made it (:func:`code_fingerprint`); after a change of the package's
code the rows are made again, never mixed with the old ones.
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import json
from concurrent.futures import as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..estimator import HybridConfig
from ..hybrid_config import DEFAULT_FUSION, changes_text
from ..io import atomic_write_json, read_json
from ..threads import set_threads
from ..workers import spawn_executor
from .modes import (COMPONENTS, load_sequence, run_cnn, run_hybrid, run_tracker, sequence_stats, trusted_errors_deg,
                    without_sun)

MODES = ("tracker", "cnn", "hybrid")


@dataclass(frozen=True)
class RunSpec:
    """One mode and its backends (registry names; ``regressor`` may also be a checkpoint file)."""

    mode: str = "hybrid"
    tracker: str = "edges"
    regressor: str = "default"
    fusion: str = DEFAULT_FUSION
    object: str = "truss"
    scale: float = 1.0
    config: HybridConfig = field(default_factory=HybridConfig)
    threads: int = 1  # CPU threads per worker (ONNX Runtime / torch / OpenCV)
    # keyword arguments of the tracker's factory, sorted ((name, value), ...): tracker and hybrid modes
    tracker_options: tuple = ()
    sun: bool = True  # space-lit frames carry the sun's direction (modes.load_sequence); False: left out

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode: expected one of {', '.join(MODES)}, got {self.mode!r}")

    @property
    def label(self) -> str:
        """How the results name this spec: ``tracker (edges)``, ``cnn (default)``, ``hybrid (edges+default+isam2)``."""
        parts = {"tracker": [self.tracker], "cnn": [Path(self.regressor).stem if self._is_file() else self.regressor],
                 "hybrid": [self.tracker, Path(self.regressor).stem if self._is_file() else self.regressor, self.fusion]}
        extra = "" if self.config == HybridConfig() or self.mode != "hybrid" else f", {changes_text(self.config)}"
        if self.tracker_options and self.mode != "cnn":
            extra = f"; {self._options_text()}{extra}"
        if not self.sun:
            extra = f"{extra}; sun unknown"
        return f"{self.mode} ({'+'.join(parts[self.mode])}{extra})"

    def _options_text(self) -> str:
        return ", ".join(f"{k}={'none' if v is None else v}" for k, v in self.tracker_options)

    @property
    def key(self) -> str:
        """A file-name-safe id of everything that changes the result."""
        blob = json.dumps(spec_dict(self), sort_keys=True).encode()
        return f"{self.mode}-{hashlib.sha1(blob).hexdigest()[:12]}"

    def _is_file(self) -> bool:
        return Path(self.regressor).suffix == ".pt"


def spec_dict(spec: RunSpec) -> dict:
    d = asdict(spec)
    d.pop("threads")
    if not spec.tracker_options or spec.mode == "cnn":
        d.pop("tracker_options")  # rows made before tracker options existed keep their keys
    if spec.sun:
        d.pop("sun")
    if spec.mode != "tracker" and spec._is_file() and Path(spec.regressor).is_file():
        # a checkpoint re-trained or re-calibrated under the same path makes other rows
        d["regressor_sha1"] = _file_sha1(str(Path(spec.regressor).resolve()), *_stamp(spec.regressor))
    return d


def _stamp(path) -> tuple[int, int]:
    st = Path(path).stat()
    return st.st_mtime_ns, st.st_size


@functools.lru_cache(maxsize=32)
def _file_sha1(path: str, mtime_ns: int, size: int) -> str:
    """sha1 of a file's bytes (cached while its time stamp and size stay)."""
    h = hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


_parts: dict = {}
# frames each backend runs once per process, untimed, before its first timed sequence: the first calls
# compile the numba kernels (seconds where their cache is cold, as after an install) and would be
# charged to whichever sequence a worker happened to take first (149 ms a frame on one of them)
WARMUP_FRAMES = 10
_warmed: set = set()


def forget_warm_up() -> None:
    """Make the next :func:`run_sequence` of this process warm every backend up again."""
    _warmed.clear()


def spec_backends(spec: RunSpec):
    """The object, tracker, regressor and estimator a spec needs, built once per process (a CNN takes
    seconds to load); the regressor is shared by every spec that names it."""
    from ..estimator import HybridEstimator
    from ..objects import load_object
    from ..registry import create, create_regressor

    obj_key = (spec.object, spec.scale)
    if ("object", obj_key) not in _parts:
        _parts[("object", obj_key)] = load_object(spec.object, scale=spec.scale)
    obj = _parts[("object", obj_key)]
    reg_key = ("regressor", spec.regressor, obj_key, spec.threads)
    if spec.mode != "tracker" and reg_key not in _parts:
        _parts[reg_key] = create_regressor(spec.regressor, object=obj, threads=spec.threads)
    tracker_kw = dict(spec.tracker_options)
    if spec.mode == "tracker":
        return obj, create("tracker", spec.tracker, object=obj, **tracker_kw)
    if spec.mode == "cnn":
        return obj, _parts[reg_key]
    return obj, HybridEstimator(create("tracker", spec.tracker, object=obj, **tracker_kw), _parts[reg_key],
                                create("fusion", spec.fusion), config=spec.config, threads=spec.threads)


def run_sequence(name: str, scene_dir: str, specs: list[RunSpec], per_frame: bool = True) -> list[dict]:
    """One row per spec for the sequence ``name`` stored in ``scene_dir`` (frames read once).

    With ``per_frame`` a row also holds per-frame lists (``rot_err_deg`` (NaN: no trusted pose),
    ``visible``, ``distance_m``, ``status``) for the plots."""
    set_threads(max(s.threads for s in specs))
    with_sun = load_sequence(scene_dir)
    rows = []
    for spec in specs:
        obj, runner = spec_backends(spec)
        seq = with_sun if spec.sun else without_sun(with_sun)
        run = {"tracker": run_tracker, "cnn": run_cnn}.get(spec.mode, run_hybrid)
        if WARMUP_FRAMES > 0 and spec.key not in _warmed:
            run(seq[:WARMUP_FRAMES], runner)  # every run starts afresh (init, reset): nothing carries over
            _warmed.add(spec.key)
        records = run(seq, runner)
        row = {"sequence": name, "mode": spec.mode, "label": spec.label, "key": spec.key,
               "tracker": spec.tracker if spec.mode != "cnn" else "",
               "regressor": spec.regressor if spec.mode != "tracker" else "",
               "fusion": spec.fusion if spec.mode == "hybrid" else "", **sequence_stats(seq, records, obj)}
        if per_frame:
            row["per_frame"] = {
                "rot_err_deg": [None if e is None else round(e, 3) for e in trusted_errors_deg(seq, records, obj.symmetries)],
                "visible": [round(s.visible, 3) for s in seq],
                "distance_m": [round(s.truth.distance_m, 4) for s in seq],
                "timestamp_s": [round(s.frame.timestamp, 4) for s in seq],
                "status": [r.status for r in records] if spec.mode == "hybrid" else None,
                "ms": [round(r.ms, 2) for r in records],
            }
        rows.append(row)
    return rows


def _row_path(out: Path, name: str, spec: RunSpec) -> Path:
    return out / "rows" / name / f"{spec.key}.json"


def code_fingerprint() -> str:
    """sha1 (12 hex digits) of the package's Python sources: what made a row, whatever git says."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha1()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:12]


def _kept(out: Path | None, name: str, spec: RunSpec, code: str) -> dict | None:
    """The row kept for (``name``, ``spec``) by this code, or None."""
    path = None if out is None else _row_path(out, name, spec)
    if path is None or not path.is_file():
        return None
    row = read_json(path)
    return row if row.get("code") == code else None


def run_all(scenes: dict[str, Path], specs: list[RunSpec], out=None, workers: int = 1, ray_address: str | None = None,
            progress: Callable[[str], None] | None = None, stats: dict | None = None) -> list[dict]:
    """Every spec on every sequence ``{name: scene_dir}``; rows in (name, spec) order.

    Args:
        out: where finished rows are kept (``out/rows/<sequence>/<spec key>.json``); rows already
            there are reused, so a rerun resumes. None: nothing kept.
        workers: local worker processes (1: this process).
        ray_address: run the sequences as Ray tasks on this cluster (``"auto"``, ``"local"`` or an
            address) instead of local processes; needs ``pip install "hybridpose[ray]"``.
        stats: a dict that gets ``reused``: how many rows came from ``out`` instead of being run.
    """
    out = Path(out) if out is not None else None
    code = code_fingerprint()
    done: dict[tuple[str, str], dict] = {}
    todo: dict[str, list[RunSpec]] = {}
    for name in sorted(scenes):
        missing = []
        for s in specs:
            row = _kept(out, name, s, code)
            if row is None:
                missing.append(s)
            else:
                done[(name, s.key)] = row
        if missing:
            todo[name] = missing
    if stats is not None:
        stats["reused"] = len(done)

    def keep(rows: list[dict], name: str) -> None:
        for r in rows:
            r["code"] = code
        if out is not None:
            by_key = {s.key: s for s in specs}
            for r in rows:
                atomic_write_json(_row_path(out, name, by_key[r["key"]]), r, indent=None)
        if progress:
            progress(name)

    if ray_address is not None:
        for name, rows in _run_on_ray(todo, scenes, ray_address):
            keep(rows, name)
            done.update({(name, r["key"]): r for r in rows})
    elif workers <= 1:
        for name, sp in todo.items():
            rows = run_sequence(name, str(scenes[name]), sp)
            keep(rows, name)
            done.update({(name, r["key"]): r for r in rows})
    else:
        # fresh interpreters, not forks: the parent may have just rendered the suite, and a fork of a
        # process holding the renderer's threads and GL context hung its workers before their first task
        with spawn_executor(workers) as pool:
            futures = {pool.submit(run_sequence, name, str(scenes[name]), sp): name for name, sp in todo.items()}
            for fut in as_completed(futures):
                name = futures[fut]
                try:
                    rows = fut.result()
                except Exception as exc:
                    # stop at once (the rows finished so far are kept): the pool would otherwise run
                    # every queued sequence before the error surfaced
                    for other in futures:
                        other.cancel()
                    raise RuntimeError(f"bench: sequence {name}: {type(exc).__name__}: {exc}") from exc
                keep(rows, name)
                done.update({(name, r["key"]): r for r in rows})
    return [done[(name, s.key)] for name in sorted(scenes) for s in specs]


@contextlib.contextmanager
def ray_connection(address: str | None):
    """This process connected to Ray for the block: ``"local"`` starts a Ray instance here for the run,
    ``"auto"`` joins the cluster this machine belongs to, anything else is a cluster's address; None
    (or already connected): nothing to do. Shut down after the block when it connected. ValueError
    naming ``--ray`` where Ray is not installed or no cluster answers (before any long work)."""
    if address is None:
        yield
        return
    try:
        import ray
    except ImportError:
        raise ValueError("--ray: Ray is not installed; pip install \"hybridpose[ray]\" (or run with --workers N)") from None
    started = not ray.is_initialized()
    if started:
        try:
            ray.init(address=None if address == "local" else address, include_dashboard=False, log_to_driver=False)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise ValueError(f"--ray {address}: no Ray cluster answered ({str(exc).splitlines()[0]}); start one with "
                             "`ray start --head`, give a running cluster's address, or use --ray local to start "
                             "one on this machine for the run") from None
    try:
        yield
    finally:
        if started:
            ray.shutdown()


def _run_on_ray(todo: dict[str, list[RunSpec]], scenes: dict[str, Path], address: str):
    with ray_connection(address):
        import ray

        task = ray.remote(run_sequence)
        refs = {task.remote(name, str(scenes[name]), sp): name for name, sp in todo.items()}
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield refs[ready[0]], ray.get(ready[0])


def _nanmedian(values) -> float:
    values = np.asarray(values, dtype=float)
    return float(np.nanmedian(values)) if np.any(np.isfinite(values)) else float("nan")


def _nanmean(values) -> float:
    values = np.asarray(values, dtype=float)
    return float(np.nanmean(values)) if np.any(np.isfinite(values)) else float("nan")


def summarise(rows: list[dict], group: Callable[[dict], str] = lambda r: r["label"]) -> dict[str, dict]:
    """Spread over sequences per group (default: per spec label): the median / p90 / worst of each
    sequence's mean rotation error, pooled means, totals of silent failures and of covered frames
    tracked > 10° off, losses recovered and the worst recovery, cost."""
    out = {}
    for key in sorted({group(r) for r in rows}):
        rs = [r for r in rows if group(r) == key]
        mean_rot = np.array([r["rot_mean_deg"] for r in rs])
        rec = [n for r in rs for n in r["recover_frames"]]
        finite = mean_rot[np.isfinite(mean_rot)]
        edge_px = np.array([r.get("edge_px_median", np.nan) for r in rs])
        out[key] = {
            "sequences": len(rs),
            "rot_mean_deg": float(np.mean(finite)) if finite.size else float("nan"),
            "seq_rot_mean_median_deg": float(np.nanmedian(mean_rot)) if finite.size else float("nan"),
            "seq_rot_mean_p90_deg": float(np.nanpercentile(mean_rot, 90)) if finite.size else float("nan"),
            "seq_rot_mean_worst_deg": float(np.nanmax(mean_rot)) if finite.size else float("nan"),
            "seq_rot_median_median_deg": float(np.nanmedian([r["rot_median_deg"] for r in rs])) if finite.size
            else float("nan"),
            "seq_rot_median_p90_deg": float(np.nanpercentile([r["rot_median_deg"] for r in rs], 90)) if finite.size
            else float("nan"),
            "seq_trans_median_median_pct": _nanmedian([r.get("trans_median_pct", np.nan) for r in rs]),
            "trans_mean_m": _nanmean(np.array([r["trans_mean_m"] for r in rs])),
            "trans_mean_pct": _nanmean(np.array([r["trans_mean_pct"] for r in rs])),
            "speed_mean": _nanmean(np.array([r["speed_mean"] for r in rs])),
            "in_basin": _nanmean(np.array([r.get("in_basin", np.nan) for r in rs])),
            "edge_px_median": float(np.nanmedian(edge_px)) if np.any(np.isfinite(edge_px)) else float("nan"),
            "add_recall": _nanmean(np.array([r.get("add_recall", np.nan) for r in rs])),
            "add_auc": _nanmean(np.array([r.get("add_auc", np.nan) for r in rs])),
            "coverage": float(np.mean([r["coverage"] for r in rs])),
            "silent_failures": int(sum(r["silent_failures"] for r in rs)),
            "false_alarm_pct": 100.0 * sum(r.get("false_alarms", 0) for r in rs)
            / max(sum(r.get("clear_good_frames", 0) for r in rs), 1),
            "nees_coverage90": _nanmean(np.array([r.get("nees_coverage90", np.nan) for r in rs])),
            "frames": int(sum(r["frames"] for r in rs)),
            "frames_lost": int(sum(r["frames_lost"] for r in rs)),
            "covered_tracking_10deg": int(sum(r["covered_tracking_10deg"] for r in rs)),
            "recoveries": len(rec),
            "recover_never": sum(n is None for n in rec),
            "recover_frames_max": max((n for n in rec if n is not None), default=None),
            "ms_per_frame": float(np.mean([r["ms_per_frame"] for r in rs])),
            **{f"ms_{part}": _nanmean([r.get(f"ms_{part}", np.nan) for r in rs]) for part in COMPONENTS},
            "cnn_calls_per_100": float(np.mean([r["cnn_calls_per_100"] for r in rs])),
            **_frame_time_spread(rs),
        }
    return out


# the hybrid's states as the cost table groups them: a start and a restart cost alike
STATE_GROUPS = {"tracking": ("tracking",), "lost": ("lost",), "starting": ("init", "reinit")}


def _frame_time_spread(rs: list[dict]) -> dict:
    """Pooled frame times of a group's rows: ``ms_frame_p99`` (from the per-frame times where the rows
    hold them), ``ms_frame_max``, and for the hybrid the mean ms of a frame in each of
    ``STATE_GROUPS`` (``ms_tracking``, ``ms_lost``, ``ms_starting``; NaN where no frame was)."""
    times = [t for r in rs for t in ((r.get("per_frame") or {}).get("ms") or ())]
    out = {"ms_frame_p99": float(np.percentile(times, 99)) if times else float("nan"),
           "ms_frame_max": _nanmax([r.get("ms_frame_max", np.nan) for r in rs])}
    for group, states in STATE_GROUPS.items():
        parts = [(r.get("ms_by_state") or {}).get(state, (0.0, 0)) for r in rs for state in states]
        frames = sum(n for _, n in parts)
        out[f"ms_{group}"] = sum(ms for ms, _ in parts) / frames if frames else float("nan")
    return out


def _nanmax(values) -> float:
    values = np.asarray(values, dtype=float)
    return float(np.nanmax(values)) if np.any(np.isfinite(values)) else float("nan")
