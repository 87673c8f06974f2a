"""Finding the object in a frame without a prior, and the crop around it.

On black space the object is what the sun lights: :func:`detect_bright_object` finds the sunlit
pixels (and the dim rest of an object a glint was found on), :func:`detect_dim_object` an object lit
too faintly for that. On an Earth or cluttered background pass the regressor a ``roi`` instead (the
hybrid passes the box of its predicted pose).
"""
from __future__ import annotations

import cv2
import numpy as np

from ..geometry.crops import crop_box

CROP_MARGIN = 1.2  # crop side / detected box side
DETECT_THRESHOLD = 12  # grey levels: a pixel this bright over black space is the object's
DETECT_DIM_THRESHOLD = 3  # grey levels, after smoothing: the dim rest of an object a glint was found on
DETECT_GROW_RATIO = 2.0   # …used only when it makes the box this much larger (diagonal)
DETECT_DIM_SIGMAS = 6.0   # …and only above this many σ of the smoothed sensor noise
SMOOTH_NOISE_GAIN = 0.26  # noise σ after the 5×5 Gaussian (σ = 1.1 px): 1 / (2 √π · 1.1)
# detect_dim_object: the dim parts kept (full-resolution pixels). A faint truss 1.2 m away covers
# thousands; the leftovers of lost views with nothing there covered ≤ 52 (test seeds 128–138)
DETECT_DIM_MIN_AREA_PX = 200


def detect_bright_object(image: np.ndarray, threshold: int = DETECT_THRESHOLD, min_area_px: int = 30,
                         grow: bool = True):
    """Box ``(x, y, w, h)`` around the sunlit object on a dark background, or None.

    Space imagery is a lit object on black: pixels brighter than ``threshold`` (grey levels),
    specks smaller than ``min_area_px`` removed (noise, stars). The box then grows over the dim
    pixels (smoothed, above ``DETECT_DIM_THRESHOLD``) connected to those bright ones: under grazing
    sun most of the object can sit just above black with only a glint over ``threshold``, and a
    box around the glint alone gave the network a fragment (a 14 × 20 px box on a truss 1 m away,
    PnP then put it at 13 m). Dim pixels not connected to a bright one are ignored, so sensor noise
    does not grow the box. Not for an Earth background — pass the ``roi`` there (the hybrid passes
    the tracker's predicted box). ``grow=False``: the bright pixels' box only (≈ 0.45 ms less on
    640 × 480).
    """
    # at half resolution (4× fewer pixels to label; a 1.2 m-away beam is still 3–4 px wide)
    gray = _half_gray(image)
    bright = (gray > threshold).astype(np.uint8)
    found = mask_components(bright)
    if found is None:
        return None
    labels, stats, (bx, by, bw, bh) = found
    keep = 1 + np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] * 4 >= min_area_px)
    if not len(keep):
        return None
    if not grow:
        return _union_box(stats[keep])
    is_kept = np.zeros(len(stats), bool)
    is_kept[keep] = True
    seeds = is_kept[labels]                                    # (bh, bw): the bright mask's box
    dim = _dim_mask(gray)
    dim[by:by + bh, bx:bx + bw] |= seeds
    dim_labels, dim_stats, (dx, dy, _, _) = mask_components(dim, include=(bx, by, bw, bh))
    seed_labels = dim_labels[by - dy:by - dy + bh, bx - dx:bx - dx + bw][seeds]
    box, grown = _union_box(stats[keep]), _union_box(dim_stats[np.unique(seed_labels)])
    # only a box that grows a lot is a fragment's: growing every box over its dim, shadowed
    # pixels gave crops the network had not learnt (docs/decisions.md)
    return grown if np.hypot(*grown[2:]) > DETECT_GROW_RATIO * np.hypot(*box[2:]) else box


def detect_dim_object(image: np.ndarray, min_area_px: int = DETECT_DIM_MIN_AREA_PX):
    """Box ``(x, y, w, h)`` around an object lit too faintly for :func:`detect_bright_object`, or None.

    Under grazing sun the whole truss can sit a few grey levels above black with no glint, or with
    glints too small to keep (≈ 1 view in 1000 of the 40°-cone test sets): the pixels of the
    smoothed image above the noise-aware dim threshold (:func:`_dim_mask`), parts smaller than
    ``min_area_px`` (full-resolution pixels) dropped. With sensor noise the threshold rises with it,
    so noise alone finds nothing. The predictor falls back to it only where the bright detection
    found nothing or its box gave no plausible pose.
    """
    found = mask_components(_dim_mask(_half_gray(image)))
    if found is None:
        return None
    _, stats, _ = found
    keep = 1 + np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] * 4 >= min_area_px)
    return _union_box(stats[keep]) if len(keep) else None


