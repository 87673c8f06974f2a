"""The twin choice of the shipped keypoint regressor, measured candidate by candidate.

Usage:
    python benchmarks/pooled_twins.py --seen data/truss_test128 ... --confirm data/truss_test142 ... \
        --fresh data/truss_test146 ... [--wide data/truss_wide216 ...] [--side data/truss_side240 ...] \
        [--cache runs/twin_cache]

Most views > 30° off on the 40°-cone test sets are end-for-end twins of the truth (errors near 180°), and
most of them lie within a few degrees of edge-on, where the shipped predictor has two estimates (the
default network's and the edge-on expert's) with four box twins each. For every view this script records
every candidate the predictor weighs: per estimate and twin, the twin head's probability, the twin
verifier's probability, the edge fit's quality, and the rotation error of the pose the predictor would
return for that twin (the edge-fitted one where the fit reaches ``REFINE_MIN_QUALITY``), plus each
estimate's PnP quality. Both rules are replayed on those numbers (exactly what the predictor returns):
the quality rule (twin per estimate by ``log p + 8 log q + log p_verifier``, then the estimate of higher
measurement quality) and the pooled rule (``expert_rule="pooled"``: the best of all eight candidates by
that score plus ``POOLED_PNP_WEIGHT · log q_pnp``), compared view by view on each group of sets (McNemar
on the > 30° views, paired bootstrap of the mean); ``--seen`` (sets looked at before the rule being
confirmed was written) also shows other weights. The dim fallback is off here (it only adds views neither rule differs on).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from hybridpose.core import Frame
from hybridpose.metrics import rotation_error_deg
from hybridpose.objects import view_elevation_deg
from _common import PAIRED_HEADER, cached_npz, concat_sets, environment, paired_cells, publish, test_views, weights_tag
from hybridpose.regressors.evaluate import GROSS_ERROR_DEG, paired_comparison
from hybridpose.regressors.predictor import (POOLED_PNP_WEIGHT, REFINE_MIN_QUALITY, REFINE_SEARCH_PX,
                                             VERIFIER_EDGE_WEIGHT, VERIFIER_SURE, CheckpointRegressor, _pnp_quality,
                                             WEIGHTS_DIR, shipped_checkpoint, twin_scores)
from hybridpose.edges import fit_edges, to_gray

N_TWINS = 4


def measure(data: str, checkpoint: str, expert: str = "auto", limit=None) -> dict:
    """Per view of ``data`` (arrays over views; ``[:, e, k]``: estimate e (0 the default's, 1 the
    expert's), twin k in that estimate's head order): ``n_est`` (0–2), ``elevation`` (first estimate's
    view elevation, °), ``pnp_quality`` (V, 2), ``head`` / ``verifier`` / ``fit_quality`` (V, 2, 4),
    ``err`` (V, 2, 4: rotation error of the pose returned for that twin, °), ``shipped`` (the predictor's
    error under the quality rule, shipped until session 26 (the key name is kept for existing caches); 180
    where lost) and ``seconds`` (its time)."""
    reg = CheckpointRegressor(checkpoint, threads=1, edge_on_expert=expert, expert_rule="quality",
                              dim_fallback=False)
    view = reg.twin_check.view
    rows = {k: [] for k in ("n_est", "elevation", "pnp_quality", "head", "verifier", "fit_quality", "err",
                             "shipped", "seconds", "twin_gap")}
    with torch.no_grad():
        for frame, gt in test_views(data, limit):
            t0 = time.perf_counter()
            m = reg.predict(frame)
            rows["seconds"].append(time.perf_counter() - t0)
            rows["shipped"].append(180.0 if m.lost else rotation_error_deg(m.pose, gt.pose))
            image, cam, ests, all_starts = estimates_and_twins(reg, frame)
            shape = (2, N_TWINS)
            pq, head, ver, fq, err = np.zeros(2), np.zeros(shape), np.zeros(shape), np.zeros(shape), np.full(shape, 180.0)
            gap = np.full((N_TWINS, N_TWINS), 180.0)
            gray = to_gray(image)
            und = Frame(image, cam, 0.0, frame.index)
            for e, (est, starts) in enumerate(zip(ests, all_starts)):
                _, order, prob, _ = est
                pq[e] = _pnp_quality(est)
                head[e] = [prob[k] for k in order]
                ver[e] = reg.verifier.probabilities(image, cam.K, starts)
                for k, start in enumerate(starts):
                    fit = fit_edges(view, und, start, gray=gray, search_px=REFINE_SEARCH_PX)
                    fq[e, k] = 0.0 if fit is None else fit.quality
                    pose = fit.pose if fit is not None and fit.quality >= REFINE_MIN_QUALITY else start
                    err[e, k] = rotation_error_deg(pose, gt.pose)
            if len(all_starts) == 2:
                gap = np.array([[rotation_error_deg(a, b) for b in all_starts[1]] for a in all_starts[0]])
            rows["twin_gap"].append(gap)
            rows["n_est"].append(len(ests))
            rows["elevation"].append(view_elevation_deg(ests[0][0].pose, reg.expert_object) if ests else 90.0)
            for k, v in (("pnp_quality", pq), ("head", head), ("verifier", ver), ("fit_quality", fq), ("err", err)):
                rows[k].append(v)
    return {k: np.asarray(v, dtype=float) for k, v in rows.items()}


def estimates_and_twins(reg: CheckpointRegressor, frame: Frame):
    """(undistorted image, its camera, the predictor's estimates of ``frame``, each estimate's box twins in
    its head's order): the candidates :func:`measure` and :func:`verifier_column` record."""
    image, cam = reg._undistorted(frame)
    ests = reg._keypoint_estimates(image, cam, None)
    return image, cam, ests, [reg._twin_starts(res.pose, order) for res, order, _, _ in ests]


def cached(folder, data: str, checkpoint: str, expert: str = "auto", limit=None, verifier: str | None = None) -> dict:
    """:func:`measure` (with ``verifier``: :func:`verifier_column` of that verifier), kept in ``folder``
    (one .npz per set, checkpoint, expert, limit and verifier, keyed by their names and
    :func:`weights_tag` of their files; the shipped verifier's where :func:`measure` records it) when given:
    a cache made with other weights under the same names gets another key instead of being replayed as if
    it were current."""
    tag = "" if expert == "auto" else f"__{Path(expert).stem}"
    expert_file = WEIGHTS_DIR / "edge_on_expert.pt" if expert == "auto" else expert
    key = f"{Path(data).name}__{Path(checkpoint).stem}{tag}__{limit}"
    if verifier is not None:
        return cached_npz(folder, f"{key}__verifier_{Path(verifier).parent.name}_{Path(verifier).stem}__"
                                  f"{weights_tag(checkpoint, expert_file, verifier)}",
                          lambda: verifier_column(data, checkpoint, verifier, expert, limit))
    return cached_npz(folder, f"{key}__{weights_tag(checkpoint, expert_file, WEIGHTS_DIR / 'twin_verifier.pt')}",
                      lambda: measure(data, checkpoint, expert, limit))


def verifier_column(data: str, checkpoint: str, verifier: str, expert: str = "auto", limit=None) -> dict:
    """``{"verifier": (V, 2, 4)}``: another twin verifier's probabilities of the candidates
    :func:`measure` records (same estimates, same twin order; zeros where an estimate is missing), so
    the twin choice can be replayed with that verifier in its place (every other number is
    unchanged: the verifier only weighs the candidates)."""
    reg = CheckpointRegressor(checkpoint, threads=1, edge_on_expert=expert, expert_rule="quality",
                              dim_fallback=False, verifier=verifier)
    rows = []
    with torch.no_grad():
        for frame, _ in test_views(data, limit):
            image, cam, _, all_starts = estimates_and_twins(reg, frame)
            ver = np.zeros((2, N_TWINS))
            for e, starts in enumerate(all_starts):
                ver[e] = reg.verifier.probabilities(image, cam.K, starts)
            rows.append(ver)
    return {"verifier": np.asarray(rows, dtype=float)}


def quality_choice(m: dict) -> tuple[np.ndarray, np.ndarray]:
    """(estimate, twin) per view that the predictor returns under ``expert_rule="quality"`` (the default
    until session 26), replayed from :func:`measure`'s numbers: per estimate the head's twin where it is sure (≥ ``VERIFIER_SURE``), else the best
    :func:`twin_scores` over every twin; then the estimate of higher measurement quality (PnP quality ×
    the head's probability of its twin), the default's on a tie."""
    scores = twin_scores(m["head"], m["fit_quality"], edge_weight=VERIFIER_EDGE_WEIGHT, verifier_prob=m["verifier"])
    twin = np.where(m["head"][:, :, 0] >= VERIFIER_SURE, 0, scores.argmax(-1))  # (V, 2)
    belief = np.take_along_axis(m["head"], twin[..., None], -1)[..., 0]
    quality = m["pnp_quality"] * belief
    est = ((m["n_est"] == 2) & (quality[:, 1] > quality[:, 0])).astype(int)
    return est, twin[np.arange(len(est)), est]


def errors_of(m: dict, est: np.ndarray, twin: np.ndarray) -> np.ndarray:
    """Rotation error (°) of the chosen candidates; 180 where a view has no estimate."""
    err = m["err"][np.arange(len(est)), est, twin]
    return np.where(m["n_est"] > 0, err, 180.0)


def pooled_choice(m: dict, pnp_weight: float = POOLED_PNP_WEIGHT) -> tuple[np.ndarray, np.ndarray]:
    """(estimate, twin) per view under ``expert_rule="pooled"``: where both estimates exist, the best
    of their eight candidates by ``twin_scores(head, q_fit, verifier) + pnp_weight · log q_pnp`` (the
    predictor prunes its fits but returns this same candidate); elsewhere the quality rule's."""
    scores = (twin_scores(m["head"], m["fit_quality"], edge_weight=VERIFIER_EDGE_WEIGHT, verifier_prob=m["verifier"])
              + pnp_weight * np.log(m["pnp_quality"] + 1e-3)[..., None]).reshape(len(m["n_est"]), -1)
    best = scores.argmax(1)
    est, twin = quality_choice(m)
    both = m["n_est"] == 2
    return np.where(both, best // N_TWINS, est), np.where(both, best % N_TWINS, twin)


def pooled_unsure_choice(m: dict) -> tuple[np.ndarray, np.ndarray]:
    """(estimate, twin) per view under ``expert_rule="pooled-unsure"`` (shipped since session 26): the pooled
    choice where both estimates exist and either twin head is below ``VERIFIER_SURE``, else the quality rule's."""
    est, twin = quality_choice(m)
    p_est, p_twin = pooled_choice(m)
    pools = (m["n_est"] == 2) & (m["head"][:, :, 0] < VERIFIER_SURE).any(1)
    return np.where(pools, p_est, est), np.where(pools, p_twin, twin)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seen", nargs="+", required=True,
                    help="sets looked at before the rule was written (its weight was chosen on seeds 128-141)")
    ap.add_argument("--confirm", nargs="*", default=[], help="sets lit like the training data, not used to choose")
    ap.add_argument("--fresh", nargs="*", default=[], help="sets lit alike, rendered after the rule was written")
    ap.add_argument("--wide", nargs="*", default=[], help="sets lit from within 85° of the optical axis")
    ap.add_argument("--side", nargs="*", default=[], help="sets lit from within 120° (side- and back-light)")
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--expert", default="auto", help="edge-on expert checkpoint (default: the shipped one)")
    ap.add_argument("--pnp-weights", type=float, nargs="*", default=[0.0, 0.5, 2.0],
                    help="other weights of log q_pnp shown on --seen beside the chosen one")
    ap.add_argument("--limit", type=int, default=None)
    ap.add_argument("--cache", default=None, help="folder keeping each set's per-view numbers (reused when present)")
    args = ap.parse_args()
    groups = {"seen": args.seen, "confirm": args.confirm, "fresh": args.fresh, "wide": args.wide, "side": args.side}
    measured = {g: concat_sets([cached(args.cache, d, args.checkpoint, args.expert, args.limit) for d in dirs])
                for g, dirs in groups.items() if dirs}
    out = {"env": environment(), "checkpoint": args.checkpoint, "expert": args.expert, "sets": groups,
           "pnp_weight": POOLED_PNP_WEIGHT, "groups": {}}
    lines = ["## Pooled twin choice of the shipped keypoint regressor (`benchmarks/pooled_twins.py`)", "",
             f"Checkpoint `{Path(args.checkpoint).name}`, edge-on expert `{args.expert}`. A = the quality rule "
             "(each estimate's twin by head, edge fit and verifier, then the estimate of higher measurement "
             "quality; the default before session 26), B = the pooled rule (the best-scored of every twin of both "
             f"estimates, log q_pnp weighted {POOLED_PNP_WEIGHT:g}), or it only where a twin head is unsure; they "
             "differ only where both estimates exist (first estimate within the expert's gate). Oracle: the best "
             "candidate by true error.", "",
             f"| sets | views | both estimates | rule B | {PAIRED_HEADER.format(gross=GROSS_ERROR_DEG)} | oracle mean ° |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for g, m in measured.items():
        a = errors_of(m, *quality_choice(m))
        valid = np.arange(2)[None, :, None] < m["n_est"][:, None, None]
        oracle = np.where(m["n_est"] > 0, np.where(valid, m["err"], np.inf).reshape(len(a), -1).min(1), 180.0)
        weights = [POOLED_PNP_WEIGHT] + (args.pnp_weights if g == "seen" else [])
        out["groups"][g] = {"views": len(a), "both": int(np.sum(m["n_est"] == 2)), "oracle_mean_deg": float(oracle.mean()),
                            "rules": {}}
        for w in weights:
            c = paired_comparison(a, errors_of(m, *pooled_choice(m, w)))
            out["groups"][g]["rules"][f"pooled pnp_weight={w:g}"] = c
            name = f"pooled, log q_pnp × {w:g}" + (" (chosen weight)" if w == POOLED_PNP_WEIGHT else "")
            lines.append(f"| {g} ({len(groups[g])}) | {len(a)} | {int(np.sum(m['n_est'] == 2))} | {name} | "
                         f"{paired_cells(c)} | {oracle.mean():.2f} |")
        c = paired_comparison(a, errors_of(m, *pooled_unsure_choice(m)))
        out["groups"][g]["rules"]["pooled-unsure"] = c
        lines.append(f"| {g} ({len(groups[g])}) | {len(a)} | {int(np.sum(m['n_est'] == 2))} | pooled where a head is "
                     f"unsure (the default since session 26) | {paired_cells(c)} | {oracle.mean():.2f} |")
    publish("pooled_twins", "pooled-twins", out, lines)


if __name__ == "__main__":
    main()
