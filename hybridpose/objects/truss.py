"""The built-in ``truss``: an asymmetric space-truss segment, about 0.38 × 0.20 × 0.05 m.

Two square-section chords along x, three verticals at uneven spacing, one diagonal per bay in
opposite senses, a corner connector node, a grapple plate on the lower chord and bolt heads on the
+z face. The uneven spacing, the plate and the one-sided bolts break every symmetry (tested), and
the bolt heads and plate give corners a keypoint tracker can follow. Built as a watertight boolean
union (manifold3d) so that its crease edges are the real visible edges, with no faces buried
inside other beams.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import trimesh

from ..registry import register
from .base import ObjectModel

LENGTH_M, HEIGHT_M = 0.38, 0.20  # the paper's truss module, as modelled for the renders
CHORD_M = 0.025  # square chord section
CHORD_Y_M = HEIGHT_M / 2 - CHORD_M / 2


def _box(size, center, rot_z_rad: float = 0.0) -> trimesh.Trimesh:
    T = trimesh.transformations.rotation_matrix(rot_z_rad, [0, 0, 1])
    T[:3, 3] = center
    return trimesh.creation.box(extents=size, transform=T)


def _strut(p0, p1, width: float, depth: float) -> trimesh.Trimesh:
    """A beam of section width × depth (m) from p0 to p1 in the z = 0 plane."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    return _box([np.linalg.norm(d), width, depth], (p0 + p1) / 2, np.arctan2(d[1], d[0]))


@lru_cache(maxsize=1)
def truss_mesh() -> trimesh.Trimesh:
    """The truss mesh in metres; object origin at the bounding-box centre, x along the chords."""
    half_l = LENGTH_M / 2
    xv = [-half_l + CHORD_M / 2, -0.045, half_l - CHORD_M / 2]  # verticals, unevenly spaced
    parts = [
        _box([LENGTH_M, CHORD_M, CHORD_M], [0, CHORD_Y_M, 0]),
        _box([LENGTH_M, CHORD_M, CHORD_M], [0, -CHORD_Y_M, 0]),
    ]
    parts += [_box([0.02, 2 * CHORD_Y_M, 0.02], [x, 0, 0]) for x in xv]
    parts.append(_strut([xv[0], -CHORD_Y_M, 0], [xv[1], CHORD_Y_M, 0], 0.015, 0.015))
    parts.append(_strut([xv[1], CHORD_Y_M, 0], [xv[2], -CHORD_Y_M, 0], 0.015, 0.015))
    # corner connector node (upper left) and grapple plate (lower right): full 0.05 m thickness
    parts.append(_box([0.04, 0.04, 0.04], [-half_l + 0.02, HEIGHT_M / 2 - 0.02, 0]))
    parts.append(_box([0.07, 0.045, 0.042], [0.105, -HEIGHT_M / 2 + 0.0225, 0]))
    # grapple pin on the plate and bolt heads on the +z face, in an irregular pattern
    parts.append(_box([0.012, 0.012, 0.008], [0.118, -0.075, 0.021 + 0.004]))
    for x, y in [(-0.12, CHORD_Y_M), (-0.01, CHORD_Y_M), (0.07, CHORD_Y_M), (0.15, CHORD_Y_M),
                 (-0.15, -CHORD_Y_M), (-0.08, -CHORD_Y_M), (0.02, -CHORD_Y_M)]:
        parts.append(_box([0.008, 0.008, 0.004], [x, y, CHORD_M / 2 + 0.002]))
    mesh = trimesh.boolean.union(parts, engine="manifold")
    mesh.apply_translation(-0.5 * (mesh.bounds[0] + mesh.bounds[1]))
    mesh.merge_vertices()
    return mesh


@register("object", "truss")
def truss() -> ObjectModel:
    """The built-in truss as an :class:`ObjectModel` (asymmetric, metres)."""
    return ObjectModel("truss", truss_mesh().copy(), symmetries=())
