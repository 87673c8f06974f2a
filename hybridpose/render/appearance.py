"""Domain randomisation for the world outside space: what a training image may look like besides
the pose — the background behind the object, ambient and extra lights, the part's colour and print.

A CNN trained on one look (a grey part on black space) learns that look; one meant for a user's part on
a bench, in a hand or against the Earth must see many. :func:`random_appearance` draws a seeded
:class:`Appearance` per image; :func:`clutter_background` makes procedural clutter (gradients, noise,
shapes, distractor edges) and :class:`PhotoBackgrounds` cuts random crops from the user's photos.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from ..geometry import as_unit_direction
from .carton import carton_sheet
from .face_print import FACES, draw_face_prints

# a few photos released into the public domain (scikit-image's CC0 samples: SOURCES.md there), the
# backgrounds of a fit's views where the user gives none: a network fitted on procedural clutter alone
# found a printed cube in none of 76 frames of real footage, with photos in 10 (docs/decisions.md)
SHIPPED_PHOTOS = Path(__file__).with_name("photos")
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
MAX_FILL_LIGHTS = 2  # lights besides the sun (the renderer's scene holds this many, off unless asked)
TEXTURE_FLOOR = 0.3  # a printed part's darkest ink still reflects this share of the light
DECODED_PHOTOS_MB = 256  # decoded photos a process keeps (decoding one took 8 ms of a 130-ms training view)


@dataclass(frozen=True)
class Appearance:
    """How one image looks besides the pose.

    Attributes:
        ambient: grey ambient light, 0..1 (0: space, where nothing unlit is seen).
        object_rgb: (3,) the part's diffuse colour, 0..1, or None (the model's material).
        fill_lights: up to ``MAX_FILL_LIGHTS`` extra directional lights as ``(direction (3,) the light
            travels in the camera frame, intensity 0..1.5)``.
        background: (H, W, 3) uint8 RGB drawn behind the object, or None (the lighting's background).
        object_texture: (H, W, 3) uint8 RGB print on the part, or None (plain): the shaded part is
            multiplied by ``TEXTURE_FLOOR + (1 − TEXTURE_FLOOR) · texture / 255`` where it is seen. It
            lies in the image, not on the surface (no perspective of its own), unless ``print_faces``
            lays it on the part's faces.
        print_faces: (6, 5) float64 patches of ``object_texture`` on the faces of the part's bounding
            box (:func:`~hybridpose.render.face_print.draw_face_prints`), or None: the print in the image.
    """

    ambient: float = 0.0
    object_rgb: tuple[float, float, float] | None = None
    fill_lights: tuple = ()
    background: np.ndarray | None = None
    object_texture: np.ndarray | None = None
    print_faces: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.ambient <= 1.0:
            raise ValueError(f"ambient: expected a grey level in [0, 1], got {self.ambient!r}")
        if self.object_rgb is not None:
            rgb = np.asarray(self.object_rgb, dtype=np.float64)
            if rgb.shape != (3,) or not np.all((rgb >= 0) & (rgb <= 1)):
                raise ValueError(f"object_rgb: expected (3,) colours in [0, 1], got {self.object_rgb!r}")
        if len(self.fill_lights) > MAX_FILL_LIGHTS:
            raise ValueError(f"fill_lights: at most {MAX_FILL_LIGHTS} lights besides the sun, got {len(self.fill_lights)}")
        for d, k in self.fill_lights:
            as_unit_direction(d, "fill_lights direction")
            if not 0.0 <= k <= 1.5:
                raise ValueError(f"fill_lights: expected intensities in [0, 1.5], got {k!r}")
        for name in ("background", "object_texture"):
            img = getattr(self, name)
            if img is not None and (img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8):
                raise ValueError(f"{name}: expected an (H, W, 3) uint8 RGB image, got {img.shape} {img.dtype}")
        if self.print_faces is not None:
            if self.object_texture is None:
                raise ValueError("print_faces: a print on the faces needs the picture (object_texture)")
            if np.shape(self.print_faces) != (FACES, 5):
                raise ValueError(f"print_faces: expected ({FACES}, 5) face patches, got {np.shape(self.print_faces)}")


def clutter_background(width: int, height: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB procedural clutter, seeded: a colour gradient, multi-octave noise, and
    random rectangles, ellipses and lines — straight edges and corners a tracker or a CNN might
    mistake for the part's, which is the point."""
    rng = np.random.default_rng(rng)
    # one (H, W) float32 plane a channel, merged last: the (H, W, 3) float64 version took 29 ms a
    # 640×480 image, a fifth of a training view's render
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    c0, c1 = rng.uniform(0, 255, 3), rng.uniform(0, 255, 3)
    angle = rng.uniform(0, 2 * np.pi)
    ramp = np.float32(np.cos(angle) / width) * xx + np.float32(np.sin(angle) / height) * yy
    ramp = (ramp - ramp.min()) / np.float32(max(float(np.ptp(ramp)), 1e-6))
    texture = np.zeros((height, width), np.float32)
    for octave, weight in ((rng.integers(32, 128), 0.6), (rng.integers(8, 32), 0.3), (rng.integers(2, 8), 0.1)):
        small = rng.random((max(2, height // int(octave)), max(2, width // int(octave)))).astype(np.float32)
        texture += np.float32(weight) * cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    shade = np.float32(0.6) + np.float32(0.8 * rng.uniform(0.2, 1.0)) * texture
    img = cv2.merge([np.clip((np.float32(a) + np.float32(b - a) * ramp) * shade, 0, 255).astype(np.uint8)
                     for a, b in zip(c0, c1)])
    for _ in range(int(rng.integers(3, 15))):
        colour = tuple(int(v) for v in rng.integers(0, 256, 3))
        kind = rng.integers(0, 3)
        x, y = int(rng.integers(0, width)), int(rng.integers(0, height))
        if kind == 0:
            w, h = int(rng.integers(10, width // 2)), int(rng.integers(10, height // 2))
            cv2.rectangle(img, (x, y), (x + w, y + h), colour, -1 if rng.random() < 0.6 else int(rng.integers(1, 5)))
        elif kind == 1:
            axes = (int(rng.integers(5, width // 4)), int(rng.integers(5, height // 4)))
            cv2.ellipse(img, (x, y), axes, float(rng.uniform(0, 180)), 0, 360, colour, -1 if rng.random() < 0.6 else 2)
        else:
            cv2.line(img, (x, y), (int(rng.integers(0, width)), int(rng.integers(0, height))), colour,
                     int(rng.integers(1, 6)))
    if rng.random() < 0.5:
        img = cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.5, 3.0)))
    return img


class PhotoBackgrounds:
    """Random crops of the photos in ``folder`` (any size; resized to cover the frame), seeded per draw.

    Raises:
        ValueError: ``folder`` is not a folder or holds no readable image.
    """

    def __init__(self, folder) -> None:
        folder = Path(folder)
        if not folder.is_dir():
            raise ValueError(f"backgrounds: {folder} is not a folder of photos")
        self.files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in PHOTO_SUFFIXES)
        if not self.files:
            raise ValueError(f"backgrounds: no photos ({', '.join(PHOTO_SUFFIXES)}) under {folder}")
        self.folder = folder
        self._decoded: dict[Path, np.ndarray] = {}  # up to DECODED_PHOTOS_MB, in the order first drawn

    def draw(self, width: int, height: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        rng = np.random.default_rng(rng)
        bgr = self._photo(self.files[int(rng.integers(len(self.files)))])
        h, w = bgr.shape[:2]
        scale = max(width / w, height / h) * rng.uniform(1.0, 1.6)
        bgr = cv2.resize(bgr, (max(width, int(np.ceil(w * scale))), max(height, int(np.ceil(h * scale)))),
                         interpolation=cv2.INTER_AREA)
        y = int(rng.integers(0, bgr.shape[0] - height + 1))
        x = int(rng.integers(0, bgr.shape[1] - width + 1))
        crop = bgr[y:y + height, x:x + width]
        if rng.random() < 0.5:
            crop = crop[:, ::-1]
        return np.ascontiguousarray(crop[..., ::-1])

    def _photo(self, path: Path) -> np.ndarray:
        """The photo at ``path`` decoded (BGR), kept while the decoded photos fit in ``DECODED_PHOTOS_MB``."""
        bgr = self._decoded.get(path)
        if bgr is None:
            bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if bgr is None:
                raise ValueError(f"backgrounds: {path}: unreadable image")
            if sum(b.nbytes for b in self._decoded.values()) + bgr.nbytes <= DECODED_PHOTOS_MB * 2**20:
                self._decoded[path] = bgr
        return bgr


def random_appearance(width: int, height: int, rng: np.random.Generator | int | None = None,
                      photos: PhotoBackgrounds | None = None, ambient_range: tuple[float, float] = (0.1, 0.5),
                      max_fill_lights: int = MAX_FILL_LIGHTS, colour: bool = True,
                      photo_share: float = 0.5) -> Appearance:
    """A seeded :class:`Appearance` for a ``width`` × ``height`` image: background from ``photos``
    (``photo_share`` of the draws when given) or procedural clutter, ambient light in ``ambient_range``,
    0 to ``max_fill_lights`` extra lights from random directions, and (``colour``) a random part colour."""
    rng = np.random.default_rng(rng)
    lo, hi = ambient_range
    if not 0 <= lo <= hi <= 1:
        raise ValueError(f"ambient_range: expected 0 ≤ low ≤ high ≤ 1, got {ambient_range}")
    if photos is not None and rng.random() < photo_share:
        bg = photos.draw(width, height, rng)
    else:
        bg = clutter_background(width, height, rng)
    fills = []
    for _ in range(int(rng.integers(0, max_fill_lights + 1))):
        d = rng.normal(size=3)
        d[2] = abs(d[2]) + 0.2  # light travelling away from the camera: it lights the faces the camera sees
        fills.append((tuple(float(v) for v in d / np.linalg.norm(d)), float(rng.uniform(0.2, 0.8))))
    rgb = tuple(float(v) for v in rng.uniform(0.15, 1.0, 3)) if colour else None
    return Appearance(ambient=float(rng.uniform(lo, hi)), object_rgb=rgb, fill_lights=tuple(fills), background=bg)


def part_texture(width: int, height: int, rng: np.random.Generator | int | None = None,
                 photos: PhotoBackgrounds | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB print for the part (:attr:`Appearance.object_texture`): a crop of ``photos``
    where given (half the draws) or procedural clutter, seeded."""
    rng = np.random.default_rng(rng)
    if photos is not None and rng.random() < 0.5:
        return photos.draw(width, height, rng)
    return clutter_background(width, height, rng)


def _panel_fill(photos: PhotoBackgrounds | None):
    """A carton panel's picture: a crop of ``photos`` (half the draws, where given) or procedural clutter."""
    def fill(width: int, height: int, rng: np.random.Generator) -> np.ndarray:
        return part_texture(width, height, rng, photos)
    return fill


APPEARANCES = ("space", "random")
PRINT_PLACES = ("image", "faces")


@dataclass(frozen=True)
class AppearanceSpec:
    """What a rendering job draws per image (picklable, recorded in the dataset's config).

    Attributes:
        kind: ``"space"`` (the lighting's look: black or Earth background, no ambient light) or
            ``"random"`` (:func:`random_appearance` per image).
        backgrounds: a folder of photos that ``"random"`` draws ``photo_share`` of its backgrounds from.
        photo_share: the share of backgrounds cut from ``backgrounds`` (the rest procedural clutter).
        fixed: one look for every image (drawn for index 0): a video, where the background and the
            lights stay while the part moves; False: a new look per image (training data).
        texture_share: the share of images whose part carries a print (:func:`part_texture`; drawn
            from a stream of its own, so the other draws of a seed do not change); 0: plain parts.
        print_on: where the print lies: ``"image"`` (one picture across the silhouette) or
            ``"faces"`` (a patch of it on each face, cut at the faces' edges: :mod:`~hybridpose.render.face_print`).
        carton_share: with ``print_on="faces"``, the share of the prints drawn as a carton's
            (:func:`~hybridpose.render.carton.carton_sheet`: picture panels and lettering on white card)
            instead of a photo or clutter over each face; drawn from a stream of its own.
        grey_share: with ``camera_effects``, the share of images that come out grey (a monochrome camera).
        camera_effects: each image also gets a draw of a real camera's motion blur, exposure and
            white balance, noise and JPEG (:func:`~hybridpose.render.camera_effects.camera_effects`).
    """

    kind: str = "space"
    backgrounds: str | None = None
    photo_share: float = 0.5
    fixed: bool = False
    texture_share: float = 0.0
    camera_effects: bool = False
    print_on: str = "image"
    grey_share: float = 0.0
    carton_share: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in APPEARANCES:
            raise ValueError(f"appearance: expected one of {', '.join(APPEARANCES)}, got {self.kind!r}")
        if self.backgrounds is not None:
            if self.kind != "random":
                raise ValueError("backgrounds: photos are drawn only with appearance 'random'")
            _photos(self.backgrounds)  # refuse a bad folder before any work starts
        if not 0.0 <= self.photo_share <= 1.0:
            raise ValueError(f"photo_share: expected a share in [0, 1], got {self.photo_share!r}")
        if not 0.0 <= self.texture_share <= 1.0:
            raise ValueError(f"texture_share: expected a share of the images in [0, 1], got {self.texture_share!r}")
        if self.texture_share > 0 and self.kind != "random":
            raise ValueError("texture_share: a print on the part is drawn only with appearance 'random'")
        if self.print_on not in PRINT_PLACES:
            raise ValueError(f"print_on: expected one of {', '.join(PRINT_PLACES)}, got {self.print_on!r}")
        if not 0.0 <= self.carton_share <= 1.0:
            raise ValueError(f"carton_share: expected a share of the prints in [0, 1], got {self.carton_share!r}")
        if self.carton_share > 0 and self.print_on != "faces":
            raise ValueError("carton_share: a carton's print is laid on the faces (print_on='faces')")
        if not 0.0 <= self.grey_share <= 1.0:
            raise ValueError(f"grey_share: expected a share of the images in [0, 1], got {self.grey_share!r}")
        if self.grey_share > 0 and not self.camera_effects:
            raise ValueError("grey_share: grey images are drawn among the camera effects (camera_effects=True)")
        if self.camera_effects and self.kind != "random":
            raise ValueError("camera_effects: drawn only with appearance 'random' (space has its own sensor model)")

    def record(self) -> dict:
        """The spec as a dataset config records it (``texture_share``, ``camera_effects``, ``print_on``
        and ``grey_share`` only where not their defaults, so configs written before they existed still match)."""
        out = asdict(self)
        if out["print_on"] == "image":
            del out["print_on"]
        if out["grey_share"] == 0:
            del out["grey_share"]
        if out["carton_share"] == 0:
            del out["carton_share"]
        if out["texture_share"] == 0:
            del out["texture_share"]
        if not out["camera_effects"]:
            del out["camera_effects"]
        return out

    def draw(self, width: int, height: int, seed: int, index: int) -> Appearance | None:
        """Image ``index``'s appearance (None for space), seeded by ``(seed, index)`` alone."""
        if self.kind == "space":
            return None
        photos = _photos(self.backgrounds) if self.backgrounds else None
        key = 0 if self.fixed else index
        look = random_appearance(width, height, np.random.default_rng([seed, key, 13]),
                                 photos=photos, photo_share=self.photo_share)
        if self.texture_share > 0:
            rng = np.random.default_rng([seed, key, 29])
            if rng.random() < self.texture_share:
                carton = np.random.default_rng([seed, key, 37])
                if self.carton_share > 0 and carton.random() < self.carton_share:
                    look = replace(look, object_texture=carton_sheet(width, height, carton, _panel_fill(photos)))
                else:
                    look = replace(look, object_texture=part_texture(width, height, rng, photos))
                if self.print_on == "faces":
                    look = replace(look, print_faces=draw_face_prints(rng, width, height))
        return look


_PHOTO_FOLDERS: dict[str, PhotoBackgrounds] = {}


def _photos(folder: str) -> PhotoBackgrounds:
    if folder not in _PHOTO_FOLDERS:
        _PHOTO_FOLDERS[folder] = PhotoBackgrounds(folder)
    return _PHOTO_FOLDERS[folder]
