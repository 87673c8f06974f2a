"""What a benchmark run reports: markdown tables, the hybrid's ratios and targets, plots."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..viz import save_figure
from .modes import COMPONENTS
from .runner import summarise

# what the hybrid must reach on the standard suite (seeds no tuning used)
TARGETS = {
    "rot_vs_cnn": 1 / 3,       # hybrid mean rotation error / CNN-only's, same frames
    "cost_vs_cnn": 1 / 3,      # hybrid ms per frame / CNN-only's
    "silent_failures": 0,      # frames > 5° off not flagged lost
    "recover_frames": 5,       # frames after the arm leaves until ≤ 2°
    "rot_mean_deg": 1.0,
    "trans_mean_pct": 1.0,
    "add_recall": 0.95,
    "fps": 60.0,               # amortised, one thread, 640×480
}

# what a tracker alone must reach from the true first pose (standard suite, seeds no tuning used)
TRACKER_TARGETS = {
    "rot_median_deg": 0.2,        # median rotation error, on every kind of sequence
    "trans_median_pct": 0.1,      # median translation error, % of distance, on every kind of sequence
    "seq_rot_median_p90_deg": 1.0,  # p90 over sequences of each sequence's median rotation error
    "silent_pct": 0.5,            # frames > 5° off not flagged lost, % of frames
    "false_alarm_pct": 2.0,       # clear frames at a good pose flagged lost
    "ms_per_frame": 5.0,          # one thread, 640×480
}

COLUMNS = ("| run | seq. | rot. mean ° | per-seq. mean °: median / p90 / worst | trans. % dist. | ADD-0.1d | ADD AUC "
           "| in basin | edge px | silent failures | false alarms | covered, > 10° | lost | recovery (worst, never) "
           "| NEES ≤ χ²₀.₉ | ms/frame | CNN / 100 fr. |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")


def _f(x, fmt="{:.2f}") -> str:
    return "—" if x is None or (isinstance(x, float) and not np.isfinite(x)) else fmt.format(x)


def table(summary: dict[str, dict]) -> str:
    lines = list(COLUMNS)
    for name, s in summary.items():
        rec = "—" if not s["recoveries"] else (_f(s["recover_frames_max"], "{}") + (f", {s['recover_never']}"
                                                                                     if s["recover_never"] else ", 0"))
        lines.append(f"| {name} | {s['sequences']} | {_f(s['rot_mean_deg'])} | {_f(s['seq_rot_mean_median_deg'])} / "
                     f"{_f(s['seq_rot_mean_p90_deg'])} / {_f(s['seq_rot_mean_worst_deg'])} | {_f(s['trans_mean_pct'])} "
                     f"| {_f(s['add_recall'], '{:.3f}')} | {_f(s['add_auc'], '{:.3f}')} "
                     f"| {_f(s.get('in_basin'), '{:.3f}')} | {_f(s.get('edge_px_median'), '{:.2f}')} "
                     f"| {s['silent_failures']} of {s['frames']} | {_f(s['false_alarm_pct'], '{:.1f} %')} "
                     f"| {s['covered_tracking_10deg']} | {s['frames_lost']} | {rec} | {_f(s['nees_coverage90'], '{:.2f}')} "
                     f"| {_f(s['ms_per_frame'], '{:.1f}')} | {_f(s['cnn_calls_per_100'], '{:.0f}')} |")
    return "\n".join(lines)


def _sizes(rows: list[dict]) -> str:
    """The rows' image sizes, ``"640×480"`` (rows made before rows recorded it: the suites' 640×480)."""
    sizes = sorted({tuple(r.get("image_size") or (640, 480)) for r in rows})
    return ", ".join(f"{w}×{h}" for w, h in sizes)


def cost_table(summary: dict[str, dict]) -> str:
    """Milliseconds per frame by component (the rest: the policy, image checks, bookkeeping), CNN
    calls, the hybrid's mean frame while tracking / lost / (re)starting, and the p99 and slowest
    frame (what a real-time budget must hold), one line per run."""
    heads = {"tracker": "tracker ms", "regressor": "CNN ms", "fusion": "fusion ms"}
    lines = ["| run | " + " | ".join(heads[p] for p in COMPONENTS)
             + " | rest ms | total ms/frame | CNN calls / 100 fr. | CNN ms / call "
             "| ms/frame tracking / lost / (re)starting | frame ms p99 / slowest |",
             "|---" * (len(COMPONENTS) + 7) + "|"]
    for name, s in summary.items():
        parts = [s.get(f"ms_{p}", float("nan")) for p in COMPONENTS]
        rest = s["ms_per_frame"] - float(np.nansum(parts)) if np.any(np.isfinite(parts)) else float("nan")
        cnn_ms = s.get("ms_regressor", float("nan"))
        per_call = cnn_ms / (s["cnn_calls_per_100"] / 100) if s["cnn_calls_per_100"] > 0 else float("nan")
        states = [s.get(f"ms_{g}", float("nan")) for g in ("tracking", "lost", "starting")]
        by_state = " / ".join(_f(x, "{:.1f}") for x in states) if np.any(np.isfinite(states)) else "—"
        spread = " / ".join(_f(s.get(k, float("nan")), "{:.0f}") for k in ("ms_frame_p99", "ms_frame_max"))
        lines.append(f"| {name} | " + " | ".join(_f(x, "{:.1f}") for x in (*parts, rest, s["ms_per_frame"]))
                     + f" | {_f(s['cnn_calls_per_100'], '{:.0f}')} | {_f(per_call, '{:.1f}')} | {by_state} | {spread} |")
    return "\n".join(lines)


def _first(summary: dict[str, dict], mode: str) -> tuple[str, dict] | None:
    for name, s in summary.items():
        if name.startswith(mode + " "):
            return name, s
    return None


def headline_runs(runs: list[str]) -> list[str]:
    """The first run of each mode, in the order given (the defaults: first tracker, first fusion)."""
    out = []
    for mode in ("tracker", "cnn", "hybrid"):
        out += [r for r in runs if r.startswith(mode + " ")][:1]
    return out


def targets(summary: dict[str, dict]) -> str:
    """One line per target for the (first) hybrid run of ``summary``: met, or missed by how much."""
    hyb, cnn, trk = _first(summary, "hybrid"), _first(summary, "cnn"), _first(summary, "tracker")
    if hyb is None:
        return ""
    name, h = hyb
    checks = []
    if cnn is not None:
        c = cnn[1]
        checks.append(("mean rotation ≤ 1/3 of CNN-only's", h["rot_mean_deg"] / c["rot_mean_deg"], TARGETS["rot_vs_cnn"],
                       "×{:.2f}"))
        notes = ([f"while tracking: ×{h['ms_tracking'] / c['ms_per_frame']:.2f}"]
                 if np.isfinite(h.get("ms_tracking", float("nan"))) else [])
        notes += [f"the tracker alone, every frame: ×{trk[1]['ms_per_frame'] / c['ms_per_frame']:.2f}"] if trk else []
        floor = f" ({'; '.join(notes)})" if notes else ""
        checks.append(("cost ≤ 1/3 of CNN-only's", h["ms_per_frame"] / c["ms_per_frame"], TARGETS["cost_vs_cnn"],
                       "×{:.2f}" + floor))
    silent = f"{h['silent_failures']} frames" + (f" (tracker-only: {trk[1]['silent_failures']})" if trk else "")
    checks.append(("silent failures = 0", h["silent_failures"], TARGETS["silent_failures"], silent))
    if h["recoveries"]:
        checks.append(("every loss recovered within 5 frames", (h["recover_frames_max"] or 0) + 1000 * h["recover_never"],
                       TARGETS["recover_frames"],
                       f"{h['recoveries']} full occlusions: " + (f"worst {h['recover_frames_max']} frames, "
                                                                  if h["recover_frames_max"] is not None else "")
                       + f"{h['recover_never']} never"))
    checks += [
               ("mean rotation ≤ 1°", h["rot_mean_deg"], TARGETS["rot_mean_deg"], "{:.2f}°"),
               ("translation ≤ 1 % of distance", h["trans_mean_pct"], TARGETS["trans_mean_pct"], "{:.2f} %"),
               ("ADD-0.1d ≥ 0.95", -h["add_recall"], -TARGETS["add_recall"], f"{h['add_recall']:.3f}"),
               ("≥ 60 frames/s amortised", h["ms_per_frame"], 1000 / TARGETS["fps"],
                f"{1000 / h['ms_per_frame']:.0f} frames/s")]
    lines = [f"Targets for `{name}`:"]
    for what, value, limit, shown in checks:
        text = shown.format(value) if "{" in shown else shown
        lines.append(f"- {'met' if value <= limit else 'MISSED'}: {what} — {text}")
    return "\n".join(lines)


@dataclass(frozen=True)
class TargetCheck:
    """One tracker target against a run: ``key`` (of :data:`TRACKER_TARGETS`), what it asks, the run's
    ``value`` and the ``limit`` (the same unit), the kind of sequence that gave the value where it is
    the worst kind's (else None), and whether it is ``met``."""

    key: str
    what: str
    value: float
    limit: float
    unit: str
    kind: str | None = None

    @property
    def met(self) -> bool:
        return bool(np.isfinite(self.value) and self.value <= self.limit)


