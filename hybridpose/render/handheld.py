"""Hand-held scenes with ground truth, off black space: a part — printed or plain — standing in a lit,
cluttered room, filmed by a hand-held camera that moves 5–30 px a frame, stops and turns, with motion
blur, auto-exposure, sensor noise, JPEG, and a hand that may pass in front.

A compositor, not a light simulator: each frame's part is drawn from the model's facet-id raster
(every pixel lifted onto its facet, so a print moves with the surface: each face shows a region of a
photo), shaded by a room light; the background is a photo or procedural clutter far behind it (it
turns with the camera: a rotation homography); the hand is a skin-toned palm and fingers. What the
MuJoCo space renderer cannot give: a print on the part, a lit, busy background, hand-held motion.

:func:`handheld_sequence` draws one seeded sequence; :class:`HandheldSpec` says what it holds;
:func:`handheld_scene` also gives the part as drawn — a printed one as a model that carries its print
(:attr:`ObjectModel.texture`), as a user's textured mesh of a printed part would.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..edges import ModelView
from ..edges.print_match import footprint_level
from ..geometry import Camera, Pose
from ..objects import ObjectModel
from .appearance import PhotoBackgrounds, clutter_background
from .camera_effects import jpeg, motion_blur

BACKGROUNDS = ("photo", "clutter")
SKIN_RGB = ((224, 172, 138), (198, 134, 106), (141, 85, 60), (236, 188, 160))  # hand tones, light to dark
PRINT_PX_PER_M = 4000.0  # the print's scale on the part: a 8.5-cm face spans 340 px of its photo


@dataclass(frozen=True)
class HandheldSpec:
    """One hand-held sequence.

    Attributes:
        frames, fps: length and rate. seed: everything random in it.
        printed: the part's faces carry a photo print (else one plain colour).
        background: ``"photo"`` (crops of the photos given to :func:`handheld_sequence`; clutter where
            none are) or ``"clutter"`` (procedural).
        hand: a hand passes in front of the part once (frames 40–70 % of the sequence).
        size_px: the part's projected size (its diameter, px) the camera keeps it at, about.
        speed_px: (low, high) image motion of the part a frame while the camera moves, px.
        blur, noise: motion blur along the image motion (half-frame exposure); sensor noise, auto-
            exposure and JPEG.
    """

    frames: int = 90
    fps: float = 30.0
    seed: int = 0
    printed: bool = True
    background: str = "photo"
    hand: bool = False
    size_px: float = 160.0
    speed_px: tuple[float, float] = (5.0, 30.0)
    blur: bool = True
    noise: bool = True

    def __post_init__(self) -> None:
        if self.frames < 2 or not self.fps > 0:
            raise ValueError(f"frames, fps: expected ≥ 2 frames at a positive rate, got {self.frames}, {self.fps}")
        if self.background not in BACKGROUNDS:
            raise ValueError(f"background: expected one of {BACKGROUNDS}, got {self.background!r}")
        lo, hi = self.speed_px
        if not 0 <= lo <= hi:
            raise ValueError(f"speed_px: expected 0 ≤ low ≤ high px a frame, got {self.speed_px}")
        if not self.size_px > 10:
            raise ValueError(f"size_px: expected the part's projected size in px (> 10), got {self.size_px}")


@dataclass(frozen=True)
class HandheldFrame:
    """One rendered frame: ``image`` (H, W, 3) uint8 RGB, the true ``pose`` (T_cam_obj), the share of
    the part's projected pixels left ``visible`` by the hand (0..1), the part's image ``motion_px``
    since the previous frame, ``timestamp`` (s), ``index``, and the part's (H, W) bool ``mask``
    (its whole silhouette) and ``mask_visib`` (what the hand leaves of it)."""

    image: np.ndarray
    pose: Pose
    visible: float
    motion_px: float
    timestamp: float
    index: int
    mask: np.ndarray
    mask_visib: np.ndarray


def _look_at(eye: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """R_cam_world of a camera at ``eye`` looking at ``target`` (OpenCV axes), rolled by ``roll`` rad."""
    z = target - eye
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-6:
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in the world
    c, s = np.cos(roll), np.sin(roll)
    return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1.0]]) @ R


def _rate_profile(frames: int, rng: np.random.Generator, low: float, high: float) -> np.ndarray:
    """(frames, 2) a hand's 2D rate per frame: segments of 8–25 frames, each a stop (a fifth of them)
    or a move of a random direction and speed in [low, high], eased into one another over 3 frames."""
    rates = np.zeros((frames, 2))
    k = 0
    while k < frames:
        n = int(rng.integers(8, 26))
        if rng.random() >= 0.2:
            angle = rng.uniform(0, 2 * np.pi)
            rates[k:k + n] = rng.uniform(low, high) * np.array([np.cos(angle), np.sin(angle)])
        k += n
    kernel = np.ones(3) / 3
    return np.stack([np.convolve(rates[:, i], kernel, mode="same") for i in range(2)], 1)


def camera_path(spec: HandheldSpec, obj: ObjectModel, camera: Camera, rng: np.random.Generator) -> list[Pose]:
    """The true ``T_cam_obj`` of each frame: the part rests at the world origin; the camera, at a
    distance that shows it ``size_px`` across, circles it and turns so that the part drifts across the
    image at the profile's rate (:func:`_rate_profile`), with hand shake (0.15° and 0.4 mm a frame)."""
    f = 0.5 * (camera.fx + camera.fy)
    distance = f * obj.diameter / spec.size_px
    lo, hi = spec.speed_px
    drift = _rate_profile(spec.frames, rng, lo, hi)             # the part's image motion, px a frame
    orbit = _rate_profile(spec.frames, rng, 0.0, 1.5)           # the view's turn, degrees a frame
    azimuth, elevation = rng.uniform(0, 2 * np.pi), rng.uniform(np.radians(15), np.radians(60))
    offset = rng.uniform(-0.25, 0.25, 2) * [camera.width, camera.height]
    roll = rng.uniform(-0.3, 0.3)
    poses = []
    for k in range(spec.frames):
        azimuth += np.radians(orbit[k, 0])
        elevation = float(np.clip(elevation + np.radians(orbit[k, 1]), np.radians(5), np.radians(80)))
        offset = offset + drift[k]
        # keep the part in view: a drift that would take it out turns back
        limit = np.array([0.35 * camera.width, 0.35 * camera.height])
        over = np.abs(offset) > limit
        drift[k:, over] *= -1
        offset = np.clip(offset, -limit, limit)
        eye = distance * np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                                   np.sin(elevation)])
        R_cw = _look_at(eye, np.zeros(3), roll + rng.normal(0, np.radians(0.15)))
        # turn the camera so that the part lies `offset` px from the image centre
        R_off = cv2.Rodrigues(np.array([offset[1] / f, -offset[0] / f, 0.0]))[0]
        R_cw = R_off @ R_cw
        t = -R_cw @ (eye + rng.normal(0, 0.0004, 3))
        poses.append(Pose(R_cw, t))
    return poses


