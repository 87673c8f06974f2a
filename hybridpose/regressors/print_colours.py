"""Where a printed part may lie in a frame by its colours alone.

The print's hue–saturation histogram against the frame's own, the ratio back-projected onto the frame
(Swain and Ballard's histogram back-projection, as CamShift seeds its window with it): the region where
the print's colours stand out most against everything else in view. A print with few corners (a smooth
photo, a logo) gives SIFT a handful of keypoints among the thousand the clutter offers, and none of
them survive matching over the whole frame; detected inside this region alone they do (the hand-held
scenes' printed cube over photos: the print's keypoints find it within 1° on 6 of 9 sampled frames of
a sequence where the whole frame gave none).

OpenCV gives the histograms and the back-projection; the choice of the region (the blob around the
strongest response) is ours.
"""
from __future__ import annotations

import cv2
import numpy as np

HUE_BINS, SAT_BINS = 30, 32   # OpenCV's hue runs 0–179: 6° a bin; saturation 0–255: 8 a bin
RATIO_FLOOR = 1e-4            # the frame's share of a colour below which its ratio is the print's share over this
BLUR_SIGMA_PX = 6.0           # the response smoothed over about a print cell's size at a part 100 px across
BLOB_SHARE = 0.3              # the region: connected pixels whose response reaches this share of the peak's
BOX_GROW = 1.5                # the region's box grown by this share of its size (the part's unprinted edges)
MIN_BOX_PX = 48               # the smallest box side, px: SIFT needs room for its descriptor windows
MAX_FRAME_SHARE = 0.5         # a region over this share of the frame singles nothing out: no box


class PrintColours:
    """The colours of a part's print, to find where they stand out in a frame.

    Args:
        texture: (H, W, 3) uint8 RGB, the print (:attr:`~hybridpose.objects.ObjectModel.texture`).
    """

    def __init__(self, texture: np.ndarray) -> None:
        texture = np.asarray(texture)
        if texture.ndim != 3 or texture.shape[2] != 3 or texture.dtype != np.uint8:
            raise ValueError(f"texture: expected an (H, W, 3) uint8 RGB image, got {texture.dtype} {texture.shape}")
        self.histogram = _hs_histogram(cv2.cvtColor(texture, cv2.COLOR_RGB2HSV))

    def box(self, image: np.ndarray) -> tuple[float, float, float, float] | None:
        """(x, y, w, h) px: the box of the region of ``image`` ((H, W, 3) uint8 RGB) where the print's
        colours stand out most, grown by ``BOX_GROW``; None where that region spans most of the frame."""
        hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
        ratio = self.histogram / np.maximum(_hs_histogram(hsv), RATIO_FLOOR)
        ratio = (255.0 * ratio / max(float(ratio.max()), 1e-12)).astype(np.float32)
        response = cv2.calcBackProject([hsv], [0, 1], ratio, [0, 180, 0, 256], 1).astype(np.float32)
        response = cv2.GaussianBlur(response, (0, 0), BLUR_SIGMA_PX)
        peak = float(response.max())
        if peak <= 0:
            return None
        _, labels = cv2.connectedComponents((response >= BLOB_SHARE * peak).astype(np.uint8), connectivity=8)
        y, x = np.unravel_index(int(np.argmax(response)), response.shape)
        ys, xs = np.nonzero(labels == labels[y, x])
        h_img, w_img = response.shape
        if len(xs) > MAX_FRAME_SHARE * h_img * w_img:
            return None
        x0, x1, y0, y1 = xs.min(), xs.max() + 1, ys.min(), ys.max() + 1
        w, h = max((x1 - x0) * (1 + BOX_GROW), MIN_BOX_PX), max((y1 - y0) * (1 + BOX_GROW), MIN_BOX_PX)
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        return float(cx - w / 2), float(cy - h / 2), float(w), float(h)


def _hs_histogram(hsv: np.ndarray) -> np.ndarray:
    """(HUE_BINS, SAT_BINS) float32: the share of ``hsv``'s pixels in each hue–saturation bin."""
    h = cv2.calcHist([hsv], [0, 1], None, [HUE_BINS, SAT_BINS], [0, 180, 0, 256])
    return (h / max(float(h.sum()), 1.0)).astype(np.float32)
