"""The region cue (sparse, as SRT3D): the part's colours against its background's, along
correspondence lines across the projected silhouette.

* Colour statistics: RGB histograms (``BINS``³) of the part (its projected faces, eroded) and of a
  band of background around it, learned at the start and blended in on every trusted frame
  (``LEARN_RATE``); each pixel's posterior ``p(part | colour)``.
* Correspondence lines: the model's silhouette edges at the pose (sharp edges between a face turned to
  the camera and one turned away) sampled as the edge cue samples its edges, each line along the
  outward image normal. On each line the contour is where the posterior changes from part to
  background most likely: the split maximising ``Σ_inside log p + Σ_outside log(1 − p)``.
* Residuals: the distance from the projected silhouette to that split, along the normal (point to
  line), with Tukey weights.

No verdict (inactive) where the colours do not tell part from background (mean posterior on the part
less than ``MIN_CONTRAST`` above the background's): a grey part on a grey desk, a shadowed face on
black space. Only the outline of a polyhedral mesh has silhouette edges here; a smooth mesh gives
none and the cue stays silent.

Quality = share of the silhouette's lines whose split lies within ``INLIER_PX`` of the fitted
silhouette with a clear change of colour.
"""
from __future__ import annotations

import math

import cv2
import numba
import numpy as np

from ...core import Frame
from ...edges import ModelView
from ...edges.model_view import ID_SCALE
from ...geometry import Pose
from .base import Cue
from .solve import LineRows

BINS = 16                 # per colour channel
LEARN_RATE = 0.2          # share of a trusted frame's histograms blended into the model
LEARN_EVERY = 2           # …on every LEARN_EVERY-th frame (colours change slowly; a frame's learning costs ~0.5 ms)
BAND_PX = (6, 30)         # background band: this far beyond the silhouette
ERODE_PX = 4              # part pixels: this far inside it
MIN_CONTRAST = 0.3        # mean posterior on the part − on the background, for the cue to speak
SPLIT_CONTRAST = 0.3      # a line's inside − outside mean posterior for its split to count
INLIER_PX = 2.0
QUALITY_SEARCH_PX = 5  # quality reads splits this near the fitted silhouette
MAX_LINES = 200  # lines across the silhouette a frame, spread evenly along it
CACHE_MARGIN_PX = 48      # the frame's posterior is worked out this far around the start's silhouette
EPS = 1e-3  # histogram smoothing: an unseen colour is 50/50, not certain