def _face_frames(view: ModelView) -> tuple[np.ndarray, np.ndarray]:
    """Per facet id: two unit vectors spanning its plane (F, 2, 3) and an offset into the print (F, 2)."""
    n = view.plane_normal
    a = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    e1 = np.cross(n, a)
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-12)
    e2 = np.cross(n, e1)
    offsets = (np.arange(len(n))[:, None] * [0.37, 0.61]) % 1.0
    return np.stack([e1, e2], 1), offsets


def _print_texels(axes: np.ndarray, offsets: np.ndarray, facet: np.ndarray, points: np.ndarray, size) -> np.ndarray:
    """(N, 2) where the model points ``points`` (N, 3) on facets ``facet`` (N,) lie on a print of
    ``size`` (W, H) texels, before it repeats (:func:`_face_frames`' axes and offsets, ``PRINT_PX_PER_M``)."""
    return np.einsum("nkj,nj->nk", axes[facet], points) * PRINT_PX_PER_M + offsets[facet] * np.asarray(size, float)


def printed_part(obj: ObjectModel, print_rgb: np.ndarray) -> ObjectModel:
    """``obj`` carrying ``print_rgb`` ((H, W, 3) uint8 RGB) as :func:`handheld_sequence` draws it on
    its faces: each facet shows the print at ``PRINT_PX_PER_M`` from its own offset, the print repeating
    every W − 1 and H − 1 texels (the period :class:`~hybridpose.edges.PrintView` reads texture
    coordinates outside [0, 1] with). ``face_uv`` in OBJ's convention (``v`` up from the bottom row)."""
    view = ModelView(obj)
    axes, offsets = _face_frames(view)
    h, w = print_rgb.shape[:2]
    facet = np.repeat(view.facet_of, 3)  # each triangle corner's facet id
    uv_px = _print_texels(axes, offsets, facet, view.triangles.reshape(-1, 3), (w, h)).reshape(-1, 3, 2)
    face_uv = np.stack([uv_px[..., 0] / (w - 1), 1.0 - uv_px[..., 1] / (h - 1)], axis=-1)
    return replace(obj, texture=np.ascontiguousarray(print_rgb, dtype=np.uint8), face_uv=face_uv)