def detected_crop(image: np.ndarray) -> tuple[float, float, float] | None:
    """(cx, cy, side) px of the parallel model's "bounded image" around the object detected in ``image``
    (bright, else dim), cropped as it trained on the true box (× ``CROP_MARGIN``); None where nothing is
    detected. On the seed-100 views this crop lies within 3.4 % of its side of the true one in 90 % of
    them, its side 1.14–1.20 × the true extent ."""
    seen = detect_bright_object(image) or detect_dim_object(image)
    return None if seen is None else crop_box(seen, CROP_MARGIN)


def translation_crop(t: np.ndarray, K: np.ndarray, diameter_m: float) -> tuple[float, float, float]:
    """(cx, cy, side) px of the crop around the projection of the translation ``t`` (3,) m, sized by the
    object's diameter: the parallel model's fallback where nothing is detected (an Earth background, a
    dim object). It misses the true crop by tens of pixels and up to 2× in scale: a parallel VGG-19
    scored 41° mean on validation (true crops) and 90° on test views through it."""
    z = max(float(t[2]), 0.05)
    uv = K @ (np.asarray(t, dtype=np.float64) / z)
    return float(uv[0]), float(uv[1]), CROP_MARGIN * max(K[0, 0], K[1, 1]) * diameter_m / z


def _half_gray(image: np.ndarray) -> np.ndarray:
    """(H/2, W/2) uint8 grey of an (H, W, 3) uint8 RGB frame: what both detections label."""
    small = cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)


def _dim_mask(gray: np.ndarray) -> np.ndarray:
    """(H, W) uint8 mask of the pixels of a (half-resolution) grey image that are dimly lit: the
    5×5-smoothed image above ``DETECT_DIM_THRESHOLD`` and above the sensor noise, so that noise cannot
    chain dim pixels across the background."""
    smooth = cv2.GaussianBlur(gray, (5, 5), 0)
    # above the background (clipped noise lifts black by ≈ 0.4 σ; the median is the background while
    # the object covers less than half the frame, and above it a dim mask is pointless anyway)
    dim_threshold = max(DETECT_DIM_THRESHOLD,
                        float(np.median(smooth)) + DETECT_DIM_SIGMAS * SMOOTH_NOISE_GAIN * noise_sigma(gray))
    return (smooth > dim_threshold).astype(np.uint8)


def mask_components(mask: np.ndarray, include=None):
    """8-connected components of a uint8 ``mask``, labelled within the box around its non-zero
    pixels only (the same components; on a space image that box is a fifth of the frame on average,
    and labelling is most of the detection's cost), grown to hold the box ``include`` (x, y, w, h)
    if given: (labels (h, w) int32 of that box, stats as ``cv2.connectedComponentsWithStats`` in
    ``mask``'s coordinates (row 0: the box's background), box (x, y, w, h)), or None for an empty mask."""
    x, y, w, h = cv2.boundingRect(mask)
    if w == 0 or h == 0:
        return None
    if include is not None:
        x0, y0 = min(x, include[0]), min(y, include[1])
        x, y, w, h = x0, y0, max(x + w, include[0] + include[2]) - x0, max(y + h, include[1] + include[3]) - y0
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask[y:y + h, x:x + w], connectivity=8)
    stats[:, cv2.CC_STAT_LEFT] += x
    stats[:, cv2.CC_STAT_TOP] += y
    return labels, stats, (x, y, w, h)


def noise_sigma(gray: np.ndarray) -> float:
    """Standard deviation of an image's noise, grey levels (Immerkær 1996: a Laplacian-difference
    filter cancels smooth structure; the mean absolute response scales with σ). OpenCV has no
    noise estimator; this one is six lines and robust on mostly-black space images."""
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    response = cv2.filter2D(gray.astype(np.float32), -1, kernel)[1:-1, 1:-1]
    return float(np.sqrt(np.pi / 2) * np.abs(response).mean() / 6.0)


def _union_box(stats: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, w, h) at full resolution around half-resolution connected-component ``stats`` rows."""
    x0, y0 = stats[:, cv2.CC_STAT_LEFT].min(), stats[:, cv2.CC_STAT_TOP].min()
    x1 = (stats[:, cv2.CC_STAT_LEFT] + stats[:, cv2.CC_STAT_WIDTH]).max()
    y1 = (stats[:, cv2.CC_STAT_TOP] + stats[:, cv2.CC_STAT_HEIGHT]).max()
    return 2.0 * x0, 2.0 * y0, 2.0 * (x1 - x0), 2.0 * (y1 - y0)
