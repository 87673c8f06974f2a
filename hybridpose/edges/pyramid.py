"""Coarse-to-fine edge fits over an image pyramid: a start for objects that fill the view.

Close up (the truss at 0.3–0.6 m overflows a 640×480 view), a CNN pose 5–10° off puts the model's
edges tens of pixels from the image's, beyond the moving-edge search; a wider search at full
resolution finds a neighbouring beam first (`docs/decisions.md`). On the frame shrunk 4× and 2×
the same search covers 4× and 2× the distance, and the beams' fine detail that misleads it is
blurred away. On objects of ordinary size the shrunk fits lose precision a good start already had,
so callers take this path only where the object appears large (:func:`projected_diagonal_px`)
and the direct fit failed — from a CNN pose, or from a prediction that coasted through an occlusion
with its distance 10–30 % off.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..core import Frame
from ..geometry import Camera, Pose
from .fit import fit_edges
from .model_view import ModelView

COARSE_LEVELS = (4, 2)        # shrink factors, coarse first
COARSE_SEARCH_PX = (16, 12)   # the search range at each level (pixels of that level)


def projected_diagonal_px(view: ModelView, pose: Pose, camera: Camera) -> float:
    """Diagonal (px) of the image box of the object's bounding-box corners at ``pose``; ``inf`` where a
    corner is not in front of the camera (an object that close overflows any view)."""
    box = camera.image_box(view.object.bbox_corners, pose)
    return float("inf") if box is None else float(np.hypot(box[2] - box[0], box[3] - box[1]))


def coarse_to_fine(view: ModelView, frame: Frame, start: Pose, levels=COARSE_LEVELS,
                   search_px=COARSE_SEARCH_PX) -> Pose:
    """``start`` refined by one edge fit (:func:`fit_edges`, three iterations, no polish) on
    ``frame`` shrunk by each factor of ``levels`` in turn (``cv2.INTER_AREA``; the camera resampled
    with it), searching ``search_px`` pixels of that level; a level whose fit fails leaves the pose
    as it was. The caller fits the result at full resolution."""
    if len(levels) != len(search_px):
        raise ValueError(f"search_px: expected one range per level ({len(levels)}), got {len(search_px)}")
    pose = start
    cam = frame.camera
    for factor, spx in zip(levels, search_px):
        size = (max(1, round(cam.width / factor)), max(1, round(cam.height / factor)))
        image = cv2.resize(frame.image, size, interpolation=cv2.INTER_AREA)
        small = Frame(image, cam.scaled(size), frame.timestamp, frame.index, frame.sun_direction_cam)
        fit = fit_edges(view, small, pose, search_px=int(spx), outer=3)
        if fit is not None:
            pose = fit.pose
    return pose
