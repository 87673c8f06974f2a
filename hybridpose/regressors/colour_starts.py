"""Starts for a printed part that its keypoints do not find: the part posed every way round where its
print's colours stand out (:class:`~hybridpose.regressors.print_colours.PrintColours`), at the distance
the size of that region gives — candidates for the hybrid's start checks, as a network's answer is.

Why: a dark or smooth print (a star field, a near-uniform blue) shows SIFT too few corners for the
keypoint memory to find it in a blurred, cluttered frame, while its colours still single out the
region it lies in (the hand-held tuning scenes: the region holds the whole part on 11 of 12 sampled
frames of two such sequences where the memory found it on 3 and 0). The tracker, started from each
candidate, and the start checks (:func:`hybridpose.starts.confirmed_start`: the fit's quality, the
image singling the fit out, the print showing it) then decide; on those frames the checks accepted no
candidate's fit more than 4.2° and 1.1 cm from the truth. The price is time (tens of fits a frame:
seconds on a CPU core), so the hybrid asks for them every few frames while it has no pose
(:attr:`~hybridpose.hybrid_config.HybridConfig.colour_start_every`).

Written here: OpenCV gives the colour region; how to cover the orientations a start's basin can reach,
up to the part's symmetries, is the part's.
"""
from __future__ import annotations

import numpy as np

from ..core import Frame, Measurement
from ..geometry import Pose, facing_pose, rotvec_to_matrix, sphere_directions
from ..objects import ObjectModel
from .print_colours import BOX_GROW, PrintColours

DIRECTIONS = 26      # directions the part is seen from (a Fibonacci lattice: ~40° apart)
TURNS = 4            # turns about the line of sight at each, 90° apart
# a candidate within this of one kept (up to the part's symmetries) is left out: a start's fit turns
# ~10° into the truth (the printed cube: 104 orientations → 32)
SPACING_DEG = 20.0
# the distance from the region's size: the part's diameter over the region's larger side (the box
# unshrunk by BOX_GROW), a little nearer (the region misses the part's shaded edges); the start's depth
# search (``start_depth_span``) covers the rest
NEARER = 0.9
# a colour region smaller than this (px, the box unshrunk) is more often one patch of a many-coloured print
# than the whole part: on ViSP's MegaPose cube (150 px across) its print's region spans 25–68 px on most
# frames, and the part posed to that size, a tiny cube inside one of its own tiles, scored the print 0.9
# there; the hand-held tuning scenes' accepted colour starts came from regions of 104–161 px
MIN_REGION_PX = 80
SIGMA_DEG = SPACING_DEG          # a candidate's rotation uncertainty (1σ): the spacing of the candidates
SIGMA_DISTANCE_SHARE = 0.3       # its position's (1σ, each axis): this share of its distance
SOURCE = "regressor:colours"     # the candidates' Measurement.source


class ColourStarts:
    """Candidate poses of ``object`` (a part carrying its print) where its print's colours stand out.

    Args:
        object: the part (:class:`~hybridpose.objects.ObjectModel` with ``texture``).
        directions, turns: the orientations tried: ``directions`` over the sphere × ``turns`` about
            the line of sight, thinned to ``spacing_deg`` apart up to ``object.symmetries``.
    """

    def __init__(self, object: ObjectModel, directions: int = DIRECTIONS, turns: int = TURNS,
                 spacing_deg: float = SPACING_DEG) -> None:
        if object.texture is None:
            raise ValueError(f"object: expected a part that carries its print (texture), got {object.name!r} without one")
        self.object = object
        self.colours = PrintColours(object.texture)
        self.rotations = _orientations(object.symmetries, directions, turns, spacing_deg)

    def __len__(self) -> int:
        return len(self.rotations)

    def candidates(self, frame: Frame) -> list[Measurement]:
        """The candidate poses (``T_cam_obj``) in ``frame``, one per orientation, the part's centre on the
        ray through the centre of the print's colour region; none where no region stands out, or where it
        spans less than ``MIN_REGION_PX`` (a patch of the print, not the part)."""
        box = self.colours.box(frame.image)
        if box is None:
            return []
        x, y, w, h = box
        K = frame.camera.K
        region_px = max(w, h) / (1 + BOX_GROW)
        if region_px < MIN_REGION_PX:
            return []
        depth = NEARER * K[0, 0] * self.object.diameter / region_px
        ray = np.linalg.solve(K, [x + w / 2, y + h / 2, 1.0])
        centre_cam = ray / ray[2] * depth
        toward = _turn_onto(centre_cam / np.linalg.norm(centre_cam))
        sigma_m = SIGMA_DISTANCE_SHARE * float(np.linalg.norm(centre_cam))
        covariance = np.diag([np.radians(SIGMA_DEG) ** 2] * 3 + [sigma_m ** 2] * 3)
        out = []
        for R in self.rotations:
            R_cam = toward @ R
            pose = Pose(R_cam, centre_cam - R_cam @ self.object.center)
            out.append(Measurement(pose, covariance, 0.0, SOURCE, frame.timestamp))
        return out


def _orientations(symmetries, directions: int, turns: int, spacing_deg: float) -> np.ndarray:
    """(N, 3, 3) rotations (object → camera looking at the part), ``spacing_deg`` apart up to ``symmetries``."""
    equivalents = np.array([np.eye(3)] + [S.R for S in symmetries])              # (E, 3, 3)
    taken = np.zeros((0, 3, 3))   # every kept rotation times every symmetry
    kept = []
    cos_spacing = np.cos(np.radians(spacing_deg))
    for d in sphere_directions(directions):
        base = facing_pose(d, 1.0).R
        for k in range(turns):
            R = rotvec_to_matrix([0.0, 0.0, 2 * np.pi * k / turns]) @ base
            # the geodesic angle to each: cos θ = (trace(Rᵀ A) − 1) / 2
            cos = (np.einsum("ij,nij->n", R, taken) - 1) / 2
            if not np.any(cos > cos_spacing):
                kept.append(R)
                taken = np.concatenate([taken, R @ equivalents])
    return np.array(kept)


def _turn_onto(direction: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation turning the camera's optical axis onto the unit vector ``direction``."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, direction)
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        return np.eye(3)
    return rotvec_to_matrix(axis / s * np.arctan2(s, float(direction @ z)))
