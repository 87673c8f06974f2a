"""What a real camera does to an image after the optics, for training views of a part on a bench or in
a hand: the hand's motion during the exposure (linear motion blur), auto-exposure and white balance
(gains), sensor noise and JPEG compression. A network trained on clean renders meets all of them in a
user's footage at once.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..geometry import as_rgb_image

# ranges drawn per training view, chosen to cover the hand-held scenes' (hybridpose.render.handheld:
# blur of half a frame's 5–30 px motion, exposure gains, noise σ 3, JPEG 75–95) and a webcam's darker
# and harsher ends
EXPOSURE_LOG_SIGMA, EXPOSURE_RANGE = 0.3, (0.5, 2.0)  # exposure gain exp(N(0, σ)), clipped: a stop either way
WHITE_BALANCE_LOG_SIGMA = 0.07  # per-channel gain exp(N(0, σ)): a few hundred kelvin either way
BLUR_SHARE, BLUR_PX = 0.5, (2.0, 14.0)  # share of views blurred, and the streak's length range (px)
NOISE_GREY = (0.0, 4.0)  # sensor noise σ range, grey levels
JPEG_SHARE, JPEG_QUALITY = 0.7, (40, 95)  # share of views compressed, and the quality range


def motion_blur(image: np.ndarray, direction, length_px: float) -> np.ndarray:
    """``image`` (H, W, C) uint8 smeared along the unit image ``direction`` (2,) over ``length_px``
    pixels (a straight streak: the exposure's motion); unchanged below a pixel."""
    if length_px < 1.0:
        return image
    size = int(np.ceil(length_px)) | 1
    kernel = np.zeros((size, size), np.float32)
    c = size // 2
    direction = np.asarray(direction, np.float64)
    a = np.round(c + direction * length_px / 2).astype(int)
    b = np.round(c - direction * length_px / 2).astype(int)
    cv2.line(kernel, tuple(int(v) for v in a), tuple(int(v) for v in b), 1.0, 1)
    return cv2.filter2D(image, -1, kernel / kernel.sum())


def jpeg(image: np.ndarray, quality: int) -> np.ndarray:
    """``image`` (H, W, 3) uint8 RGB through JPEG at ``quality`` (1–100) and back."""
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("cv2.imencode failed to write a JPEG")
    return np.ascontiguousarray(cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1])


def camera_effects(image: np.ndarray, rng: np.random.Generator | int | None = None,
                   grey_share: float = 0.0) -> np.ndarray:
    """(H, W, 3) uint8 RGB → the same with one draw of motion blur, exposure and white-balance gains,
    noise and JPEG (ranges: this module's constants), seeded by ``rng``; ``grey_share`` of the draws
    then come out grey in all three channels (a monochrome camera: ViSP's videos, most machine-vision
    and space cameras)."""
    image = as_rgb_image(image)
    rng = np.random.default_rng(rng)
    if rng.random() < BLUR_SHARE:
        angle = rng.uniform(0.0, np.pi)
        image = motion_blur(image, (np.cos(angle), np.sin(angle)), rng.uniform(*BLUR_PX))
    gain = np.clip(np.exp(rng.normal(0.0, EXPOSURE_LOG_SIGMA)), *EXPOSURE_RANGE)
    gains = gain * np.exp(rng.normal(0.0, WHITE_BALANCE_LOG_SIGMA, 3))
    noise = np.empty(image.shape, np.float32)
    # OpenCV's generator, seeded from ``rng``: numpy's normal draws took 17 ms a 640×480 image, cv2.randn 4
    cv2.setRNGSeed(int(rng.integers(2**31)))
    cv2.randn(noise, 0.0, float(rng.uniform(*NOISE_GREY)))
    noisy = image.astype(np.float32) * gains.astype(np.float32) + noise
    image = np.clip(noisy, 0, 255).astype(np.uint8)
    if rng.random() < JPEG_SHARE:
        image = jpeg(image, int(rng.integers(JPEG_QUALITY[0], JPEG_QUALITY[1] + 1)))
    if grey_share > 0 and rng.random() < grey_share:  # drawn last: the other draws of a seed stay as they were
        image = np.repeat(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[..., None], 3, axis=2)
    return image
