"""The one grey conversion every edge measure shares (fits, qualities, shadows, silhouettes), in a
module below all of them so that none has to import another for it."""
from __future__ import annotations

import cv2
import numpy as np


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB → (H, W) float32 intensity (0..255)."""
    return to_gray8(image).astype(np.float32)


def to_gray8(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB → (H, W) uint8 intensity: :func:`to_gray` before its float conversion (what
    KLT and corner detection take)."""
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
