"""Painter's-algorithm raster of a triangle mesh at a pose (no OpenGL context).

The trackers' facet-id image and the twin verifier's flat-shaded drawings both need "which face is
seen at this pixel" for a few hundred triangles, often, on the CPU, inside loops where a GL
context (MuJoCo) is not available or too slow to switch: far-to-near ``cv2.fillConvexPoly`` of the
front faces does it in ≈ 1 ms. OpenCV has the polygon fill but no depth-ordered mesh raster.
"""
from __future__ import annotations

import cv2
import numpy as np

from .pose import Pose

MIN_DEPTH_M = 1e-3  # triangles with a vertex closer to (or behind) the camera plane are not drawn
SUBPIXEL_BITS = 4


def front_faces_far_first(triangles: np.ndarray, normals: np.ndarray, pose: Pose):
    """The triangles a camera sees the front of, in painting order.

    Args:
        triangles: (F, 3, 3) vertices in the object frame, metres. normals: (F, 3) unit outward
            face normals, object frame. pose: T_cam_obj.
    Returns:
        (tri_cam (F, 3, 3) vertices in the camera frame, facing (F,) cosine between each face's
        normal and the direction to the camera (> 0: front), order (M,) indices of the front faces
        wholly in front of the camera, farthest first).
    """
    tri_cam = triangles @ pose.R.T + pose.t
    centres = tri_cam.mean(1)
    facing = -np.einsum("ij,ij->i", normals @ pose.R.T, centres) / np.linalg.norm(centres, axis=1)
    order = np.flatnonzero((facing > 0) & np.all(tri_cam[:, :, 2] > MIN_DEPTH_M, axis=1))
    return tri_cam, facing, order[np.argsort(-tri_cam[order, :, 2].max(1))]


def fill_triangles(canvas: np.ndarray, uv: np.ndarray, values) -> np.ndarray:
    """Fill triangles ``uv`` (M, 3, 2) canvas pixels (centres at integers) with ``values`` (M,), in
    order (later ones paint over earlier ones), with 1/16 px vertex precision; returns ``canvas``."""
    pts = np.round(np.asarray(uv) * (1 << SUBPIXEL_BITS)).astype(np.int32)
    for poly, value in zip(pts, values):
        cv2.fillConvexPoly(canvas, poly, int(value), lineType=cv2.LINE_8, shift=SUBPIXEL_BITS)
    return canvas