def tracker_target_checks(rows: list[dict], runs: list[str]) -> tuple[str | None, list[TargetCheck]]:
    """(the first tracker-only run of ``runs``, its checks against :data:`TRACKER_TARGETS`); the
    per-kind figures are the worst kind's. (None, []) without a tracker-only run."""
    name = next((r for r in runs if r.startswith("tracker ")), None)
    own = [r for r in rows if r["label"] == name]
    if not own:
        return None, []
    s = summarise(own)[name]
    kinds = summarise(own, group=lambda r: kind_of(r["sequence"]))

    def worst(key: str) -> tuple[float, str]:
        values = {k: v[key] for k, v in kinds.items() if np.isfinite(v[key])}
        k = max(values, key=values.get) if values else "—"
        return values.get(k, float("nan")), k

    rot, rot_kind = worst("seq_rot_median_median_deg")
    trans, trans_kind = worst("seq_trans_median_median_pct")
    T = TRACKER_TARGETS
    return name, [
        TargetCheck("rot_median_deg", "median rotation ≤ 0.2° on every kind of sequence", rot, T["rot_median_deg"],
                    "°", rot_kind),
        TargetCheck("trans_median_pct", "median translation ≤ 0.1 % of distance on every kind", trans,
                    T["trans_median_pct"], " %", trans_kind),
        TargetCheck("seq_rot_median_p90_deg", "p90 over sequences of each sequence's median rotation ≤ 1°",
                    s["seq_rot_median_p90_deg"], T["seq_rot_median_p90_deg"], "°"),
        TargetCheck("silent_pct", "silent failures ≤ 0.5 % of frames", 100.0 * s["silent_failures"] / max(s["frames"], 1),
                    T["silent_pct"], " %"),
        TargetCheck("false_alarm_pct", "false alarms on clear frames ≤ 2 %", s["false_alarm_pct"], T["false_alarm_pct"],
                    " %"),
        TargetCheck("ms_per_frame", "≤ 5 ms per frame", s["ms_per_frame"], T["ms_per_frame"], " ms"),
    ]


