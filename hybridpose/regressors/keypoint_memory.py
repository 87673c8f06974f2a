"""Find the part by the look of its surface: image keypoints (SIFT) stored with the model points under
them, matched in a new frame, the pose by RANSAC PnP — what ViSP's keypoint detection tutorial and
SPN-free relocalisers do, on a CPU in tens of milliseconds.

The views come from two sources:

- the part's print (:attr:`ObjectModel.texture`), rendered from directions all around it before any
  frame (:meth:`KeypointMemory.from_print`): a printed part is found from the first frame;
- the user's own frames where the track is sure (:meth:`KeypointMemory.learn`): the part as this camera,
  this light and this print show it, whether or not the CAD model carries the print. After the track
  is lost the part is found again by its look, not by a network's guess.

A network trained on renders answers every frame within tens of degrees; the memory answers few frames
with nothing, but a pose it gives agrees with dozens of points to a few pixels. Each answer is still a
candidate: the hybrid's tracker must confirm it like a CNN's (:func:`hybridpose.starts.confirmed_start`).

Written here, not taken from a library: OpenCV gives the detector, the matcher and the PnP; which points
to keep (on the part's surface, fixed on it, one view per direction) and the ratio test among distinct
model points (a point stored from several views has several near-identical descriptors) are the part's.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..core import Frame, Measurement
from ..edges import ModelView, to_gray8
from ..edges.silhouette import LIT_PIXEL_GREY
from ..edges.print_match import PrintView
from ..geometry import Camera, Pose, facing_pose, sphere_directions
from .keypoint_pnp import solve_pnp
from .print_colours import PrintColours

# Lowe's ratio test: the best match's distance below this share of the nearest match to another point
MATCH_RATIO = 0.8
# fewer RANSAC inliers than this is no answer: a wrong pose among a thousand cluttered keypoints gathers
# up to 8 by chance on ViSP's cube videos
MIN_INLIERS = 15
INLIER_PX = 4.0              # RANSAC's reprojection threshold, px (SIFT's keypoints are good to ~1 px)
RANSAC_ITERATIONS = 1000     # at 20 % inliers and 4-point samples 0.999 confidence needs ~4 300; the
                             # answers that matter carry more than a third of the matches (~400 suffice)
FEATURES = 1500              # keypoints detected per frame (SIFT's strongest)
# SIFT's contrast threshold (OpenCV's default 0.04): a print on a shaded face under a camera's noise
# shows weak corners; at 0.01 the print alone finds ViSP's MegaPose cube in a tracker's basin on 68 of 76
# sampled frames (64 at 0.04), and low-contrast prints of the hand-held scenes at all (tuning seeds)
CONTRAST_THRESHOLD = 0.01
# image kept around a mask's box when detecting in it, px: SIFT's descriptor window reaches ~20 px past a
# keypoint at the scales a part a hundred pixels across shows
BOX_MARGIN_PX = 24
# a descriptor nearer than this to a stored point's is the same point seen again (model units: metres)
SAME_POINT_M = 0.004
LEARN_STEP_DEG = 15.0        # a frame is learned where it sees the part from this far from every stored view
MAX_VIEWS = 48               # the most views kept (the print's and the learned ones); SIFT handles ±30° tilt
SOURCE = "regressor:keypoints"  # the memory's answers' Measurement.source
FLANN_SEED = 0                # the KD-trees' random splits (see _build_index)
PIXEL_SIGMA = 1.5            # px: the noise of a matched keypoint, for the answer's covariance
MIN_SIGMA_DEG, MIN_SIGMA_M = 1.0, 0.003  # the answer's covariance floor: a PnP on one face's points is surer
                                         # than the pose it gives when the print was learned off by a degree


@dataclass
class _Views:
    descriptors: list
    points: list
    directions: list  # unit vectors, object frame: where each view's camera stood
    tried: list       # the same for views that showed too few keypoints to keep (not tried again)


class KeypointMemory:
    """Keypoints of ``view``'s object with their model points, found again in a frame.

    Args:
        view: the object's :class:`~hybridpose.edges.ModelView` (its facets lift pixels onto the model).
        features: keypoints detected per image.
        max_views: the most views kept.
    """

    def __init__(self, view: ModelView, features: int = FEATURES, max_views: int = MAX_VIEWS) -> None:
        self.view = view
        self.max_views = int(max_views)
        self._sift = cv2.SIFT_create(nfeatures=int(features), contrastThreshold=CONTRAST_THRESHOLD)
        self._views = _Views([], [], [], [])
        self._index = None  # cv2.flann_Index over every stored descriptor, built when first needed
        self._all_points = np.zeros((0, 3))
        self._colours = None  # the print's colours (from_print): where to look again when the frame gives nothing

    @classmethod
    def from_print(cls, printed: PrintView, camera: Camera, directions: int = 26, fill: float = 0.5,
                   **kw) -> KeypointMemory:
        """A memory holding the print of ``printed``'s part (its :class:`~hybridpose.edges.print_match.
        PrintView`) seen from ``directions`` directions spread over the sphere, at the distance where the
        part spans ``fill`` of ``camera``'s shorter side (SIFT finds its keypoints again from about half
        to twice that size)."""
        view = printed.view
        memory = cls(view, **kw)
        memory._colours = PrintColours(view.object.texture)
        distance = view.object.diameter * camera.K[0, 0] / (fill * min(camera.width, camera.height))
        for direction in sphere_directions(directions):
            pose = facing_pose(direction, distance)
            memory._add(printed.image(pose, camera), pose, camera)
        return memory

    @classmethod
    def for_part(cls, view: ModelView, camera: Camera, printed: PrintView | None, **kw) -> KeypointMemory:
        """The memory of ``view``'s object for ``camera``: holding its print (:meth:`from_print`) where
        ``printed`` gives it (the caller's :class:`~hybridpose.edges.print_match.PrintView`, made once:
        :func:`hybridpose.starts.print_view`), else empty until it learns."""
        return cls(view, **kw) if printed is None else cls.from_print(printed, camera, **kw)

    @property
    def views(self) -> int:
        """How many views the memory holds."""
        return len(self._views.directions)

    @property
    def points(self) -> int:
        """How many keypoints the memory holds."""
        return sum(len(p) for p in self._views.points)

    def wants(self, pose: Pose) -> bool:
        """Whether a frame at ``pose`` would be learned: the memory has room and no stored view sees
        the part from within ``LEARN_STEP_DEG`` of its direction (nor showed too few keypoints from
        there: a plain part on black space shows a handful, and is not looked at again each frame)."""
        if len(self._views.directions) >= self.max_views:
            return False
        seen = self._views.directions + self._views.tried
        if not seen:
            return True
        cos = float(np.max(np.asarray(seen) @ _direction(pose)))
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) >= LEARN_STEP_DEG

    def learn(self, frame: Frame, pose: Pose) -> int:
        """Store the keypoints ``frame`` shows on the part at ``pose`` (``T_cam_obj``, a pose the caller
        is sure of) where the memory :meth:`wants` it; returns how many were stored (0: none)."""
        return self._add(_gray8(frame), pose, frame.camera) if self.wants(pose) else 0

    def find(self, frame: Frame, roi: tuple[float, float, float, float] | None = None) -> Measurement | None:
        """The part's pose in ``frame`` from its keypoints (within ``roi`` = (x, y, w, h) px where given),
        or None where fewer than ``MIN_INLIERS`` matches agree on one. With no ``roi`` and nothing found
        in the whole frame, a memory holding a print looks again where the print's colours stand out
        (:class:`~hybridpose.regressors.print_colours.PrintColours`): there a smooth print's few
        keypoints are not outnumbered by the clutter's."""
        found = self._find(frame, roi)
        if found is None and roi is None and self._colours is not None and self._views.descriptors:
            box = self._colours.box(frame.image)
            found = None if box is None else self._find(frame, box)
        return found

    def _find(self, frame: Frame, roi: tuple[float, float, float, float] | None) -> Measurement | None:
        if self._index is None:
            if not self._views.descriptors:
                return None
            self._build_index()
        gray = _gray8(frame)
        # the lit pixels only: on black space SIFT's pyramid over the dark costs what finds nothing
        mask = cv2.dilate((gray > LIT_PIXEL_GREY).astype(np.uint8) * 255, np.ones((9, 9), np.uint8))
        if roi is not None:
            x, y, w, h = (int(round(v)) for v in roi)
            box = np.zeros_like(mask)
            box[max(y, 0):max(y + h, 0), max(x, 0):max(x + w, 0)] = 255
            mask &= box
        uv, descriptors = self._detect(gray, mask)
        if len(uv) < MIN_INLIERS:
            return None
        uv, X = self._matches(uv, descriptors)
        if len(uv) < MIN_INLIERS:
            return None
        result = self._pose(uv, X, frame.camera.K)
        if result is None:
            return None
        covariance = np.linalg.pinv(result.information) * max(result.rms_px, PIXEL_SIGMA) ** 2
        floor = np.r_[np.full(3, np.radians(MIN_SIGMA_DEG) ** 2), np.full(3, MIN_SIGMA_M ** 2)]
        covariance = covariance + np.diag(floor)
        inliers = int(result.inliers.sum())
        return Measurement(result.pose, covariance, min(1.0, inliers / (4 * MIN_INLIERS)), SOURCE,
                           frame.timestamp)

    # --- helpers -----------------------------------------------------------------------------------
    def _add(self, gray: np.ndarray, pose: Pose, camera: Camera) -> int:
        ids = self.view.facet_ids(pose, camera, scale=1.0)
        # keypoints off the outline: a corner there mixes the part with whatever lies behind it
        inner = cv2.erode((ids > 0).astype(np.uint8) * 255, np.ones((7, 7), np.uint8))
        uv, descriptors = self._detect(gray, inner)
        ok = np.zeros(len(uv), bool)
        if len(uv):
            X, ok = self.view.lift(pose, camera, uv, ids=ids)
            ok &= self.view.surface_fixed(pose, camera, uv, ids)
        if ok.sum() < MIN_INLIERS:
            self._views.tried.append(_direction(pose))
            return 0
        self._views.descriptors.append(descriptors[ok].astype(np.float32))
        self._views.points.append(X[ok])
        self._views.directions.append(_direction(pose))
        self._index = None
        return int(ok.sum())

    def _detect(self, gray: np.ndarray, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """SIFT keypoints (N, 2) px and descriptors (N, 128) float32 of the (H, W) uint8 ``gray`` image
        within ``mask`` (detected on the mask's box only: SIFT's pyramid costs by the pixel)."""
        x0 = y0 = 0
        if mask is not None:
            x, y, w, h = cv2.boundingRect(mask)
            if w == 0:
                return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
            x0, y0 = max(x - BOX_MARGIN_PX, 0), max(y - BOX_MARGIN_PX, 0)
            x1, y1 = min(x + w + BOX_MARGIN_PX, gray.shape[1]), min(y + h + BOX_MARGIN_PX, gray.shape[0])
            gray, mask = gray[y0:y1, x0:x1], mask[y0:y1, x0:x1]
        keypoints, descriptors = self._sift.detectAndCompute(np.ascontiguousarray(gray), mask)
        if descriptors is None or not keypoints:
            return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
        return np.array([k.pt for k in keypoints], np.float64) + (x0, y0), descriptors.astype(np.float32)

    def _build_index(self) -> None:
        self._all_points = np.concatenate(self._views.points)
        # FLANN's KD-trees: a brute-force match of 1 500 keypoints against thousands costs ~0.1 s. Their
        # random splits draw from OpenCV's generator: seeded, the same views give the same matches (unseeded,
        # the print's keypoints alone moved from 6 to 4 of 18 frames in basin between two builds)
        cv2.setRNGSeed(FLANN_SEED)
        self._index = cv2.flann_Index(np.concatenate(self._views.descriptors), {"algorithm": 1, "trees": 4})

    def _matches(self, uv: np.ndarray, descriptors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(uv (M, 2) px, model points (M, 3)) of the keypoints at ``uv`` whose nearest stored descriptor
        passes the ratio test against the nearest descriptor of another model point."""
        k = min(4, len(self._all_points))
        train, dist2 = self._index.knnSearch(descriptors, k, params={"checks": 64})  # squared L2
        X = self._all_points[train]                                          # (N, k, 3)
        other = np.linalg.norm(X[:, 1:] - X[:, :1], axis=2) > SAME_POINT_M    # (N, k - 1)
        # the nearest descriptor of another point (none among the k: all the same point, kept)
        second = np.full(len(uv), np.inf)
        has = other.any(1)
        second[has] = dist2[:, 1:][has, np.argmax(other[has], 1)]
        keep = dist2[:, 0] < MATCH_RATIO ** 2 * second
        return uv[keep], X[keep, 0]

    def _pose(self, uv: np.ndarray, X: np.ndarray, K: np.ndarray):
        """OpenCV's USAC (RANSAC over minimal P3P solves with local optimisation, seeded: most matches in a
        cluttered frame are wrong), then the inliers' refined fit and its information
        (:func:`~hybridpose.regressors.keypoint_pnp.solve_pnp`)."""
        params = cv2.UsacParams()
        params.threshold, params.confidence, params.maxIterations = INLIER_PX, 0.999, RANSAC_ITERATIONS
        params.randomGeneratorState = 0  # the same frame, the same answer
        try:
            ok, _, _, _, idx = cv2.solvePnPRansac(np.ascontiguousarray(X.reshape(-1, 1, 3)),
                                                  np.ascontiguousarray(uv.reshape(-1, 1, 2)), K, None, params=params)
        except cv2.error:  # degenerate samples
            return None
        if not ok or idx is None or len(idx) < MIN_INLIERS:
            return None
        idx = idx.ravel()
        return solve_pnp(uv[idx], X[idx], K, threshold_px=INLIER_PX, min_inliers=MIN_INLIERS,
                         outliers="drop-worst-only")


def _gray8(frame: Frame) -> np.ndarray:
    """The frame's (H, W) uint8 grey image (SIFT reads 8-bit images)."""
    return to_gray8(np.ascontiguousarray(frame.image))


def _direction(pose: Pose) -> np.ndarray:
    """Unit vector (3,) from the object's origin towards the camera, object frame."""
    d = -pose.R.T @ pose.t
    return d / np.linalg.norm(d)