class RegionCue(Cue):
    """Part-versus-background colour statistics along lines across the silhouette.

    Args:
        view: the model's :class:`~hybridpose.edges.ModelView`. sigma_px: a line's standard deviation, px.
    """

    name = "region"

    def __init__(self, view: ModelView, sigma_px: float = 1.5, max_lines: int = MAX_LINES) -> None:
        super().__init__()
        self.view, self.sigma_px, self.max_lines = view, float(sigma_px), int(max_lines)
        self.h_part = self.h_back = None
        self._lut = None  # p(part | colour bin), worked out where the histograms change
        self._cached = None  # (frame, posterior, box) of the frame being fitted
        self._frames = 0
        self.contrast = 0.0
        self.X = np.zeros((0, 3))

    # --- colour statistics -------------------------------------------------------------------------
    @staticmethod
    def _bins(rgb: np.ndarray) -> np.ndarray:
        q = (rgb >> (8 - int(np.log2(BINS)))).astype(np.int32)
        return (q[..., 0] * BINS + q[..., 1]) * BINS + q[..., 2]

    def _learn(self, frame: Frame, ids: np.ndarray, rate: float) -> None:
        """Blend the colours of ``frame`` at the pose whose facet-id raster is ``ids`` (any scale) into
        the histograms, over the object's box and the band around it at the raster's resolution."""
        scale = ids.shape[1] / frame.camera.width
        part = ids > 0
        bx, by, bw, bh = cv2.boundingRect(part.astype(np.uint8))
        if bw == 0:
            return
        r = int(np.ceil(BAND_PX[1] * scale)) + 1
        y0, y1 = max(by - r, 0), min(by + bh + r, ids.shape[0])
        x0, x1 = max(bx - r, 0), min(bx + bw + r, ids.shape[1])
        part = part[y0:y1, x0:x1]
        u8 = part.astype(np.uint8)
        def disc(px):
            return np.ones((2 * max(1, round(px * scale)) + 1,) * 2, np.uint8)
        inner = cv2.erode(u8, disc(ERODE_PX)) > 0
        band = (cv2.dilate(u8, disc(BAND_PX[1])) > 0) & ~(cv2.dilate(u8, disc(BAND_PX[0])) > 0)
        if inner.sum() < 20 or band.sum() < 20:
            return
        if scale == 1.0:
            image = frame.image[y0:y1, x0:x1]
        else:  # the full-resolution box, shrunk to the raster's
            X0, Y0 = int(x0 / scale), int(y0 / scale)
            X1, Y1 = min(int(np.ceil(x1 / scale)), frame.camera.width), min(int(np.ceil(y1 / scale)), frame.camera.height)
            image = cv2.resize(frame.image[Y0:Y1, X0:X1], (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        bins = self._bins(image)
        hp = np.bincount(bins[inner], minlength=BINS**3).astype(np.float64)
        hb = np.bincount(bins[band], minlength=BINS**3).astype(np.float64)
        hp, hb = hp / hp.sum(), hb / hb.sum()
        if self.h_part is None or rate >= 1.0:
            self.h_part, self.h_back = hp, hb
        else:
            self.h_part = (1 - rate) * self.h_part + rate * hp
            self.h_back = (1 - rate) * self.h_back + rate * hb
        post = self._lut = self._posterior_lut()
        self.contrast = float(post[bins[inner]].mean() - post[bins[band]].mean())
        self.active = self.contrast >= MIN_CONTRAST

    def _posterior_lut(self) -> np.ndarray:
        return ((self.h_part + EPS / BINS**3) / (self.h_part + self.h_back + 2 * EPS / BINS**3)).astype(np.float32)

    def start(self, frame: Frame, gray: np.ndarray, pose: Pose, ids: np.ndarray) -> None:
        self.h_part = None
        self._frames = 0  # the learning cadence counts this track's frames, not the trial fits before it
        self._learn(frame, ids, 1.0)

    def begin(self, sight) -> None:
        super().begin(sight)
        # the silhouette's samples once a frame, at the start pose (re-projected as the pose moves),
        # each line turned outward: towards the side where the start's raster shows background
        view, cam, ids = self.view, sight.frame.camera, sight.ids
        idx = view.silhouette_index(sight.visible, sight.start)
        step = max(1, int(np.ceil(len(idx) / self.max_lines)))
        s = view.samples_at(sight.start, cam, idx[::step], margin_px=2.0)
        h, w = ids.shape
        probe = np.round((s.uv + 3.0 * s.normals + 0.5) * ID_SCALE - 0.5).astype(int)
        inside = (probe[:, 0] >= 0) & (probe[:, 0] < w) & (probe[:, 1] >= 0) & (probe[:, 1] < h)
        out = np.ones(len(probe), bool)
        out[inside] = ids[probe[inside, 1], probe[inside, 0]] == 0
        self.lines, self.outward = s.index, np.where(out, 1.0, -1.0)
        if self.active:
            self._cache_posterior(sight.frame, s.uv)

    def finish(self, frame: Frame, gray: np.ndarray, pose: Pose, trusted: bool, ids) -> None:
        self._frames += 1
        if trusted and self._frames % LEARN_EVERY == 0:
            # at the raster's resolution of the fit (ID_SCALE): colour statistics need no more
            self._learn(frame, self.view.facet_ids(pose, frame.camera), LEARN_RATE)

    # --- correspondence lines ----------------------------------------------------------------------
    def _lines(self, frame: Frame, pose: Pose):
        """(points (S, 3) m, uv (S, 2) px, outward normals (S, 2)) of the frame's silhouette lines at ``pose``."""
        s = self.view.samples_at(pose, frame.camera, self.lines)
        return s.points_m, s.uv, s.normals * self.outward[:, None]

    def _posterior(self, frame: Frame, box):
        """(posterior p(part | colour) (h, w) float32 over ``box`` (x0, y0, x1, y1 px) clipped to the image,
        its top-left corner): cut from this frame's cached posterior where that covers ``box``."""
        h, w = frame.image.shape[:2]
        x0, y0, x1, y1 = max(box[0], 0), max(box[1], 0), min(box[2], w), min(box[3], h)
        if x1 <= x0 or y1 <= y0:
            return None, (0, 0)
        cached = self._cached
        if cached is not None and cached[0] is frame:
            cx0, cy0, cx1, cy1 = cached[2]
            if cx0 <= x0 and cy0 <= y0 and x1 <= cx1 and y1 <= cy1:
                return cached[1][y0 - cy0:y1 - cy0, x0 - cx0:x1 - cx0], (x0, y0)
        return posterior_image(np.ascontiguousarray(frame.image[y0:y1, x0:x1]), self._lut, BINS), (x0, y0)

    def _cache_posterior(self, frame: Frame, uv: np.ndarray) -> None:
        """One posterior image a frame, over the silhouette at the start grown by ``CACHE_MARGIN_PX``."""
        self._cached = None
        if len(uv) == 0 or self.h_part is None:
            return
        lo, hi = np.floor(uv.min(0)).astype(int) - CACHE_MARGIN_PX, np.ceil(uv.max(0)).astype(int) + CACHE_MARGIN_PX
        post, (x0, y0) = self._posterior(frame, (lo[0], lo[1], hi[0], hi[1]))
        if post is not None:
            self._cached = (frame, post, (x0, y0, x0 + post.shape[1], y0 + post.shape[0]))

    def _splits(self, frame: Frame, uv: np.ndarray, normals: np.ndarray, search_px: int):
        """Each line's most likely split (offset px along the outward normal) and whether it is clear."""
        L = int(search_px)
        k = np.arange(-L - 1, L + 2, dtype=np.float32)
        mu = (uv[:, None, 0] + k * normals[:, None, 0]).astype(np.float32)
        mv = (uv[:, None, 1] + k * normals[:, None, 1]).astype(np.float32)
        box = (int(np.floor(mu.min())) - 1, int(np.floor(mv.min())) - 1, int(np.ceil(mu.max())) + 2,
               int(np.ceil(mv.max())) + 2)
        post, (x0, y0) = self._posterior(frame, box)
        if post is None:
            return np.zeros(len(uv)), np.zeros(len(uv), bool)
        p = cv2.remap(post, mu - x0, mv - y0, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return best_splits(p, L, SPLIT_CONTRAST)

    def correspond(self, frame: Frame, gray: np.ndarray, pose: Pose, search_px: int) -> None:
        self.X = np.zeros((0, 3))
        if not self.active or self.h_part is None:
            return
        X, uv, normals = self._lines(frame, pose)
        if len(X) < 6:
            return
        offset, clear = self._splits(frame, uv, normals, search_px)
        self.X, self.n, self.m = X[clear], normals[clear], uv[clear] + offset[clear, None] * normals[clear]
        self.search_px = int(search_px)

    def rows(self) -> LineRows | None:
        return LineRows(self.X, self.n, self.m, self.sigma_px, 1.0, max(1.5, self.search_px / 3)) if len(self.X) >= 6 else None

    def quality(self, frame: Frame, gray: np.ndarray, pose: Pose) -> float:
        if not self.active or self.h_part is None:
            return float("nan")
        X, uv, normals = self._lines(frame, pose)
        if len(X) < 6:
            return float("nan")
        offset, clear = self._splits(frame, uv, normals, QUALITY_SEARCH_PX)
        return float((clear & (np.abs(offset) < INLIER_PX)).mean())


@numba.njit(cache=True, nogil=True)
def best_splits(p, search_px, split_contrast):
    """Each line's most likely split: ``p`` (S, n) float32 posteriors p(part | colour) along S lines,
    n = 2·search_px + 3 samples from inside to outside. The split after sample d−1 maximises
    ``Σ_{i<d} log p_i + Σ_{i≥d} log(1 − p_i)`` (p clipped to 0.02…0.98), refined by a parabola through
    the peak and its neighbours. Returns (offset (S,) px along the line from its centre, clear (S,) bool:
    the mean posterior inside the split exceeds the outside's by ``split_contrast``).

    Compiled: a dozen NumPy passes over a few thousand samples cost more in dispatch than in work, three
    or four times a frame."""
    S, n = p.shape
    offset = np.zeros(S)
    clear = np.zeros(S, np.bool_)
    ll = np.empty(n - 1)
    lq = np.empty(n)
    for s in range(S):
        total_out = 0.0
        total_p = 0.0
        for i in range(n):
            q = min(max(p[s, i], 0.02), 0.98)
            lq[i] = math.log1p(-q)
            total_out += lq[i]
            total_p += q
        inside = 0.0
        outside = total_out
        best, d = -np.inf, 0
        for j in range(n - 1):  # split after sample j
            inside += math.log(min(max(p[s, j], 0.02), 0.98))
            outside -= lq[j]
            ll[j] = inside + outside
            if ll[j] > best:
                best, d = ll[j], j
        a, b, c = ll[max(d - 1, 0)], ll[d], ll[min(d + 1, n - 2)]
        den = a - 2.0 * b + c
        sub = 0.5 * (a - c) / den if (d > 0 and d < n - 2 and den < -1e-9) else 0.0
        offset[s] = d + 0.5 + sub - (search_px + 1)
        mean_in = 0.0
        for i in range(d + 1):
            mean_in += min(max(p[s, i], 0.02), 0.98)
        mean_out = (total_p - mean_in) / (n - d - 1)
        clear[s] = mean_in / (d + 1) - mean_out > split_contrast
    return offset, clear


@numba.njit(cache=True, nogil=True)
def posterior_image(rgb, lut, bins):
    """(h, w) float32 p(part | colour) of the (h, w, 3) uint8 RGB image: ``lut`` (bins³,) indexed by each
    pixel's colour bin (``RegionCue._bins``). One pass, where NumPy makes five over the image."""
    h, w = rgb.shape[0], rgb.shape[1]
    shift = 8 - int(np.log2(bins))
    out = np.empty((h, w), np.float32)
    for y in range(h):
        for x in range(w):
            out[y, x] = lut[((rgb[y, x, 0] >> shift) * bins + (rgb[y, x, 1] >> shift)) * bins + (rgb[y, x, 2] >> shift)]
    return out