def tracker_targets(rows: list[dict], runs: list[str]) -> str:
    """One line per tracker target (:func:`tracker_target_checks`) for the first tracker-only run of
    ``runs``: met, or missed by how much; "" without one."""
    name, checks = tracker_target_checks(rows, runs)
    if name is None:
        return ""
    digits = {"°": 2, " %": 2, " ms": 1}
    lines = [f"Targets for `{name}` (from the true first pose; medians over each sequence's half-visible frames "
             "with a trusted pose, then over the sequences of a kind):"]
    for c in checks:
        shown = f"{c.value:.{1 if c.key == 'false_alarm_pct' else digits[c.unit]}f}{c.unit}"
        shown = f"worst {shown} ({c.kind})" if c.kind is not None else shown
        lines.append(f"- {'met' if c.met else 'MISSED'}: {c.what} — {shown}")
    return "\n".join(lines)


def kind_of(sequence: str) -> str:
    """``tumble_arm-partial_s503`` → ``tumble_arm-partial``."""
    return sequence.rsplit("_s", 1)[0]


def seed_ranges(seeds) -> str:
    """``[500, 501, …, 519, 560]`` → ``"500–519, 560"``."""
    seeds, parts = sorted(int(x) for x in seeds), []
    for s in seeds:
        if parts and s == parts[-1][1] + 1:
            parts[-1][1] = s
        else:
            parts.append([s, s])
    return ", ".join(f"{a}–{b}" if b > a else f"{a}" for a, b in parts)


