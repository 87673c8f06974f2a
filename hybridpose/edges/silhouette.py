"""How much of the lit image around the object its projected silhouette explains: a dense cue beside
the sparse edges, for a tracker's quality.

On a dark background (space, or the shadowed side of a scene) every lit pixel near the object must
be the object. At a wrong pose that the edges still fit (parallel beams, a face slid along its own
edge), slivers of the real, lit object stick out of the projected silhouette. OpenCV has the pieces
(morphology, masks) but no such measure; the silhouette comes from the facet-id raster that the
edge visibility already uses.
"""
from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from ..core import Frame
from ..geometry import Pose
from .image import to_gray
from .model_view import ID_SCALE, ModelView

LIT_PIXEL_GREY = 12.0  # a pixel brighter than this grey level is lit (black space renders at 0–3)
# where at least this share of a frame's pixels is dark (grey ≤ LIT_PIXEL_GREY), the scene is black space.
# Measured (first and later frames): rendered space scenes 0.73–0.97 before the arm comes in (0.15 with it
# across the view); ViSP's real videos (cube, castle, MegaPose cube, detection cube, lego square) ≤ 0.02;
# the hand-held suite's photo scenes ≤ 0.04, a deep-sky photo behind the part 0.66
SPACE_DARK_SHARE = 0.5
SLACK_PX = 2  # lit pixels this close to the projected silhouette count as explained (frame pixels)
SLACK_SHARE = 0.005  # ... or this share of the silhouette's diagonal (frame pixels), where more
BAND_PX = 10  # lit pixels this close to it must be explained (frame pixels)
RING_PX = 12  # the ring beyond the band whose lit share tells a dark background from a lit one
DARK_RING_SHARE = 0.1  # a ring more lit than this is a lit background or an occluder: no verdict
MIN_SILHOUETTE_PX = 20  # silhouettes smaller than this (at the raster's scale) give no verdict
# an occluder in front of an object seen on dark space (the arm): the lit pixels off the object's
# projected silhouette that an opening OCCLUDER_WIDTH_SHARE of the object's diagonal wide leaves (the
# arm's body stays; a beam of the truss that a wrong pose leaves out does not), grown by
# OCCLUDER_EDGE_PX (frame pixels) to take in its outline
OCCLUDER_WIDTH_SHARE = 0.12
OCCLUDER_EDGE_PX = 3  # an occluder's outline drawn this wide (its blur and the pose's error)


def occluder_mask(lit: np.ndarray, off: np.ndarray, diagonal_px: float, edge_px: float = OCCLUDER_EDGE_PX) -> np.ndarray:
    """(h, w) bool: the pixels a broad lit occluder covers. ``lit``: (h, w) bool, the lit pixels;
    ``off``: (h, w) bool, the pixels off the object's projected silhouette (grown by its slack);
    ``diagonal_px``: the object's projected size, in the same pixels; ``edge_px``: how far the
    occluder is grown, in the same pixels (0: not at all).

    An opening by a disc, made of two distance transforms: OpenCV's morphology with a kernel this wide
    costs tens of milliseconds, the transforms under one whatever the width."""
    radius = max(1.0, 0.5 * OCCLUDER_WIDTH_SHARE * diagonal_px)
    inner = cv2.distanceTransform((lit & off).astype(np.uint8), cv2.DIST_L2, 3) > radius
    if not inner.any():
        return np.zeros(lit.shape, bool)
    return cv2.distanceTransform((~inner).astype(np.uint8), cv2.DIST_L2, 3) <= radius + max(0.0, edge_px)


class LitVerdict(NamedTuple):
    """:func:`lit_verdict`'s answer: ``share`` of the lit pixels near the silhouette it explains (NaN:
    no verdict) and whether something lit stands ``beside`` the object (its ring is lit)."""

    share: float
    beside: bool


