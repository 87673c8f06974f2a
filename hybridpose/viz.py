"""Pictures of what the tracker sees: wireframe and axes overlays, contact sheets."""
from __future__ import annotations

import cv2
import numpy as np

from .geometry import Camera, Pose
from .objects import ObjectModel

_MIN_Z_M = 1e-3  # model points nearer the camera plane are not drawn


def _draw_segments(img: np.ndarray, seg_cam: np.ndarray, camera: Camera, color, thickness: int) -> None:
    """Draw (E, 2, 3) camera-frame segments, clipped to z > 1 mm."""
    p0, p1 = seg_cam[:, 0], seg_cam[:, 1]
    keep = (p0[:, 2] > _MIN_Z_M) | (p1[:, 2] > _MIN_Z_M)
    p0, p1 = p0[keep], p1[keep]
    # clip segments that cross the camera plane so that projection stays finite
    for a, b in ((p0, p1), (p1, p0)):
        bad = a[:, 2] <= _MIN_Z_M
        if np.any(bad):
            s = (_MIN_Z_M - b[bad, 2]) / (a[bad, 2] - b[bad, 2])
            a[bad] = b[bad] + s[:, None] * (a[bad] - b[bad])
    if len(p0) == 0:
        return
    uv0, uv1 = camera.project_cam(p0), camera.project_cam(p1)
    shift = 4
    for a, b in zip(np.round(uv0 * (1 << shift)).astype(np.int64), np.round(uv1 * (1 << shift)).astype(np.int64)):
        if np.all(np.abs(a) < 2**30) and np.all(np.abs(b) < 2**30):
            cv2.line(img, tuple(int(x) for x in a), tuple(int(x) for x in b), color, thickness, cv2.LINE_AA, shift)


def draw_wireframe(image: np.ndarray, obj: ObjectModel, T_cam_obj: Pose, camera: Camera,
                   color=(0, 255, 0), thickness: int = 1) -> np.ndarray:
    """Copy of ``image`` (H, W, 3) uint8 RGB with the model's sharp edges projected at ``T_cam_obj``."""
    img = camera.check_image(image).copy()
    edges = obj.sharp_edges
    seg = (T_cam_obj @ edges.reshape(-1, 3)).reshape(-1, 2, 3)
    _draw_segments(img, seg, camera, color, thickness)
    return img


def draw_axes(image: np.ndarray, T_cam_obj: Pose, camera: Camera, length_m: float = 0.1, thickness: int = 2) -> np.ndarray:
    """Copy of ``image`` with the object frame's x (red), y (green), z (blue) axes."""
    img = camera.check_image(image).copy()
    o = T_cam_obj.t
    for axis, color in zip(np.eye(3), ((255, 0, 0), (0, 255, 0), (0, 0, 255))):
        seg = np.stack([o, T_cam_obj @ (axis * length_m)])[None]
        _draw_segments(img, seg, camera, color, thickness)
    return img


# the moving-edge sites' colours (RGB), as ViSP tells its sites apart by why they were kept or rejected
SITE_COLOURS = {"inlier": (0, 255, 255), "outlier": (255, 40, 40), "lit_no_edge": (255, 160, 0),
                "dark_no_edge": (130, 130, 130)}
# ASCII only: OpenCV's Hershey fonts draw nothing else
SITE_LEGEND = "sites: cyan matched, red rejected, orange no edge (lit line), grey no edge (dark)"


def draw_edge_sites(image: np.ndarray, sites, to_image=None) -> np.ndarray:
    """Copy of ``image`` (H, W, 3) uint8 RGB with an edge fit's sites
    (:class:`~hybridpose.edges.fit.EdgeSites`): each model sample at the fitted pose as a dot —
    cyan where its match is an inlier, red (with a line to the edge it found) where the fit rejected
    that match, orange where its lit search line showed no edge (evidence against the pose), grey
    where a dark one showed none — the picture ViSP's moving-edge tracker draws. ``to_image``: maps
    (N, 2) fit pixels (an undistorted image's) to ``image``'s, e.g. ``Camera.distort_pixels``."""
    img = np.ascontiguousarray(image).copy()
    if sites is None:
        return img
    h, w = img.shape[:2]
    uv, matched = np.asarray(sites.uv, float), np.asarray(sites.matched, float)
    if to_image is not None:
        uv, matched = to_image(uv), to_image(matched)
    has_match = np.all(np.isfinite(matched), axis=1)
    kinds = (("dark_no_edge", ~has_match & ~sites.lit_no_edge), ("lit_no_edge", sites.lit_no_edge),
             ("outlier", has_match & ~sites.inlier), ("inlier", sites.inlier))
    for kind, mask in kinds:
        colour = SITE_COLOURS[kind]
        for i in np.flatnonzero(mask & np.all(np.isfinite(uv), axis=1)):
            u, v = (int(round(x)) for x in uv[i])
            if not (0 <= u < w and 0 <= v < h):
                continue
            if kind == "outlier":
                cv2.line(img, (u, v), tuple(int(round(x)) for x in matched[i]), colour, 1, cv2.LINE_AA)
            cv2.circle(img, (u, v), 1, colour, -1)
    return img


def draw_mask_contour(image: np.ndarray, mask: np.ndarray, color=(255, 0, 255), thickness: int = 1) -> np.ndarray:
    """Copy of ``image`` with the outline of a boolean mask."""
    img = np.ascontiguousarray(image).copy()
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(img, contours, -1, color, thickness)
    return img


