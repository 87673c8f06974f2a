"""Rasters of a triangle mesh at a pose (no OpenGL context): "which face is seen at this pixel".

The trackers' facet-id image and the twin verifier's flat-shaded drawings both need it for a few
hundred triangles, often, on the CPU, inside loops where a GL context (MuJoCo) is not available or
too slow to switch. Two kinds: :func:`zbuffer_front_faces` (depth-tested at each pixel, ≈ 0.16 ms
for the truss at 320×240 on test views; the trackers' facet ids) and the painter's far-to-near ``cv2.fillConvexPoly`` of
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
SUBPIXEL_BITS = 4  # 1/16-px vertex positions (cv2.fillConvexPoly's shift)


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


SPAN_MIN_SLOPE = 1e-3  # edges flatter than this (px of height) do not narrow a row's span


@numba.njit(cache=True, nogil=True, inline="always")
def _row_span(uv, area, y, x0, x1):
    """Pixel columns [xs, xe] of row ``y`` that may lie inside the triangle ``uv`` (3, 2): its box
    ``x0..x1`` narrowed by each edge's crossing of the row, one pixel wider than exact. The caller
    still tests every pixel, so the span only skips pixels that certainly fail: a truss beam's thin
    diagonal triangles fill a small part of their box."""
    lo, hi = float(x0), float(x1)
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        # barycentric weight of vertex i times the area: a + b·x along the row
        a = uv[j, 0] * (uv[k, 1] - y) - uv[k, 0] * (uv[j, 1] - y)
        b = uv[j, 1] - uv[k, 1]
        if area < 0:
            a, b = -a, -b
        if b > SPAN_MIN_SLOPE:
            lo = max(lo, -a / b)
        elif b < -SPAN_MIN_SLOPE:
            hi = min(hi, -a / b)
    return max(x0, int(math.ceil(lo)) - 1), min(x1, int(math.floor(hi)) + 1)


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
            xs, xe = _row_span(uv, area, y, x0, x1)
            for x in range(xs, xe + 1):
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
