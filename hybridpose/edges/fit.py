"""The moving-edge fit (RAPID / ViSP-style) of the model's visible sharp edges to an image: what the
edge trackers run every frame and the CNN regressor runs to refine its pose.

Each visible edge sample is searched for along its image normal (``±search_px``) for the strongest
intensity step; the pose then minimises the point-to-*line* distances (only the normal component
is measured: the aperture problem) by Gauss–Newton with Tukey weights, re-searching from the new
pose a few times. ``cv2.rapid`` cannot do this part itself: its line search assumes an ordered
silhouette contour and its pose step uses point-to-point distances.

Quality = inliers (within ``inlier_px`` after the last iteration) / (matched samples + samples
whose search line is lit but shows no edge) × min(1, inliers / 40), capped by how much of the
image's edges around the object the model explains (:func:`~hybridpose.edges.quality.honest_quality`: a fit that found an
edge for every model sample on the wrong beams still leaves the real ones unexplained) and, on a
dark background, how much of the lit pixels its silhouette covers. Samples on dark search lines
with no edge are left out: edges between a face in shadow and black space have almost no
contrast, and counting them made the quality swing 0.2–0.6 with the lighting on a clean tumble.
When the arm covers the truss, its tool plate is a lit surface without the model's edges, and
its rim a single line: the quality collapses.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from ..core import Frame, covariance_from_information
from ..geometry import Pose, line_jacobian
from . import kernels
from .image import to_gray
from .model_view import EdgeSamples, ModelView, thin
from .silhouette import LIT_PIXEL_GREY, occluder_mask

MIN_SUPPORT = 40  # inlier samples for full quality
LIT_GREY = 30.0  # mean grey level of a search line that is lit (not shadow on black space)


@dataclass(frozen=True, eq=False)
class EdgeSites:
    """What a fit saw, per model edge sample of its last search (the moving-edge sites ViSP draws).
    Made from the fit's own arrays; the pictures' values are worked out when first asked for (a fit
    that nobody draws costs nothing more).

    Properties:
        uv: (S, 2) float px, the samples projected at the fitted pose.
        matched: (S, 2) float px, the image edge found along each sample's normal (NaN: none).
        inlier: (S,) bool, matched and within the fit's inlier distance of the fitted edge.
        lit_no_edge: (S,) bool, no edge found on a lit search line (evidence against the pose: an
            occluder in front, or the pose wrong); no edge on a dark line says nothing.
    """

    points: np.ndarray          # (S, 3) m, the searched samples
    pose: Pose                  # the fitted pose
    K: np.ndarray               # (3, 3) px
    target: np.ndarray          # (S, 2) px, where each search ended (meaningful where valid)
    valid: np.ndarray           # (S,) bool, the search found an edge
    inlier_of_valid: np.ndarray  # (valid.sum(),) bool
    brightness: np.ndarray      # (S,) mean grey of each search line

    @functools.cached_property
    def uv(self) -> np.ndarray:
        cam_pts = self.points @ self.pose.R.T + self.pose.t
        return cam_pts[:, :2] / cam_pts[:, 2:3] * self.K[[0, 1], [0, 1]] + self.K[:2, 2]

    @functools.cached_property
    def matched(self) -> np.ndarray:
        return np.where(self.valid[:, None], self.target, np.nan)

    @functools.cached_property
    def inlier(self) -> np.ndarray:
        inlier = np.zeros(len(self.points), bool)
        inlier[np.flatnonzero(self.valid)[self.inlier_of_valid]] = True
        return inlier

    @functools.cached_property
    def lit_no_edge(self) -> np.ndarray:
        return ~self.valid & (self.brightness > LIT_GREY)


@dataclass(frozen=True)
class EdgeFit:
    """Result of :func:`fit_edges`: pose, covariance (6, 6) over ``[ω, v]``, inlier fraction, RMS px,
    inlier samples, and the sites of its last search (:class:`EdgeSites`, for pictures)."""

    pose: Pose
    covariance: np.ndarray
    quality: float
    rms_px: float
    samples: int
    sites: EdgeSites | None = None


def search_edges(gray: np.ndarray, samples: EdgeSamples, search_px: int, min_contrast: float = 4.0):
    """Strongest intensity step along each sample's normal within ``±search_px``.

    Returns (offset (S,) px along the normal, sub-pixel; valid (S,) bool: step ≥ ``min_contrast``
    grey levels per pixel; mean intensity (S,) along the search line). A mild Gaussian preference for
    nearer steps breaks ties as RAPID's nearest-maximum rule would. No sign is kept from frame to frame,
    as ViSP does: under a fixed sun, crease edges of a tumbling truss flip sign.
    """
    return _search(gray, samples.uv, samples.normals, search_px, min_contrast)


def _search(gray: np.ndarray, uv: np.ndarray, normals: np.ndarray, search_px: int, min_contrast: float = 4.0,
            limits: np.ndarray | None = None):
    if len(uv) == 0:  # nothing of the model in view: OpenCV refuses an empty map
        return np.zeros(0, np.float32), np.zeros(0, bool), np.zeros(0, np.float32)
    map_u, map_v = kernels.search_maps(uv, normals, int(search_px))
    profiles = cv2.remap(gray, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if limits is None:
        limits = np.full(len(uv), np.float32(search_px))
    return kernels.strongest_steps(profiles, int(search_px), float(min_contrast), limits)


# the strip around the object where a dark background is looked for (px beyond the projected samples'
# box, and its width), and the share of lit pixels (LIT_PIXEL_GREY) below which it is dark
SURROUND_GAP_PX, SURROUND_WIDTH_PX, SURROUND_LIT_SHARE = 16, 8, 0.1


def dark_surround(gray: np.ndarray, uv: np.ndarray) -> bool:
    """Whether the strip around the box of the points ``uv`` (N, 2) px — ``SURROUND_GAP_PX`` beyond it,
    ``SURROUND_WIDTH_PX`` wide, inside the (H, W) grey image — is dark: black space behind the object,
    not the Earth, a lit scene or an arm beside it. No strip in the image: not dark."""
    h, w = gray.shape[:2]
    x0, y0 = np.floor(uv.min(0)).astype(int) - SURROUND_GAP_PX
    x1, y1 = np.ceil(uv.max(0)).astype(int) + SURROUND_GAP_PX
    X0, Y0 = max(x0 - SURROUND_WIDTH_PX, 0), max(y0 - SURROUND_WIDTH_PX, 0)
    X1, Y1 = min(x1 + SURROUND_WIDTH_PX, w), min(y1 + SURROUND_WIDTH_PX, h)
    if X1 <= X0 or Y1 <= Y0:
        return False
    # the inner box, clipped to the outer one; the strip counted as four bands around it (a close
    # truss's box covers most of the frame: thresholding all of it cost more than the rest of the test)
    ra, rb = min(max(y0, Y0), Y1), min(max(y1, Y0), Y1)
    ca, cb = min(max(x0, X0), X1), min(max(x1, X0), X1)
    strip = (Y1 - Y0) * (X1 - X0) - (rb - ra) * (cb - ca)
    if strip <= 0:
        return False
    lit = sum(int(np.count_nonzero(gray[r0:r1, c0:c1] > LIT_PIXEL_GREY))
              for r0, r1, c0, c1 in ((Y0, ra, X0, X1), (rb, Y1, X0, X1), (ra, rb, X0, ca), (ra, rb, cb, X1)))
    return lit / strip < SURROUND_LIT_SHARE


def sun_shown(view: ModelView, frame: Frame, gray: np.ndarray, pose: Pose, visible: np.ndarray) -> np.ndarray:
    """The samples of ``visible`` (S,) the sun can show as image edges at ``pose``
    (:meth:`ModelView.sun_shows`, with the background around them judged dark or lit from ``gray``);
    all of them where ``frame`` gives no sun direction."""
    if frame.sun_direction_cam is None or not len(visible):
        return visible
    dark = dark_surround(gray, view.samples_at(pose, frame.camera, visible).uv)
    return visible[view.sun_shows(visible, pose, frame.sun_direction_cam, dark)]


def _half_stretch(view: ModelView, pose: Pose, cam, normals: np.ndarray) -> np.ndarray:
    """(S, 2) px: half of each projected sample's stretch along its edge (perpendicular to its image
    ``normals`` (S, 2)), 0.6 × the samples' spacing so that neighbouring stretches overlap a little
    and draw a continuous edge."""
    along = np.stack([normals[:, 1], -normals[:, 0]], 1)
    return (0.6 * view.step_px(pose, cam)) * along


# the trackers' polish iterations (``fit_edges(polish=...)``), chosen on the standard suite's tuning
# seeds (docs/decisions.md)
TRACKING_POLISH = 2


def check_polish(polish) -> int:
    """``polish`` as a whole number of iterations ≥ 0 (ValueError naming it otherwise)."""
    if isinstance(polish, bool) or int(polish) != polish or polish < 0:
        raise ValueError(f"polish: expected a whole number of iterations ≥ 0, got {polish!r}")
    return int(polish)


def fit_edges(view: ModelView, frame: Frame, start: Pose, gray: np.ndarray | None = None, search_px: int = 12,
              outer: int = 3, inner: int = 3, inlier_px: float = 2.0, max_samples: int = 400,
              covariance_scale: float = 1.0, max_step_m: float | None = None, polish: int = 0) -> EdgeFit | None:
    """Align the visible model edges with the image edges, starting from ``start``.

    ``search_px`` halves at each outer iteration (coarse to fine, never below 4); each outer
    iteration searches the edges from the current pose and runs ``inner`` Gauss–Newton steps on
    them (compiled: :mod:`hybridpose.edges.kernels`). Quality =
    inliers / (matched samples + samples whose lit search line shows no edge) × min(1, inliers /
    MIN_SUPPORT). None when fewer than 6 samples are visible or matched, or
    when the pose moves more than ``max_step_m`` (default: the object's diameter) from ``start``.

    ``polish`` more iterations follow at the finest range with each sample's search stopped
    halfway to the nearest other projected model edge (a thin beam's far side, a parallel beam
    behind: farther away, the step found is more likely that edge's). The coarse-to-fine stage keeps
    the full search, since it gives the fit its basin; the polish removes most of the error the
    full search leaves where edges crowd (the truss at 1.1 m, fitted from its true pose: 0.46° →
    0.25° median rotation). The quality is judged by the full search at the polished pose.
    """
    cam = frame.camera
    K = cam.K
    gray = to_gray(frame.image) if gray is None else gray
    max_step_m = view.object.diameter if max_step_m is None else max_step_m
    # visibility once per fit (at the start pose: the pose moves by a fraction of a degree); the
    # samples are re-projected as the pose moves and those that leave the image dropped
    visible = thin(sun_shown(view, frame, gray, start, view.visible_index(start, cam, margin_px=2)), max_samples)
    points, directions = view.points[visible], view.directions[visible]
    R, t = start.R, start.t
    rng_px = search_px
    for _ in range(outer):
        keep, uv, normals = kernels.project_samples(points, directions, R, t, K, cam.width, cam.height,
                                                          2.0, True)
        if not keep.all():
            points, directions, uv, normals = points[keep], directions[keep], uv[keep], normals[keep]
            visible = visible[keep]
        if len(points) < 6:
            return None
        offset, valid, brightness = _search(gray, uv, normals, rng_px)
        if valid.sum() < 6:
            return None
        target = uv + offset[:, None] * normals   # matched edge points
        n, X, m = normals[valid], points[valid], target[valid]
        # MAD scale capped by the search range: when an occluder's edges outnumber the model's the
        # MAD would grow and let them in
        R, t, ok = kernels.solve_lines(R, t, X, n, m, K, max(1.0, rng_px / 4), inner)
        if not ok:
            return None
        if np.linalg.norm(t - start.t) > max_step_m:
            return None
        rng_px = max(4, rng_px // 2)
    if polish > 0:
        # polish: the same fit with each sample's search stopped halfway to the next model edge, then
        # the full search again at the polished pose for the matches the quality is judged on
        keep, uv, normals = kernels.project_samples(points, directions, R, t, K, cam.width, cam.height, 2.0, True)
        if keep.sum() < 6:
            return None
        points, directions, uv, normals, visible = points[keep], directions[keep], uv[keep], normals[keep], visible[keep]
        reach = 0.5 * kernels.edge_clearance(uv, normals, _half_stretch(view, Pose(R, t), cam, normals),
                                              view.edge_of[visible], cam.width, cam.height, 2 * rng_px + 2)
        limits = np.minimum(reach, np.float32(rng_px)).astype(np.float32)
        for _ in range(int(polish)):
            _, uv, normals = kernels.project_samples(points, directions, R, t, K, cam.width, cam.height, 2.0, False)
            offset, valid_p, _ = _search(gray, uv, normals, rng_px, limits=limits)
            if valid_p.sum() < 6:
                break
            target = uv + offset[:, None] * normals
            R2, t2, ok = kernels.solve_lines(R, t, points[valid_p], normals[valid_p], target[valid_p], K,
                                              max(1.0, rng_px / 4), inner)
            if not ok:
                break
            R, t = R2, t2
        keep, uv, normals = kernels.project_samples(points, directions, R, t, K, cam.width, cam.height, 2.0, True)
        if keep.sum() < 6:
            return None
        offset, valid, brightness = _search(gray, uv[keep], normals[keep], rng_px)
        if valid.sum() < 6:
            return None
        target = uv[keep] + offset[:, None] * normals[keep]
        points = points[keep]
        n, X, m = normals[keep][valid], points[valid], target[valid]
    pose = Pose(R, t)
    uv, Jn = line_jacobian(pose, X, K, n)
    r = np.einsum("si,si->s", n, uv - m)
    inl = np.abs(r) < inlier_px
    if inl.sum() < 6:
        return None
    # a sample with no edge on a *lit* search line contradicts the model (a uniform occluder in
    # front, e.g. the arm's tool plate); on a dark line it says nothing (a face in shadow on black)
    contradicted = int((~valid & (brightness > LIT_GREY)).sum())
    ratio = float(inl.sum()) / (len(inl) + contradicted)
    dof = max(int(inl.sum()) - 6, 1)
    sigma2 = float((r[inl] ** 2).sum() / dof)
    # neighbouring samples on one edge are not independent: covariance_scale (≥ 1) accounts for it
    cov = covariance_from_information(Jn[inl].T @ Jn[inl], covariance_scale * max(sigma2, 0.05))
    support = min(1.0, float(inl.sum()) / MIN_SUPPORT)
    return EdgeFit(pose=pose, covariance=cov, quality=support * ratio,
                   rms_px=float(np.sqrt(np.mean(r[inl] ** 2))), samples=int(inl.sum()),
                   sites=EdgeSites(points, pose, K, target, valid, inl, brightness))


GOOD_FIT = 0.7  # a fit this good from the first proposal is kept without trying the next
# image edges (Canny, grey-level thresholds) near the projected model that its visible edges must
# explain, and how near (px): see explained_edge_share
CANNY_LOW, CANNY_HIGH = 20, 60
EXPLAIN_TOLERANCE_PX = 2  # an image edge within this of a model edge is explained by it
EXPLAIN_MARGIN_PX = 10  # image edges counted within this of the object's box
# a background whose ring around the object holds more edge pixels than this is cluttered: the explained
# share then counts only the edges within SILHOUETTE_SLACK_PX of the object's projected outline
CLUTTER_RING_PX = 12
CLUTTER_EDGE_DENSITY = 0.05  # edge pixels per ring pixel
SILHOUETTE_SLACK_PX = 3  # the outline's own blur and a pose's residual error
# a textured surface (print, paint, labels) puts edges inside the model's faces that no model edge
# explains at any pose. The faces' inside — visible faces, at least TEXTURE_CLEAR_PX from every visible
# model edge — holding more edge pixels than TEXTURE_EDGE_DENSITY is texture, and is left out of the
# count. Edge density there: the truss at its true pose 0.001 median, 0.02 p99; at poses 4° / 1 cm
# off 0.05 median, 0.16 p99 (real beams crossing the faces); ViSP's textured cube (real video) 0.19–0.22.
TEXTURE_CLEAR_PX = 4
TEXTURE_EDGE_DENSITY = 0.15  # see above: renders of plain faces ≤ 0.16 at p99, ViSP's cube 0.19–0.22
# …and only where the band just outside the faces (TEXTURE_BAND_PX wide) holds TEXTURE_CONTRAST times
# fewer: edges that carry on beyond the outline are the background's, not the object's texture. The
# cube: 4.1–12× (10th percentile 7×); a CNN start 83° off lying over a chip on a circuit-board photo
# (the box's tuning sequences): 3×, which at 2× passed as texture and was tracked for 11 frames
TEXTURE_BAND_PX = 8
TEXTURE_CONTRAST = 4.0  # see above: 2× passed the box's background clutter as a print


def printed_faces(view: ModelView, frame: Frame, pose: Pose, gray: np.ndarray | None = None,
                  ids: np.ndarray | None = None) -> bool:
    """Whether the part seen at ``pose`` in ``frame`` carries a print on its faces: more than
    ``TEXTURE_EDGE_DENSITY`` of the pixels inside its visible faces — at least ``TEXTURE_CLEAR_PX`` from
    any border between facets (the model's edges) — are Canny edges. Meant for a pose the caller trusts
    (a tracker's initial pose): at a wrong pose the faces may lie over a cluttered background.
    ``gray``: (H, W) float32 intensity, ``ids``: the full-resolution facet-id raster of ``pose``, where
    the caller has them."""
    ids = view.facet_ids(pose, frame.camera, scale=1.0) if ids is None else ids
    # the morphology on the part's box padded by the kernel's reach gives the whole frame's (nothing but
    # background beyond it) for less: 3.2 → 2.2 ms a call on the truss at 640 × 480, once per tracker start
    bx, by, bw, bh = cv2.boundingRect((ids > 0).astype(np.uint8))
    if bw == 0:
        return False
    r = TEXTURE_CLEAR_PX
    oy, ox = max(by - r, 0), max(bx - r, 0)
    crop = np.ascontiguousarray(ids[oy:by + bh + r, ox:bx + bw + r], np.uint16)
    k = np.ones((2 * r + 1,) * 2, np.uint8)
    interior = (crop > 0) & (cv2.dilate(crop, k) == cv2.erode(crop, k))
    if interior.sum() < 100:
        return False
    ys, xs = np.nonzero(interior)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    gray = to_gray(frame.image) if gray is None else gray
    patch = gray[oy + y0:oy + y1, ox + x0:ox + x1]
    edges = cv2.Canny(np.clip(patch, 0, 255).astype(np.uint8), CANNY_LOW, CANNY_HIGH) > 0
    return float(edges[interior[y0:y1, x0:x1]].mean()) > TEXTURE_EDGE_DENSITY


def explained_edge_share(view: ModelView, frame: Frame, pose: Pose, gray: np.ndarray | None = None,
                         ids: np.ndarray | None = None, occluder: bool = False, printed: bool = False) -> float:
    """Share (0..1) of the image's edge pixels around the projected model that lie within
    ``EXPLAIN_TOLERANCE_PX`` of a visible model edge at ``pose``; NaN where that region shows no edge.

    The fit's own quality looks from the model to the image (does each model edge find an image
    edge?), and on the truss's parallel beams a wrong pose finds one for most samples. This looks
    the other way: at a wrong pose the object's real edges, inside the same region, go unexplained.
    Measured on the standard suite's tuning seeds (`edges` from the true first pose): 0.99 median
    (p10 0.90) on frames within 2° of the truth, 0.69 median on frames > 5° off that the fit's
    quality did not flag. On a textured part (many more edges inside its visible faces than just
    outside them: ``TEXTURE_EDGE_DENSITY``, ``TEXTURE_CONTRAST``) the edges on its faces that no model
    edge explains are left out; with ``printed`` (the caller saw a print on the part at a pose it trusts,
    :func:`printed_faces`) always — in clutter the band outside the faces is as busy as the print, and
    the contrast test would count the print against a right pose. ``ids``: the view's facet ids of ``pose``, where the caller has them.
    ``occluder``: the region may show an occluder in front of the object on dark space (the arm);
    the edges on it (:func:`occluder_mask`) are left out too.
    """
    cam = frame.camera
    ids = view.facet_ids(pose, cam) if ids is None else ids  # one raster for the samples and the faces
    idx = view.visible_index(pose, cam, margin_px=2, ids=ids)
    if len(idx) < 6:
        return float("nan")
    s = view.samples_at(pose, cam, idx)
    stretch = _half_stretch(view, pose, cam, s.normals)
    a, b = s.uv - stretch, s.uv + stretch
    lo = np.floor(np.minimum(a, b).min(0)).astype(int) - EXPLAIN_MARGIN_PX
    hi = np.ceil(np.maximum(a, b).max(0)).astype(int) + EXPLAIN_MARGIN_PX
    x0, y0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
    x1, y1 = min(int(hi[0]), cam.width), min(int(hi[1]), cam.height)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return float("nan")
    full = to_gray(frame.image) if gray is None else gray
    # one Canny for the box and the ring around it
    around, (X0, Y0) = _edges_around(full, (x0, y0, x1, y1))
    edges = around[y0 - Y0:y1 - Y0, x0 - X0:x1 - X0]
    found = edges.copy()  # every edge of the region: what texture is told from clutter by
    if _ring_density(around, (x0 - X0, y0 - Y0, x1 - X0, y1 - Y0)) > CLUTTER_EDGE_DENSITY:
        # a cluttered background (a bench, a photo, the Earth): only the image edges on the object's
        # projected outline and inside it are the object's to explain
        hull = cv2.convexHull(np.round(s.uv - [x0, y0]).astype(np.int32))
        inside = np.zeros(edges.shape, np.uint8)
        cv2.fillConvexPoly(inside, hull, 1)
        k = 2 * SILHOUETTE_SLACK_PX + 1
        edges &= cv2.dilate(inside, np.ones((k, k), np.uint8)) > 0
    model = np.zeros(edges.shape, np.uint8)
    kernels.draw_segments(model, np.ascontiguousarray(a, np.float64), np.ascontiguousarray(b, np.float64), x0, y0)
    k = 2 * EXPLAIN_TOLERANCE_PX + 1
    near = cv2.dilate(model, np.ones((k, k), np.uint8)) > 0
    faces = _faces(ids, cam, (x0, y0, x1, y1), model.shape)
    k = 2 * TEXTURE_CLEAR_PX + 1
    interior = faces & (cv2.dilate(model, np.ones((k, k), np.uint8)) == 0)
    density = found[interior].mean() if interior.any() else 0.0
    if printed:
        edges &= ~faces | near
    elif density > TEXTURE_EDGE_DENSITY:
        k = 2 * TEXTURE_BAND_PX + 1
        band = (cv2.dilate(faces.astype(np.uint8), np.ones((k, k), np.uint8)) > 0) & ~faces & ~near
        if not band.any() or density > TEXTURE_CONTRAST * found[band].mean():
            edges &= ~faces | near  # on a textured surface only the model's own edges are the object's to explain
    if occluder:
        k = 2 * SILHOUETTE_SLACK_PX + 1
        off = cv2.dilate(faces.astype(np.uint8), np.ones((k, k), np.uint8)) == 0
        edges &= ~occluder_mask(full[y0:y1, x0:x1] > LIT_PIXEL_GREY, off, float(np.hypot(x1 - x0, y1 - y0)))
    n = int(edges.sum())
    if n == 0:
        return float("nan")
    return float((edges & near).sum()) / n


def _faces(ids: np.ndarray, cam, box, shape) -> np.ndarray:
    """(h, w) = ``shape`` bool over ``box`` (x0, y0, x1, y1 px of ``cam``'s image): the pixels where a
    visible face lies in the facet-id raster ``ids`` (:meth:`ModelView.facet_ids`, any scale)."""
    x0, y0, x1, y1 = box
    scale = ids.shape[1] / cam.width
    r0, r1 = int(y0 * scale), min(int(np.ceil(y1 * scale)), ids.shape[0])
    c0, c1 = int(x0 * scale), min(int(np.ceil(x1 * scale)), ids.shape[1])
    if r1 <= r0 or c1 <= c0:
        return np.zeros(shape, bool)
    return cv2.resize((ids[r0:r1, c0:c1] > 0).astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0


def background_edge_density(gray: np.ndarray, box, ring_px: int = CLUTTER_RING_PX) -> float:
    """Share of edge pixels (Canny) in a ``ring_px`` band around ``box`` (x0, y0, x1, y1 px) of the
    (H, W) grey image: ≈ 0 on black space (at most 0.012 with the arm beside the truss, tuning seeds),
    0.16–0.30 around a part in front of a photo."""
    x0, y0, x1, y1 = box
    edges, (X0, Y0) = _edges_around(gray, box, ring_px)
    return _ring_density(edges, (x0 - X0, y0 - Y0, x1 - X0, y1 - Y0))


def _edges_around(gray: np.ndarray, box, ring_px: int = CLUTTER_RING_PX) -> tuple[np.ndarray, tuple[int, int]]:
    """Canny edges (bool) of ``box`` (x0, y0, x1, y1 px) grown by ``ring_px`` and clipped to the (H, W)
    grey image, and the grown box's top-left corner (x, y)."""
    x0, y0, x1, y1 = box
    h, w = gray.shape[:2]
    X0, Y0, X1, Y1 = max(x0 - ring_px, 0), max(y0 - ring_px, 0), min(x1 + ring_px, w), min(y1 + ring_px, h)
    return cv2.Canny(np.clip(gray[Y0:Y1, X0:X1], 0, 255).astype(np.uint8), CANNY_LOW, CANNY_HIGH) > 0, (X0, Y0)


def _ring_density(edges: np.ndarray, inner) -> float:
    """Share of edge pixels in ``edges`` outside its ``inner`` box (x0, y0, x1, y1, in its pixels)."""
    x0, y0, x1, y1 = inner
    box = edges[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)]
    ring_px = edges.size - box.size
    return float(int(edges.sum()) - int(box.sum())) / ring_px if ring_px else 0.0


def fit_from_proposals(view: ModelView, frame: Frame, starts, gray: np.ndarray | None = None,
                       good_fit: float = GOOD_FIT, **kwargs) -> EdgeFit | None:
    """Edge fits from ``starts`` in order, stopping at the first with quality ≥ ``good_fit``; the
    fit most samples agree with (inliers × quality) among those run, or None."""
    gray = to_gray(frame.image) if gray is None else gray
    fits = []
    for start in starts:
        fit = fit_edges(view, frame, start, gray=gray, **kwargs)
        if fit is not None:
            fits.append(fit)
            if fit.quality >= good_fit:
                break
    return max(fits, key=lambda f: f.samples * f.quality) if fits else None