def report_markdown(result: dict, plots: list[str] = ()) -> str:
    """The run as a page: what ran, the table per run, the hybrid's ratios and targets, per kind of
    sequence, and the plots."""
    rows, cfg = result["rows"], result["config"]
    summary = summarise(rows)
    head = headline_runs(cfg["runs"])
    headline = {k: summary[k] for k in head if k in summary}
    by_kind = summarise([r for r in rows if r["label"] in head],
                        group=lambda r: f"{r['label'].split(' ')[0]} · {kind_of(r['sequence'])}")
    seeds = cfg.get("seeds")
    # the edge-on tumbles draw their own seeds (those whose start lies near edge-on)
    edge_on = sorted(int(n.rsplit("_s", 1)[1]) for n in cfg["sequences"] if "edgeon" in n and "_s" in n)
    what = (f"Sequences from `{cfg['data']}` ({len(cfg['sequences'])}), object `{cfg.get('object')}`" if cfg.get("data")
            else f"Suite `{cfg['suite']}`, split `{cfg['split']}` ({len(cfg['sequences'])} sequences"
            + (f", seeds {seed_ranges(seeds)}" if seeds else "")
            + (f"; edge-on tumbles: seeds {edge_on[0]}–{edge_on[-1]}" if edge_on else "")
            + ("; a tuning seed: it checks the machinery, its figures are no result" if cfg["split"] == "smoke" else "")
            + ")")
    lines = [
        what + f", commit `{result['commit']}`, "
        f"{cfg['workers']} worker(s), {result['seconds']:.0f} s{_reused(result)}. Tracker-only starts from the true first pose and is "
        "never re-initialised; CNN-only runs on every frame with no prior; the hybrid gets no ground truth. "
        "Errors over the frames where the object is ≥ 50 % visible and the run gave a trusted pose (for a "
        "symmetric object, to the nearest equivalent of the truth); in basin: share of those half-visible frames "
        "with a trusted pose within 10° and 5 % of the distance (where a tracker can start); edge px: median image "
        "distance of the model's edges from where they truly are; silent "
        "failures: frames with a trusted pose > 5° off; false alarms: share of clear frames (≥ 90 % visible) "
        "flagged lost at a pose within 2°; covered, > 10°: frames < 5 % visible with a trusted pose > 10° off; "
        "recovery: frames after a full occlusion until ≤ 2°; NEES: share of errors inside the reported "
        "covariance's 90 % ellipsoid (0.90 when calibrated).",
        "",
        table(headline),
        "",
        # the targets are the space suites'; off black space the per-kind table says what held
        *([] if cfg.get("suite") == "realistic" else [targets(headline), ""]),
        f"Cost per frame by component (one thread per process, {_sizes(rows)}):",
        "",
        cost_table(headline),
        "",
        *([] if cfg.get("suite") == "realistic" else [tracker_targets(rows, cfg["runs"]), ""]),
        "<details><summary>Per kind of sequence</summary>",
        "",
        table(by_kind),
        "",
        "</details>",
    ]
    if len(summary) > len(headline):
        lines += ["", "Ablations (every run, same frames):", "", table(summary)]
    if plots:
        lines += ["", "Plots in the run's output folder: " + ", ".join(f"`{p}`" for p in plots)]
    return "\n".join(lines) + "\n"


