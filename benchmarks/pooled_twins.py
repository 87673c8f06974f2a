"""The twin choice of the shipped keypoint regressor, measured candidate by candidate.

Usage:
    python benchmarks/pooled_twins.py --tune data/truss_test128 ... --confirm data/truss_test146 ... \
        [--wide data/truss_wide218 ...] [--side data/truss_side242 ...] [--cache runs/twin_cache]

Most views > 30° off on the 40°-cone test sets are end-for-end twins of the truth (errors near 180°), and
most of them lie within a few degrees of edge-on, where the shipped predictor has two estimates (the
default network's and the edge-on expert's) with four box twins each. For every view this script records
every candidate the predictor weighs: per estimate and twin, the twin head's probability, the twin
verifier's probability, the edge fit's quality, and the rotation error of the pose the predictor would
return for that twin (the edge-fitted one where the fit reaches ``REFINE_MIN_QUALITY``), plus each
estimate's PnP quality. Rules that choose one candidate are then replayed on those numbers: the shipped
one (twin per estimate by ``log p + 8 log q + log p_verifier``, estimate by measurement quality) and the
ones listed in ``RULES``; the rule is chosen on ``--tune`` and compared with the shipped one on the other
groups (McNemar on the > 30° views, paired bootstrap of the mean).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from hybridpose.core import Frame
from hybridpose.datasets.bop import BopScene, find_scenes
from hybridpose.metrics import rotation_error_deg
from hybridpose.objects import view_elevation_deg
from hybridpose.regressors.predictor import (REFINE_MIN_QUALITY, REFINE_SEARCH_PX, VERIFIER_EDGE_WEIGHT,
                                             VERIFIER_SURE, CheckpointRegressor, _pnp_quality, shipped_checkpoint,
                                             twin_scores)
from hybridpose.trackers.edges import fit_edges, to_gray

N_TWINS = 4


def measure(data: str, checkpoint: str, limit=None) -> dict:
    """Per view of ``data`` (arrays over views; ``[:, e, k]``: estimate e (0 the default's, 1 the
    expert's), twin k in that estimate's head order): ``n_est`` (0–2), ``elevation`` (first estimate's
    view elevation, °), ``pnp_quality`` (V, 2), ``head`` / ``verifier`` / ``fit_quality`` (V, 2, 4),
    ``err`` (V, 2, 4: rotation error of the pose returned for that twin, °), ``shipped`` (the shipped
    predictor's error; 180 where lost) and ``seconds`` (its time)."""
    reg = CheckpointRegressor(checkpoint, threads=1)
    view = reg.twin_check.view
    V = lambda: []  # noqa: E731
    rows = {k: V() for k in ("n_est", "elevation", "pnp_quality", "head", "verifier", "fit_quality", "err",
                             "shipped", "seconds", "twin_gap")}
    items = [(s, i) for s in map(BopScene, find_scenes(data)) for i in s.image_ids][:limit]
    with torch.no_grad():
        for scene, im_id in items:
            gt = scene.image(im_id)
            frame = Frame(scene.rgb(im_id), gt.camera, 0.0, im_id)
            t0 = time.perf_counter()
            m = reg.predict(frame)
            rows["seconds"].append(time.perf_counter() - t0)
            rows["shipped"].append(180.0 if m.lost else rotation_error_deg(m.pose, gt.pose))
            image, cam = reg._undistorted(frame)
            ests = reg._keypoint_estimates(image, cam, None)
            shape = (2, N_TWINS)
            pq, head, ver, fq, err = np.zeros(2), np.zeros(shape), np.zeros(shape), np.zeros(shape), np.full(shape, 180.0)
            gap = np.full((N_TWINS, N_TWINS), 180.0)
            gray = to_gray(image)
            und = Frame(image, cam, 0.0, im_id)
            all_starts = []
            for e, est in enumerate(ests):
                res, order, prob, _ = est
                starts = reg._twin_starts(res.pose, order)
                all_starts.append(starts)
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


def cached(folder, data: str, checkpoint: str, limit=None) -> dict:
    """:func:`measure`, kept in ``folder`` (one .npz per set, checkpoint and limit) when given."""
    if folder is None:
        return measure(data, checkpoint, limit)
    path = Path(folder) / f"{Path(data).name}__{Path(checkpoint).stem}__{limit}.npz"
    if path.is_file():
        with np.load(path) as f:
            return {k: f[k] for k in f.files}
    m = measure(data, checkpoint, limit)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path.with_suffix(".tmp.npz"), **m)
    path.with_suffix(".tmp.npz").replace(path)
    return m


def shipped_choice(m: dict) -> tuple[np.ndarray, np.ndarray]:
    """(estimate, twin) per view that the shipped predictor returns, replayed from :func:`measure`'s
    numbers: per estimate the head's twin where it is sure (≥ ``VERIFIER_SURE``), else the best
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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--checkpoint", default=str(shipped_checkpoint("default")))
    ap.add_argument("--limit", type=int, default=None)
    ap.add_argument("--cache", default="runs/twin_cache")
    args = ap.parse_args()
    for d in args.data:
        t0 = time.time()
        m = cached(args.cache, d, args.checkpoint, args.limit)
        replayed = errors_of(m, *shipped_choice(m))
        print(d, f"{time.time() - t0:.0f} s", "shipped mean", m["shipped"].mean(), "replayed", replayed.mean(),
              "differ", int(np.sum(np.abs(replayed - m["shipped"]) > 0.01)), flush=True)


if __name__ == "__main__":
    main()
