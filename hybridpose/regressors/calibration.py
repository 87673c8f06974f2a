"""Covariance calibration from held-out errors, so the fusion layer gets honest uncertainties.

The fusion layer gates and weighs every measurement by its covariance; an over-confident regressor
would make it reject good tracker poses or jump to bad CNN ones. After training, the errors on the
validation split fix one scale per checkpoint:

* keypoint models: ``Σ = s · σ² · (JᵀJ)⁻¹`` from PnP (J: reprojection Jacobian w.r.t. the right
  perturbation ``[ω, v]``, σ: the inliers' RMS reprojection error, floored);
* direct models: ``Σ = s · E[ξ ξᵀ]``, the second moment of the validation errors ``ξ``.

``s`` is chosen so that ``COVERAGE`` of the validation errors fall inside the χ²₆ ellipsoid of
the same probability (not the mean NEES: a few gross failures would inflate every covariance).

One scale is over-confident where the measurement is poor and under-confident where it is good
(the shipped default, under light from within 120° of the optical axis: 32 % of the errors inside
the 90 % ellipsoid at quality < 0.1, 97 % at quality ≥ 0.5). ``hybridpose calibrate`` therefore
also fits a factor per band of measurement quality, which the regressor applies on top of ``s``
(:func:`quality_factor`). This module holds what a regressor applies at predict time; fitting the
scale and the bands is :mod:`hybridpose.training.calibrate`'s.
"""
from __future__ import annotations

import numpy as np


COVERAGE = 0.9
# quality bands of the covariance factor (lower edges): the quality the regressor reports (PnP inlier
# share × reprojection term × twin belief) is mostly 0.2–0.6, and its errors spread ten times wider
# below 0.3 than above 0.4. Bands up to 0.9 were tried for fitted parts (whose quality is mostly
# 0.5–0.95) and not adopted (docs/decisions.md)
QUALITY_EDGES = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
MIN_BAND_POSES = 50  # a band with fewer poses is merged into the next one up
SIGMA_FLOOR_PX = 0.5  # a keypoint's spread is never taken below half a pixel (heatmap cells are 4 px)
PNP_THRESHOLD = 0.03  # RANSAC inlier threshold, fraction of the crop side


def pnp_covariance(information: np.ndarray, rms_px: float, scale: float = 1.0,
                   sigma_floor_px: float = SIGMA_FLOOR_PX) -> np.ndarray:
    """(6, 6) ``s · σ² · inv(JᵀJ)`` with ``σ = max(rms_px, sigma_floor_px)`` (pseudo-inverse if singular)."""
    sigma2 = max(float(rms_px), sigma_floor_px) ** 2
    cov = scale * sigma2 * np.linalg.pinv(information)
    return 0.5 * (cov + cov.T)


def quality_factor(record: dict | None, quality: float) -> float:
    """The covariance factor for a measurement of ``quality`` under a calibration ``record``'s
    ``quality_scale`` (:func:`quality_scale`); 1 without one."""
    bands = (record or {}).get("quality_scale")
    if not bands:
        return 1.0
    k = int(np.searchsorted(np.asarray(bands["edges"], dtype=float), quality, side="right")) - 1
    return float(bands["factors"][max(k, 0)])


def nees(xi: np.ndarray, cov: np.ndarray) -> float:
    """Normalised estimation error squared ``ξᵀ Σ⁻¹ ξ``."""
    return float(xi @ np.linalg.pinv(cov) @ xi)


UNCALIBRATED_SCALE = 100.0  # covariance inflation for a checkpoint without calibration


def uncalibrated_record(kind: str) -> dict:
    """The calibration a checkpoint without one is used with (and :func:`~hybridpose.regressors.
    evaluate.calibrate_checkpoint` starts from): PnP covariances inflated ``UNCALIBRATED_SCALE``×
    for keypoint models, a fixed diagonal of variances 0.01 rad² / m² × ``UNCALIBRATED_SCALE`` for direct ones."""
    if kind == "keypoints":
        return {"kind": "pnp", "scale": UNCALIBRATED_SCALE, "sigma_floor_px": SIGMA_FLOOR_PX}
    return {"kind": "fixed", "covariance": (UNCALIBRATED_SCALE * np.diag([0.01] * 6)).tolist()}
