"""Square image crops and the intrinsics that go with them: where the CNN regressors and their
training data cut the object out of a frame (pixel centres at integer coordinates)."""
from __future__ import annotations

import cv2
import numpy as np

MIN_CROP_PX = 16  # no crop is smaller than this many pixels a side


def crop_box(bbox_xywh, margin: float = 1.2) -> tuple[float, float, float]:
    """Square crop ``(cx, cy, side)`` in pixels around a BOP bbox, ``side = margin · max(w, h)``."""
    x, y, w, h = (float(v) for v in bbox_xywh)
    if w <= 0 or h <= 0:
        raise ValueError(f"bbox: expected positive width and height, got {bbox_xywh}")
    return x + (w - 1) / 2, y + (h - 1) / 2, max(MIN_CROP_PX, margin * max(w, h))


def crop_affine(cx: float, cy: float, side: float, out_w: int, out_h: int) -> np.ndarray:
    """(2, 3) affine mapping source pixels to crop pixels (pixel centres at integers)."""
    sx, sy = out_w / side, out_h / side
    return np.array([[sx, 0.0, (out_w - 1) / 2 - sx * cx], [0.0, sy, (out_h - 1) / 2 - sy * cy]])


def crop_image(image: np.ndarray, K: np.ndarray, cx: float, cy: float, side: float, size: tuple[int, int]):
    """The square ``(cx, cy, side)`` (source pixels) of ``image`` resampled to ``size`` (W, H), and the
    intrinsics of the crop; outside the frame is black (space). Training and inference share it so
    the network sees the same resampling in both."""
    w, h = size
    A = crop_affine(cx, cy, side, w, h)
    out = cv2.warpAffine(image, A, (w, h), flags=cv2.INTER_AREA if side > w else cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out, np.vstack([A, [0, 0, 1]]) @ K


def projection_roi(points_obj, pose, camera, margin: float) -> tuple[int, int, int, int] | None:
    """Box (x, y, w, h) px of the (N, 3) object-frame points (metres; e.g. an object's bounding-box
    corners) projected at ``pose`` (a :class:`~hybridpose.geometry.Pose`, object→camera), grown by
    ``margin`` (a share of its size) on each side: where a CNN check looks. None (the CNN then takes
    the whole image) without a pose, where it does not overlap the image, or where the points reach
    behind the camera (a prediction coasting ever closer: the object would overflow the view)."""
    if pose is None:
        return None
    box = camera.image_box(points_obj, pose)
    if box is None:
        return None
    x0, y0, x1, y1 = box
    x0, x1 = x0 - margin * (x1 - x0), x1 + margin * (x1 - x0)
    y0, y1 = y0 - margin * (y1 - y0), y1 + margin * (y1 - y0)
    x0, y0 = max(x0, 0.0), max(y0, 0.0)
    x1, y1 = min(x1, camera.width - 1.0), min(y1, camera.height - 1.0)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    return int(x0), int(y0), int(np.ceil(x1 - x0)), int(np.ceil(y1 - y0))


def box_iou(a, b) -> float:
    """Intersection over union of two boxes (x, y, w, h) px; 0 where they do not overlap."""
    iw = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = iw * ih
    return inter / (a[2] * a[3] + b[2] * b[3] - inter) if inter > 0 else 0.0
