"""``ObjectModel``: the CAD model of the tracked object, in metres, in its own object frame."""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import trimesh

from ..geometry import read_only

SHARP_EDGE_ANGLE_DEG = 30.0  # faces meeting at more than this show an edge


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """A rigid object known by its mesh.

    Attributes:
        name: identifier (e.g. ``"truss"`` or the file stem).
        mesh: ``trimesh.Trimesh`` in metres, object frame (the frame ``T_cam_obj`` refers to).
        keypoints: (K, 3) float64 3D keypoints in metres (corners / extremal points), for keypoint
            CNNs and PnP. Computed by :func:`default_keypoints` when not given.
        symmetries: the rotations ``S`` (object frame, as poses) that map the object onto itself, so
            that ``T_cam_obj @ S`` looks the same: metrics take the nearest (and ADD-S for ADD). None
            (default): detected from the mesh's shape (:func:`~hybridpose.objects.symmetry.discrete_symmetries`),
            a ``texture`` or not; () declares an asymmetric object.
        texture: (H, W, 3) uint8 RGB image printed on the part through ``face_uv``, or None (a plain
            part): the renderer draws it on the surface (a textured mesh file's own image).
        face_uv: (M, 3, 2) float texture coordinates of each face's corners (``u`` right, ``v`` up
            from the image's bottom row, as OBJ's ``vt``), given with ``texture``.
    """

    name: str
    mesh: trimesh.Trimesh
    keypoints: np.ndarray = field(default=None)
    symmetries: tuple = None
    texture: np.ndarray = field(default=None, repr=False)
    face_uv: np.ndarray = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.mesh, trimesh.Trimesh) or len(self.mesh.faces) == 0:
            raise ValueError(f"mesh: expected a non-empty trimesh.Trimesh, got {type(self.mesh).__name__}")
        kp = default_keypoints(self.mesh) if self.keypoints is None else np.asarray(self.keypoints, np.float64)
        if kp.ndim != 2 or kp.shape[1] != 3:
            raise ValueError(f"keypoints: expected (K, 3) metres, got shape {kp.shape}")
        kp = kp.copy()
        kp.flags.writeable = False
        object.__setattr__(self, "keypoints", kp)
        self._check_texture()
        if self.symmetries is None:
            from .symmetry import discrete_symmetries

            object.__setattr__(self, "symmetries", discrete_symmetries(self.mesh))
        else:
            from ..geometry import Pose

            syms = tuple(self.symmetries)
            if not all(isinstance(S, Pose) for S in syms):
                raise ValueError("symmetries: expected a tuple of hybridpose Pose (object-frame rotations)")
            object.__setattr__(self, "symmetries", syms)

    def _check_texture(self) -> None:
        if (self.texture is None) != (self.face_uv is None):
            raise ValueError("texture, face_uv: expected both (a print and where each face corner sits on it) or neither")
        if self.texture is None:
            return
        tex, uv = np.asarray(self.texture), np.asarray(self.face_uv, dtype=np.float64)
        if tex.ndim != 3 or tex.shape[2] != 3 or tex.dtype != np.uint8 or min(tex.shape[:2]) < 1:
            raise ValueError(f"texture: expected an (H, W, 3) uint8 RGB image, got {tex.dtype} {tex.shape}")
        if uv.shape != (len(self.mesh.faces), 3, 2) or not np.all(np.isfinite(uv)):
            raise ValueError(f"face_uv: expected finite ({len(self.mesh.faces)}, 3, 2) texture coordinates "
                             f"(one per face corner), got {uv.shape}")
        tex = tex.copy()
        tex.flags.writeable = False
        object.__setattr__(self, "texture", tex)
        object.__setattr__(self, "face_uv", read_only(uv))

    @property
    def symmetric(self) -> bool:
        """True when some rotation maps the object onto itself (use ADD-S, not ADD)."""
        return bool(self.symmetries)

    @property
    def vertices(self) -> np.ndarray:
        """(N, 3) float64 mesh vertices, metres."""
        return np.asarray(self.mesh.vertices, dtype=np.float64)

    @property
    def faces(self) -> np.ndarray:
        """(M, 3) int64 triangle vertex indices."""
        return np.asarray(self.mesh.faces, dtype=np.int64)

    @cached_property
    def sharp_edges(self) -> np.ndarray:
        """(E, 2, 3) float64 segments (metres) where adjacent faces meet at more than
        ``SHARP_EDGE_ANGLE_DEG``, plus open boundary edges: the edges an edge tracker can see."""
        return sharp_edges(self.mesh, SHARP_EDGE_ANGLE_DEG)

    @cached_property
    def diameter(self) -> float:
        """Largest distance between two points of the model, metres (BOP's diameter)."""
        hull = np.asarray(self.mesh.convex_hull.vertices)
        d = hull[:, None, :] - hull[None, :, :]
        return float(np.sqrt((d**2).sum(-1)).max())

    # the box is read in every tracked frame: worked out once (as ``diameter`` and ``sharp_edges``), read-only
    @cached_property
    def bbox_min(self) -> np.ndarray:
        """(3,) lowest corner of the axis-aligned bounding box, metres."""
        return read_only(self.mesh.bounds[0])

    @cached_property
    def bbox_max(self) -> np.ndarray:
        """(3,) highest corner of the axis-aligned bounding box, metres."""
        return read_only(self.mesh.bounds[1])

    @property
    def extents(self) -> np.ndarray:
        """(3,) size of the axis-aligned bounding box, metres."""
        return self.bbox_max - self.bbox_min

    @cached_property
    def bbox_corners(self) -> np.ndarray:
        """(8, 3) corners of the axis-aligned bounding box, metres."""
        return read_only(box_corners(self.bbox_min, self.bbox_max))

    @cached_property
    def center(self) -> np.ndarray:
        """(3,) centre of the bounding box, metres."""
        return 0.5 * (self.bbox_min + self.bbox_max)

    def sample_surface(self, count: int, rng: np.random.Generator | int | None = 0) -> np.ndarray:
        """(count, 3) points uniformly on the surface (for ADD / ADD-S), seeded."""
        seed = int(np.random.default_rng(rng).integers(2**31))
        pts, _ = trimesh.sample.sample_surface(self.mesh, count, seed=seed)
        return np.asarray(pts, dtype=np.float64)


