"""What ``hybridpose eval`` reports of a regressor on held-out views: errors in bins (distance,
view elevation, sun phase, light azimuth), accuracy by quality gate, the covariance check's lines, the
markdown report beside the paper's table and the error-vs-distance plot (:mod:`.evaluate` measures).
"""
from __future__ import annotations

import numpy as np

from ..machine import cpu_label

# The paper's results after 100 epochs on its truss data (mean rot °, median rot °, mean trans m).
PAPER = {"VGG-16": (13.56, 12.33, 0.18), "VGG-19": (12.21, 11.34, 0.15),
         "Branched VGG-19": (8.34, 7.34, 0.06), "Parallel VGG-19": (4.61, 4.41, 0.03)}
DISTANCE_BINS_M = np.linspace(0.3, 1.2, 10)
GROSS_ERROR_DEG = 30.0  # a view this far off is a gross error (a wrong twin or a flip)
# Edge-on views (a flat object seen along its plane) hold most of the gross errors: bins fine near 0°.
ELEVATION_BINS_DEG = np.array([0.0, 6.0, 12.0, 20.0, 30.0, 45.0, 90.0])
QUALITY_GATES = (0.0, 0.2, 0.3, 0.4, 0.5)  # accuracy is reported above each of these qualities
# Lighting geometry of a view (datasets written by `hybridpose render` record each image's sun):
# phase angle 0° sun behind the camera, 90° side-lit; azimuth where the light travels in the image.
PHASE_BINS_DEG = np.array([0.0, 30.0, 45.0, 60.0, 75.0, 90.0, 180.0])
AZIMUTH_BINS_DEG = np.arange(0.0, 361.0, 45.0)

# Below coverage by more than this (≈ 3 binomial σ at 100 views) the report says over-confident.
OVER_CONFIDENT_MARGIN = 0.1


def over_confident(check: dict) -> bool:
    """Whether a :func:`covariance_check` shows the covariance over-confident: fewer errors inside
    the ellipsoid (to the nearest box twin, what the covariance promises) than its coverage by
    more than :data:`OVER_CONFIDENT_MARGIN`."""
    return bool(check.get("views")) and check["inside_share_twin"] < check["coverage"] - OVER_CONFIDENT_MARGIN


def error_vs_distance(rows) -> list[dict]:
    """Mean ± 1σ of rotation (°) and translation (m) errors per distance bin (successful predictions)."""
    d = np.array([r["distance_m"] for r in rows])
    ok = np.array([not r["lost"] for r in rows])
    rot = np.array([r["rot_deg"] for r in rows])
    trans = np.array([r["trans_m"] for r in rows])
    out = []
    for lo, hi in zip(DISTANCE_BINS_M[:-1], DISTANCE_BINS_M[1:]):
        sel = ok & (d >= lo) & (d < hi)
        if sel.any():
            out.append({"lo_m": float(lo), "hi_m": float(hi), "n": int(sel.sum()),
                        "rot_mean_deg": float(rot[sel].mean()), "rot_std_deg": float(rot[sel].std()),
                        "trans_mean_m": float(trans[sel].mean()), "trans_std_m": float(trans[sel].std())})
    return out


def error_vs_elevation(rows) -> list[dict]:
    """Per view-elevation bin (°, :func:`view_elevation_deg`): count, mean / median rotation error (°)
    and the share of views more than ``GROSS_ERROR_DEG`` off (failures included, as 180°)."""
    return error_in_bins(rows, "elevation_deg", ELEVATION_BINS_DEG)


def error_in_bins(rows, key: str, edges) -> list[dict]:
    """Per bin ``[lo, hi)`` of ``row[key]`` (the last bin closed): count, mean / median rotation error (°)
    and the share more than ``GROSS_ERROR_DEG`` off (failures included, as 180°). Rows without
    ``key`` (e.g. no recorded sun) are left out; no such rows, no bins."""
    rows = [r for r in rows if r.get(key) is not None]
    if not rows:
        return []
    value = np.array([r[key] for r in rows])
    rot = np.array([r["rot_deg"] for r in rows])
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (value >= lo) & ((value < hi) | (hi == edges[-1]))
        if sel.any():
            out.append({"lo_deg": float(lo), "hi_deg": float(hi), "n": int(sel.sum()),
                        "rot_mean_deg": float(rot[sel].mean()), "rot_median_deg": float(np.median(rot[sel])),
                        "gross_error_share": float(np.mean(rot[sel] > GROSS_ERROR_DEG))})
    return out


