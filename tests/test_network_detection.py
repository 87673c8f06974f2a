"""Detection by the network without a prior (``detection="network"``): the tiles it looks at, the
proposals it makes (one per place, the whole frame's first), the estimate the regressor keeps
(the one PnP fits best) and the other distinct poses a start may try."""

import numpy as np
import pytest

from hybridpose.geometry import Camera, Pose
from hybridpose.regressors.keypoint_passes import KeypointEstimate, pnp_quality
from hybridpose.regressors.keypoint_pnp import PnPResult
from hybridpose.regressors.network_detection import (FINE_TILE_SIDE, box_iou, distinct_estimates, find_object, network_boxes,
                                                     tile_boxes)

CORNERS = np.array([[x, y, z] for x in (-0.09, 0.09) for y in (-0.055, 0.055) for z in (-0.035, 0.035)])


def test_two_480_px_tiles_on_a_640_by_480_frame():
    assert tile_boxes(640, 480) == [(240.0, 240.0, 480.0), (400.0, 240.0, 480.0)]


@pytest.mark.parametrize("size", [(640, 480), (480, 640), (640, 640), (1920, 1080), (1280, 400), (96, 128)])
def test_tiles_cover_the_frame_inside_it_and_overlap_by_half(size):
    w, h = size
    tiles = tile_boxes(w, h)
    side = tiles[0][2]
    assert all(t[2] == side for t in tiles) and side <= min(w, h) + 1e-9
    assert all(side / 2 - 1e-9 <= cx <= w - side / 2 + 1e-9 and side / 2 - 1e-9 <= cy <= h - side / 2 + 1e-9
               for cx, cy, _ in tiles)
    ys, xs = np.mgrid[0:h:7, 0:w:7]
    covered = np.zeros(xs.shape, bool)
    for cx, cy, s in tiles:
        covered |= (np.abs(xs + 0.5 - cx) <= s / 2) & (np.abs(ys + 0.5 - cy) <= s / 2)
    assert covered.all()
    for axis in (0, 1):
        centres = sorted({t[axis] for t in tiles})
        assert all(b - a <= side / 2 + 1e-9 for a, b in zip(centres, centres[1:]))


def test_box_iou_matches_counted_pixels():
    rng = np.random.default_rng(0)
    for _ in range(50):
        a, b = [(*rng.integers(0, 40, 2), *rng.integers(1, 30, 2)) for _ in range(2)]
        masks = []
        for x, y, w, h in (a, b):
            m = np.zeros((80, 80), bool)
            m[y:y + h, x:x + w] = True
            masks.append(m)
        oracle = (masks[0] & masks[1]).sum() / (masks[0] | masks[1]).sum()
        assert box_iou(a, b) == pytest.approx(oracle)


def _result(pose: Pose, kept: float = 1.0, rms_px: float = 1.0) -> PnPResult:
    inliers = np.arange(len(CORNERS)) < round(kept * len(CORNERS))
    return PnPResult(pose, inliers, rms_px, np.eye(6))


class FakePasses:
    """Passes whose network 'sees' a fixed pose in chosen views (by index: 0 the whole frame, then tiles)."""

    def __init__(self, seen: dict) -> None:
        self.keypoints_m, self.image_size, self.unlabelled = CORNERS, 128, None
        self.seen, self.views = seen, None

    def solve_boxes(self, image, K, views):
        self.views = list(views)
        self.calls = getattr(self, "calls", 0) + 1
        return [(self.seen.get(i), np.zeros((0, 2)), np.eye(3), [0], None) for i in range(len(views))]


def test_one_proposal_per_place_the_whole_frames_first():
    cam = Camera.default().scaled((640, 480))
    left = _result(Pose.from_rotvec_t([0.3, 0.2, 0.1], [-0.25, 0.0, 1.2]))
    right = _result(Pose.from_rotvec_t([0.1, -0.4, 0.2], [0.25, 0.05, 1.0]))
    passes = FakePasses({0: left, 1: _result(left.pose @ Pose.from_rotvec_t([0, 0, 0], [0.002, 0, 0])), 2: right})
    boxes = network_boxes(passes, np.zeros((480, 640, 3), np.uint8), cam)
    assert passes.views == [(319.5, 239.5, 640.0), *tile_boxes(640, 480)]
    assert len(boxes) == 2
    uv = cam.project(CORNERS, left.pose)
    np.testing.assert_allclose(boxes[0][:2], uv.min(0), atol=1e-6)
    assert box_iou(boxes[1], boxes[0]) == 0.0
    assert network_boxes(FakePasses({}), np.zeros((480, 640, 3), np.uint8), cam) == []
    # without tiles: the whole frame's pass only
    only = FakePasses({2: right})
    assert network_boxes(only, np.zeros((480, 640, 3), np.uint8), cam, tiles=False) == [] and len(only.views) == 1


