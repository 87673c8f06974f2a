"""Rasters of a triangle mesh at a pose (no OpenGL context): "which face is seen at this pixel".

The trackers' facet-id image and the twin verifier's flat-shaded drawings both need it for a few
hundred triangles, often, on the CPU, inside loops where a GL context (MuJoCo) is not available or
too slow to switch. Two kinds: :func:`zbuffer_front_faces` (depth-tested at each pixel, ≈ 0.6 ms at
320×240 on test views; the trackers' facet ids) and the painter's far-to-near ``cv2.fillConvexPoly`` of
:func:`front_faces_far_first` + :func:`fill_triangles` (≈ 1.2 ms there; it can misorder long thin triangles,
and is kept for the twin verifier, whose network was trained on its drawings). OpenCV has the polygon
fill but no depth-ordered mesh raster.
"""
from __future__ import annotations

import math

import cv2
import numba
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


@numba.njit(cache=True, nogil=True)
def zbuffer_front_faces(triangles, normals, values, R, t, K, scale, height, width):
    """Depth-tested raster of a mesh's front faces: (height, width) uint16 canvas with the ``values``
    (F,) of the triangle nearest the camera at each pixel centre (0 where none is).

    Why not :func:`fill_triangles` in far-first order: painting whole triangles by their farthest
    vertex misorders long thin ones (a truss's beams), so a farther beam's face could be painted over
    a nearer one; a per-pixel depth test cannot. Depth is interpolated as 1/z, linear in the image
    for a planar triangle, so the test is exact at each pixel centre.

    Args:
        triangles: (F, 3, 3) vertices, object frame, metres. normals: (F, 3) unit outward normals.
        values: (F,) integers (< 2¹⁶) to write. R (3, 3), t (3,): ``T_cam_obj``. K (3, 3) intrinsics
            of the full-resolution image; ``scale``: canvas resolution relative to it (pixel
            centres at integers at both). Triangles with a vertex nearer than ``MIN_DEPTH_M`` are skipped.
    """
    ids = np.zeros((height, width), np.uint16)
    inv_depth = np.zeros((height, width))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    P = np.empty((3, 3))
    uv = np.empty((3, 2))
    for f in range(triangles.shape[0]):
        ok = True
        for i in range(3):
            for r in range(3):
                P[i, r] = (R[r, 0] * triangles[f, i, 0] + R[r, 1] * triangles[f, i, 1]
                           + R[r, 2] * triangles[f, i, 2] + t[r])
            ok = ok and P[i, 2] > MIN_DEPTH_M
        if not ok:
            continue
        # front face: its normal points against the ray to its centre
        facing = 0.0
        for r in range(3):
            n_cam = R[r, 0] * normals[f, 0] + R[r, 1] * normals[f, 1] + R[r, 2] * normals[f, 2]
            facing += n_cam * (P[0, r] + P[1, r] + P[2, r])
        if facing >= 0:
            continue
        for i in range(3):
            uv[i, 0] = (fx * P[i, 0] / P[i, 2] + cx + 0.5) * scale - 0.5
            uv[i, 1] = (fy * P[i, 1] / P[i, 2] + cy + 0.5) * scale - 0.5
        area = (uv[1, 0] - uv[0, 0]) * (uv[2, 1] - uv[0, 1]) - (uv[2, 0] - uv[0, 0]) * (uv[1, 1] - uv[0, 1])
        if abs(area) < 1e-12:
            continue
        x0 = max(int(math.ceil(min(uv[0, 0], uv[1, 0], uv[2, 0]))), 0)
        x1 = min(int(math.floor(max(uv[0, 0], uv[1, 0], uv[2, 0]))), width - 1)
        y0 = max(int(math.ceil(min(uv[0, 1], uv[1, 1], uv[2, 1]))), 0)
        y1 = min(int(math.floor(max(uv[0, 1], uv[1, 1], uv[2, 1]))), height - 1)
        w0z, w1z, w2z = 1.0 / P[0, 2], 1.0 / P[1, 2], 1.0 / P[2, 2]
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                # barycentric weights of the pixel centre (edge functions over twice the area)
                b0 = ((uv[1, 0] - x) * (uv[2, 1] - y) - (uv[2, 0] - x) * (uv[1, 1] - y)) / area
                b1 = ((uv[2, 0] - x) * (uv[0, 1] - y) - (uv[0, 0] - x) * (uv[2, 1] - y)) / area
                b2 = 1.0 - b0 - b1
                if b0 < 0 or b1 < 0 or b2 < 0:
                    continue
                iz = b0 * w0z + b1 * w1z + b2 * w2z
                if iz > inv_depth[y, x]:
                    inv_depth[y, x] = iz
                    ids[y, x] = values[f]
    return ids
