"""A learned check of a pose against its box twins: the image beside a render of each hypothesis.

The keypoint network's twin head decides which of the truss's near-symmetric box twins
(:func:`~hybridpose.regressors.verify.box_half_turns`) its keypoints follow; it is right ≈ 96 % of
the time, and the rest are the end-for-end flips that dominate the regressor's mean rotation error,
most of them within 12° of edge-on (benchmarks/RESULTS.md). Rendering each twin with MuJoCo and
comparing grey levels was worse than the head (the sun direction changes which faces are lit more
than the twin does), so here the comparison is *learned*, as MegaPose's coarse model scores
(image, render) pairs: each candidate pose is drawn as a flat-shaded model on a strip of the full
resolution image aligned with the object's long axis, the image and the drawing go into a small CNN
as two channels, and a softmax over the candidates says which one the image shows.

The strip is the same for every candidate (its direction is the projected long axis with a sign
fixed in the image, which the twins share), so only the drawing differs between them; it is cut
from the full-resolution frame, where the grapple plate and the connector node are several times
larger than in the keypoint network's 128 px crop of the whole object.
"""
from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn

from ..geometry import Pose
from ..geometry.raster import fill_triangles, front_faces_far_first
from ..objects import ObjectModel

log = logging.getLogger(__name__)

STRIP_W, STRIP_H = 160, 80  # the verifier's input image, px
STRIP_MARGIN = 1.15  # strip side / the drawn object's extent
SHADE_MIN = 0.35  # grey of a face seen edge-on in the drawing (1.0 face-on); 0 is background
CHECKPOINT_FORMAT = "hybridpose-twin-verifier/1"
VERIFIER_ENGINES = ("auto", "torch", "onnxruntime")


def strip_affine(pose: Pose, obj: ObjectModel, K: np.ndarray, size=(STRIP_W, STRIP_H)) -> np.ndarray:
    """(2, 3) affine from frame pixels to the strip: x along the projected long (x) axis of ``obj``.

    The axis direction's sign is fixed in the image (its x component ≥ 0, or y ≥ 0 when vertical),
    so a pose and its box twins get the same strip. The object's projected bounding box, enlarged by
    ``STRIP_MARGIN``, fits the strip (aspect ``size``) at one scale in both directions.

    Args:
        pose: T_cam_obj (metres). obj: the object model. K: (3, 3) intrinsics of the (undistorted)
            frame. size: (W, H) of the strip in pixels.
    """
    w, h = size
    corners = obj.bbox_corners @ pose.R.T + pose.t                     # (8, 3) camera frame
    if np.any(corners[:, 2] <= 1e-3):
        raise ValueError("pose: the object's box reaches behind the camera; no strip to cut")
    p = corners @ K.T
    uv = p[:, :2] / p[:, 2:3]
    c = 0.5 * (obj.bbox_min + obj.bbox_max)
    ends = np.array([c - [obj.extents[0] / 2, 0, 0], c + [obj.extents[0] / 2, 0, 0]]) @ pose.R.T + pose.t
    e = ends @ K.T
    e = e[:, :2] / e[:, 2:3]
    u = e[1] - e[0]
    n = float(np.hypot(*u))
    u = u / n if n > 1e-6 else np.array([1.0, 0.0])  # looking down the axis: any direction
    if u[0] < -1e-9 or (abs(u[0]) <= 1e-9 and u[1] < 0):
        u = -u
    v = np.array([-u[1], u[0]])
    a, b = uv @ u, uv @ v
    centre = 0.5 * (a.max() + a.min()) * u + 0.5 * (b.max() + b.min()) * v
    length = STRIP_MARGIN * max(np.ptp(a), np.ptp(b) * w / h, 1.0)
    s = w / length
    R = s * np.stack([u, v])                                            # rows: strip x, strip y
    return np.hstack([R, ((np.array([w, h]) - 1) / 2 - R @ centre)[:, None]])


