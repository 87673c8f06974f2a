"""What the trackers see of the CAD model at a pose: visible edge samples, a facet-id image, and
the projection Jacobian they all share.

Visibility of model edges (what ViSP does with its scanline renderer): an edge sample is kept when
one of its two faces looks at the camera *and* that face's facet is what the image shows around
the sample's pixel. The facet-id image comes from a depth-tested raster of the front faces
(:func:`hybridpose.geometry.raster.zbuffer_front_faces`): no OpenGL context in the tracking loop,
≈ 0.6 ms at half resolution on test views (`docs/decisions.md`). (A far-first painter's raster, used
before, misordered the truss's long thin triangles: MuJoCo's depth disagreed with twice as many
of its visibility calls.)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import Camera, Pose
from ..geometry.raster import zbuffer_front_faces
from ..objects import ObjectModel
from ..objects.base import SHARP_EDGE_ANGLE_DEG, boundary_edges
from . import kernels

DEFAULT_STEP_M = 0.005  # edge samples every 5 mm along the model's sharp edges
ID_SCALE = 0.5  # facet-id image resolution relative to the frame
# a face whose normal makes a smaller cosine with the direction towards the sun is in shadow (grazing
# light leaves it too dark to make an edge)
SUNLIT_COSINE = 0.05


def thin(index: np.ndarray, max_samples: int | None) -> np.ndarray:
    """``index`` evenly thinned to at most ``max_samples`` entries (all of them when None)."""
    if max_samples is not None and len(index) > max_samples:
        index = index[np.linspace(0, len(index) - 1, max_samples).round().astype(int)]
    return index


@dataclass(frozen=True)
class EdgeSamples:
    """Visible edge samples at one pose (S samples).

    Attributes:
        index: (S,) indices into :attr:`ModelView.points`.
        points_m: (S, 3) model points, metres, object frame.
        uv: (S, 2) their projections, pixels.
        normals: (S, 2) unit image normals of the edges at the samples.
    """

    index: np.ndarray
    points_m: np.ndarray
    uv: np.ndarray
    normals: np.ndarray


class ModelView:
    """Edge samples and facets of an :class:`ObjectModel`, precomputed once per tracker.

    The samples lie along the sharp edges (two faces meeting at more than ``SHARP_EDGE_ANGLE_DEG``)
    and along the outline of open surfaces (an edge of a single face: a model of separate polygons).

    Args:
        object: the model (metres).
        step_m: spacing of samples along those edges, metres.

    Attributes:
        raster_mesh: (triangles (T, 3, 3) m, normals (T, 3), facet ids (T,)) that the facet-id raster
            draws: the mesh's triangles, each convex planar facet as a fan of its corners.

    Raises:
        ValueError: the mesh has no sharp edge and no open outline (nothing an edge tracker could follow).
    """

    def __init__(self, object: ObjectModel, step_m: float = DEFAULT_STEP_M) -> None:
        mesh = object.mesh
        if step_m <= 0:
            raise ValueError(f"step_m: expected a positive sample spacing in metres, got {step_m}")
        self.step_m = float(step_m)
        sharp = mesh.face_adjacency_angles > np.radians(SHARP_EDGE_ANGLE_DEG)
        open_edges, open_faces = boundary_edges(mesh)
        if not np.any(sharp) and not len(open_edges):
            raise ValueError(
                f"object: {object.name!r} has no sharp edges (no faces meeting at > {SHARP_EDGE_ANGLE_DEG}° "
                "and no open outline); an edge tracker has nothing to follow — use the klt-pnp tracker"
            )
        verts = np.asarray(mesh.vertices, dtype=np.float64)
        # creases between two faces, and the outline of open surfaces (a CAD model of separate
        # polygons, as ViSP's .cao files often are) with its one face on both sides
        edges = verts[np.concatenate([mesh.face_adjacency_edges[sharp], open_edges])]      # (E, 2, 3)
        faces = np.concatenate([mesh.face_adjacency[sharp], np.stack([open_faces, open_faces], 1)])  # (E, 2)
        length = np.linalg.norm(edges[:, 1] - edges[:, 0], axis=1)
        n_per = np.maximum(1, np.ceil(length / step_m).astype(int))
        e_idx = np.repeat(np.arange(len(edges)), n_per)
        frac = np.concatenate([(np.arange(n) + 0.5) / n for n in n_per])
        a, b = edges[e_idx, 0], edges[e_idx, 1]
        self.object = object
        self.points = a + frac[:, None] * (b - a)                 # (P, 3) samples
        self.directions = (b - a) / length[e_idx, None]           # (P, 3) unit edge directions
        self.edge_of = e_idx                                      # (P,) the sharp edge each sample lies on
        self.faces = faces[e_idx]                                 # (P, 2) adjacent triangles
        self.face_normals = np.asarray(mesh.face_normals, dtype=np.float64)
        # (P, 2) n·p for each sample's two faces: a face turns to the camera where n·p + n·(Rᵀt) < 0
        self.normal_dot_point = np.einsum("pkj,pj->pk", self.face_normals[self.faces], self.points)
        self.triangles = verts[np.asarray(mesh.faces)]            # (F, 3, 3)
        # coplanar triangles form one facet: a pixel showing any of them shows "that face"
        facet_of = np.arange(len(mesh.faces)) + len(mesh.facets)
        for k, tri in enumerate(mesh.facets):
            facet_of[tri] = k
        self.facet_of = facet_of + 1                             # 0 = background
        # one plane per facet id (a point on it and its normal), for lifting pixels onto the model
        self.plane_point = np.zeros((self.facet_of.max() + 1, 3))
        self.plane_normal = np.zeros((self.facet_of.max() + 1, 3))
        self.plane_point[self.facet_of] = self.triangles[:, 0]
        self.plane_normal[self.facet_of] = self.face_normals
        if self.facet_of.max() >= 2**16:
            raise ValueError(f"object: mesh has too many faces ({len(mesh.faces)}) for the facet-id raster")
        # what the raster draws: each convex planar facet as a fan of few triangles (a textured export
        # tessellates its faces densely: ViSP's MegaPose cube has 12 288 triangles for 6 faces)
        self.raster_mesh = _raster_mesh(mesh, verts, self.face_normals, self.facet_of)

    # --- rendering of facet ids ------------------------------------------------------------------
    def facet_ids(self, pose: Pose, camera: Camera, scale: float = ID_SCALE) -> np.ndarray:
        """(h, w) uint16 facet id + 1 of the surface seen at each pixel (0 = background), at
        ``scale`` × the camera's resolution."""
        w, h = max(1, int(round(camera.width * scale))), max(1, int(round(camera.height * scale)))
        triangles, normals, facet_of = self.raster_mesh
        return zbuffer_front_faces(triangles, normals, facet_of, pose.R, pose.t, camera.K,
                                   float(scale), h, w)

    def lift(self, pose: Pose, camera: Camera, uv: np.ndarray, ids: np.ndarray | None = None,
             scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Model points (N, 3) metres seen at pixels ``uv`` (N, 2), and which are on the object (N,) bool.

        The facet under each pixel comes from the facet-id raster (``ids`` at ``scale``, rendered
        here when None); the point is the intersection of the pixel's ray with that facet's plane.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if ids is None:
            ids = self.facet_ids(pose, camera, scale)
        h, w = ids.shape
        c = np.round((uv + 0.5) * scale - 0.5).astype(int)
        inside = (c[:, 0] >= 0) & (c[:, 0] < w) & (c[:, 1] >= 0) & (c[:, 1] < h)
        f = np.zeros(len(uv), np.int64)
        f[inside] = ids[c[inside, 1], c[inside, 0]]
        origin = -pose.R.T @ pose.t                                          # camera centre, object frame
        d, lam, ok = self.ray_plane_depths(pose, camera, uv, f)
        return origin + lam[:, None] * d, ok

    def ray_plane_depths(self, pose: Pose, camera: Camera, uv: np.ndarray, facets: np.ndarray):
        """Where the rays of pixels ``uv`` (N, 2) meet the planes of ``facets`` ((N,) or (N, M) facet
        id + 1, 0 = background): ray directions (N, 3) in the object frame (camera z = 1, so the ray
        parameter is the depth in metres), parameters λ of ``facets``' shape, and where a plane is met
        in front of the camera."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        f = np.asarray(facets, dtype=np.int64)
        rays = np.c_[uv, np.ones(len(uv))] @ np.linalg.inv(camera.K).T       # camera frame, z = 1
        origin = -pose.R.T @ pose.t                                          # camera centre, object frame
        d = rays @ pose.R                                                    # ray directions, object frame
        n, p0 = self.plane_normal[f], self.plane_point[f]
        d_b = d.reshape(len(d), *([1] * (f.ndim - 1)), 3)
        denom = np.sum(n * d_b, axis=-1)
        ok = (f > 0) & (np.abs(denom) > 1e-9)
        lam = np.where(ok, np.sum(n * (p0 - origin), axis=-1) / np.where(ok, denom, 1.0), 0.0)
        return d, lam, ok & (lam > 0)

    def surface_fixed(self, pose: Pose, camera: Camera, uv: np.ndarray, ids: np.ndarray, r: int = 2,
                      tol_m: float = 0.002) -> np.ndarray:
        """(N,) True where the ray of each pixel ``uv`` (N, 2) meets every facet seen within ±``r`` px
        in the full-resolution facet-id raster ``ids`` at the same depth (within ``tol_m`` metres): a
        point fixed on the object (a corner of the geometry, a point of a face's print). False at
        occlusion boundaries (a beam in front of another) and on the silhouette, where an image corner
        is no point of the object."""
        h, w = ids.shape
        c = np.round(uv).astype(int)
        off = np.arange(-r, r + 1)
        ys = np.clip(c[:, 1, None, None] + off[None, :, None], 0, h - 1)
        xs = np.clip(c[:, 0, None, None] + off[None, None, :], 0, w - 1)
        f = ids[ys, xs].reshape(len(uv), -1)                                  # (N, (2r+1)²)
        _, lam, ok = self.ray_plane_depths(pose, camera, uv, f)
        depth_spread = np.where(ok, lam, -np.inf).max(1) - np.where(ok, lam, np.inf).min(1)  # ray parameter = depth
        return ok.all(1) & (depth_spread < tol_m)

    # --- visible samples ----------------------------------------------------------------------------
    def step_px(self, pose: Pose, camera: Camera) -> float:
        """The samples' spacing in pixels at the depth of the object's nearest point (≥ 1)."""
        depth = max(float(pose.t[2]) - 0.5 * self.object.diameter, 1e-3)
        return max(1.0, self.step_m * max(camera.fx, camera.fy) / depth)

    def visible_samples(self, pose: Pose, camera: Camera, margin_px: float = 0.0,
                        max_samples: int | None = None) -> EdgeSamples:
        """Edge samples visible at ``pose``: a front-facing adjacent face, not hidden by another
        part (facet-id test), inside the image by ``margin_px``; evenly thinned to ``max_samples``."""
        return self.samples_at(pose, camera, self.visible_index(pose, camera, margin_px, max_samples))

    def visible_index(self, pose: Pose, camera: Camera, margin_px: float = 0.0,
                      max_samples: int | None = None, ids: np.ndarray | None = None) -> np.ndarray:
        """Indices (S,) into :attr:`points` of the samples :meth:`visible_samples` returns; ``ids``: the
        :meth:`facet_ids` of ``pose`` where the caller has them (rendered here otherwise)."""
        idx, uv, facing = kernels.facing_samples(
            self.points, self.normal_dot_point, self.face_normals, self.faces, pose.R, pose.t, camera.K,
            camera.width, camera.height, float(margin_px))
        if len(idx):
            own = self.facet_of[self.faces[idx]] * facing                 # (S, 2): 0 where back-facing
            ids = self.facet_ids(pose, camera) if ids is None else ids
            idx = idx[kernels.shows_own_facet(ids, uv, own, ID_SCALE)]
        return thin(idx, max_samples)

    def sun_shows(self, index: np.ndarray, pose: Pose, sun_direction_cam, dark_background: bool = True) -> np.ndarray:
        """(S,) bool: which samples ``index`` (S,) the sun can show as an image edge at ``pose``, where
        it is the only light (``sun_direction_cam``: (3,) unit direction the sunlight travels, camera
        frame). A crease between two faces seen from the camera shows unless both are turned from the
        sun (black on black); an outline (one face seen) shows where that face is sunlit, or, with
        ``dark_background`` False (the Earth behind), always: a face in shadow stands out against it.

        An edge the sun cannot show pulls its search onto whatever lit edge lies within reach (the
        neighbouring beam), so it is left out (evidence in ``docs/decisions.md``)."""
        index = np.asarray(index, dtype=np.int64)
        normals = self.face_normals[self.faces[index]]                           # (S, 2, 3) object frame
        towards_sun = pose.R.T @ -np.asarray(sun_direction_cam, dtype=np.float64)
        lit = normals @ towards_sun > SUNLIT_COSINE                               # (S, 2)
        # turned to the camera as in the visibility test (kernels.facing_samples): n · (p + Rᵀt) < 0
        facing = self.normal_dot_point[index] + normals @ (pose.R.T @ pose.t) < 0
        crease = facing[:, 0] & facing[:, 1] & (self.faces[index, 0] != self.faces[index, 1])
        outline_lit = np.where(facing[:, 0], lit[:, 0], lit[:, 1]) | (not dark_background)
        return np.where(crease, lit[:, 0] | lit[:, 1], outline_lit)

    def silhouette_index(self, index: np.ndarray, pose: Pose) -> np.ndarray:
        """The samples of ``index`` (S,) on the silhouette at ``pose``: on a crease between a face turned
        to the camera and one turned away (the outline of a closed polyhedral mesh)."""
        index = np.asarray(index, dtype=np.int64)
        normals = self.face_normals[self.faces[index]]                                   # (S, 2, 3)
        facing = self.normal_dot_point[index] + normals @ (pose.R.T @ pose.t) < 0         # (S, 2)
        return index[facing[:, 0] != facing[:, 1]]

    def samples_at(self, pose: Pose, camera: Camera, index: np.ndarray, margin_px: float | None = None) -> EdgeSamples:
        """The samples ``index`` projected at ``pose`` (no visibility test: the trackers decide
        visibility once per frame and re-project as the pose moves); with ``margin_px`` those that
        left the image are dropped. The image normal is perpendicular to the projected edge."""
        index = np.asarray(index, dtype=np.int64)
        keep, uv, normals = kernels.project_samples(
            self.points[index], self.directions[index], pose.R, pose.t, camera.K, camera.width, camera.height,
            0.0 if margin_px is None else float(margin_px), margin_px is not None)
        if margin_px is not None and not keep.all():
            index, uv, normals = index[keep], uv[keep], normals[keep]
        return EdgeSamples(index=index, points_m=self.points[index], uv=uv, normals=normals)


def _raster_mesh(mesh, verts: np.ndarray, face_normals: np.ndarray, facet_of: np.ndarray):
    """(triangles (T, 3, 3), normals (T, 3), facet ids (T,)) drawing the same surface as the mesh's own
    triangles with fewer of them: every planar facet whose outline is one convex loop becomes a fan
    over its corners (collinear outline points dropped); other triangles stay as they are."""
    faces = np.asarray(mesh.faces)
    keep = np.ones(len(faces), bool)
    tris, normals, ids = [], [], []
    for k, members in enumerate(mesh.facets):
        loop = _outline_loop(np.asarray(mesh.facets_boundary[k]))
        if loop is None:
            continue
        normal = face_normals[members[0]]
        corners = _convex_corners(verts[loop], normal)
        if corners is None:
            continue
        keep[members] = False
        for i in range(1, len(corners) - 1):
            tris.append([corners[0], corners[i], corners[i + 1]])
            normals.append(normal)
            ids.append(facet_of[members[0]])
    if not tris:
        return verts[faces], face_normals, facet_of
    return (np.concatenate([verts[faces[keep]], np.asarray(tris)]),
            np.concatenate([face_normals[keep], np.asarray(normals)]),
            np.concatenate([facet_of[keep], np.asarray(ids, dtype=facet_of.dtype)]))


def _outline_loop(edges: np.ndarray) -> np.ndarray | None:
    """The vertex indices of ``edges`` (E, 2) in order around their one closed loop; None where the
    edges make more than one loop (a facet with a hole) or no loop."""
    if len(edges) < 3:
        return None
    nxt: dict[int, list[int]] = {}
    for a, b in edges:
        nxt.setdefault(int(a), []).append(int(b))
        nxt.setdefault(int(b), []).append(int(a))
    if any(len(v) != 2 for v in nxt.values()):
        return None
    start = int(edges[0, 0])
    loop, prev, cur = [start], None, start
    while True:
        a, b = nxt[cur]
        step = b if a == prev else a
        if step == start:
            break
        loop.append(step)
        prev, cur = cur, step
        if len(loop) > len(edges):
            return None
    return np.asarray(loop) if len(loop) == len(edges) else None


def _convex_corners(points: np.ndarray, normal: np.ndarray) -> np.ndarray | None:
    """``points`` (N, 3), an outline in order, reduced to its corners and turned counter-clockwise about
    ``normal``; None where the outline is not convex."""
    turn = np.einsum("ij,j->i", np.cross(points - np.roll(points, 1, 0), np.roll(points, -1, 0) - points), normal)
    scale = np.linalg.norm(points - np.roll(points, 1, 0), axis=1) * np.linalg.norm(np.roll(points, -1, 0) - points, axis=1)
    corner = np.abs(turn) > 1e-9 * np.maximum(scale, 1e-30)
    if corner.sum() < 3:
        return None
    signs = np.sign(turn[corner])
    if not (np.all(signs > 0) or np.all(signs < 0)):
        return None
    corners = points[corner]
    return corners if signs[0] > 0 else corners[::-1]