def explained_lit_share(view: ModelView, frame: Frame, pose: Pose, gray: np.ndarray | None = None,
                        ids: np.ndarray | None = None) -> float:
    """Share (0..1) of the lit pixels within ``BAND_PX`` beyond the slack of the object's projected
    silhouette at ``pose`` that lie within the slack (``SLACK_PX``, or ``SLACK_SHARE`` of the
    silhouette's diagonal where more); NaN where there is no verdict: no lit pixel near
    it, a silhouette under ``MIN_SILHOUETTE_PX``, or a lit ring around the band (the Earth, a
    photo, the arm beside the object).

    Args:
        view: the object's :class:`ModelView`. frame: the image and its camera. pose: T_cam_obj.
        gray: (H, W) float32 grey image of ``frame`` (made here when None). ids: the view's
            :meth:`~ModelView.facet_ids` of ``pose`` (rendered here when None).
    """
    return lit_verdict(view, frame, pose, gray, ids).share


def lit_verdict(view: ModelView, frame: Frame, pose: Pose, gray: np.ndarray | None = None,
                ids: np.ndarray | None = None, dark_surround: bool = False) -> LitVerdict:
    """:func:`explained_lit_share` (same arguments), with whether the ring beyond the band is lit
    (more than ``DARK_RING_SHARE`` of it): something lit beside the object's silhouette — on black
    space, an occluder such as the arm; on a photo or the Earth, the background itself.

    ``dark_surround``: the caller saw the object on dark space before (a tracker's earlier fits), so
    a broad lit thing that reaches the band is an occluder coming in (:func:`occluder_mask`): no
    verdict and ``beside``, as once it reaches the ring — not a wrong pose's unexplained pixels."""
    cam = frame.camera
    ids = view.facet_ids(pose, cam) if ids is None else ids  # at ID_SCALE of the frame
    mask = (ids > 0).astype(np.uint8)
    if int(mask.sum()) < MIN_SILHOUETTE_PX:
        return LitVerdict(float("nan"), False)
    x, y, w, h = cv2.boundingRect(mask)
    # a pose a degree off moves the silhouette's far end by more pixels the larger it appears
    slack = max(SLACK_PX, SLACK_SHARE * float(np.hypot(w, h)) / ID_SCALE)
    reach = int(np.ceil((BAND_PX + RING_PX + slack) * ID_SCALE))
    H, W = mask.shape
    x0, y0, x1, y1 = max(x - reach, 0), max(y - reach, 0), min(x + w + reach, W), min(y + h + reach, H)
    mask = mask[y0:y1, x0:x1]
    full = to_gray(frame.image) if gray is None else gray
    s = 1.0 / ID_SCALE
    box = full[int(y0 * s):int(np.ceil(y1 * s)), int(x0 * s):int(np.ceil(x1 * s))]
    lit = cv2.resize(np.asarray(box, np.float32), (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA) > LIT_PIXEL_GREY

    def grown(px: float) -> np.ndarray:
        k = 2 * max(1, int(round(px * ID_SCALE))) + 1
        return cv2.dilate(mask, np.ones((k, k), np.uint8)) > 0

    explained, band, outer = grown(slack), grown(BAND_PX + slack), grown(BAND_PX + slack + RING_PX)
    ring = outer & ~band
    if ring.any() and float(lit[ring].mean()) > DARK_RING_SHARE:
        return LitVerdict(float("nan"), True)
    if dark_surround:
        stray = lit & band & ~explained  # mostly none at a right pose: the opening then need not run
        if stray.any() and (occluder_mask(lit, ~explained, float(np.hypot(w, h)), 0) & stray).any():
            # the arm coming in: not in the ring yet, but it is no part of the object either
            return LitVerdict(float("nan"), True)
    n = int((lit & band).sum())
    if n == 0:
        return LitVerdict(float("nan"), False)
    return LitVerdict(float((lit & explained).sum()) / n, False)


def dark_share(gray: np.ndarray) -> float:
    """Share (0..1) of the (H, W) uint8 grey image's pixels that are dark (grey ≤ ``LIT_PIXEL_GREY``);
    ``SPACE_DARK_SHARE`` or more: black space, where only the part and what sits near it are lit."""
    return float((gray <= LIT_PIXEL_GREY).mean())
