"""Fitting a checkpoint's covariance calibration (:mod:`hybridpose.regressors.calibration` applies it):
one scale from the held-out errors (:func:`calibrate`), and a factor per band of measurement quality
(:func:`quality_scale`)."""
from __future__ import annotations

import numpy as np
import torch
from scipy.stats import chi2

from ..geometry import Pose
from ..regressors.calibration import (COVERAGE, MIN_BAND_POSES, PNP_THRESHOLD, QUALITY_EDGES, SIGMA_FLOOR_PX, nees,
                                      pnp_covariance)
from ..regressors.keypoint_pnp import solve_pnp


def quality_scale(quality, nees_values, coverage: float = COVERAGE, edges=QUALITY_EDGES,
                  min_poses: int = MIN_BAND_POSES) -> dict:
    """Covariance factors per band of measurement quality, relative to one factor for all poses.

    Args:
        quality: (N,) the measurements' quality, 0..1.
        nees_values: (N,) their NEES under the covariance the factors will multiply.
        coverage: share of each band's errors to put inside the χ²₆ ellipsoid of that probability.
        edges: lower edges of the bands (increasing, the first 0).
        min_poses: a band with fewer poses is merged into the next one up (the last into the one below).
    Returns:
        ``{"edges": [...], "factors": [...], "poses": [...], "overall": f}``: band k covers quality in
        ``[edges[k], edges[k + 1])``; its factor puts ``coverage`` of its errors inside, divided by
        ``overall`` (the factor that does so for all poses at once). Factors never rise with
        quality (a band's is at least the one above it): a better measurement is never reported as
        less certain.
    """
    q, v = np.asarray(quality, dtype=float), np.asarray(nees_values, dtype=float)
    if q.shape != v.shape or q.ndim != 1 or len(q) < min_poses:
        raise ValueError(f"quality, nees_values: expected two (N,) arrays with N ≥ {min_poses}, got {q.shape} and {v.shape}")
    if not np.all(np.isfinite(q)) or not np.all(np.isfinite(v)):
        raise ValueError("quality, nees_values: expected finite values")
    bound = float(chi2.ppf(coverage, 6))
    overall = float(np.quantile(v, coverage)) / bound
    band = np.searchsorted(np.asarray(edges, dtype=float), q, side="right") - 1
    counts = np.bincount(band, minlength=len(edges))
    groups, current = [], []
    for k in range(len(edges)):
        current.append(k)
        if counts[current].sum() >= min_poses:
            groups.append(current)
            current = []
    if current:  # the last bands hold too few poses: they join the band below
        groups[-1] += current
    members = [np.isin(band, g) for g in groups]
    factors = [float(np.quantile(v[m], coverage)) / bound / overall for m in members]
    for k in range(len(factors) - 2, -1, -1):
        factors[k] = max(factors[k], factors[k + 1])
    return {"edges": [float(edges[g[0]]) for g in groups], "factors": factors,
            "poses": [int(m.sum()) for m in members], "overall": overall}


def keypoint_pnp_batch(model, batch, device=None) -> tuple[list, torch.Tensor | None]:
    """One network pass of a keypoint model over ``batch`` and PnP per sample (crop pixels, the
    batch's crop ``K``): (``PnPResult`` or None where PnP fails, per sample; twin logits (B, T) or None)."""
    pred, score, twin = model(batch["image"].to(device or "cpu"), with_twin=True)
    pts3 = model.keypoints_m.cpu().numpy().astype(np.float64)
    Ks = batch["K"].numpy().astype(np.float64)
    pred = pred.float().cpu().numpy().astype(np.float64)
    if getattr(model, "unlabelled", False):
        from ..regressors.unlabelled import detections, solve_pnp_unlabelled

        planes, gauge = model.pnp_geometry()
        return [solve_pnp_unlabelled(detections(uv, s), pts3, planes, gauge, K, PNP_THRESHOLD * model.image_size)
                for uv, s, K in zip(pred, score.float().cpu().numpy(), Ks)], None
    return [solve_pnp(uv, pts3, K, threshold_px=PNP_THRESHOLD * model.image_size) for uv, K in zip(pred, Ks)], twin


def _keypoint_errors(model, loader, twins=(), device=None) -> tuple[list[float], int, int]:
    """Unscaled NEES of every validation sample (PnP in crop pixels), and the failure count."""
    raw, failures, n = [], 0, 0
    for batch in loader:
        results, _ = keypoint_pnp_batch(model, batch, device)
        for res, t, q in zip(results, batch["t"].numpy(), batch["q"].numpy()):
            n += 1
            if res is None:
                failures += 1
                continue
            gt = Pose.from_quat_t(q, t)
            cov = pnp_covariance(res.information, res.rms_px)
            # with twin-trained models the error is to the nearest twin (the twin check resolves it)
            raw.append(min(nees(res.pose.local(gt @ S), cov) for S in (Pose.identity(), *twins)))
    return raw, failures, n


def calibrate(model, loader, predict_batch, twins=(), device=None) -> dict:
    """Calibration record stored in the checkpoint (``checkpoint["calibration"]``).

    Args:
        model: the trained network (eval mode is set here).
        loader: validation batches (held out from training).
        predict_batch: ``(model, batch) → (t, q)`` for direct models.
        twins: poses the keypoint model was trained up to — its box twins, or a symmetric object's
            symmetries — (errors to the nearest of them: no measurement can say which it is).
        device: where ``model`` lives (default CPU); PnP and statistics run on the CPU.
    """
    model.eval()
    target = float(chi2.ppf(COVERAGE, 6))
    with torch.no_grad():
        if getattr(model, "kind", "direct") == "keypoints":
            raw, failures, n = _keypoint_errors(model, loader, twins, device)
            if not raw:
                raise ValueError("calibration: PnP failed on every validation sample; train longer")
            scale = float(np.quantile(raw, COVERAGE)) / target
            return {"kind": "pnp", "scale": max(scale, 1e-6), "sigma_floor_px": SIGMA_FLOOR_PX,
                    "coverage": COVERAGE, "samples": n, "failures": failures}
        xis = []
        for batch in loader:
            t, q = predict_batch(model, batch)
            for tp, qp, tt, qt in zip(t.float().cpu().numpy(), q.float().cpu().numpy(), batch["t"].numpy(), batch["q"].numpy()):
                xis.append(Pose.from_quat_t(qp, tp).local(Pose.from_quat_t(qt, tt)))
    xis = np.array(xis)
    cov = xis.T @ xis / len(xis) + 1e-12 * np.eye(6)
    raw = [nees(x, cov) for x in xis]
    scale = max(float(np.quantile(raw, COVERAGE)) / target, 1.0)
    return {"kind": "fixed", "covariance": (scale * cov).tolist(), "coverage": COVERAGE, "samples": len(xis), "failures": 0}