def bins_table(bins, label: str) -> list[str]:
    """Markdown rows of :func:`error_in_bins` output under a ``label`` column."""
    lines = [f"| {label} | n | mean rot ° | median rot ° | > 30° |", "|---|---|---|---|---|"]
    for b in bins:
        lines.append(f"| {b['lo_deg']:.0f}–{b['hi_deg']:.0f} | {b['n']} | {b['rot_mean_deg']:.2f} | "
                     f"{b['rot_median_deg']:.2f} | {b['gross_error_share']:.1%} |")
    return lines


def plot_error_vs_distance(bins, path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not bins:
        return
    c = [(b["lo_m"] + b["hi_m"]) / 2 for b in bins]
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for ax, key, unit in ((axes[0], "rot", "°"), (axes[1], "trans", "m")):
        mean = np.array([b[f"{key}_mean_{'deg' if key == 'rot' else 'm'}"] for b in bins])
        std = np.array([b[f"{key}_std_{'deg' if key == 'rot' else 'm'}"] for b in bins])
        ax.errorbar(c, mean, yerr=std, fmt="o-", capsize=3)
        ax.set_xlabel("distance from camera (m)")
        ax.set_ylabel(f"{'rotation' if key == 'rot' else 'translation'} error ({unit})")
        ax.grid(alpha=0.3)
    fig.suptitle(f"{title}: error vs distance (mean ± 1σ)")
    fig.tight_layout()
    from ..io import atomic_write_with

    try:
        atomic_write_with(path, lambda f: fig.savefig(f, format="png", dpi=110))
    finally:
        plt.close(fig)


def accuracy_by_quality(rows, gates=QUALITY_GATES) -> list[dict]:
    """Per gate ``g``: the share of all views whose measurement has quality ≥ ``g`` (``kept_share``;
    failures, quality 0, are kept only by the gate 0) and, over those kept, mean / median rotation
    error (°), mean translation error (m) and the share more than ``GROSS_ERROR_DEG`` off. A gate
    that keeps no view reports only ``kept_share`` = 0."""
    quality = np.array([r["quality"] for r in rows], dtype=float)
    rot = np.array([r["rot_deg"] for r in rows], dtype=float)
    trans = np.array([r["trans_m"] for r in rows], dtype=float)
    out = []
    for g in gates:
        sel = quality >= g
        row = {"min_quality": float(g), "kept_share": float(sel.mean()) if len(sel) else 0.0}
        if sel.any():
            row.update(rot_mean_deg=float(rot[sel].mean()), rot_median_deg=float(np.median(rot[sel])),
                       trans_mean_m=float(trans[sel].mean()), gross_error_share=float(np.mean(rot[sel] > GROSS_ERROR_DEG)))
        out.append(row)
    return out


def report_markdown(s: dict) -> str:
    lines = [
        f"# Evaluation of `{s['model']}` on `{s['data']}` ({s['images']} images)",
        "",
        *([] if s.get("roi", "none") == "none" else
          ["Each view given its true object box as `roi` (what a tracker on the object passes; the timings run "
           "without it).", ""]),
        "| model | mean rot ° | median rot ° | mean trans m | SPEED | ADD-0.1d | > 30° | failures | ms/img 1 thr | ms/img 2 thr |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, (mr, md, mt) in PAPER.items():
        lines.append(f"| paper: {name} | {mr:.2f} | {md:.2f} | {mt:.2f} | – | – | – | – | – | – |")
    ms = s["ms_per_image"]
    lines.append(f"| **ours: {s['model']}** | {s['rot_mean_deg']:.2f} | {s['rot_median_deg']:.2f} | {s['trans_mean_m']:.3f} | "
                 f"{s['speed_score']:.3f} | {s['add_0.1d_recall']:.2f} | {s['gross_error_share']:.1%} | {s['failures']} | "
                 f"{_ms_cell(ms, '1_thread')} | {_ms_cell(ms, '2_threads')} |")
    lines += ["", "Failures (no pose) count as 180° / 1 m in the means. Error vs distance: `error_vs_distance.png`; "
              "Grad-CAM of the best and worst predictions: `gradcam.png`."]
    if "network_1_thread" in ms:
        lines += ["", f"Timed on {cpu_label(s.get('machine', {}))}: ms/img is the whole `predict` path; one bare "
                  f"network call (batch 1, on {s.get('engine', 'torch')}) takes {ms['network_1_thread']:.1f} ms on 1 thread here, "
                  f"{ms.get('network_2_threads', float('nan')):.1f} ms on 2 (compare machines by it)."]
    if "1_thread_p95" in ms:
        lines += ["", f"Latency per image on 1 thread (the views the mean was taken on): median {ms['1_thread_p50']:.1f} ms, "
                  f"95th percentile {ms['1_thread_p95']:.1f} ms, largest {ms['1_thread_max']:.1f} ms (the hard views run "
                  "extra network passes and edge fits)."]
    lines += [""]
    lines += ["| distance m | n | rot ° (mean ± σ) | trans m (mean ± σ) |", "|---|---|---|---|"]
    for b in s["error_vs_distance"]:
        lines.append(f"| {b['lo_m']:.1f}–{b['hi_m']:.1f} | {b['n']} | {b['rot_mean_deg']:.2f} ± {b['rot_std_deg']:.2f} | "
                     f"{b['trans_mean_m']:.3f} ± {b['trans_std_m']:.3f} |")
    if s.get("error_vs_elevation"):
        lines += ["", "View elevation: the line of sight's angle to the object's main plane (0° edge-on, 90° face-on).", ""]
        lines += bins_table(s["error_vs_elevation"], "elevation °")
    if s.get("error_vs_phase"):
        lines += ["", "Sun phase angle: at the object, the angle between the directions to the sun and to the camera "
                  "(0° sun behind the camera, 90° side-lit, 180° back-lit).", ""]
        lines += bins_table(s["error_vs_phase"], "phase °")
    if s.get("error_vs_light_azimuth"):
        lines += ["", "Light azimuth: the direction the sunlight travels across the image, from +x (right) towards "
                  "+y (down); 0° light from the left, 90° from above, 180° from the right, 270° from below.", ""]
        lines += bins_table(s["error_vs_light_azimuth"], "azimuth °")
    if s.get("accuracy_by_quality"):
        lines += ["", quality_table(s["accuracy_by_quality"])]
    lines += covariance_lines(s.get("covariance_check") or {}, s.get("checkpoint", "CK"))
    return "\n".join(lines) + "\n"


def covariance_lines(c: dict, checkpoint="CK") -> list[str]:
    """Markdown lines of a :func:`covariance_check` (none without views), with how to re-scale an
    over-confident covariance of ``checkpoint``."""
    lines = []
    if c.get("views"):
        lines += ["", f"Covariance check: of the {c['views']} views with a pose, {c['inside_share']:.1%} lie inside the "
                      f"{c['coverage']:.0%} χ²₆ ellipsoid of the reported covariance around the true pose, "
                      f"{c['inside_share_twin']:.1%} around the nearest box twin (calibrated: ≈ {c['coverage']:.0%}; "
                      "far below: over-confident)."]
        if c.get("by_quality"):
            lines[-1] += " By measurement quality (nearest twin): " + "; ".join(
                f"{b['min_quality']:.1f}–{b['max_quality']:.1f}" if b["max_quality"] is not None else f"≥ {b['min_quality']:.1f}"
                for b in c["by_quality"]) + " → " + "; ".join(
                f"{b['inside_share_twin']:.0%} of {b['views']}" for b in c["by_quality"]) + "."
        if over_confident(c):
            lines += ["", f"**Over-confident covariance** (the training calibration saw only the network's first pass): "
                          f"re-scale it on the whole inference path over held-out views before a filter uses it: "
                          f"`hybridpose calibrate --checkpoint {checkpoint} --data OTHER_DIR "
                          "--out calibrated.pt`."]
    return lines


def quality_table(gates) -> str:
    """Markdown of :func:`accuracy_by_quality`."""
    lines = ["Accuracy by quality: the views a caller keeps when it trusts only measurements of quality ≥ the gate.", "",
             "| quality ≥ | views kept | mean rot ° | median rot ° | mean trans m | > 30° |", "|---|---|---|---|---|---|"]
    for g in gates:
        if g["kept_share"] == 0:
            lines.append(f"| {g['min_quality']:.2f} | 0 % | – | – | – | – |")
            continue
        lines.append(f"| {g['min_quality']:.2f} | {g['kept_share']:.1%} | {g['rot_mean_deg']:.2f} | {g['rot_median_deg']:.2f} | "
                     f"{g['trans_mean_m']:.3f} | {g['gross_error_share']:.1%} |")
    return "\n".join(lines)


def _ms_cell(ms: dict, key: str) -> str:
    """A table cell of ms: ``ms[key]`` to 0.1 ms, or – where it was not timed (``timing_images=0``)."""
    return f"{ms[key]:.1f}" if key in ms else "–"