class _Part:
    """Draws the part at a pose: printed from ``print_rgb`` (H, W, 3) or plain ``colour``."""

    def __init__(self, obj: ObjectModel, print_rgb: np.ndarray | None, colour: np.ndarray, light_obj: np.ndarray):
        self.view = ModelView(obj)
        self.print_rgb, self.colour, self.light = print_rgb, colour, light_obj
        self.axes, self.offsets = _face_frames(self.view)
        # the print's pyramid: a pixel sees many texels of it (a face 90 px across shows 340), and a
        # camera's lens and pixels average them; one texel a pixel aliases into detail no camera shows
        self.levels = [] if print_rgb is None else [np.float32(print_rgb)]
        while self.levels and min(self.levels[-1].shape[:2]) > 16:
            self.levels.append(cv2.pyrDown(self.levels[-1]))

    def draw(self, image: np.ndarray, camera: Camera, pose: Pose) -> np.ndarray:
        """Draws into ``image``; returns the part's (H, W) bool mask."""
        ids = self.view.facet_ids(pose, camera, scale=1.0)
        ys, xs = np.nonzero(ids)
        if len(xs) == 0:
            return ids > 0
        facet = ids[ys, xs]
        X, ok = self.view.lift(pose, camera, np.c_[xs, ys].astype(float), ids=ids)
        colour = (np.broadcast_to(self.colour, (len(xs), 3)).astype(np.float64) if self.print_rgb is None
                  else self._printed(camera, pose, xs, ys, facet, X, ids))
        shade = 0.45 + 0.55 * np.clip(self.view.plane_normal[facet] @ self.light, 0.0, 1.0)
        keep = ok
        image[ys[keep], xs[keep]] = np.clip(colour[keep] * shade[keep, None], 0, 255).astype(np.uint8)
        return ids > 0

    def _printed(self, camera: Camera, pose: Pose, xs, ys, facet, X, ids) -> np.ndarray:
        """(N, 3) the print's colour at pixels (``xs``, ``ys``) seeing model points ``X`` on ``facet``:
        from the pyramid level whose texel matches the pixel's footprint (the texels between it and its
        right and lower neighbours), bilinear; the print repeats every W − 1 and H − 1 texels."""
        h, w = self.print_rgb.shape[:2]

        def texel(points):
            return np.mod(_print_texels(self.axes, self.offsets, facet, points, (w, h)), [w - 1, h - 1])

        uv = texel(X)
        right, below = (texel(self.view.lift(pose, camera, np.c_[xs + dx, ys + dy].astype(float), ids=ids)[0])
                        for dx, dy in ((1, 0), (0, 1)))
        du, dv = right - uv, below - uv
        # a neighbour across the print's repeat seam jumps by a period: measure the step the short way
        du -= np.round(du / [w - 1, h - 1]) * [w - 1, h - 1]
        dv -= np.round(dv / [w - 1, h - 1]) * [w - 1, h - 1]
        level = footprint_level(du, dv, len(self.levels))
        colour = np.zeros((len(xs), 3))
        for lv in np.unique(level):
            sel = level == lv
            at = (uv[sel] + 0.5) / 2.0 ** lv - 0.5  # level lv's texel i covers level 0's [2^lv i, 2^lv (i + 1))
            colour[sel] = cv2.remap(self.levels[lv], at[:, 0].astype(np.float32)[None], at[:, 1].astype(np.float32)[None],
                                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)[0]
        return colour


def _hand(image: np.ndarray, centre: np.ndarray, scale: float, angle: float, rgb) -> np.ndarray:
    """Draws a palm and four fingers at ``centre`` (px), ``scale`` px across; returns its mask."""
    mask = np.zeros(image.shape[:2], np.uint8)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    palm = (centre).astype(int)
    cv2.ellipse(mask, tuple(int(v) for v in palm), (int(0.45 * scale), int(0.55 * scale)), np.degrees(angle), 0, 360, 1, -1)
    for k in range(4):
        base = centre + rot @ np.array([(k - 1.5) * 0.22 * scale, -0.45 * scale])
        tip = base + rot @ np.array([0.05 * (k - 1.5) * scale, -(0.55 + 0.1 * (k % 2)) * scale])
        cv2.line(mask, tuple(int(v) for v in base), tuple(int(v) for v in tip), 1, max(2, int(0.16 * scale)))
    image[mask > 0] = np.array(rgb, np.uint8)
    shade = cv2.GaussianBlur(mask.astype(np.float32), (0, 0), 0.08 * scale)  # rounded edges darker
    image[mask > 0] = (image[mask > 0] * (0.7 + 0.3 * shade[mask > 0, None])).astype(np.uint8)
    return mask > 0


