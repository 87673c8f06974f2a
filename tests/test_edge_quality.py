"""The trackers' quality terms (hybridpose.edges): how much of the image around the object the model
explains at a pose — its edges and, on a dark background, its lit pixels — on rendered truss views."""
import numpy as np
import pytest

from hybridpose.core import Frame
from hybridpose.edges import ModelView, explained_edge_share, explained_lit_share, lit_verdict
from hybridpose.geometry import Pose
from hybridpose.registry import create
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


def with_arm(frame: Frame, pose: Pose, truss) -> Frame:
    """``frame`` with a flat lit plate (the arm's tool plate) over the right 40 % of the object's
    projected box, reaching beyond it above, below and to the right."""
    uv = frame.camera.project(truss.bbox_corners, pose)
    (x0, y0), (x1, y1) = uv.min(0), uv.max(0)
    image = frame.image.copy()
    image[max(int(y0) - 40, 0):int(y1) + 40, int(x1 - 0.4 * (x1 - x0)):] = 140
    return Frame(image, frame.camera, frame.timestamp, frame.index, sun_direction_cam=frame.sun_direction_cam)


def test_something_lit_beside_the_object_is_seen(view, views, truss):
    frame, pose = views[1]
    clear = lit_verdict(view, frame, pose)
    assert not clear.beside and clear.share >= 0.99
    covered = lit_verdict(view, with_arm(frame, pose, truss), pose)
    assert covered.beside and np.isnan(covered.share)  # no lit-pixel verdict beside an occluder


TELLS_COVERED = ["edges", "klt-pnp", "rapid", "rapid-gos", "rapid-ols"]  # the edge-refining trackers


def test_the_trackers_that_tell_covered_are_the_edge_refining_ones(truss):
    from hybridpose.registry import available

    assert [n for n in available("tracker") if create("tracker", n, object=truss).tells_covered] == TELLS_COVERED
    assert not create("tracker", "rapid", object=truss, refine=False).tells_covered
    assert not create("tracker", "edges", object=truss, explain=False).tells_covered


@pytest.mark.parametrize("name", TELLS_COVERED)
def test_a_tracker_sees_an_arm_come_in_but_not_a_lit_background(name, views, truss):
    frame, pose = views[1]
    trk = create("tracker", name, object=truss)
    trk.init(frame, pose)
    assert not trk.track(frame, pose).lost and not trk.covered
    armed = with_arm(frame, pose, truss)
    m = trk.track(armed, pose)
    assert trk.covered and 0 < m.quality < 0.5  # the arm's edges and the hidden beams cost the fit
    assert trk.track(armed, pose, lost_quality=m.quality + 0.05).lost
    kept = trk.track(armed, pose, lost_quality=m.quality + 0.05, covered_lost_quality=m.quality - 0.05)
    assert not kept.lost and kept.pose is not None
    # a background lit from the start (a photo, the Earth) is not an occluder
    lit_background = Frame(np.maximum(armed.image, 90).astype(np.uint8), frame.camera, 0.0, 0)
    trk.init(lit_background, pose)
    trk.track(lit_background, pose)
    assert not trk.covered
    with pytest.raises(ValueError, match="covered_lost_quality"):
        trk.track(frame, pose, covered_lost_quality=1.5)
