"""How well a frame shows a printed part's own print at a pose (:attr:`ObjectModel.texture`).

A start the edges confirm may lay the part's outline on something of its shape: a bottle's label, a
picture inside one of the part's own faces. Where the part's print is known, the image inside the
projected part must look like it. Each pixel the part covers at the pose is lifted onto its facet
(:meth:`ModelView.lift`) and mapped onto the print through that facet's texture coordinates; the
grey image and the grey print are compared by normalised cross-correlation facet by facet (each
face has its own light) and the facets' scores averaged by their pixels. For a part whose shape has
symmetries the print decides among them: the best of the equivalent poses is the score.

Written here rather than rendered with MuJoCo: a check inside the estimator needs no GL context,
and a planar facet's print is an affine function of the point on it (a UV unwrap of flat faces), so
the facet-id raster and one 2 × 4 map per facet give the print at every pixel. Facets whose texture
coordinates are not affine on them (a curved, seamed unwrap) are left out of the score.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..core import Frame
from ..geometry import Pose
from .image import to_gray
from .model_view import ModelView

AFFINE_TOL = 0.01   # texture-coordinate units: a facet whose corners leave its affine map by more is left out
BORDER_PX = 2       # pixels this near a facet border or the outline are left out (blur, a misfit of a pixel)
MAX_PIXELS = 4000   # at most this many pixels compared (evenly spaced)
MIN_FACET_PIXELS = 30  # a facet showing fewer pixels is left out (its correlation is noise)


class PrintView:
    """The print of ``view``'s object at each pixel of a pose (needs :attr:`ObjectModel.texture`).

    Raises:
        ValueError: the object carries no print, or none of its facets maps affinely onto it.
    """

    def __init__(self, view: ModelView) -> None:
        obj = view.object
        if obj.texture is None:
            raise ValueError(f"object: {obj.name!r} carries no print (ObjectModel.texture)")
        self.view = view
        # a pyramid of the grey print: a face a few dozen pixels across shows the print many texels to a
        # pixel, and sampling the full print there gives aliasing, not what the camera sees
        self.levels = [cv2.cvtColor(np.ascontiguousarray(obj.texture), cv2.COLOR_RGB2GRAY).astype(np.float32)]
        while min(self.levels[-1].shape) > 16:
            self.levels.append(cv2.pyrDown(self.levels[-1]))
        self.maps = np.full((len(view.plane_point), 4, 2), np.nan)   # per facet id: [X, 1] → (u, v)
        ids = np.unique(view.facet_of)
        centroids = np.zeros((len(view.plane_point), 3))
        for fid in ids:
            tris = np.nonzero(view.facet_of == fid)[0]
            corners = view.triangles[tris].reshape(-1, 3)
            centroids[fid] = corners.mean(0)
            A = np.c_[corners, np.ones(len(corners))]
            uv = np.asarray(obj.face_uv[tris], dtype=np.float64).reshape(-1, 2)
            M = np.linalg.lstsq(A, uv, rcond=None)[0]
            if np.abs(A @ M - uv).max() <= AFFINE_TOL:
                self.maps[fid] = M
        if not np.isfinite(self.maps).any():
            raise ValueError(f"object: no facet of {obj.name!r} maps affinely onto its print (a curved unwrap)")
        # the shape's symmetries permute its facets: the pose's equivalents are scored from one raster
        self.branches = (Pose.identity(), *obj.symmetries)
        self._facets_of_branch = []
        for S in self.branches:
            seen = S.inverse() @ centroids[ids]  # where each facet's centre lies on the part turned by S
            perm = np.zeros(len(view.plane_point), np.int64)
            perm[ids] = ids[np.argmin(np.linalg.norm(seen[:, None] - centroids[ids][None], axis=2), axis=1)]
            self._facets_of_branch.append(perm)

    def score(self, frame: Frame, pose: Pose, gray: np.ndarray | None = None, max_pixels: int = MAX_PIXELS) -> float:
        """Pixel-weighted mean over the visible facets of the correlation (−1..1) between the grey
        image (``gray``: (H, W) float32, computed when None) and the grey print at ``pose``, over at
        most ``max_pixels`` pixels (evenly spaced); NaN where fewer than ``MIN_FACET_PIXELS`` pixels of
        any mapped facet show."""
        return float(self.branch_scores(frame, pose, gray, branches=[0], max_pixels=max_pixels)[0])

    def branch_scores(self, frame: Frame, pose: Pose, gray: np.ndarray | None = None, branches=None,
                      max_pixels: int = MAX_PIXELS) -> np.ndarray:
        """:meth:`score` of ``pose @ S`` for each ``S`` of :attr:`branches` (indices ``branches``; all
        where None), from one raster of ``pose``: the pixel that sees point ``X`` at ``pose`` sees
        ``S⁻¹ X`` at ``pose @ S``, on the facet ``S⁻¹`` takes ``X``'s to."""
        camera = frame.camera
        branches = range(len(self.branches)) if branches is None else branches
        ids = self.view.facet_ids(pose, camera, scale=1.0)
        # within the part's box only (grown past the border test's reach: the same pixels as the whole
        # frame's); a full frame's mask and np.nonzero cost more than the comparison itself
        bx, by, bw, bh = cv2.boundingRect((ids > 0).astype(np.uint8))
        if bw == 0:
            return np.full(len(branches), np.nan)
        pad = BORDER_PX + 1
        x0, y0 = max(bx - pad, 0), max(by - pad, 0)
        box = ids[y0:by + bh + pad, x0:bx + bw + pad]
        k = np.ones((2 * BORDER_PX + 1,) * 2, np.uint8)
        ys, xs = np.nonzero((box > 0) & (cv2.dilate(box, k) == cv2.erode(box, k)))
        if len(xs) == 0:
            return np.full(len(branches), np.nan)
        ys, xs = ys + y0, xs + x0
        step = max(1, len(xs) // max_pixels)
        ys, xs = ys[::step], xs[::step]
        f = ids[ys, xs].astype(np.int64)
        points, ok = self._lifted(pose, camera, xs, ys, ids)
        seen = (to_gray(frame.image) if gray is None else gray)[ys, xs].astype(np.float64)
        out = []
        for b in branches:
            S_inv = self.branches[b].inverse()
            f_b = self._facets_of_branch[b][f]
            out.append(self._correlation(seen, f_b, [S_inv @ X for X in points], ok & np.isfinite(self.maps[f_b, 0, 0])))
        return np.array(out)

    def image(self, pose: Pose, camera) -> np.ndarray:
        """The grey print as ``camera`` sees the part at ``pose``: (H, W) uint8, 0 off the part and on
        facets that do not map onto the print (an untextured light: what a matcher of image points
        learns the print's look from)."""
        ids = self.view.facet_ids(pose, camera, scale=1.0)
        ys, xs = np.nonzero(ids)
        out = np.zeros(ids.shape, np.uint8)
        if len(xs) == 0:
            return out
        f = ids[ys, xs].astype(np.int64)
        points, ok = self._lifted(pose, camera, xs, ys, ids)
        ok &= np.isfinite(self.maps[f, 0, 0])
        values = self._printed(f, points)
        out[ys[ok], xs[ok]] = np.clip(values[ok], 0, 255).astype(np.uint8)
        return out

    def _lifted(self, pose: Pose, camera, xs: np.ndarray, ys: np.ndarray, ids: np.ndarray) -> tuple[list, np.ndarray]:
        """The model points seen at pixels (``xs``, ``ys``) (N,) and at their right and lower
        neighbours (three (N, 3) arrays: the neighbours only measure how many texels a pixel covers),
        and where the pixel itself sees the part (N,) bool; ``ids``: the pose's facet-id raster."""
        lifted = [self.view.lift(pose, camera, np.c_[xs + dx, ys + dy].astype(np.float64), ids=ids)
                  for dx, dy in ((0, 0), (1, 0), (0, 1))]
        return [X for X, _ in lifted], lifted[0][1]

    def _printed(self, f: np.ndarray, points: list) -> np.ndarray:
        """The grey print (N,) float at the model points ``points`` (the pixel's and its two
        neighbours', each (N, 3)) on facets ``f`` (N,), from the pyramid level whose texel matches
        the pixel's footprint."""
        h, w = self.levels[0].shape
        texels = [np.einsum("nk,nkj->nj", np.c_[X, np.ones(len(X))], np.nan_to_num(self.maps[f])) * (w, h)
                  for X in points]
        level = footprint_level(texels[1] - texels[0], texels[2] - texels[0], len(self.levels))
        # OBJ's v counts up from the print's bottom row; coordinates outside [0, 1] repeat it
        u, v = np.mod(texels[0][:, 0] / w, 1.0), 1.0 - np.mod(texels[0][:, 1] / h, 1.0)
        printed = np.zeros(len(f), np.float64)
        for lv in np.unique(level):
            sel = level == lv
            img = self.levels[lv]
            col, row = u[sel] * (img.shape[1] - 1), v[sel] * (img.shape[0] - 1)
            printed[sel] = cv2.remap(img, col.astype(np.float32)[None], row.astype(np.float32)[None],
                                     cv2.INTER_LINEAR)[0]
        return printed

    def _correlation(self, seen: np.ndarray, f: np.ndarray, points: list, ok: np.ndarray) -> float:
        """The facet-by-facet correlation of the grey values ``seen`` (N,) with the print at the model
        points ``points`` (the pixel's and its two neighbours', each (N, 3)) on facets ``f`` (N,)."""
        printed = self._printed(f, points)
        total, weight = 0.0, 0
        for fid in np.unique(f[ok]):
            sel = ok & (f == fid)
            if sel.sum() < MIN_FACET_PIXELS:
                continue
            a, b = seen[sel] - seen[sel].mean(), printed[sel] - printed[sel].mean()
            denom = np.sqrt((a * a).sum() * (b * b).sum())
            if denom <= 1e-9:
                continue
            total += float((a * b).sum() / denom) * sel.sum()
            weight += int(sel.sum())
        return total / weight if weight else float("nan")


def footprint_level(du: np.ndarray, dv: np.ndarray, levels: int) -> np.ndarray:
    """(N,) int: the level of a print's pyramid (``levels`` of them, each half the last) whose texel
    matches a pixel's footprint — ``du``, ``dv`` (N, 2): the texels between the pixel and its right and
    lower neighbours (the footprint's area, as its side; level 0 where it is undefined)."""
    footprint = np.sqrt(np.abs(du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0]))
    return np.clip(np.round(np.log2(np.maximum(np.nan_to_num(footprint, nan=1.0), 1.0))), 0, levels - 1).astype(int)


