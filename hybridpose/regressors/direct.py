"""The direct (VGG) regressors' inference, the paper's models: the whole frame in, translation (m) and
quaternion (w, x, y, z) out; the parallel VGG-19's rotation stream sees a crop around the object
(its "bounded image"). :class:`~hybridpose.regressors.predictor.CheckpointRegressor` runs it for
checkpoints of a direct model; the keypoint models' path is the rest of that module.
"""
from __future__ import annotations

from typing import Callable

import cv2
import numpy as np
import torch

from ..geometry import Camera
from ..geometry.crops import crop_box, crop_image
from .detection import CROP_MARGIN, detected_crop, translation_crop

ToTensor = Callable[[np.ndarray], torch.Tensor]  # (H, W, 3) uint8 RGB → the network's (1, 3, H, W) input


def bounded_image(net, image: np.ndarray, cam: Camera, image_size: int, to_tensor: ToTensor, roi=None,
                  diameter_m: float = 0.5, x: torch.Tensor | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The parallel model's translation stream on the undistorted ``image`` and the crop its rotation
    stream sees: (t (3,) m, (S, S, 3) uint8 "bounded image"). The crop is around ``roi`` (x, y, w, h
    px) or, without one, around the detected object, else around the projection of its own
    translation sized by the object's ``diameter_m`` (:func:`translation_crop`). ``x``: the resized
    frame's tensor, when the caller has it."""
    if x is None:
        x = to_tensor(cv2.resize(image, (image_size,) * 2, interpolation=cv2.INTER_AREA))
    t = net.translation(x)[0].float().cpu().numpy().astype(np.float64)
    box = (crop_box(roi, CROP_MARGIN) if roi is not None
           else detected_crop(image) or translation_crop(t, cam.K, diameter_m))
    return t, crop_image(image, cam.K, *box, (image_size, image_size))[0]


def direct_pose(net, model_name: str, image: np.ndarray, cam: Camera, image_size: int, to_tensor: ToTensor,
                roi=None, diameter_m: float = 0.5) -> tuple[np.ndarray, np.ndarray] | None:
    """(t (3,) m, unit q (4,) w-x-y-z) of a direct model on the undistorted ``image`` of camera ``cam``
    (OpenCV frame), or None where the output names no pose in front of the camera whose centre falls
    inside the image (a direct regressor has no per-image residual to tell a bad answer by)."""
    x = to_tensor(cv2.resize(image, (image_size, image_size), interpolation=cv2.INTER_AREA))
    if model_name == "parallel-vgg19":
        t, crop = bounded_image(net, image, cam, image_size, to_tensor, roi, diameter_m, x)
        q = net.rotation(to_tensor(crop))[0].float().cpu().numpy().astype(np.float64)
    else:
        t_, q_ = net(x)
        t, q = t_[0].float().cpu().numpy().astype(np.float64), q_[0].float().cpu().numpy().astype(np.float64)
    q_norm = np.linalg.norm(q)
    # a raw quaternion of (near) zero length names no rotation: a network with zero biases gives it
    # on a black frame (every ReLU off), so it is a lost view, not a NaN pose
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))) or t[2] <= 0 or q_norm < 1e-12:
        return None
    uv = cam.K @ (t / t[2])
    if not (0 <= uv[0] < cam.width and 0 <= uv[1] < cam.height):
        return None
    return t, q / q_norm