@dataclass(frozen=True)
class HandheldScene:
    """:func:`handheld_scene`'s answer: the ``frames`` and the ``part`` as drawn (for a printed part,
    the model carrying its print: :func:`printed_part`; else the model given)."""

    frames: list[HandheldFrame]
    part: ObjectModel


def handheld_sequence(spec: HandheldSpec, obj: ObjectModel, camera: Camera,
                      photos: PhotoBackgrounds | None = None) -> list[HandheldFrame]:
    """Render ``spec`` of ``obj`` seen through ``camera`` (its pinhole; no distortion drawn).

    ``photos``: the photos the background (``"photo"``) and the print are cut from; without them both
    are procedural clutter (:func:`~hybridpose.render.appearance.clutter_background`)."""
    return handheld_scene(spec, obj, camera, photos).frames


def handheld_scene(spec: HandheldSpec, obj: ObjectModel, camera: Camera,
                   photos: PhotoBackgrounds | None = None) -> HandheldScene:
    """:func:`handheld_sequence`'s frames and the part as drawn (:class:`HandheldScene`)."""
    rng = np.random.default_rng(spec.seed)
    W, H = camera.width, camera.height

    def picture(w, h):
        if photos is not None:
            return photos.draw(w, h, rng)
        return clutter_background(w, h, rng)

    poses = camera_path(spec, obj, camera, rng)
    # the background: a picture twice the frame, far away; it turns with the camera (homography K R K⁻¹)
    back = picture(2 * W, 2 * H) if spec.background == "photo" else clutter_background(2 * W, 2 * H, rng)
    print_rgb = picture(1024, 1024) if spec.printed else None
    colour = rng.uniform(90, 230, 3)
    light_world = np.array([0.3, -0.4, 0.87])
    K, Kinv = camera.K, np.linalg.inv(camera.K)
    R0 = poses[0].R
    shift = np.array([[1, 0, -W / 2], [0, 1, -H / 2], [0, 0, 1.0]])  # the big picture centred on frame 0
    hand_frames = (int(0.4 * spec.frames), int(0.7 * spec.frames))
    hand_rgb = SKIN_RGB[int(rng.integers(len(SKIN_RGB)))]
    hand_side = rng.choice([-1.0, 1.0])
    gain_knots = rng.uniform(0.8, 1.2, max(2, spec.frames // 20 + 2))
    gains = np.interp(np.arange(spec.frames), np.linspace(0, spec.frames - 1, len(gain_knots)), gain_knots)
    part = _Part(obj, print_rgb, colour, light_world)
    out, prev_uv = [], None
    for k, pose in enumerate(poses):
        H_bg = shift @ K @ R0 @ pose.R.T @ Kinv  # frame pixel → the big picture's pixel (rotation only)
        image = cv2.warpPerspective(back, H_bg, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                    borderMode=cv2.BORDER_REFLECT)
        light_obj = pose.R.T @ (R0 @ light_world)  # the room light stays with the world
        part.light = light_obj / np.linalg.norm(light_obj)
        mask = part.draw(image, camera, pose)
        uv = camera.project(np.zeros((1, 3)), pose)[0]
        motion = 0.0 if prev_uv is None else float(np.linalg.norm(uv - prev_uv))
        visible, mask_visib = 1.0, mask
        if spec.hand and hand_frames[0] <= k < hand_frames[1] and mask.any():
            progress = (k - hand_frames[0]) / max(hand_frames[1] - hand_frames[0] - 1, 1)
            across = (1.6 * progress - 0.8) * spec.size_px * 1.5
            where = uv + np.array([hand_side * across, 0.2 * spec.size_px])
            covered = _hand(image, where, 1.3 * spec.size_px, np.radians(20 * hand_side), hand_rgb)
            mask_visib = mask & ~covered
            visible = float(mask_visib.sum() / max(mask.sum(), 1))
        if spec.blur and prev_uv is not None and motion > 1.0:
            image = motion_blur(image, (uv - prev_uv) / motion, 0.5 * motion)  # half-frame exposure
        if spec.noise:
            image = np.clip(image.astype(np.float32) * gains[k] + rng.normal(0, 3.0, image.shape), 0, 255).astype(np.uint8)
            image = jpeg(image, int(rng.integers(75, 96)))
        out.append(HandheldFrame(np.ascontiguousarray(image), pose, visible, motion, k / spec.fps, k, mask, mask_visib))
        prev_uv = uv
    return HandheldScene(out, obj if print_rgb is None else printed_part(obj, print_rgb))
