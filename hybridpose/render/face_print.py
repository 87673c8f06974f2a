"""A print that lies on the part's faces: each face of the part's bounding box carries its own patch of a
picture (or none), seen in perspective and cut at the faces' edges — as a printed carton's is.

The image-space print (:attr:`~hybridpose.render.appearance.Appearance.object_texture` alone) lays one
picture across the whole silhouette: its lines run on across the part's edges, so a network trained on it
never sees the edge of a face where the print changes, the commonest edge on a real printed part. A box
projection (the surface point's largest coordinate, relative to the bounding box, names the face it is
on) is exact for a box and gives any other shape a print in patches; no UV map is needed.

Written here: MuJoCo maps textures through a mesh's UVs, which a user's CAD model (a ``.cao``, an STL)
does not carry, and it would need a new model per picture; the depth image the renderer reads back
already gives every visible pixel's surface point.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..geometry import Camera, Pose

FACES = 6                # the bounding box's faces: −x, +x, −y, +y, −z, +z
PLAIN_SHARE = 0.25       # share of the faces left without print (a carton's white ends, a label on one side)
# the picture's width spans the face's longer side this many times over (drawn log-uniformly): a
# carton's print is one face-sized panel, a wrapping or a label is finer or coarser
SPAN_RANGE = (0.3, 1.5)
REMAP_ROW = 1024         # pixels per row of the remap tables (below OpenCV's limit of 32 767 a side)


def draw_face_prints(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """(FACES, 5) float64 per-face mapping of a ``width`` × ``height`` print: (centre x, centre y in the
    print's pixels, print pixels per face length, turn in radians, 1 where the face is plain)."""
    out = np.empty((FACES, 5))
    out[:, 0] = rng.uniform(0.2, 0.8, FACES) * width
    out[:, 1] = rng.uniform(0.2, 0.8, FACES) * height
    out[:, 2] = width / np.exp(rng.uniform(*np.log(SPAN_RANGE), FACES))
    out[:, 3] = rng.choice([0.0, np.pi / 2, np.pi, 3 * np.pi / 2], FACES)
    out[:, 4] = rng.random(FACES) < PLAIN_SHARE
    return out


def face_print_gain(texture: np.ndarray, faces: np.ndarray, depth: np.ndarray, mask: np.ndarray,
                    camera: Camera, T_cam_obj: Pose, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(P, 3) float32 print in [0, 1] at the ``mask`` pixels (row-major order), 1 on plain faces.

    Args:
        texture: (H, W, 3) uint8 RGB picture the faces' patches are cut from (any size).
        faces: (FACES, 5) :func:`draw_face_prints`.
        depth: (H, W) depth along the optical axis, metres (the render's); mask: (H, W) bool pixels of the part.
        camera: the render's intrinsics; T_cam_obj: the part's pose (object → camera, metres).
        box_min, box_max: (3,) the part's bounding box in its own frame, metres.
    """
    v, u = np.nonzero(mask)
    z = depth[v, u].astype(np.float64)
    K = camera.K
    cam = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], 1)
    p = (cam - T_cam_obj.t) @ T_cam_obj.R                       # object frame (R orthonormal: Rᵀ(x − t))
    centre, half = (box_min + box_max) / 2, np.maximum((box_max - box_min) / 2, 1e-9)
    q = (p - centre) / half
    rows = np.arange(len(q))
    axis = np.abs(q).argmax(1)
    face = 2 * axis + (q[rows, axis] > 0)
    # the two coordinates across each face, metres from its centre, over its longer side
    across = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    side = 2 * half[across].max(1)
    a, b = ((p - centre)[rows[:, None], across] / side[:, None]).T
    f = faces[face]
    c, s = np.cos(f[:, 3]), np.sin(f[:, 3])
    # cv2.remap's maps are images (each side under 32 767): the pixels laid out in rows of REMAP_ROW
    n, rows_needed = len(q), -(-len(q) // REMAP_ROW)
    maps = np.zeros((2, rows_needed * REMAP_ROW), np.float32)
    maps[0, :n] = f[:, 0] + f[:, 2] * (c * a - s * b)
    maps[1, :n] = f[:, 1] + f[:, 2] * (s * a + c * b)
    maps = maps.reshape(2, rows_needed, REMAP_ROW)
    sampled = cv2.remap(texture, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
    gain = sampled.reshape(-1, 3)[:n].astype(np.float32) / 255.0
    gain[f[:, 4] > 0] = 1.0
    return gain
