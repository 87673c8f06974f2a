"""Which parts of the object the sun lights at a pose, the shadows it casts on itself included, and how
well that matches the image: a check of a pose that does not rest on the edges it was fitted to.

On black space everything the sun does not light is black, so a pose predicts its image's lit pixels
exactly (95–99 % of the silhouette's pixels agree with MuJoCo's renders of the truss close up, where
its beams shade its plates). A pose a few degrees off that the edges still fit (parallel beams, a
truss lit in slivers) predicts light where the image is dark. A point of a face turned to the sun
lies in shadow where another face is between it and the sun: a shadow map, drawn with the facet-id
raster the edge visibility already uses (OpenCV has no shadow test; MuJoCo needs a GL context for
each call).
"""
from __future__ import annotations

import numpy as np

from ..geometry import Camera, Pose
from ..geometry.raster import zbuffer_front_faces
from .image import to_gray
from .model_view import ID_SCALE, SUNLIT_COSINE, ModelView

SHADOW_MAP_MAX_PX = 1024  # the shadow map's side at most (a far object needs far fewer)
SUN_DISTANCE_DIAMETERS = 1000.0  # the shadow map's eye this far up the sunlight: as good as parallel rays
# a face counts as shading a point only this many shadow-map pixels up the sunlight from it (faces
# meeting at a crease share the crease's pixels)
SHADOW_GAP_PX = 3.0
# a face turned to the sun by less than this cosine may render too dim to tell from shadow: left out
SURE_LIT_COSINE = 0.25
LIT_GREY_MIN = 8.0  # a pixel brighter than this grey level may be lit (black space renders at 0–3)
LIT_GREY_SHARE = 0.1  # ... and must be brighter than this share of the silhouette's brightest pixels (p99)
AGREEMENT_SLACK_PX = 1  # lit pixels this close (raster pixels) to the other set count as matched
MIN_LIT_PX = 20  # fewer predicted and seen lit pixels than this (raster pixels): no verdict


def facet_sun_cosine(view: ModelView, pose: Pose, sun_direction_cam) -> np.ndarray:
    """(F + 1,) float: per value of the facet-id raster (facet id + 1; 0, the background, has a zero
    normal), the cosine between the facet's outward normal and the way to the sun, whose light
    travels along ``sun_direction_cam`` ((3,), camera frame, any length) onto the object at ``pose``."""
    sun = np.asarray(sun_direction_cam, dtype=np.float64).reshape(3)
    return view.plane_normal @ (pose.R.T @ -(sun / np.linalg.norm(sun)))


def sunlit_mask(view: ModelView, pose: Pose, camera: Camera, sun_direction_cam, ids: np.ndarray | None = None,
                scale: float = ID_SCALE) -> np.ndarray:
    """(h, w) bool over the facet-id raster ``ids`` of ``pose`` (:meth:`ModelView.facet_ids` at
    ``scale`` × the camera's resolution; rendered here when None): the pixels showing a face turned to
    the sun that no other part of the model shades.

    Args:
        view: the object's :class:`ModelView`. pose: T_cam_obj. camera: the frame's camera.
        sun_direction_cam: (3,) the direction the sunlight travels, camera frame (any length).
    """
    ids = view.facet_ids(pose, camera, scale) if ids is None else ids
    sun = np.asarray(sun_direction_cam, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(sun)) or np.linalg.norm(sun) == 0:
        raise ValueError(f"sun_direction_cam: expected a finite non-zero (3,) direction, got {sun_direction_cam!r}")
    lit = np.zeros(ids.shape, bool)
    rows, cols = np.nonzero(ids)
    if not len(rows):
        return lit
    facets = ids[rows, cols].astype(np.int64)
    s = pose.R.T @ (sun / np.linalg.norm(sun))                       # the light's travel, object frame
    turned = facet_sun_cosine(view, pose, sun)[facets] > SUNLIT_COSINE
    rows, cols, facets = rows[turned], cols[turned], facets[turned]  # only these can be lit: lift only them
    if not len(rows):
        return lit
    uv = (np.c_[cols, rows] + 0.5) / scale - 0.5                     # full-resolution pixel centres
    d, lam, ok = view.ray_plane_depths(pose, camera, uv, facets)
    if not ok.any():
        return lit
    points = -pose.R.T @ pose.t + lam[ok, None] * d[ok]             # (N, 3) surface seen, object frame
    shaded = _shaded(view, points, facets[ok], s, float(np.median(lam[ok])) / (camera.fx * scale))
    lit[rows[ok][~shaded], cols[ok][~shaded]] = True
    return lit


