"""Points on the model's surface in an image: corners lifted onto the CAD model and followed with
pyramidal KLT — what the KLT + PnP tracker and the combined tracker's texture cue both track."""
from __future__ import annotations

import cv2
import numpy as np

from ..edges import ModelView
from ..geometry import Camera, Pose

# how far past its points (and their guesses) KLT may look, beyond its window's reach at the top level, px:
# the texture cue's and klt-pnp's motion per frame after their motion prediction stays well inside it
FLOW_MARGIN_PX = 48


def surface_corners(view: ModelView, gray: np.ndarray, pose: Pose, camera: Camera, ids: np.ndarray, count: int,
                    existing: np.ndarray | None = None, box_margin_px: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``count`` corners (``cv2.goodFeaturesToTrack``) of the (H, W) uint8 ``gray`` image inside the
    part's projected faces at ``pose`` (``ids``: their full-resolution facet-id raster, eroded 3 px so
    that no corner sits on the silhouette), at least 7 px from the ``existing`` (M, 2) px points, lifted
    onto the model; those that are no fixed point of its surface (:meth:`ModelView.surface_fixed`) are
    dropped. The search covers the faces' box grown by ``box_margin_px``. Returns (uv (N, 2) float32 px,
    points (N, 3) m, object frame)."""
    empty = np.zeros((0, 2), np.float32), np.zeros((0, 3))
    # everything within the faces' box (OpenCV's bounding rectangle: a full-frame np.nonzero cost ~1 ms)
    bx, by, bw, bh = cv2.boundingRect((ids > 0).astype(np.uint8))
    if count <= 0 or bw == 0:
        return empty
    H, W = gray.shape[:2]
    pad = 4 + box_margin_px  # the erosion's reach and the margin: the crop's edges hold the same zeros
    cx0, cy0, cx1, cy1 = max(bx - pad, 0), max(by - pad, 0), min(bx + bw + pad, W), min(by + bh + pad, H)
    mask = cv2.erode((ids[cy0:cy1, cx0:cx1] > 0).astype(np.uint8) * 255, np.ones((7, 7), np.uint8))
    for x, y in (() if existing is None else existing.astype(int)):
        cv2.circle(mask, (int(x) - cx0, int(y) - cy0), 7, 0, -1)
    mx, my, mw, mh = cv2.boundingRect(mask)
    if mw == 0:
        return empty
    # detect inside the object's box only: goodFeaturesToTrack scores every pixel it is given
    x0, y0 = max(cx0 + mx - box_margin_px, 0), max(cy0 + my - box_margin_px, 0)
    x1, y1 = min(cx0 + mx + mw + box_margin_px, W), min(cy0 + my + mh + box_margin_px, H)
    full = np.zeros((y1 - y0, x1 - x0), np.uint8)
    sy0, sx0 = max(y0, cy0), max(x0, cx0)
    sy1, sx1 = min(y1, cy1), min(x1, cx1)
    full[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = mask[sy0 - cy0:sy1 - cy0, sx0 - cx0:sx1 - cx0]
    pts = cv2.goodFeaturesToTrack(np.ascontiguousarray(gray[y0:y1, x0:x1]), maxCorners=count, qualityLevel=0.01,
                                  minDistance=7, mask=full, blockSize=5)
    if pts is None:
        return empty
    uv = pts.reshape(-1, 2) + (x0, y0)
    X, ok = view.lift(pose, camera, uv, ids=ids)
    ok &= view.surface_fixed(pose, camera, uv, ids)
    return uv[ok].astype(np.float32), X[ok]


def flow(previous: np.ndarray, current: np.ndarray, points: np.ndarray, guess: np.ndarray,
         lk: dict, around: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.calcOpticalFlowPyrLK`` of ``points`` (N, 2) px from the uint8 image ``previous`` to
    ``current``, started at ``guess`` (N, 2), on the crop of both images that holds the points, their
    guesses and the reach of the search (``lk``: its keywords).

    Why a crop: the call builds both images' pyramids and derivatives whole (its Python binding takes no
    prebuilt pyramid), ≈ 0.4 ms of a full 640 × 480 frame each call, where the part covers a fraction of
    it. The crop's corner is a multiple of 2^(levels + 1) px, so each pyramid level samples the same pixels
    as the whole frame's: tracks agree with the full-frame call to 1e-3 px. ``around`` (M, 2) px: more
    points the crop holds (the same crop for several calls gives the same tracks). Returns (uv (N, 2)
    float32 in ``current``, found (N,) bool)."""
    prev = np.asarray(points, np.float32).reshape(-1, 2)
    start = np.asarray(guess, np.float32).reshape(-1, 2)
    if len(prev) == 0:
        return start.copy(), np.zeros(0, bool)
    levels = int(lk.get("maxLevel", 3))
    step = 2 ** (levels + 1)
    margin = FLOW_MARGIN_PX + (int(lk.get("winSize", (21, 21))[0]) // 2 + 1) * 2 ** levels
    both = np.vstack([prev, start] + ([] if around is None else [np.asarray(around, np.float32).reshape(-1, 2)]))
    h, w = previous.shape[:2]
    x0, y0 = (np.maximum(np.floor(both.min(0)).astype(int) - margin, 0) // step) * step
    x1, y1 = np.minimum(np.ceil(both.max(0)).astype(int) + margin + 1, (w, h))
    if x1 <= x0 or y1 <= y0:  # every point far outside the image
        return start.copy(), np.zeros(len(prev), bool)
    offset = np.array([x0, y0], np.float32)
    nxt, st, _ = cv2.calcOpticalFlowPyrLK(previous[y0:y1, x0:x1], current[y0:y1, x0:x1],
                                          (prev - offset).reshape(-1, 1, 2), (start - offset).reshape(-1, 1, 2),
                                          flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    return nxt.reshape(-1, 2) + offset, st.ravel() == 1


def forward_backward_flow(previous: np.ndarray, current: np.ndarray, points: np.ndarray, guess: np.ndarray,
                          lk: dict, fb_px: float, back_lk: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pyramidal KLT (:func:`flow`) of ``points`` (N, 2) px from the uint8 image ``previous`` to ``current``,
    started at ``guess`` (N, 2), then back (``back_lk``, default ``lk``: ``cv2.calcOpticalFlowPyrLK``
    keywords). Returns (uv (N, 2) float32 in ``current``, good (N,) bool: both passes found the point and
    the round trip lands within ``fb_px`` of where it began)."""
    prev = np.asarray(points, np.float32).reshape(-1, 2)
    nxt, found = flow(previous, current, prev, guess, lk)
    good = np.zeros(len(prev), bool)
    idx = np.flatnonzero(found)  # back only what was found (each point's search is its own)
    back, found_back = flow(current, previous, nxt[idx], prev[idx], lk if back_lk is None else back_lk,
                            around=np.vstack([nxt, prev]))
    good[idx] = found_back & (np.linalg.norm(back - prev[idx], axis=1) < fb_px)
    return nxt, good
