"""How far the model's visible edges at a pose lie from the image's edges: the check of a track on
real video, where no true pose exists (what ViSP's and OpenCV's tracker demos are judged by)."""
from __future__ import annotations

import cv2
import numpy as np

from ..core import Frame
from ..geometry import Pose
from .fit import CANNY_HIGH, CANNY_LOW, to_gray
from .model_view import ModelView


def edge_distances_px(view: ModelView, frame: Frame, pose: Pose, gray: np.ndarray | None = None) -> np.ndarray:
    """(S,) float32 pixels: for each visible model-edge sample at ``pose`` (T_cam_obj, metres) inside
    ``frame``, the distance to the nearest image edge (Canny with the edge fit's thresholds on the
    grey image; ``gray``: that image where the caller has it). Empty where no sample is visible or
    the image has no edge. A right pose puts most samples within a pixel or two of an edge; texture
    and clutter can put a wrong one near edges too, so this measures fit, not truth."""
    gray = to_gray(frame.image) if gray is None else gray
    edges = cv2.Canny(np.clip(gray, 0, 255).astype(np.uint8), CANNY_LOW, CANNY_HIGH)
    if not edges.any():
        return np.zeros(0, np.float32)
    distance = cv2.distanceTransform((edges == 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    idx = view.visible_index(pose, frame.camera, margin_px=1)
    if len(idx) == 0:
        return np.zeros(0, np.float32)
    uv = view.samples_at(pose, frame.camera, idx).uv.astype(np.float32)
    h, w = distance.shape
    uv = uv[(uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)]
    if len(uv) == 0:
        return np.zeros(0, np.float32)
    # bilinear between pixel centres: a sample half a pixel off an edge pixel reads ≈ 0.5, not 0 or 1
    return cv2.remap(distance, uv[:, 0].reshape(1, -1), uv[:, 1].reshape(1, -1), cv2.INTER_LINEAR)[0]