def put_label(image: np.ndarray, text: str, bottom: bool = False) -> np.ndarray:
    """Copy of ``image`` with one line of white text on a dark box at its top (or ``bottom``) left (a
    box, not an outline: an outline's dark strokes stood out as ghost letters on a bright arm)."""
    img = np.ascontiguousarray(image).copy()
    y = img.shape[0] - 7 if bottom else 16
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
    x0, y0, x1, y1 = 2, max(y - h - 3, 0), min(5 + w + 3, img.shape[1]), min(y + base + 1, img.shape[0])
    img[y0:y1, x0:x1] = (0.35 * img[y0:y1, x0:x1]).astype(np.uint8)
    cv2.putText(img, text, (5, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def contact_sheet(images: list[np.ndarray], columns: int = 4, tile_width: int = 320,
                  labels: list[str] | None = None) -> np.ndarray:
    """Tile RGB images (resized to ``tile_width``, keeping aspect) into one (H, W, 3) uint8 sheet;
    ``labels`` are written on the tiles after resizing, so they stay legible."""
    if not images:
        raise ValueError("images: need at least one image")
    columns = max(1, min(columns, len(images)))
    h0, w0 = images[0].shape[:2]
    tile_h = int(round(h0 * tile_width / w0))
    tiles = [cv2.resize(im, (tile_width, tile_h), interpolation=cv2.INTER_AREA) for im in images]
    if labels is not None:
        tiles = [put_label(t, text) for t, text in zip(tiles, labels)]
    rows = -(-len(tiles) // columns)
    sheet = np.full((rows * tile_h + (rows - 1) * 2, columns * tile_width + (columns - 1) * 2, 3), 40, np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, columns)
        sheet[r * (tile_h + 2): r * (tile_h + 2) + tile_h, c * (tile_width + 2): c * (tile_width + 2) + tile_width] = tile
    return sheet


def silhouette(obj: ObjectModel, T_cam_obj: Pose, camera: Camera, supersample: int = 8) -> np.ndarray:
    """(H, W) bool silhouette of the projected mesh, sampled at pixel centres.

    Each triangle is filled with ``cv2.fillConvexPoly`` on a grid ``supersample`` times finer and the
    coverage is thresholded at one half; OpenCV's fill includes every touched pixel, which would
    otherwise fatten thin beams by about half a pixel on each side.
    """
    s = int(supersample)
    uv = camera.project(obj.vertices, T_cam_obj)
    uv_hr = (uv + 0.5) * s - 0.5  # pixel centre (u) of the coarse grid → centre of the fine block
    canvas = np.zeros((camera.height * s, camera.width * s), np.uint8)
    shift = 4
    pts = np.round(uv_hr * (1 << shift)).astype(np.int64)
    for f in obj.faces:
        tri = pts[f]
        if np.all(np.abs(tri) < 2**30):
            cv2.fillConvexPoly(canvas, tri.astype(np.int32), 1, cv2.LINE_8, shift)
    coverage = canvas.reshape(camera.height, s, camera.width, s).mean(axis=(1, 3))
    return coverage >= 0.5


def save_figure(path, draw, figsize=(8, 3.8), dpi: int = 110) -> None:
    """A one-axes matplotlib figure drawn by ``draw(ax)``, written atomically to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .io import atomic_write_with

    fig, ax = plt.subplots(figsize=figsize, dpi=dpi)
    try:
        draw(ax)
        fig.tight_layout()
        atomic_write_with(path, lambda f: fig.savefig(f, format="png"))
    finally:
        plt.close(fig)


def plot_error_over_time(path, timestamps, errors_deg: dict, visible, title: str = "",
                         statuses: list[str] | None = None) -> None:
    """PNG of rotation error (°, log scale) over time per mode, frames where the object is less than
    half visible shaded grey (darker: covered), frames a mode flagged lost left as gaps (NaN).

    Args:
        timestamps: (N,) seconds. errors_deg: {mode: (N,) degrees, NaN where the mode gave no trusted
        pose}. visible: (N,) visible share 0..1. statuses: the hybrid's status per frame (reinit
        frames are marked).
    """
    t = np.asarray(timestamps, dtype=np.float64)
    vis = np.asarray(visible, dtype=np.float64)
    dt = np.median(np.diff(t)) if len(t) > 1 else 1.0

    def draw(ax):
        for k in range(len(t)):
            if vis[k] < 0.5:
                ax.axvspan(t[k] - dt / 2, t[k] + dt / 2, color="0.55" if vis[k] < 0.05 else "0.85", lw=0)
        for mode, err in errors_deg.items():
            ax.plot(t, np.maximum(np.asarray(err, dtype=np.float64), 1e-3), ".-", ms=3, lw=1, label=mode)
        if statuses is not None:
            re = [t[k] for k, s in enumerate(statuses) if s == "reinit"]
            if re:
                ax.plot(re, [0.0015] * len(re), "v", color="k", ms=5, label="hybrid re-init")
        ax.set_yscale("log")
        ax.set_ylim(1e-3, 200)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("rotation error (°)")
        ax.set_title(title + "   grey: object < 50 % visible (dark: covered); gaps: flagged lost", fontsize=9)
        ax.legend(fontsize=8, loc="upper left")

    save_figure(path, draw, figsize=(9, 3.6))
