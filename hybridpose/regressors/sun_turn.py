"""The sun turn of a keypoint regressor's crop: where the caller knows the sun, the crop is turned
in-plane so that the light crosses it as it crossed the network's training images."""
from __future__ import annotations

import numpy as np

from ..objects import light_azimuth_deg

# Sun turn: a network trained with the sun on one side of its images (the shipped default: within 40°
# of (0.6, 0.4, 0.7), light from the upper left) errs three times as often when the light crosses the
# image from elsewhere. Where the caller knows the sun (sun sensor, or ephemeris and attitude), the
# crop is turned in-plane so that the light crosses it as in training, when the light's image azimuth
# is more than SUN_TURN_BEYOND_DEG from the training sun's (nearer, the training data had such light
# and a turn only resamples the crop). Chosen among full / beyond 45° / beyond 60° / the excess beyond
# 30–60° on 800 tuning views (docs/decisions.md).
SUN_TURN_BEYOND_DEG = 60.0


def trained_light_azimuth_deg(lighting: dict | None) -> float | None:
    """The image azimuth (°, :func:`~hybridpose.objects.light_azimuth_deg`) of a training set's sun
    (``{"sun_direction_cam", "sun_cone_deg"}`` as :func:`~hybridpose.training.train_data.dataset_info`
    records it), or None when the set had light from every side (its sun cone holds the optical axis)
    or no record."""
    if not lighting or lighting.get("sun_direction_cam") is None:
        return None
    d = np.asarray(lighting["sun_direction_cam"], dtype=np.float64)
    d = d / np.linalg.norm(d)
    if np.degrees(np.arccos(np.clip(d[2], -1.0, 1.0))) <= float(lighting.get("sun_cone_deg", 0.0)):
        return None
    return light_azimuth_deg(d)


def sun_turn_deg(sun_direction_cam, trained_azimuth_deg: float | None, beyond_deg: float = SUN_TURN_BEYOND_DEG) -> float:
    """In-plane crop turn (°, OpenCV's sense: counter-clockwise on screen) that makes light travelling
    along ``sun_direction_cam`` cross the crop at ``trained_azimuth_deg``, when the two azimuths differ
    by more than ``beyond_deg`` (else 0, as without a sun or a training azimuth)."""
    if sun_direction_cam is None or trained_azimuth_deg is None:
        return 0.0
    # turning the crop by a (counter-clockwise) moves every direction in it, the light's too, by -a in
    # light_azimuth_deg's clockwise sense
    delta = (light_azimuth_deg(sun_direction_cam) - trained_azimuth_deg + 180.0) % 360.0 - 180.0
    return float(delta) if abs(delta) > beyond_deg else 0.0
