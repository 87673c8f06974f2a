"""The trackers' quality terms (hybridpose.edges): how much of the image around the object the model
explains at a pose — its edges and, on a dark background, its lit pixels — on rendered truss views."""
import numpy as np
import pytest

from hybridpose.core import Frame
from hybridpose.edges import ModelView, explained_edge_share, explained_lit_share
from hybridpose.geometry import Pose
from hybridpose.render import Renderer, random_poses

OFF_DEG = 5.0


@pytest.fixture(scope="module")
def views(truss, camera):
    """Eight sunlit 640×480 views of the whole truss on black space (0.4–1.0 m, seed 11)."""
    poses = random_poses(8, camera, (0.4, 1.0), rng=11, in_view_points=truss.bbox_corners)
    with Renderer(truss, camera) as r:
        return [(Frame(r.render(p, rng=i).rgb, camera, float(i), i), p) for i, p in enumerate(poses)]


@pytest.fixture(scope="module")
def view(truss):
    return ModelView(truss)


def off(pose: Pose, deg: float, seed: int) -> Pose:
    axis = np.random.default_rng(seed).normal(size=3)
    return pose.retract(np.r_[np.radians(deg) * axis / np.linalg.norm(axis), 0, 0, 0])


def test_the_true_pose_explains_the_lit_pixels_and_a_wrong_one_does_not(view, views):
    at_truth = [explained_lit_share(view, f, p) for f, p in views]
    wrong = [explained_lit_share(view, f, off(p, OFF_DEG, f.index)) for f, p in views]
    assert all(np.isfinite(at_truth)) and min(at_truth) >= 0.99, at_truth
    # the quality's lit term falls to the lost threshold (0.5) at 98 %
    assert np.median(wrong) < 0.98 and sum(w < 0.98 for w in wrong) >= 6, wrong


def test_the_edge_term_agrees_on_the_same_views(view, views):
    at_truth = [explained_edge_share(view, f, p) for f, p in views]
    wrong = [explained_edge_share(view, f, off(p, OFF_DEG, f.index)) for f, p in views]
    assert np.median(at_truth) > 0.9 and np.median(wrong) < np.median(at_truth) - 0.2


def test_no_verdict_on_a_lit_background_or_without_the_object(view, views):
    frame, pose = views[0]
    lit_background = np.maximum(frame.image, 90).astype(np.uint8)  # a bright scene behind the truss
    assert np.isnan(explained_lit_share(view, Frame(lit_background, frame.camera, 0.0, 0), pose))
    black = np.zeros_like(frame.image)
    assert np.isnan(explained_lit_share(view, Frame(black, frame.camera, 0.0, 0), pose))  # nothing lit near it
    far = Pose(pose.R, pose.t * 40.0)  # a silhouette of a few pixels
    assert np.isnan(explained_lit_share(view, frame, far))
