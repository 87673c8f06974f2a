"""Whether the image singles out a pose (hybridpose.edges.distinct): a rendered box on a plain table
stands out from its own view slid beside it; the same box's outline laid small over clutter matches
about as many edges as a right pose does, but no more than the placements around it."""
import numpy as np
import pytest
import trimesh

from hybridpose import Frame, HybridConfig, HybridEstimator, Measurement, registry
from hybridpose.edges import ModelView, edge_support, placement_contrast
from hybridpose.edges.distinct import PlacementContrast
from hybridpose.geometry import Camera, Pose, shifted_in_image
from hybridpose.objects import load_object
from hybridpose.render import Renderer
from hybridpose.render.appearance import Appearance

CAM = Camera.default().scaled((320, 240))
TRUTH = Pose.from_rotvec_t([0.5, 0.3, 0.1], [-0.06, 0.0, 0.7])


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    path = tmp_path_factory.mktemp("box") / "box.obj"
    trimesh.creation.box(extents=(0.2, 0.12, 0.08)).export(path)
    return load_object(str(path))


def busy_right_half(seed: int = 5) -> np.ndarray:
    """A plain grey table on the left, random 5-px tiles (a keyboard, cables) on the right."""
    image = np.full((CAM.height, CAM.width, 3), 150, np.uint8)
    tiles = np.random.default_rng(seed).integers(0, 256, (CAM.height // 5 + 1, CAM.width // 5 + 1, 3), dtype=np.uint8)
    busy = np.repeat(np.repeat(tiles, 5, 0), 5, 1)[:CAM.height, :CAM.width]
    image[:, CAM.width // 2 + 40:] = busy[:, CAM.width // 2 + 40:]
    return image


@pytest.fixture(scope="module")
def scene(box):
    with Renderer(box, CAM) as r:
        image = r.render(TRUTH, rng=0, appearance=Appearance(ambient=0.4, background=busy_right_half())).rgb
    return Frame(image, CAM, 0.0, 0)


MARGIN = HybridConfig().start_contrast


def test_a_right_pose_on_a_plain_table_stands_out(box, scene):
    view = ModelView(box)
    contrast = placement_contrast(view, scene, TRUTH)
    assert contrast.here == edge_support(view, scene, TRUTH) > 0.8
    assert contrast.here - contrast.around > 0.5 and contrast.stands_out(MARGIN)


def test_an_outline_laid_small_over_clutter_matches_edges_but_does_not_stand_out(box, scene):
    view = ModelView(box)
    # the part three times as far, over the tiles: what a CNN fooled by the clutter proposes
    far = shifted_in_image(Pose(TRUTH.R, TRUTH.t * 3.0), CAM, 120.0, 10.0)
    u = CAM.project(box.bbox_corners, far)[:, 0]
    assert u.min() > CAM.width // 2 + 40  # all of it over the tiles
    contrast = placement_contrast(view, scene, far)
    assert contrast.here > 0.3  # the tiles' edges hold a good share of its outline …
    assert not contrast.stands_out(MARGIN)  # … as they hold its neighbours'


def test_no_score_without_enough_of_the_part_in_view(box, scene):
    view = ModelView(box)
    beside_the_frame = Pose(TRUTH.R, TRUTH.t + [1.0, 0.0, 0.0])
    assert np.isnan(edge_support(view, scene, beside_the_frame))
    contrast = placement_contrast(view, scene, beside_the_frame)
    assert np.isnan(contrast.here) and contrast.stands_out(MARGIN)  # no verdict: no veto


def test_on_black_space_a_sliver_of_matched_edges_stands_out():
    """A sunlit sliver matches few of the part's edges, and the black around it none."""
    contrast = PlacementContrast(here=0.2, around=0.02)
    assert contrast.here - contrast.around < MARGIN and contrast.stands_out(MARGIN)
    assert not PlacementContrast(here=0.5, around=0.25).stands_out(MARGIN)


class FooledRegressor:
    """A CNN fooled by the clutter: the part small, over the tiles, with a wide covariance."""

    hybrid_config = {}

    def __init__(self, pose: Pose):
        self.pose = pose

    def predict(self, frame, roi=None):
        return Measurement(self.pose, np.diag([0.5**2] * 3 + [0.3**2] * 3), 0.5, "regressor:fooled", frame.timestamp)


def test_a_start_over_clutter_that_its_neighbours_match_as_well_stays_init(box, scene):
    far = shifted_in_image(Pose(TRUTH.R, TRUTH.t * 3.0), CAM, 120.0, 10.0)
    fooled = FooledRegressor(far)

    def first_step(start_contrast):
        est = HybridEstimator(registry.create("tracker", "edges", object=box), fooled, registry.create("fusion", "ukf"),
                              HybridConfig(start_contrast=start_contrast))
        return est.step(scene)

    assert first_step(0.0).pose is not None  # the edge tracker alone confirms it …
    assert first_step(HybridConfig().start_contrast).pose is None  # … the contrast test does not


class TruthRegressor(FooledRegressor):
    """A CNN that gives the true pose."""


def test_off_black_space_a_start_that_only_the_edges_confirm_stays_init(box):
    """``combined`` reports its cues: on the frame a start is checked on its texture cannot speak, and
    where the part's colours do not stand out from a lit background its region cue has no verdict
    either — the edges alone do not start the hybrid there. The tracker alone is not judged."""
    from hybridpose.render.appearance import Appearance

    for grey, starts in ((196, False), (150, True)):  # the part's brightest face's grey; a darker table
        with Renderer(box, CAM) as r:
            image = r.render(TRUTH, rng=0, appearance=Appearance(ambient=0.4, background=np.full(
                (CAM.height, CAM.width, 3), grey, np.uint8))).rgb
        frame = Frame(image, CAM, 0.0, 0)
        tracker = registry.create("tracker", "combined", object=box)
        est = HybridEstimator(tracker, TruthRegressor(TRUTH), registry.create("fusion", "ukf"),
                              HybridConfig(plain_surround_quality=0.0))
        assert (est.step(frame).pose is not None) == starts
        assert {n for n, q in tracker.cue_qualities.items() if np.isfinite(q)} == ({"edges", "region"} if starts else {"edges"})
        # on this plain table the edges alone may vouch where their fit is sure (plain_surround_quality)
        plain = HybridEstimator(registry.create("tracker", "combined", object=box), TruthRegressor(TRUTH),
                                registry.create("fusion", "ukf"), HybridConfig(plain_surround_quality=0.75))
        assert plain.step(frame).pose is not None
        alone = registry.create("tracker", "combined", object=box)
        alone.init(frame, TRUTH)
        assert not alone.track(frame).lost


@pytest.fixture(scope="module")
def plain_scene(box):
    """The box on a plain grey table, nothing else in view."""
    with Renderer(box, CAM) as r:
        image = r.render(TRUTH, rng=0, appearance=Appearance(ambient=0.4, background=np.full(
            (CAM.height, CAM.width, 3), 150, np.uint8))).rgb
    return Frame(image, CAM, 0.0, 0)


def test_a_plain_table_around_the_part_is_told_from_clutter(box, scene, plain_scene):
    """On a plain table the right pose's slid views find almost no edges; the outline laid over the tiles
    has tiles all round it, and so has the right pose near them."""
    view = ModelView(box)
    assert placement_contrast(view, plain_scene, TRUTH).plain_around()
    assert not placement_contrast(view, scene, TRUTH).plain_around()
    far = shifted_in_image(Pose(TRUTH.R, TRUTH.t * 3.0), CAM, 120.0, 10.0)
    assert not placement_contrast(view, scene, far).plain_around()
    assert not PlacementContrast(here=float("nan"), around=0.0).plain_around()
    assert not PlacementContrast(here=0.0, around=0.0).plain_around()  # nothing matched here either


@pytest.mark.parametrize("quality, bar, refused", [(0.85, 0.0, True), (0.85, 0.75, False), (0.7, 0.75, True)])
def test_an_edges_alone_start_on_a_plain_table_is_taken_at_the_plain_surround_bar(box, scene, plain_scene, quality, bar,
                                                                                  refused):
    """In a lit scene the edges alone do not make a start, unless the part stands on a plain surface
    (``plain_surround_quality``) and its fit reaches that bar; over clutter they never do."""
    from hybridpose.starts import start_refused_in_light

    view, edges_alone = ModelView(box), {"edges": 0.9, "region": float("nan")}
    fit = Measurement(TRUTH, np.eye(6) * 1e-4, quality, "tracker:edges", 0.0)
    assert start_refused_in_light(edges_alone, plain_scene, view, fit, 0.0, bar) == refused
    far = shifted_in_image(Pose(TRUTH.R, TRUTH.t * 3.0), CAM, 120.0, 10.0)
    assert start_refused_in_light(edges_alone, scene, view, Measurement(far, fit.covariance, 0.9, "tracker:edges", 0.0),
                                  0.0, 0.75)
    assert not start_refused_in_light({"edges": 0.9, "region": 0.7}, scene, view, fit, 0.0, 0.0)  # another cue spoke
    black = Frame(np.zeros_like(scene.image), CAM, 0.0, 0)
    assert not start_refused_in_light(edges_alone, black, view, fit, 0.0, 0.0)  # black space: the edges decide


def test_a_networks_other_poses_are_tried_only_on_plain_surroundings(box, scene, plain_scene):
    """``plain_alternatives``: the network's answer always stays first; its other poses only where the
    part's surroundings are lit and plain (the scene with tiles beside the part, black space, or no model
    view: the answer alone)."""
    from hybridpose.starts import plain_alternatives

    view = ModelView(box)
    cov = np.eye(6) * 1e-4
    answer = Measurement(shifted_in_image(TRUTH, CAM, 40.0, 0.0), cov, 0.5, "regressor:test", 0.0)
    other = Measurement(TRUTH, cov, 0.5, "regressor:test", 0.0)
    nothing = Measurement(None, cov, 0.0, "regressor:test", 0.0)
    assert plain_alternatives([answer, other, nothing], plain_scene, view) == [answer, other]
    assert plain_alternatives([answer, other], scene, view) == [answer]
    assert plain_alternatives([answer, other], plain_scene, None) == [answer]
    assert plain_alternatives([], plain_scene, view) == []
    with Renderer(box, CAM) as r:   # black space around the part: plain, but the space suites measured none
        space = Frame(r.render(TRUTH, rng=0, appearance=Appearance(ambient=0.4, background=np.zeros(
            (CAM.height, CAM.width, 3), np.uint8))).rgb, CAM, 0.0, 0)
    assert placement_contrast(view, space, TRUTH).plain_around()
    assert plain_alternatives([answer, other], space, view) == [answer]


def test_a_start_in_clutter_where_no_other_look_of_the_network_saw_the_part_is_refused(box, scene, plain_scene):
    """``unseen_in_clutter``: in a lit scene with clutter around the part, a start whose place none of the
    network's other sightings covers (by ``min_iou``) is refused; one sighting there is enough. On a plain
    table, on black space, without sightings to judge by (None) or with the test off, nothing is refused."""
    from hybridpose.starts import unseen_in_clutter

    view, bar = ModelView(box), HybridConfig().start_sighting_iou
    assert bar > 0
    fit = Measurement(TRUTH, np.eye(6) * 1e-4, 0.9, "tracker:edges", 0.0)
    far = shifted_in_image(Pose(TRUTH.R, TRUTH.t * 3.0), CAM, 120.0, 10.0)
    assert unseen_in_clutter((), scene, view, fit, bar)  # nothing else saw it
    assert unseen_in_clutter((far,), scene, view, fit, bar)  # the passes saw it elsewhere, small
    assert not unseen_in_clutter((shifted_in_image(TRUTH, CAM, 8.0, -5.0), far), scene, view, fit, bar)
    assert not unseen_in_clutter(None, scene, view, fit, bar)
    assert not unseen_in_clutter((), scene, view, fit, 0.0)
    assert not unseen_in_clutter((), plain_scene, view, fit, bar)
    assert not unseen_in_clutter((), Frame(np.zeros_like(scene.image), CAM, 0.0, 0), view, fit, bar)
    assert not unseen_in_clutter((), scene, view, Measurement(None, fit.covariance, 0.0, "tracker:edges", 0.0), bar)
    with pytest.raises(ValueError, match="start_sighting_iou"):
        HybridConfig(start_sighting_iou=1.5)


class SightingRegressor(TruthRegressor):
    """The true pose, with the places where the network's other passes saw the part (``candidates``)."""

    def __init__(self, pose: Pose, sightings):
        super().__init__(pose)
        self.sightings = sightings

    def candidates(self, frame, roi=None, limit=4):
        from hybridpose.regressors.base import Candidates

        return Candidates([self.predict(frame, roi)], self.sightings)


@pytest.mark.parametrize("sightings, iou, starts", [((), 0.25, False), ((TRUTH,), 0.25, True), ((), 0.0, True),
                                                    (None, 0.25, True)])
def test_a_start_in_clutter_needs_the_networks_other_passes_to_have_seen_the_part_there(box, scene, sightings, iou,
                                                                                        starts):
    est = HybridEstimator(registry.create("tracker", "edges", object=box), SightingRegressor(TRUTH, sightings),
                          registry.create("fusion", "ukf"), HybridConfig(start_sighting_iou=iou))
    assert (est.step(scene).pose is not None) == starts