@dataclass(frozen=True)
class PrintAgreement:
    """:func:`print_agreement`'s answer: the best and second-best :meth:`PrintView.score` among a pose
    and its equivalents under the object's shape symmetries (NaN where none / fewer than two scored),
    and the symmetry ``S`` whose ``pose @ S`` scored best (None where none did)."""

    best: float
    runner_up: float
    branch: Pose | None

    def singles_out(self, margin: float) -> bool:
        """Whether the print picks one pose: the best beats the second best by ``margin`` (an
        asymmetric object: the best reaches ``margin``). A right pose of a printed cube scores its own
        branch 0.5–0.7 and the next 0.1–0.35 on ViSP's MegaPose cube video; its outline laid on a
        bottle's label or inside one of its own faces 0.44–0.53 and 0.34–0.45."""
        if not np.isfinite(self.best):
            return False
        if not np.isfinite(self.runner_up):
            return self.best >= margin
        return self.best - self.runner_up >= margin


def print_agreement(print_view: PrintView, frame: Frame, pose: Pose, gray: np.ndarray | None = None) -> PrintAgreement:
    """:meth:`PrintView.score` of ``pose`` and of its equivalents ``pose @ S`` under the object's shape
    symmetries: which of them the print shows is the image's to say."""
    scores = print_view.branch_scores(frame, pose, gray)
    order = [k for k in np.argsort(-np.nan_to_num(scores, nan=-np.inf)) if np.isfinite(scores[k])]
    if not order:
        return PrintAgreement(float("nan"), float("nan"), None)
    runner_up = float(scores[order[1]]) if len(order) > 1 else float("nan")
    return PrintAgreement(float(scores[order[0]]), runner_up, print_view.branches[order[0]])
