"""Points on the model's surface in an image: corners lifted onto the CAD model and followed with
pyramidal KLT — what the KLT + PnP tracker and the combined tracker's texture cue both track."""
from __future__ import annotations

import cv2
import numpy as np

from ..edges import ModelView
from ..geometry import Camera, Pose


def surface_corners(view: ModelView, gray: np.ndarray, pose: Pose, camera: Camera, ids: np.ndarray, count: int,
                    existing: np.ndarray | None = None, box_margin_px: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``count`` corners (``cv2.goodFeaturesToTrack``) of the (H, W) uint8 ``gray`` image inside the
    part's projected faces at ``pose`` (``ids``: their full-resolution facet-id raster, eroded 3 px so
    that no corner sits on the silhouette), at least 7 px from the ``existing`` (M, 2) px points, lifted
    onto the model; those that are no fixed point of its surface (:meth:`ModelView.surface_fixed`) are
    dropped. The search covers the faces' box grown by ``box_margin_px``. Returns (uv (N, 2) float32 px,
    points (N, 3) m, object frame)."""
    mask = cv2.erode((ids > 0).astype(np.uint8) * 255, np.ones((7, 7), np.uint8))
    for x, y in (() if existing is None else existing.astype(int)):
        cv2.circle(mask, (int(x), int(y)), 7, 0, -1)
    if count <= 0 or not mask.any():
        return np.zeros((0, 2), np.float32), np.zeros((0, 3))
    # detect inside the object's box only: goodFeaturesToTrack scores every pixel it is given
    ys, xs = np.nonzero(mask)
    x0, y0 = max(xs.min() - box_margin_px, 0), max(ys.min() - box_margin_px, 0)
    x1, y1 = min(xs.max() + 1 + box_margin_px, gray.shape[1]), min(ys.max() + 1 + box_margin_px, gray.shape[0])
    pts = cv2.goodFeaturesToTrack(np.ascontiguousarray(gray[y0:y1, x0:x1]), maxCorners=count, qualityLevel=0.01,
                                  minDistance=7, mask=np.ascontiguousarray(mask[y0:y1, x0:x1]), blockSize=5)
    if pts is None:
        return np.zeros((0, 2), np.float32), np.zeros((0, 3))
    uv = pts.reshape(-1, 2) + (x0, y0)
    X, ok = view.lift(pose, camera, uv, ids=ids)
    ok &= view.surface_fixed(pose, camera, uv, ids)
    return uv[ok].astype(np.float32), X[ok]


def forward_backward_flow(previous: np.ndarray, current: np.ndarray, points: np.ndarray, guess: np.ndarray,
                          lk: dict, fb_px: float, back_lk: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pyramidal KLT of ``points`` (N, 2) px from the uint8 image ``previous`` to ``current``, started at
    ``guess`` (N, 2), then back (``back_lk``, default ``lk``: ``cv2.calcOpticalFlowPyrLK`` keywords).
    Returns (uv (N, 2) float32 in ``current``, good (N,) bool: both passes found the point and the round
    trip lands within ``fb_px`` of where it began)."""
    prev = np.asarray(points, np.float32).reshape(-1, 1, 2)
    start = np.asarray(guess, np.float32).reshape(-1, 1, 2).copy()
    nxt, st, _ = cv2.calcOpticalFlowPyrLK(previous, current, prev, start, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(current, previous, nxt, prev.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
                                            **(lk if back_lk is None else back_lk))
    good = (st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm((back - prev).reshape(-1, 2), axis=1) < fb_px)
    return nxt.reshape(-1, 2), good
