"""Space lighting and sensor effects: one hard sun, no ambient light, black (or Earth) background."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import as_unit_direction

BACKGROUNDS = ("black", "earth")


@dataclass(frozen=True)
class SpaceLighting:
    """How the scene is lit.

    Attributes:
        sun_direction_cam: (3,) direction the sunlight travels, camera frame (x right, y down,
            z forward); normalised on use. The default comes from behind the camera's upper left.
        sun_intensity: diffuse intensity of the sun (MuJoCo light units, 0..~1.5).
        sun_specular: specular intensity of the sun.
        exposure: multiplies the rendered image (1 = as rendered; > 1 saturates highlights).
        background: ``"black"`` (deep space) or ``"earth"`` (a bright limb with clouds behind).
    """

    sun_direction_cam: tuple[float, float, float] = (0.6, 0.4, 0.7)
    sun_intensity: float = 1.0
    sun_specular: float = 0.6
    exposure: float = 1.0
    background: str = "black"

    def __post_init__(self) -> None:
        d = as_unit_direction(self.sun_direction_cam, "sun_direction_cam")
        object.__setattr__(self, "sun_direction_cam", tuple(float(x) for x in d))
        for name in ("sun_intensity", "sun_specular", "exposure"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name}: expected a non-negative number, got {v!r}")
        if self.background not in BACKGROUNDS:
            raise ValueError(f"background: expected one of {BACKGROUNDS}, got {self.background!r}")


@dataclass(frozen=True)
class SensorModel:
    """Camera sensor effects applied after rendering, in this order: blur, noise, gamma.

    Attributes:
        blur_sigma_px: Gaussian blur (defocus) standard deviation in pixels; 0 = off.
        noise_std: additive Gaussian read noise, fraction of full scale (0.01 ≈ 2.5 grey levels).
        gamma: output = input ** (1 / gamma); 1 = linear.
    """

    blur_sigma_px: float = 0.0
    noise_std: float = 0.0
    gamma: float = 1.0

    def __post_init__(self) -> None:
        for name in ("blur_sigma_px", "noise_std"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name}: expected a non-negative number, got {v!r}")
        if not np.isfinite(self.gamma) or self.gamma <= 0:
            raise ValueError(f"gamma: expected a positive number, got {self.gamma!r}")

    @property
    def is_identity(self) -> bool:
        return self.blur_sigma_px == 0 and self.noise_std == 0 and self.gamma == 1.0

    def apply(self, rgb: np.ndarray, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """(H, W, 3) uint8 → (H, W, 3) uint8 with the sensor effects; seeded by ``rng``."""
        if self.is_identity:
            return rgb
        img = rgb.astype(np.float32) / 255.0
        if self.blur_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.blur_sigma_px)
        if self.noise_std > 0:
            img = img + np.random.default_rng(rng).normal(0.0, self.noise_std, img.shape).astype(np.float32)
        img = np.clip(img, 0.0, 1.0)
        if self.gamma != 1.0:
            img = img ** (1.0 / self.gamma)
        return (img * 255.0 + 0.5).astype(np.uint8)


def earth_background(width: int, height: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB: a bright Earth limb with procedural clouds, seeded.

    The limb is a large disc whose centre lies outside the image, so a curved horizon crosses the
    frame, as when a spacecraft looks past the Earth.
    """
    rng = np.random.default_rng(rng)
    diag = float(np.hypot(width, height))
    angle = rng.uniform(0, 2 * np.pi)
    radius = diag * rng.uniform(1.2, 2.0)
    centre = np.array([width / 2, height / 2]) + (radius - diag * rng.uniform(0.1, 0.4)) * np.array([np.cos(angle), np.sin(angle)])
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    r = np.hypot(xx - centre[0], yy - centre[1])
    inside = np.clip((radius - r) / 3.0, 0.0, 1.0)  # anti-aliased limb
    # clouds: multi-octave smoothed noise
    clouds = np.zeros((height, width), np.float32)
    for octave, weight in ((64, 0.5), (24, 0.3), (8, 0.2)):
        small = rng.random((max(2, height // octave), max(2, width // octave))).astype(np.float32)
        clouds += weight * cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    clouds = np.clip((clouds - 0.45) * 2.5, 0.0, 1.0)
    ocean = np.array([20, 60, 140], np.float32)
    white = np.array([235, 240, 245], np.float32)
    surface = ocean * (1 - clouds[..., None]) + white * clouds[..., None]
    limb_glow = np.exp(-np.maximum(radius - r, 0) / (0.02 * diag))[..., None] * np.array([60, 110, 200], np.float32)
    img = inside[..., None] * (surface + 0.5 * limb_glow)
    return np.clip(img, 0, 255).astype(np.uint8)
