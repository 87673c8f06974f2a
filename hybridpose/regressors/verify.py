"""Image check of a CNN pose against the pose's near-symmetric twins.

The truss (like most trusses) is almost symmetric under the half-turns of its bounding box: only
the grapple plate and the bolt heads tell its ends and faces apart. A keypoint network that
confuses them predicts a consistent but flipped set of keypoints, and PnP returns a confident,
flipped pose. So the regressor scores the PnP pose and its three twins by how many of their
visible model edges land on an image edge (the edge trackers' search, no optimisation: ~1 ms each)
and keeps the best one.
"""
from __future__ import annotations

import numpy as np

from ..core import Frame
from ..geometry import Pose, rotvec_to_matrix
from ..objects import ObjectModel

SWITCH_MARGIN = 0.05  # a twin must beat the PnP pose by this much support to replace it
# views estimated within this many degrees of edge-on (view_elevation_deg) get the edge-on mirror check
# (edge_on_mirror): 75 of the 83 views > 30° off in four test sets (seeds 128–131, 4000 views) lie there
MIRROR_BELOW_DEG = 20.0


def box_half_turns(obj: ObjectModel) -> list[Pose]:
    """The three half-turns about the axes through the bounding-box centre (object frame), as
    poses ``S`` with ``T_cam_obj @ S`` the flipped twin."""
    c = 0.5 * (obj.bbox_min + obj.bbox_max)
    out = []
    for axis in np.eye(3):
        R = 2 * np.outer(axis, axis) - np.eye(3)  # rotation by π about ``axis``
        out.append(Pose(R, c - R @ c))
    return out


def edge_on_mirror(pose: Pose, obj: ObjectModel) -> Pose:
    """The pose an edge-on view cannot tell from ``pose``: the object turned about its thin axis
    (through its bounding-box centre) so that the line of sight's direction within the object's main
    plane is mirrored across the long axis.

    Seen edge-on, a flat object's image fixes how foreshortened its long axis is but hardly whether
    that axis leans towards or away from the camera (the two differ only in perspective): the keypoint
    network's failures near edge-on are this pose, or its box twins. The box centre stays where it is in the camera frame and the view's elevation
    (:func:`~hybridpose.objects.view_elevation_deg`) is kept; applying it twice gives ``pose`` back.

    Args:
        pose: T_cam_obj (metres, OpenCV camera frame). obj: the object (its bounding-box axes: the
            longest is the long axis, the shortest the thin axis).
    Returns:
        T_cam_obj of the mirrored view.
    """
    order = np.argsort(obj.extents)
    thin, long_ = np.eye(3)[order[0]], np.eye(3)[order[-1]]
    c = obj.center
    centre_cam = pose.R @ c + pose.t
    sight = pose.R.T @ -centre_cam                 # box centre → camera, object frame
    in_plane = sight - (sight @ thin) * thin
    # signed angle from the long axis to the sight's in-plane part, about the thin axis: turning the
    # object by twice it mirrors the sight (Q^T turns the sight by -2·beta: beta → -beta)
    beta = np.arctan2(np.cross(long_, in_plane) @ thin, long_ @ in_plane)
    Q = rotvec_to_matrix(2.0 * beta * thin)
    R = pose.R @ Q
    return Pose(R, centre_cam - R @ c)


class TwinCheck:
    """Edge support of a pose and of its box twins (see module doc)."""

    def __init__(self, obj: ObjectModel) -> None:
        from ..edges import ModelView

        self.view = ModelView(obj)
        self.twins = box_half_turns(obj)

    def support(self, gray: np.ndarray, frame: Frame, pose: Pose) -> float:
        """Share of the visible edge samples with an image edge near the projection
        (:func:`~hybridpose.edges.edge_support`; 0 where too few are in view)."""
        from ..edges import edge_support

        share = edge_support(self.view, frame, pose, gray)
        return share if np.isfinite(share) else 0.0

    def best(self, frame: Frame, pose: Pose) -> tuple[Pose, float, bool]:
        """(chosen pose, its support, whether a twin replaced ``pose``)."""
        from ..edges import to_gray

        gray = to_gray(frame.image)
        base = self.support(gray, frame, pose)
        scored = [(self.support(gray, frame, pose @ s), pose @ s) for s in self.twins]
        score, twin = max(scored, key=lambda x: x[0])
        if score > base + SWITCH_MARGIN:
            return twin, score, True
        return pose, base, False