def plot_error_vs_distance(path, rows: list[dict], bins_m=np.arange(0.3, 1.3, 0.1)) -> None:
    """Rotation error (median and p90 per distance bin, °) against the true distance, one line per run."""
    def draw(ax):
        for label in sorted({r["label"] for r in rows}):
            err, dist = [], []
            for r in rows:
                if r["label"] == label and r.get("per_frame"):
                    pf = r["per_frame"]
                    err += [np.nan if e is None or v < 0.5 else e for e, v in zip(pf["rot_err_deg"], pf["visible"])]
                    dist += pf["distance_m"]
            err, dist = np.array(err, dtype=np.float64), np.array(dist)
            centres, med, p90 = [], [], []
            for lo, hi in zip(bins_m[:-1], bins_m[1:]):
                e = err[(dist >= lo) & (dist < hi) & np.isfinite(err)]
                if e.size >= 5:
                    centres.append(0.5 * (lo + hi))
                    med.append(np.median(e))
                    p90.append(np.percentile(e, 90))
            if centres:
                line, = ax.plot(centres, med, "o-", label=f"{label} median")
                ax.plot(centres, p90, "--", color=line.get_color(), alpha=0.6, label=f"{label} p90")
        ax.set_yscale("log")
        ax.set_xlabel("distance to the object (m)")
        ax.set_ylabel("rotation error (°)")
        ax.set_title("rotation error by distance (frames ≥ 50 % visible with a trusted pose)", fontsize=9)
        ax.legend(fontsize=7, loc="upper right")
    save_figure(path, draw)


def plot_speed_accuracy(path, summary: dict[str, dict]) -> None:
    """Mean rotation error against cost per frame, one point per run (the ablations' trade-off)."""
    def draw(ax):
        for name, s in summary.items():
            if np.isfinite(s["rot_mean_deg"]):
                ax.plot(s["ms_per_frame"], s["rot_mean_deg"], "o")
                ax.annotate(name, (s["ms_per_frame"], s["rot_mean_deg"]), fontsize=7, xytext=(4, 2),
                            textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("ms per frame (one worker)")
        ax.set_ylabel("mean rotation error (°)")
    save_figure(path, draw)


def plot_sequence(path, rows: list[dict], sequence: str) -> None:
    """Error over time of every run on one sequence, with its occlusion bands (viz.plot_error_over_time)."""
    from ..viz import plot_error_over_time

    rs = [r for r in rows if r["sequence"] == sequence and r.get("per_frame")]
    if not rs:
        raise ValueError(f"sequence: no per-frame results for {sequence!r}")
    pf = rs[0]["per_frame"]
    errors = {r["label"]: [np.nan if e is None else e for e in r["per_frame"]["rot_err_deg"]] for r in rs}
    statuses = next((r["per_frame"]["status"] for r in rs if r["per_frame"]["status"]), None)
    plot_error_over_time(path, pf["timestamp_s"], errors, pf["visible"], title=sequence, statuses=statuses)


def write_plots(out: Path, result: dict) -> list[str]:
    """error_vs_distance.png (the headline runs), speed_accuracy.png (every run) and
    error_over_time_<sequence>.png (the headline runs) for the headline hybrid's worst and median
    sequences; returns the file names."""
    rows = result["rows"]
    head = headline_runs(result["config"]["runs"])
    shown = [r for r in rows if r["label"] in head]
    out = Path(out)
    names = ["error_vs_distance.png", "speed_accuracy.png"]
    plot_error_vs_distance(out / names[0], shown)
    plot_speed_accuracy(out / names[1], summarise(rows))
    hybrid = sorted((r for r in shown if r["mode"] == "hybrid" and np.isfinite(r["rot_mean_deg"])),
                    key=lambda r: r["rot_mean_deg"])
    if hybrid:
        for seq in dict.fromkeys([hybrid[-1]["sequence"], hybrid[len(hybrid) // 2]["sequence"]]):
            names.append(f"error_over_time_{seq}.png")
            plot_sequence(out / names[-1], shown, seq)
    return names


def _reused(result: dict) -> str:
    """`` (R of N rows kept from an earlier run of the same code)`` where a run resumed, else ``""``: its
    seconds then time only the rest."""
    reused, total = result.get("rows_reused", 0), len(result["rows"])
    return f" ({reused} of {total} rows kept from an earlier run of the same code)" if reused else ""
