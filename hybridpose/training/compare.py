"""``hybridpose compare``: is checkpoint B really better than A on the same images? A paired
comparison of two ``hybridpose eval`` reports (McNemar on the gross errors, paired bootstrap on the
mean and median)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .eval_report import GROSS_ERROR_DEG


def compare_reports(report_a, report_b, gross_deg: float = GROSS_ERROR_DEG, resamples: int = 2000,
                    seed: int = 0) -> dict:
    """Paired comparison of two ``hybridpose eval`` reports on the same images: is B really better than A?

    Two checkpoints evaluated on the same 1000 views differ by a handful of gross errors, and a
    gross share of 3 % has a binomial standard error of ±0.5 %: one table row beside another does
    not say which model is better. Pairing the views does. Gross errors (rotation > ``gross_deg``)
    are compared with McNemar's exact test (the views where exactly one model errs, binomial with
    p = ½ under "no difference"); the mean and median rotation errors with a paired bootstrap
    (the same resampled views for both) 95 % interval of B − A.

    Args:
        report_a, report_b: ``report.json`` paths (or the folders holding them) from ``hybridpose eval``,
            or lists of them paired by position (A's and B's reports on several test sets, pooled:
            the views of different sets are independent samples too).
        gross_deg: rotation error that counts as gross, degrees (> 0).
        resamples, seed: the bootstrap.
    Returns:
        ``{"images", "a", "b"`` (each: path, model, rot_mean_deg, rot_median_deg, gross_share),
        ``"gross_only_a", "gross_only_b", "gross_both", "mcnemar_p",
        "rot_mean_diff_deg", "rot_median_diff_deg", "gross_share_diff"`` (each: estimate, ci95 low, high;
        B − A; the last a share of the views, 0..1)}.
    """
    if not (gross_deg > 0 and np.isfinite(gross_deg)):
        raise ValueError(f"gross_deg: expected a rotation error > 0 degrees, got {gross_deg}")
    many_a = list(report_a) if isinstance(report_a, (list, tuple)) else [report_a]
    many_b = list(report_b) if isinstance(report_b, (list, tuple)) else [report_b]
    if len(many_a) != len(many_b) or not many_a:
        raise ValueError(f"report_a, report_b: expected as many reports of A as of B (paired by position), "
                         f"got {len(many_a)} and {len(many_b)}")
    a, b, paths_a, paths_b = [], [], [], []
    for ra, rb in zip(many_a, many_b):
        (path_a, model_a, rows_a), (path_b, model_b, rows_b) = _report_rows(ra), _report_rows(rb)
        if [r["image"] for r in rows_a] != [r["image"] for r in rows_b]:
            raise ValueError(f"{path_a} and {path_b}: not the same images in the same order ({len(rows_a)} vs "
                             f"{len(rows_b)} rows); evaluate both on one dataset with the same --limit")
        a += rows_a
        b += rows_b
        paths_a.append(str(path_a))
        paths_b.append(str(path_b))
    # a failure's row already holds FAILED_ROT_DEG (evaluate_checkpoint)
    c = paired_comparison([r["rot_deg"] for r in a], [r["rot_deg"] for r in b], gross_deg, resamples, seed)
    c["a"].update(report=", ".join(paths_a), model=model_a)
    c["b"].update(report=", ".join(paths_b), model=model_b)
    return c


def paired_comparison(rot_a, rot_b, gross_deg: float = GROSS_ERROR_DEG, resamples: int = 2000, seed: int = 0) -> dict:
    """:func:`compare_reports` on two (N,) arrays of rotation errors (°) of the same views (A's and B's):
    McNemar's exact test on the views more than ``gross_deg`` off, paired bootstrap 95 % intervals of
    the mean and median difference B − A. Same keys as :func:`compare_reports` (``a`` and ``b`` without
    report paths and models)."""
    from scipy.stats import binomtest

    rot_a, rot_b = np.asarray(rot_a, dtype=float), np.asarray(rot_b, dtype=float)
    if rot_a.shape != rot_b.shape or rot_a.ndim != 1 or not len(rot_a):
        raise ValueError(f"rot_a, rot_b: expected two (N,) error arrays of the same views, got shapes "
                         f"{rot_a.shape} and {rot_b.shape}")
    gross_a, gross_b = rot_a > gross_deg, rot_b > gross_deg
    only_a, only_b = int(np.sum(gross_a & ~gross_b)), int(np.sum(gross_b & ~gross_a))
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(rot_a), size=(resamples, len(rot_a)))
    boot_mean = rot_b[idx].mean(1) - rot_a[idx].mean(1)
    boot_median = np.median(rot_b[idx], 1) - np.median(rot_a[idx], 1)
    boot_gross = gross_b[idx].mean(1) - gross_a[idx].mean(1)

    def interval(estimate, boot):
        lo, hi = np.percentile(boot, [2.5, 97.5])
        return {"estimate": float(estimate), "ci95": [float(lo), float(hi)]}

    def side(rot, gross):
        return {"rot_mean_deg": float(rot.mean()), "rot_median_deg": float(np.median(rot)),
                "gross_share": float(gross.mean())}

    return {
        "images": len(rot_a), "gross_deg": float(gross_deg), "a": side(rot_a, gross_a), "b": side(rot_b, gross_b),
        "gross_only_a": only_a, "gross_only_b": only_b, "gross_both": int(np.sum(gross_a & gross_b)),
        "mcnemar_p": float(binomtest(only_b, only_a + only_b).pvalue) if only_a + only_b else 1.0,
        "rot_mean_diff_deg": interval(rot_b.mean() - rot_a.mean(), boot_mean),
        "rot_median_diff_deg": interval(np.median(rot_b) - np.median(rot_a), boot_median),
        # a share (0..1), not %: what a non-inferiority margin on the gross errors is set on
        "gross_share_diff": interval(gross_b.mean() - gross_a.mean(), boot_gross),
    }


def _report_rows(report) -> tuple[Path, str | None, list[dict]]:
    import json

    path = Path(report)
    if path.is_dir():
        path = path / "report.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no report (run `hybridpose eval ... --out DIR` first)")
    try:
        report = json.loads(path.read_text())
        rows = report["per_image"]
        for r in rows:
            r["image"], r["lost"], float(r["rot_deg"])
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a `hybridpose eval` report.json (per_image rows with image, lost, "
                         f"rot_deg): {exc!r}") from exc
    if not rows:
        raise ValueError(f"{path}: the report has no images")
    return path, report.get("summary", {}).get("model"), rows


def comparison_markdown(c: dict) -> str:
    """The result of :func:`compare_reports` as a short Markdown table and verdict."""
    a, b = c["a"], c["b"]
    mean, med = c["rot_mean_diff_deg"], c["rot_median_diff_deg"]
    lines = [f"Paired comparison on {c['images']} images (gross: rotation > {c['gross_deg']:g}°)", "",
             "| | report | mean rot ° | median rot ° | gross |", "|---|---|---|---|---|",
             f"| A | `{a['report']}` | {a['rot_mean_deg']:.2f} | {a['rot_median_deg']:.2f} | {100 * a['gross_share']:.1f}% |",
             f"| B | `{b['report']}` | {b['rot_mean_deg']:.2f} | {b['rot_median_deg']:.2f} | {100 * b['gross_share']:.1f}% |",
             "",
             f"- gross in A only {c['gross_only_a']}, in B only {c['gross_only_b']}, in both {c['gross_both']}: "
             f"McNemar exact p = {c['mcnemar_p']:.3f}",
             f"- mean rotation B − A {mean['estimate']:+.2f}° (95 % paired bootstrap {mean['ci95'][0]:+.2f} … {mean['ci95'][1]:+.2f})",
             f"- median rotation B − A {med['estimate']:+.3f}° ({med['ci95'][0]:+.3f} … {med['ci95'][1]:+.3f})"]
    if "gross_share_diff" in c:  # older saved comparisons lack it
        g = c["gross_share_diff"]
        lines.append(f"- share of views > {c['gross_deg']:g}° B − A {100 * g['estimate']:+.2f} points "
                     f"({100 * g['ci95'][0]:+.2f} … {100 * g['ci95'][1]:+.2f})")
    return "\n".join(lines) + "\n"