def test_the_regressor_keeps_the_estimate_pnp_fits_best():
    cam = Camera.default().scaled((640, 480))
    image = np.zeros((480, 640, 3), np.uint8)
    poses = [Pose.from_rotvec_t([0.3, 0.2, 0.1], [-0.25, 0.0, 1.2]), Pose.from_rotvec_t([0.1, -0.4, 0.2], [0.25, 0.05, 1.0])]
    for kept, expect in (((0.5, 1.0), 1), ((1.0, 0.5), 0), ((1.0, 1.0), 0)):   # equals: the whole frame's
        passes = FakePasses({0: _result(poses[0]), 2: _result(poses[1])})
        estimates = {}

        def estimate_in(image, cam, box, sun_turn, kept=kept):
            i = len(estimates)
            estimates[i] = KeypointEstimate(_result(poses[i], kept[i]), [0], None, 128)
            return estimates[i]

        passes.estimate_in = estimate_in
        box, est = find_object(passes, image, cam, 0.0)
        assert est is estimates[expect] and pnp_quality(est) == max(pnp_quality(e) for e in estimates.values())
        np.testing.assert_allclose(box[:2], cam.project(CORNERS, poses[expect]).min(0), atol=1e-6)
    # proposals but no estimate: the first proposal's box, no estimate (the dim fallback may follow)
    passes = FakePasses({0: _result(poses[0])})
    passes.estimate_in = lambda *a: None
    box, est = find_object(passes, image, cam, 0.0)
    assert est is None and box == network_boxes(passes, image, cam)[0]


def test_the_other_estimates_come_best_first_and_a_start_gets_the_distinct_ones():
    """Every pass's own pose and every other proposal's estimate are offered, best PnP fit first; the
    distinct ones leave out poses that project the keypoints where the chosen one does (the same pose,
    a millimetre off, or the box turned by one of its symmetries)."""
    cam = Camera.default().scaled((640, 480))
    image = np.zeros((480, 640, 3), np.uint8)
    part, clutter = (Pose.from_rotvec_t([0.3, 0.2, 0.1], [-0.25, 0.0, 1.2]), Pose.from_rotvec_t([0.1, -0.4, 0.2], [0.25, 0.05, 1.0]))
    passes = FakePasses({0: _result(part, 0.75), 2: _result(clutter, 0.75)})
    passes.max_depth_m = None
    crops = []

    def estimate_in(image, cam, box, sun_turn):  # the crop on the part fits better than its whole-frame pass
        pose = part if box[0] + box[2] / 2 < 320 else clutter
        crops.append(KeypointEstimate(_result(pose, 1.0 if pose is part else 0.5), [0], None, 128))
        return crops[-1]

    passes.estimate_in = estimate_in
    others = []
    box, est = find_object(passes, image, cam, 0.0, others=others)
    assert est.result.pose is part and all(e is not est for _, e in others)
    assert len(others) == 3 and [pnp_quality(e) for _, e in others] == sorted((pnp_quality(e) for _, e in others), reverse=True)
    assert box == find_object(passes, image, cam, 0.0)[0]   # asking for the others changes nothing
    half_turn = Pose.from_rotvec_t([np.pi, 0, 0], [0, 0, 0])   # a symmetry of the box CORNERS
    nudged = Pose(part.R, part.t + [0.001, 0, 0])
    listed = [(None, KeypointEstimate(_result(p), [0], None, 128)) for p in (part @ half_turn, nudged, clutter, clutter @ half_turn)]
    kept = distinct_estimates(listed, part, CORNERS, cam, limit=4)
    assert [k.result.pose for k in kept] == [clutter]
    assert distinct_estimates(listed, None, CORNERS, cam, limit=4)[0].result.pose is listed[0][1].result.pose
    assert len(distinct_estimates(listed, None, CORNERS, cam, limit=4)) == 2
    assert distinct_estimates(listed, part, CORNERS, cam, limit=0) == []


def test_fine_tiles_look_again_where_no_estimate_fits_well():
    cam = Camera.default().scaled((640, 480))
    image = np.zeros((480, 640, 3), np.uint8)
    clutter, part = (Pose.from_rotvec_t([0.3, 0.2, 0.1], [-0.25, 0.0, 1.2]),
                     Pose.from_rotvec_t([0.1, -0.4, 0.2], [0.3, 0.1, 2.5]))
    fine_views = tile_boxes(640, 480, FINE_TILE_SIDE)
    assert len(fine_views) == 12 and fine_views[0][2] == 256

    def run(fine_tiles, clutter_kept, part_kept):
        passes = FakePasses({0: _result(clutter)})
        coarse = passes.solve_boxes

        def solve_boxes(image, K, views):  # only a fine tile's pass sees the small part
            views = list(views)
            out = coarse(image, K, views)
            if views == fine_views:
                out[4] = (_result(part), *out[4][1:])
            return out

        def estimate_in(image, cam, box, sun_turn):  # the clutter lies left of the frame's centre, the part right
            left = box[0] + box[2] / 2 < 320
            return KeypointEstimate(_result(clutter if left else part, clutter_kept if left else part_kept, 0.2), [0], None, 128)

        passes.solve_boxes, passes.estimate_in = solve_boxes, estimate_in
        return find_object(passes, image, cam, 0.0, fine_tiles=fine_tiles)[1], passes.calls

    # a poor fit from the coarse look: the fine tiles find the part and their well-fitting estimate wins
    est, calls = run(True, 0.5, 1.0)
    assert calls == 2 and est.result.pose.allclose(part)
    # a fine find that PnP fits no better than FINE_ACCEPT is not taken
    est, _ = run(True, 0.5, 0.6)
    assert est.result.pose.allclose(clutter)
    # a good coarse fit, or the option off: one look only
    assert run(True, 1.0, 1.0)[1] == 1 and run(False, 0.5, 1.0)[1] == 1
