"""The one grey conversion every edge measure shares (fits, qualities, shadows, silhouettes), in a
module below all of them so that none has to import another for it."""
from __future__ import annotations

import cv2
import numpy as np


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB → (H, W) float32 intensity (0..255)."""
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