def view_elevation_deg(pose, obj: ObjectModel) -> float:
    """Angle (°, 0–90) between the line of sight to ``obj``'s box centre and its main plane (the
    plane of its two longest bounding-box axes, object frame) for the object at ``pose``
    (``T_cam_obj``, metres): 0° edge-on, 90° face-on. A flat object (the truss) is hardest edge-on."""
    thin_axis = pose.R[:, int(np.argmin(obj.extents))]
    centre = pose.R @ obj.center + pose.t
    sight = centre / np.linalg.norm(centre)
    return float(np.degrees(np.arcsin(min(1.0, abs(float(thin_axis @ sight))))))


def sun_phase_angle_deg(sun_direction_cam, pose, obj: ObjectModel) -> float:
    """Phase angle (°, 0–180) of ``obj`` at ``pose`` (``T_cam_obj``, metres) under a sun whose light
    travels along ``sun_direction_cam`` ((3,), camera frame): the angle at the object's box centre
    between the directions to the sun and to the camera. 0° the sun behind the camera (the face
    seen is fully lit), 90° side-lit, 180° back-lit (only rims lit)."""
    d = np.asarray(sun_direction_cam, dtype=np.float64)
    centre = pose.R @ obj.center + pose.t
    # to the sun is -d, to the camera is -centre: their cosine is d · centre / |centre|
    cos_phase = float(d @ centre) / (np.linalg.norm(d) * np.linalg.norm(centre))
    return float(np.degrees(np.arccos(np.clip(cos_phase, -1.0, 1.0))))


def light_azimuth_deg(sun_direction_cam) -> float:
    """Direction (°, 0–360) the sunlight travels across the image: the angle of its image-plane part
    from the image's +x axis towards +y (clockwise on screen, y being down). The default sun
    (0.6, 0.4, 0.7) gives 33.7°: light from the upper left, travelling right and down."""
    d = np.asarray(sun_direction_cam, dtype=np.float64)
    return float(np.degrees(np.arctan2(d[1], d[0])) % 360.0)


def box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(8, 3) corners of the axis-aligned box [lo, hi]."""
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], dtype=np.float64)


def sharp_edges(mesh: trimesh.Trimesh, angle_deg: float = SHARP_EDGE_ANGLE_DEG) -> np.ndarray:
    """(E, 2, 3) segments of a mesh's crease and boundary edges."""
    idx = mesh.face_adjacency_edges[mesh.face_adjacency_angles > np.radians(angle_deg)]
    all_idx = np.concatenate([idx.reshape(-1, 2), boundary_edges(mesh)[0]], 0)
    return np.asarray(mesh.vertices, dtype=np.float64)[all_idx]


def boundary_edges(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's boundary edges — edges of a single face: the outline of an open surface — as (B, 2)
    vertex indices, and that face (B,)."""
    inverse = np.asarray(mesh.edges_unique_inverse)
    counts = np.bincount(inverse, minlength=len(mesh.edges_unique))
    first = np.empty(len(mesh.edges_unique), np.int64)
    first[inverse[::-1]] = np.arange(len(inverse))[::-1]  # each unique edge's first occurrence
    boundary = np.nonzero(counts == 1)[0]
    return (np.asarray(mesh.edges_unique[boundary], dtype=np.int64).reshape(-1, 2),
            np.asarray(mesh.edges_face[first[boundary]], dtype=np.int64))


def default_keypoints(mesh: trimesh.Trimesh, count: int = 12) -> np.ndarray:
    """(count, 3) well-spread extremal points: hull vertices nearest the 8 bounding-box corners,
    then farthest-point sampling over the remaining hull vertices."""
    hull = np.asarray(mesh.convex_hull.vertices, dtype=np.float64)
    corners = box_corners(*mesh.bounds)
    chosen: list[int] = []
    for c in corners:
        i = int(np.argmin(np.linalg.norm(hull - c, axis=1)))
        if i not in chosen:
            chosen.append(i)
    dist = np.min(np.linalg.norm(hull[:, None] - hull[chosen][None], axis=2), axis=1)
    while len(chosen) < min(count, len(hull)):
        i = int(np.argmax(dist))
        chosen.append(i)
        dist = np.minimum(dist, np.linalg.norm(hull - hull[i], axis=1))
    return hull[chosen[:count]]
