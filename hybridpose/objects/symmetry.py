"""Discrete symmetries of a rigid object: the rotations that map its surface onto itself.

A box, a plate or a bolt head looks the same after some half- or quarter-turns; no camera can tell
those poses apart, so metrics compare an estimate with the nearest of them (BOP's
``symmetries_discrete``) and ADD becomes ADD-S. Candidates are the turns about the bounding box's
axes through its centre — half-turns always, quarter-turns about an axis whose two other extents
are equal — kept where the turned surface lies on the surface within ``tolerance`` × the diameter.
Continuous symmetries (a cylinder about its axis) show up as their quarter-turns only.
"""
from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..geometry import Pose

SYMMETRY_TOLERANCE = 0.01  # of the diameter: how far the turned surface may lie from the surface
SAMPLES = 4000  # surface points compared per candidate rotation


def _turn(axis: np.ndarray, angle: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]


def discrete_symmetries(mesh: trimesh.Trimesh, tolerance: float = SYMMETRY_TOLERANCE) -> tuple[Pose, ...]:
    """The non-identity symmetries ``S`` (object frame: ``T_cam_obj @ S`` looks the same) among the
    bounding-box turns, as poses; () for an asymmetric object. Deterministic (seeded sampling)."""
    lo, hi = mesh.bounds
    centre, extents = 0.5 * (lo + hi), hi - lo
    diameter = float(np.linalg.norm(extents))
    pts, _ = trimesh.sample.sample_surface(mesh, SAMPLES, seed=0)
    pts = np.asarray(pts, dtype=np.float64)
    tree = cKDTree(pts)
    # a sample's nearest neighbour among the samples themselves sets the floor of the check
    spacing = float(np.percentile(tree.query(pts, k=2)[0][:, 1], 95))
    limit = tolerance * diameter + spacing
    candidates = []
    for i, axis in enumerate(np.eye(3)):
        candidates.append(_turn(axis, np.pi))
        others = extents[[j for j in range(3) if j != i]]
        if abs(others[0] - others[1]) <= tolerance * diameter:
            candidates += [_turn(axis, np.pi / 2), _turn(axis, -np.pi / 2)]
    found = [R for R in candidates if np.percentile(tree.query((pts - centre) @ R.T + centre)[0], 99) <= limit]
    # the products of symmetries are symmetries too (a square prism's diagonal half-turns)
    group = [np.eye(3)]
    frontier = found
    while frontier:
        new = []
        for R in frontier:
            if not any(np.allclose(R, G, atol=1e-9) for G in group + new):
                new.append(R)
        group += new
        frontier = [a @ b for a in new for b in group] if len(group) < 48 else []
    return tuple(Pose(R, centre - R @ centre) for R in group[1:])