class HypothesisRenderer:
    """Flat-shaded drawings of ``obj`` in a strip (painter's order; the truss has 342 triangles)."""

    def __init__(self, obj: ObjectModel) -> None:
        mesh = obj.mesh
        self.triangles = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.faces)]  # (F, 3, 3)
        self.normals = np.asarray(mesh.face_normals, np.float64)

    def draw(self, pose: Pose, K: np.ndarray, A: np.ndarray, size=(STRIP_W, STRIP_H)) -> np.ndarray:
        """(H, W) uint8: 0 background, faces shaded by how squarely they face the camera."""
        w, h = size
        tri, facing, order = front_faces_far_first(self.triangles, self.normals, pose)
        p = tri[order] @ K.T
        st = (p[..., :2] / p[..., 2:3]) @ A[:, :2].T + A[:, 2]
        grey = np.round(255 * (SHADE_MIN + (1 - SHADE_MIN) * facing[order])).astype(int)
        return fill_triangles(np.zeros((h, w), np.uint8), st, grey)


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey levels of an (H, W, 3) uint8 RGB or (H, W) uint8 image, as the training
    strips were cut (``cv2.imread(..., IMREAD_GRAYSCALE)`` of the rendered PNGs: the same weights)."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise ValueError(f"image: expected (H, W, 3) RGB or (H, W) grey uint8, got {image.shape} {image.dtype}")
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def verifier_inputs(gray: np.ndarray, K: np.ndarray, candidates: list[Pose], obj: ObjectModel,
                    renderer: HypothesisRenderer | None = None, strip_pose: Pose | None = None):
    """The network's inputs for ``candidates``: (strip (H, W) uint8, drawings (C, H, W) uint8).

    The strip is cut from ``gray`` (H0, W0) uint8 along ``strip_pose`` (default: the first candidate).
    """
    renderer = renderer or HypothesisRenderer(obj)
    A = strip_affine(strip_pose or candidates[0], obj, K)
    strip = cv2.warpAffine(gray, A, (STRIP_W, STRIP_H), flags=cv2.INTER_AREA if A[0, 0] ** 2 + A[0, 1] ** 2 < 1
                           else cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    drawings = np.stack([renderer.draw(p, K, A) for p in candidates])
    return strip, drawings


def _block(c_in: int, c_out: int, stride: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True))


