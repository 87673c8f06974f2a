"""Compiled inner loops of the moving-edge fit (:func:`hybridpose.edges.fit_edges`).

Why our own kernels: the fit works on a few hundred samples at a time, where NumPy spends more time
dispatching its ~60 small array operations per iteration than computing (a line profile of the
shipped regressor's path: Gauss–Newton small-matrix work ≈ 30 % of a fit, projections and the
edge search's bookkeeping another 25 %). No library has the point-to-line moving-edge step
(``cv2.rapid`` solves point-to-point, see :mod:`hybridpose.edges.fit`), so the same math is
compiled here with numba, one loop over the samples per step (the point-to-line rows and the SE(3)
exponential are the geometry module's compiled ones). The image sampling stays in ``cv2.remap``; the
facet raster that decides visibility is :func:`hybridpose.geometry.raster.zbuffer_front_faces`.

Conventions as in :mod:`hybridpose.geometry`: ``T_cam_obj`` as ``(R (3, 3), t (3,) metres)``,
pixels with integer centres, right perturbation ``ξ = [ω, v]`` (``Pose.retract``).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from ..geometry.camera import line_rows
from ..geometry.se3 import se3_exp_one

TUKEY_C = 4.685  # Tukey's biweight constant: 95 % efficiency under Gaussian noise
MAD_TO_SIGMA = 1.4826  # median absolute deviation → standard deviation of a Gaussian


@numba.njit(cache=True, nogil=True)
def project_samples(points_m, directions, R, t, K, width, height, margin_px, drop_outside):
    """Samples ``points_m`` (S, 3) on model edges of unit ``directions`` (S, 3), object frame,
    projected at ``(R, t)``: (keep (S,) bool: in front and inside the image by ``margin_px`` — all
    True unless ``drop_outside``; uv (S, 2) px; unit image normals (S, 2) of the edges there)."""
    S = points_m.shape[0]
    keep = np.ones(S, np.bool_)
    uv = np.empty((S, 2))
    normals = np.empty((S, 2))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    for s in range(S):
        p0, p1, p2 = points_m[s, 0], points_m[s, 1], points_m[s, 2]
        x = R[0, 0] * p0 + R[0, 1] * p1 + R[0, 2] * p2 + t[0]
        y = R[1, 0] * p0 + R[1, 1] * p1 + R[1, 2] * p2 + t[1]
        z = R[2, 0] * p0 + R[2, 1] * p1 + R[2, 2] * p2 + t[2]
        zc = max(z, 1e-3)
        u = fx * x / zc + cx
        v = fy * y / zc + cy
        uv[s, 0], uv[s, 1] = u, v
        if drop_outside:
            keep[s] = (u >= margin_px) and (u <= width - 1 - margin_px) and (v >= margin_px) \
                and (v <= height - 1 - margin_px) and (z > 1e-3)
        q0, q1, q2 = directions[s, 0], directions[s, 1], directions[s, 2]
        d0 = R[0, 0] * q0 + R[0, 1] * q1 + R[0, 2] * q2
        d1 = R[1, 0] * q0 + R[1, 1] * q1 + R[1, 2] * q2
        d2 = R[2, 0] * q0 + R[2, 1] * q1 + R[2, 2] * q2
        # image direction of the edge: derivative of the projection along it (unclamped depth)
        du = fx * (d0 * z - x * d2) / (z * z)
        dv = fy * (d1 * z - y * d2) / (z * z)
        norm = max(math.sqrt(du * du + dv * dv), 1e-12)
        normals[s, 0], normals[s, 1] = -dv / norm, du / norm
    return keep, uv, normals


@numba.njit(cache=True, nogil=True)
def search_maps(uv, normals, search_px):
    """``cv2.remap`` maps (S, 2L+3) float32 of the search lines: ``uv + k · normal`` for
    ``k = −L−1 … L+1`` pixels, ``L = search_px``."""
    S = uv.shape[0]
    n = 2 * search_px + 3
    map_u = np.empty((S, n), np.float32)
    map_v = np.empty((S, n), np.float32)
    for s in range(S):
        for i in range(n):
            k = float(i - search_px - 1)
            map_u[s, i] = uv[s, 0] + k * normals[s, 0]
            map_v[s, i] = uv[s, 1] + k * normals[s, 1]
    return map_u, map_v


@numba.njit(cache=True, nogil=True)
def draw_segments(mask, a, b, x0, y0):
    """Set to 255 the pixels of the (h, w) uint8 ``mask`` that the segments from ``a`` (S, 2) to ``b``
    (S, 2) image px pass through; ``mask``'s top-left pixel is (``x0``, ``y0``) of the image. From
    the rounded ends, one pixel a step along the longer axis: the 8-connected line that
    ``cv2.polylines`` draws at thickness 1 (up to how a tie between two pixels is broken), which spends
    ~0.4 ms turning the hundreds of two-point polylines of a model into C++ vectors."""
    h, w = mask.shape
    for s in range(a.shape[0]):
        ax, ay = round(a[s, 0] - x0), round(a[s, 1] - y0)
        bx, by = round(b[s, 0] - x0), round(b[s, 1] - y0)
        steps = int(max(abs(bx - ax), abs(by - ay)))  # one pixel a step along the longer axis
        for i in range(steps + 1):
            f = i / max(steps, 1)
            x, y = int(round(ax + f * (bx - ax))), int(round(ay + f * (by - ay)))
            if 0 <= x < w and 0 <= y < h:
                mask[y, x] = 255


@numba.njit(cache=True, nogil=True)
def edge_clearance(uv, normals, tangents_px, edge_ids, width, height, max_px):
    """Pixels (S,) float32 along each sample's normal to the nearest *other* projected model edge
    (``max_px + 1`` where none lies within ``max_px``): the samples (``uv`` (S, 2) px, unit ``normals``
    (S, 2), ``tangents_px`` (S, 2): half the sample's stretch along its edge, px) are drawn as
    segments labelled by their ``edge_ids`` (S,) into a raster of the image (``width`` × ``height``)
    around them, then each normal is walked out to ``max_px`` both ways. Crossings within 1.5 px are
    the sample's own edge or its collinear neighbour and are not counted."""
    S = uv.shape[0]
    out = np.empty(S, np.float32)
    if S == 0:
        return out
    # the raster covers the samples' box grown by the walk, clipped to the image
    pad = max_px + 2.0 + np.max(np.abs(tangents_px))
    x0 = max(int(np.floor(np.min(uv[:, 0]) - pad)), 0)
    y0 = max(int(np.floor(np.min(uv[:, 1]) - pad)), 0)
    x1 = min(int(np.ceil(np.max(uv[:, 0]) + pad)) + 1, width)
    y1 = min(int(np.ceil(np.max(uv[:, 1]) + pad)) + 1, height)
    w, h = max(x1 - x0, 1), max(y1 - y0, 1)
    labels = np.zeros((h, w), np.int32)
    for s in range(S):
        ax, ay = uv[s, 0] - tangents_px[s, 0] - x0, uv[s, 1] - tangents_px[s, 1] - y0
        bx, by = uv[s, 0] + tangents_px[s, 0] - x0, uv[s, 1] + tangents_px[s, 1] - y0
        steps = int(2.0 * max(abs(bx - ax), abs(by - ay))) + 1
        for i in range(steps + 1):
            f = i / steps
            x, y = int(round(ax + f * (bx - ax))), int(round(ay + f * (by - ay)))
            if 0 <= x < w and 0 <= y < h:
                labels[y, x] = edge_ids[s] + 1
    for s in range(S):
        own = edge_ids[s] + 1
        best = np.float32(max_px + 1)
        for k2 in range(3, 2 * max_px + 1):        # half-pixel steps from 1.5 px out
            k = 0.5 * k2
            if k >= best:
                break
            for sign in (-1.0, 1.0):
                x = int(round(uv[s, 0] + sign * k * normals[s, 0])) - x0
                y = int(round(uv[s, 1] + sign * k * normals[s, 1])) - y0
                if 0 <= x < w and 0 <= y < h:
                    lab = labels[y, x]
                    if lab != 0 and lab != own:
                        best = np.float32(k)
                        break
        out[s] = best
    return out


@numba.njit(cache=True, nogil=True)
def strongest_steps(profiles, search_px, min_contrast, limits):
    """The strongest intensity step along each search line of ``profiles`` (S, 2L+3) float32 grey
    levels (from :func:`search_maps`): (offset (S,) px along the normal, sub-pixel; valid (S,): step ≥
    ``min_contrast`` grey levels per pixel; mean grey level (S,) of the line). A mild Gaussian
    preference for nearer steps breaks ties as RAPID's nearest-maximum rule would. ``limits`` (S,)
    float32: steps farther than this from the sample are not considered."""
    S, n = profiles.shape
    m = n - 2                                      # steps at k = −L … L
    sigma = np.float32(max(search_px, 1))
    prefer = np.empty(m, np.float32)
    for i in range(m):
        kk = np.float32(i - search_px) / sigma
        prefer[i] = np.float32(math.exp(-0.5 * kk * kk))
    offset = np.empty(S, np.float32)
    valid = np.empty(S, np.bool_)
    brightness = np.empty(S, np.float32)
    g = np.empty(m, np.float32)
    for s in range(S):
        best_j, best_score, total = 0, np.float32(-1.0), 0.0
        for i in range(m):
            g[i] = abs(profiles[s, i + 2] - profiles[s, i]) * np.float32(0.5)
            if abs(i - search_px) > limits[s]:
                continue
            score = g[i] * prefer[i]
            if score > best_score:
                best_j, best_score = i, score
        for i in range(n):
            total += profiles[s, i]
        brightness[s] = total / n
        b = g[best_j]
        sub = np.float32(0.0)
        flank = False
        if 0 < best_j < m - 1:
            a, c = g[best_j - 1], g[best_j + 1]
            den = a - np.float32(2.0) * b + c
            # a line stopped short may stop on the flank of a stronger step beyond its reach: no match
            flank = limits[s] < search_px and (a > b or c > b)
            if den < -1e-6 and not flank:
                sub = np.float32(0.5) * (a - c) / den
        offset[s] = np.float32(best_j - search_px) + sub
        valid[s] = b >= min_contrast and not flank
    return offset, valid, brightness


@numba.njit(cache=True, nogil=True)
def solve_spd6(H, g):
    """``H⁻¹ g`` for a symmetric positive definite (6, 6) ``H``, by Cholesky (no pivoting needed)."""
    L = np.zeros((6, 6))
    for i in range(6):
        for j in range(i + 1):
            acc = H[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                if acc <= 0.0:
                    return np.linalg.solve(H, g)  # not positive definite: LU as NumPy would
                L[i, i] = math.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
    y = np.empty(6)
    for i in range(6):
        acc = g[i]
        for k in range(i):
            acc -= L[i, k] * y[k]
        y[i] = acc / L[i, i]
    x = np.empty(6)
    for i in range(5, -1, -1):
        acc = y[i]
        for k in range(i + 1, 6):
            acc -= L[k, i] * x[k]
        x[i] = acc / L[i, i]
    return x


@numba.njit(cache=True, nogil=True)
def gauss_newton_lines(R, t, points_m, normals, targets, K, scale_cap_px, steps):
    """Up to ``steps`` Gauss–Newton steps of the point-to-line distances with Tukey weights (MAD
    scale, at least 0.5 px, capped at ``scale_cap_px``) from ``(R, t)``: model points ``points_m``
    (S, 3) metres, their image ``normals`` (S, 2) and matched edge points ``targets`` (S, 2) px.
    Returns ``(R, t, ok)``; ``ok`` False when the weights sum below 6 (too few samples agree).
    Stops early when a step moves less than 1e-6 (rad or m)."""
    S = points_m.shape[0]
    uv = np.empty((S, 2))
    J = np.empty((S, 6))
    r = np.empty(S)
    abs_r = np.empty(S)
    for _ in range(steps):
        line_rows(R, t, points_m, K, normals, uv, J)
        for s in range(S):
            r[s] = normals[s, 0] * (uv[s, 0] - targets[s, 0]) + normals[s, 1] * (uv[s, 1] - targets[s, 1])
            abs_r[s] = abs(r[s])
        scale = min(max(MAD_TO_SIGMA * np.median(abs_r), 0.5), scale_cap_px)
        H = np.zeros((6, 6))
        g = np.zeros(6)
        w_sum = 0.0
        for s in range(S):
            u_t = r[s] / (TUKEY_C * scale)
            if abs(u_t) >= 1.0:
                continue
            w = (1.0 - u_t * u_t) ** 2
            w_sum += w
            for i in range(6):
                wj = w * J[s, i]
                g[i] += wj * r[s]
                for k in range(i + 1):
                    H[i, k] += wj * J[s, k]
        if w_sum < 6:
            return R, t, False
        for i in range(6):
            H[i, i] += 1e-9
            for k in range(i):
                H[k, i] = H[i, k]
        delta = -solve_spd6(H, g)
        dR, dt = se3_exp_one(delta)
        t = R @ dt + t
        R = R @ dR
        if np.abs(delta).max() < 1e-6:
            break
    return R, t, True


@numba.njit(cache=True, nogil=True)
def facing_samples(points_m, normal_dot_point, face_normals, faces, R, t, K, width, height, margin_px):
    """The first part of the visibility test of edge samples at ``(R, t)``: those with an adjacent
    face turned to the camera, in front of it and inside the image by ``margin_px``.

    Args: ``points_m`` (P, 3) samples, object frame; ``normal_dot_point`` (P, 2) ``n · p`` of each
    sample's two faces; ``face_normals`` (F, 3); ``faces`` (P, 2) the two faces of each sample.
    Returns (index (S,) int64 of those samples, uv (S, 2) px, facing (S, 2) bool per face)."""
    P = points_m.shape[0]
    F = face_normals.shape[0]
    # a face looks at the camera where n_cam · X_cam < 0, i.e. n · (p + Rᵀt) < 0 in the object frame:
    # n · p is fixed per sample, so one dot per face is left to do per pose
    c0 = R[0, 0] * t[0] + R[1, 0] * t[1] + R[2, 0] * t[2]
    c1 = R[0, 1] * t[0] + R[1, 1] * t[1] + R[2, 1] * t[2]
    c2 = R[0, 2] * t[0] + R[1, 2] * t[1] + R[2, 2] * t[2]
    face_dot = np.empty(F)
    for f in range(F):
        face_dot[f] = face_normals[f, 0] * c0 + face_normals[f, 1] * c1 + face_normals[f, 2] * c2
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    index = np.empty(P, np.int64)
    uv = np.empty((P, 2))
    facing = np.empty((P, 2), np.bool_)
    S = 0
    for p in range(P):
        f0 = normal_dot_point[p, 0] + face_dot[faces[p, 0]] < 0
        f1 = normal_dot_point[p, 1] + face_dot[faces[p, 1]] < 0
        if not (f0 or f1):
            continue
        p0, p1, p2 = points_m[p, 0], points_m[p, 1], points_m[p, 2]
        z = R[2, 0] * p0 + R[2, 1] * p1 + R[2, 2] * p2 + t[2]
        if z <= 1e-3:
            continue
        u = fx * (R[0, 0] * p0 + R[0, 1] * p1 + R[0, 2] * p2 + t[0]) / z + cx
        v = fy * (R[1, 0] * p0 + R[1, 1] * p1 + R[1, 2] * p2 + t[1]) / z + cy
        if u < margin_px or u > width - 1 - margin_px or v < margin_px or v > height - 1 - margin_px:
            continue
        index[S], uv[S, 0], uv[S, 1], facing[S, 0], facing[S, 1] = p, u, v, f0, f1
        S += 1
    return index[:S], uv[:S], facing[:S]


@numba.njit(cache=True, nogil=True)
def shows_own_facet(ids, uv, own, scale):
    """(S,) bool: the facet-id image ``ids`` (h, w) at ``scale`` × the camera's resolution shows one
    of a sample's own facets ``own`` (S, 2) (0: that face is turned away) within the 3×3 pixels
    around its projection ``uv`` (S, 2) px (clipped at the border)."""
    h, w = ids.shape
    S = uv.shape[0]
    out = np.zeros(S, np.bool_)
    for s in range(S):
        cu = int(np.rint((uv[s, 0] + 0.5) * scale - 0.5))
        cv = int(np.rint((uv[s, 1] + 0.5) * scale - 0.5))
        for dv in range(-1, 2):
            row = min(max(cv + dv, 0), h - 1)
            for du in range(-1, 2):
                f = ids[row, min(max(cu + du, 0), w - 1)]
                if f == own[s, 0] or f == own[s, 1]:
                    out[s] = True
    return out


def solve_lines(R, t, points_m, normals, targets, K, scale_cap_px, steps):
    """:func:`gauss_newton_lines`, failed (``ok`` False) where its normal equations are singular:
    matches that fix no pose (a handful on one short edge, from a CNN start far off)."""
    try:
        return gauss_newton_lines(R, t, points_m, normals, targets, K, scale_cap_px, steps)
    except np.linalg.LinAlgError:
        return R, t, False