def _shaded(view: ModelView, points: np.ndarray, facets: np.ndarray, s: np.ndarray, pixel_m: float) -> np.ndarray:
    """(N,) bool: which ``points`` (N, 3, object frame, on ``facets`` (N,) facet id + 1) another face
    hides from the sunlight travelling along the unit ``s``, by a shadow map of about ``pixel_m``
    metres a pixel (the camera raster's footprint, so that both resolve the same detail)."""
    diameter = view.object.diameter
    side = int(min(SHADOW_MAP_MAX_PX, np.ceil(diameter / max(pixel_m, 1e-6)) + 8))
    pixel_m = max(pixel_m, diameter / (side - 8))
    # an eye far up the sunlight looking down it: rows of R are the map's x, y and the light's travel
    helper = np.eye(3)[int(np.argmin(np.abs(s)))]
    e1 = np.cross(s, helper)
    e1 /= np.linalg.norm(e1)
    R = np.stack([e1, np.cross(s, e1), s])
    distance = SUN_DISTANCE_DIAMETERS * diameter
    eye = view.triangles.reshape(-1, 3).mean(0) - distance * s
    t = -R @ eye
    f = distance / pixel_m
    c = (side - 1) / 2.0
    K = np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])
    shadow_ids = zbuffer_front_faces(view.triangles, view.face_normals, view.facet_of, R, t, K, 1.0, side, side)
    P = points @ R.T + t
    u = np.round(f * P[:, 0] / P[:, 2] + c).astype(np.int64)
    v = np.round(f * P[:, 1] / P[:, 2] + c).astype(np.int64)
    inside = (u >= 0) & (u < side) & (v >= 0) & (v < side)
    first = np.zeros(len(points), np.int64)                          # the face the sunlight meets first
    first[inside] = shadow_ids[v[inside], u[inside]]
    other = (first > 0) & (first != facets)
    n, p0 = view.plane_normal[first], view.plane_point[first]
    along = n @ s
    # where the sunlight's line through the point meets that face's plane: < 0 is up the light
    step = np.where(other & (np.abs(along) > 1e-9),
                    np.einsum("ij,ij->i", n, p0 - points) / np.where(np.abs(along) > 1e-9, along, 1.0), 0.0)
    return other & (step < -SHADOW_GAP_PX * pixel_m)


def sunlit_agreement(view: ModelView, frame, pose: Pose, gray: np.ndarray | None = None,
                     ids: np.ndarray | None = None) -> tuple[float, float]:
    """How well the sunlit surface the model predicts at ``pose`` (under the frame's sun, with the
    shadows it casts on itself) matches the lit pixels of the image inside the projected silhouette:
    (precision, recall) — the share of the pixels predicted surely lit that are lit in the image, and
    of the image's lit pixels on the silhouette that are predicted lit — each pixel matched within
    ``AGREEMENT_SLACK_PX`` raster pixels of the other set. Faces turned to the sun by less than
    ``SURE_LIT_COSINE`` are left out (too dim to tell); a pixel is lit above ``LIT_GREY_MIN`` grey and
    ``LIT_GREY_SHARE`` of the silhouette's brightest (p99: a fading sun dims all of it), and a face is
    surely lit only where that brightness times its cosine is twice the threshold. (NaN, NaN) where
    the frame has no sun direction or both sets hold fewer than ``MIN_LIT_PX`` pixels.

    Args:
        view: the object's :class:`ModelView`. frame: the image, its camera and sun direction.
        pose: T_cam_obj. gray: (H, W) grey image of ``frame`` (made here when None). ids: the view's
            :meth:`~ModelView.facet_ids` of ``pose`` (rendered here when None).
    """
    import cv2

    nan = (float("nan"), float("nan"))
    if frame.sun_direction_cam is None:
        return nan
    cam = frame.camera
    ids = view.facet_ids(pose, cam) if ids is None else ids
    inside = ids > 0
    if not inside.any():
        return nan
    lit = sunlit_mask(view, pose, cam, frame.sun_direction_cam, ids)
    cosine = facet_sun_cosine(view, pose, frame.sun_direction_cam)[ids]  # per facet, then per pixel
    full = to_gray(frame.image) if gray is None else gray
    small = cv2.resize(np.asarray(full, np.float32), (ids.shape[1], ids.shape[0]), interpolation=cv2.INTER_AREA)
    bright = float(np.percentile(small[inside], 99))
    threshold = max(LIT_GREY_MIN, LIT_GREY_SHARE * bright)
    # a face lit at cosine c shows about c × the brightest grey (Lambert): it must show twice the threshold
    predicted = lit & (cosine >= max(SURE_LIT_COSINE, 2.0 * threshold / max(bright, 1e-6)))
    unsure = lit & ~predicted
    seen = (small > threshold) & inside & ~unsure
    if int(predicted.sum()) + int(seen.sum()) < MIN_LIT_PX:
        return nan
    k = np.ones((2 * AGREEMENT_SLACK_PX + 1,) * 2, np.uint8)
    precision = float((predicted & (cv2.dilate(seen.astype(np.uint8), k) > 0)).sum()) / max(int(predicted.sum()), 1)
    recall = float((seen & (cv2.dilate(predicted.astype(np.uint8), k) > 0)).sum()) / max(int(seen.sum()), 1)
    return precision, recall