class TwinVerifierNet(nn.Module):
    """Score of (image strip, drawing) pairs: (B, C, 2, H, W) float in [0, 1] → (B, C) logits."""

    def __init__(self, width: int = 32) -> None:
        super().__init__()
        w = int(width)
        self.features = nn.Sequential(
            _block(2, w // 2, 2), _block(w // 2, w, 2), _block(w, w, 1),
            _block(w, 2 * w, 2), _block(2 * w, 2 * w, 1), _block(2 * w, 4 * w, 2), _block(4 * w, 4 * w, 1),
            nn.AdaptiveAvgPool2d(1), nn.Flatten(),
        )
        self.score = nn.Linear(4 * w, 1)
        self.width = w

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 5 or x.shape[2] != 2:
            raise ValueError(f"x: expected (B, C, 2, H, W) image/drawing pairs, got {tuple(x.shape)}")
        b, c = x.shape[:2]
        return self.pair_scorer()(x.flatten(0, 1)).view(b, c)

    def pair_scorer(self) -> nn.Module:
        """The per-pair part of :meth:`forward`: (N, 2, H, W) pairs → (N, 1) logits (what an engine
        exports; shares this net's layers)."""
        return nn.Sequential(self.features, self.score)


def pairs_tensor(strip: np.ndarray, drawings: np.ndarray) -> torch.Tensor:
    """(1, C, 2, H, W) float in [0, 1] from a strip (H, W) and drawings (C, H, W), uint8."""
    s = torch.from_numpy(np.ascontiguousarray(strip)).float().div_(255.0)
    d = torch.from_numpy(np.ascontiguousarray(drawings)).float().div_(255.0)
    return torch.stack([s.expand_as(d), d], 1)[None]


class TwinVerifier:
    """A trained :class:`TwinVerifierNet` for one object (``hybridpose train-verifier``).

    Args:
        checkpoint: the ``.pt`` file. obj: the object the caller tracks; refused when the checkpoint
            was trained on another (diameter off by more than 1 %).
        engine: what scores the pairs: ``"auto"`` (default): ONNX Runtime's CPU kernels (the pair
            network exported at load, :class:`~hybridpose.regressors.engines.OnnxModule`; ≈ 2× as fast
            as torch on the 4 or 8 pairs of a call, the same scores to float rounding), torch where
            ONNX Runtime cannot run (the reason logged); ``"onnxruntime"`` (an error where it cannot);
            ``"torch"``.
    """

    def __init__(self, checkpoint, obj: ObjectModel, engine: str = "auto") -> None:
        if engine not in VERIFIER_ENGINES:
            raise ValueError(f"engine: expected one of {', '.join(VERIFIER_ENGINES)}, got {engine!r}")
        path = Path(checkpoint)
        try:
            ck = torch.load(path, map_location="cpu", weights_only=True)
        except FileNotFoundError:
            raise FileNotFoundError(f"checkpoint: twin verifier {path} not found") from None
        except Exception as exc:  # a truncated or foreign file: say which
            raise ValueError(f"{path}: not a readable twin-verifier checkpoint ({exc})") from exc
        if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
            raise ValueError(f"{path}: not a hybridpose twin-verifier checkpoint (format {CHECKPOINT_FORMAT!r})")
        d = float(ck["diameter_m"])
        if abs(obj.diameter - d) > 0.01 * d:
            raise ValueError(f"obj: {path} was trained on {ck['object']!r} (diameter {d:.3f} m), not on {obj.name!r} "
                             f"(diameter {obj.diameter:.3f} m)")
        self.net = TwinVerifierNet(ck["width"])
        self.net.load_state_dict(ck["model"])
        self.net.eval()
        self.onnx = None if engine == "torch" else self._onnx_pairs(engine)
        self.obj = obj
        self.renderer = HypothesisRenderer(obj)
        self.path = path

    @property
    def engine(self) -> str:
        """What scores the pairs: ``"onnxruntime"`` or ``"torch"``."""
        return "torch" if self.onnx is None else "onnxruntime"

    def _onnx_pairs(self, engine: str):
        """The pair scorer (features → score of (N, 2, H, W) pairs) on ONNX Runtime, or None (torch) where
        it cannot run and ``engine`` is "auto"."""
        from .engines import OnnxModule

        try:
            return OnnxModule(self.net.pair_scorer(), torch.zeros(1, 2, STRIP_H, STRIP_W), ["score"], name=engine)
        except RuntimeError as exc:
            if engine == "onnxruntime":
                raise
            log.info("twin verifier on torch: %s", exc)
            return None

    @torch.no_grad()
    def probabilities(self, image: np.ndarray, K: np.ndarray, candidates: list[Pose],
                      strip_pose: Pose | None = None) -> np.ndarray:
        """(C,) softmax over ``candidates`` (poses T_cam_obj of one frame): how likely each is the
        object's true orientation rather than a twin. ``image``: the undistorted frame, (H, W, 3)
        uint8 RGB or (H, W) uint8 grey; ``K``: its (3, 3) intrinsics; ``strip_pose``: the pose the
        strip is cut along (default: the first candidate)."""
        return self.probabilities_of_sets(image, K, [candidates], None if strip_pose is None else [strip_pose])[0]

    @torch.no_grad()
    def probabilities_of_sets(self, image: np.ndarray, K: np.ndarray, candidate_sets: list[list[Pose]],
                              strip_poses: list[Pose] | None = None) -> np.ndarray:
        """:meth:`probabilities` of several sets of candidates of one frame in one network batch
        (the pooled twin choice scores both estimates' twins): (S, C) softmax over each set's C
        candidates (every set the same size); ``strip_poses``: each set's strip pose (default: its
        first candidate)."""
        if not candidate_sets or any(len(c) != len(candidate_sets[0]) or not c for c in candidate_sets):
            raise ValueError("candidate_sets: expected one or more non-empty sets of poses, all the same size")
        gray, K = to_gray(image), np.asarray(K, float)
        strip_poses = strip_poses or [None] * len(candidate_sets)
        pairs = torch.cat([pairs_tensor(*verifier_inputs(gray, K, c, self.obj, self.renderer, sp))
                           for c, sp in zip(candidate_sets, strip_poses)])
        s, c = pairs.shape[:2]
        logits = self.net(pairs) if self.onnx is None else self.onnx(pairs.flatten(0, 1))[0].view(s, c)
        return torch.softmax(logits, 1).numpy().astype(np.float64)


def load_verifier(verifier, obj: ObjectModel, shipped: Path, engine: str) -> TwinVerifier | None:
    """The :class:`TwinVerifier` of ``obj`` from ``verifier``: a checkpoint path; ``"auto"``: the ``shipped``
    one where it exists and was trained for ``obj`` (the shipped ones are for the built-in truss); None or
    False: none. ``engine`` as :class:`TwinVerifier`'s."""
    if verifier is None or verifier is False:
        return None
    if isinstance(verifier, str) and verifier == "auto":
        if not shipped.is_file():
            return None
        try:
            return TwinVerifier(shipped, obj, engine=engine)
        except ValueError as exc:
            log.info("shipped %s not used: %s", shipped.name, exc)
            return None
    return TwinVerifier(verifier, obj, engine=engine)
