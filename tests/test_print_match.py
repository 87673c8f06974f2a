"""A printed part's print at a pose (edges.print_match) against MuJoCo renders of it: the right pose
shows it and singles out its branch among the shape's equivalent poses; the outline laid elsewhere
does not."""
import cv2
import numpy as np
import pytest
import trimesh

from hybridpose.core import Frame
from hybridpose.edges import ModelView
from hybridpose.edges.print_match import PrintView, print_agreement
from hybridpose.geometry import Camera, Pose, turned_about
from hybridpose.objects import ObjectModel
from hybridpose.render import Appearance, Renderer
from hybridpose.render.appearance import clutter_background

CAM = Camera.default().scaled((320, 240))


@pytest.fixture(scope="module")
def printed_cube(print_on_cube):
    """A 6-cm cube whose faces are unwrapped into the six cells of a 3 × 2 print of random blocks."""
    rng = np.random.default_rng(4)
    image = cv2.resize(rng.integers(0, 255, (12, 18, 3)).astype(np.uint8), (384, 256), interpolation=cv2.INTER_NEAREST)
    return print_on_cube(image)


def _frame(obj, pose, background):
    with Renderer(obj, CAM) as r:
        rgb = r.render(pose, appearance=Appearance(ambient=0.8, fill_lights=(((0.0, 0.0, 1.0), 0.4),),
                                                    background=background)).rgb
    return Frame(rgb, CAM, 0.0, 0)


def test_the_right_pose_shows_the_print_and_picks_its_branch(printed_cube):
    pose = Pose.from_rotvec_t([0.5, -0.4, 0.3], [0.0, 0.0, 0.35])
    background = clutter_background(CAM.width, CAM.height, np.random.default_rng(1))
    frame = _frame(printed_cube, pose, background)
    view = PrintView(ModelView(printed_cube))
    assert view.score(frame, pose) > 0.6
    shape_twins = ObjectModel("cube", printed_cube.mesh)  # the same shape, its 23 look-alike poses
    twin = PrintView(ModelView(ObjectModel("printed-cube", printed_cube.mesh, symmetries=shape_twins.symmetries,
                                           texture=printed_cube.texture, face_uv=printed_cube.face_uv)))
    agreement = print_agreement(twin, frame, pose)
    assert agreement.singles_out(0.2) and agreement.branch.allclose(Pose.identity(), atol=1e-9)
    # a look-alike pose of the shape shows another face's print: the print gives it away
    turned = pose @ shape_twins.symmetries[0]
    assert view.score(frame, turned) < 0.3
    # the same outline laid over the clutter beside the part
    beside = Pose(pose.R, pose.t + np.array([0.09, 0.0, 0.0]))
    assert not print_agreement(twin, frame, beside).singles_out(0.2)


def test_a_plain_part_has_no_print_view():
    with pytest.raises(ValueError, match="carries no print"):
        PrintView(ModelView(ObjectModel("cube", trimesh.creation.box((0.06,) * 3))))


def test_a_start_of_a_printed_part_must_show_its_print(printed_cube):
    from hybridpose.starts import image_test, print_view

    pose = Pose.from_rotvec_t([0.2, 0.6, -0.1], [0.01, 0.0, 0.3])
    frame = _frame(printed_cube, pose, clutter_background(CAM.width, CAM.height, np.random.default_rng(2)))
    view = ModelView(printed_cube)
    test = image_test(view, frame, 0.0, print_view(view), 0.2)  # the print alone (no placement contrast)
    assert test(pose).allclose(Pose.identity()) and test(Pose(pose.R, pose.t + np.array([-0.08, 0.02, 0.0]))) is None
    assert image_test(view, frame, 0.0, print_view(view), 0.0) is None  # both off: no test
    assert print_view(ModelView(ObjectModel("cube", trimesh.creation.box((0.06,) * 3)))) is None


def test_a_start_at_a_look_alike_pose_of_a_printed_part_is_restated_at_the_pose_its_print_shows(printed_cube):
    from hybridpose.core import Measurement
    from hybridpose.hybrid_config import HybridConfig
    from hybridpose.starts import confirmed_start, image_test, print_view

    twins = ObjectModel("cube", printed_cube.mesh).symmetries  # the shape's 23 look-alike poses
    obj = ObjectModel("printed-cube", printed_cube.mesh, symmetries=twins, texture=printed_cube.texture,
                      face_uv=printed_cube.face_uv)
    pose = Pose.from_rotvec_t([0.3, -0.5, 0.2], [0.0, 0.01, 0.32])
    frame = _frame(obj, pose, clutter_background(CAM.width, CAM.height, np.random.default_rng(3)))
    view = ModelView(obj)
    test = image_test(view, frame, 0.0, print_view(view), 0.2)
    covariance = np.diag([1e-4, 2e-4, 3e-4, 1e-6, 2e-6, 3e-6])
    for S in twins[::5]:
        look_alike = pose @ S  # the same outline, another face of the print in front
        assert (look_alike @ test(look_alike)).allclose(pose, atol=1e-6)
        # a CNN that cannot tell the faces apart answers the look-alike; the tracker confirms it
        cnn = Measurement(look_alike, covariance, 1.0, "cnn", 0.0)
        start = confirmed_start(cnn, lambda p: Measurement(p, covariance, 0.9, "tracker", 0.0),
                                HybridConfig(start_turn_deg=0.0), stands_out=test)
        assert start.pose.allclose(pose, atol=1e-6)
        # the same uncertainty, carried into the restated pose's own frame
        rotated = start.pose.covariance_in_camera(start.covariance)
        assert np.allclose(rotated, look_alike.covariance_in_camera(covariance), atol=1e-12)


def test_the_equivalent_poses_scored_from_one_raster_are_those_scored_one_by_one(printed_cube):
    shape_twins = ObjectModel("cube", printed_cube.mesh).symmetries
    view = PrintView(ModelView(ObjectModel("printed-cube", printed_cube.mesh, symmetries=shape_twins,
                                           texture=printed_cube.texture, face_uv=printed_cube.face_uv)))
    pose = Pose.from_rotvec_t([0.3, 0.5, -0.2], [0.0, 0.01, 0.32])
    frame = _frame(printed_cube, pose, clutter_background(CAM.width, CAM.height, np.random.default_rng(3)))
    one_by_one = [view.score(frame, pose @ S) for S in view.branches]
    assert np.allclose(view.branch_scores(frame, pose), one_by_one, atol=1e-9, equal_nan=True)


def test_a_start_a_few_degrees_off_climbs_the_prints_score_to_the_pose_it_shows(printed_cube):
    """A start 8° off that the tracker confirms as it stands (a fit that moves nothing, as the model's
    edges may): turned 3° at a time where the print scores the turn higher, it ends within 3° of the
    truth; a right start stays within a step of it; 0° leaves the start as it was."""
    from hybridpose.core import Measurement
    from hybridpose.metrics import rotation_error_deg
    from hybridpose.starts import print_climb, print_climber, print_view

    pose = Pose.from_rotvec_t([0.3, -0.5, 0.2], [0.0, 0.01, 0.32])
    frame = _frame(printed_cube, pose, clutter_background(CAM.width, CAM.height, np.random.default_rng(5)))
    printed, centre = print_view(ModelView(printed_cube)), printed_cube.bbox_corners.mean(0)
    covariance = np.diag([1e-4, 2e-4, 3e-4, 1e-6, 2e-6, 3e-6])

    def fit(p):
        return Measurement(p, covariance, 0.9, "tracker", 0.0)

    axis = np.array([0.6, -0.3, 0.74]) / np.linalg.norm([0.6, -0.3, 0.74])
    off = turned_about(pose, np.radians(8.0) * axis, centre)  # about the cube's centre: the same place in the image
    climbed = print_climb(fit(off), fit, printed, frame, centre, 3.0)
    assert rotation_error_deg(climbed.pose, pose) < 3.0 < rotation_error_deg(off, pose)
    assert rotation_error_deg(print_climb(fit(pose), fit, printed, frame, centre, 3.0).pose, pose) <= 3.0 + 1e-6
    start = fit(off)
    assert print_climb(start, fit, printed, frame, centre, 0.0) is start
    assert print_climber(fit, None, frame, printed_cube, 3.0) is None  # no print, no climb


def test_a_tracked_pose_that_does_not_show_the_print_fails_the_watch(printed_cube):
    """The right pose and one 3° off show the print; the pose turned 20° about the cube's centre (the
    same place in the image, where the outline alone may fit) does not. No print, a floor of 0 or no
    pose give no verdict."""
    from hybridpose.starts import print_fails, print_view

    pose = Pose.from_rotvec_t([0.3, -0.5, 0.2], [0.0, 0.01, 0.32])
    frame = _frame(printed_cube, pose, clutter_background(CAM.width, CAM.height, np.random.default_rng(5)))
    printed = print_view(ModelView(printed_cube))
    assert not print_fails(printed, frame, pose, 0.15)
    assert not print_fails(printed, frame, _turned_about_centre(printed_cube, pose, 3.0), 0.15)
    off = _turned_about_centre(printed_cube, pose, 20.0)
    assert print_fails(printed, frame, off, 0.15)
    assert not print_fails(None, frame, off, 0.15) and not print_fails(printed, frame, off, 0.0)
    assert not print_fails(printed, frame, None, 0.15)


# the scripted hybrid tests' scene: the printed cube over clutter, and its trackers' and CNNs' covariance
POSE = Pose.from_rotvec_t([0.3, -0.5, 0.2], [0.0, 0.01, 0.32])
COVARIANCE = np.diag([np.radians(0.5) ** 2] * 3 + [0.001 ** 2] * 3)


def _scene(printed_cube) -> np.ndarray:
    return _frame(printed_cube, POSE, clutter_background(CAM.width, CAM.height, np.random.default_rng(5))).image


def _scripted_tracker(obj, fit):
    """A tracker of ``obj`` whose measurement of a frame is ``fit(frame, prior)``: the tracker contract, nothing more."""
    class Scripted:
        lost_quality, tells_covered, object = None, False, obj

        def init(self, frame, start):
            pass

        def reset(self):
            pass

        def track(self, frame, prior=None, **options):
            return fit(frame, prior)

    return Scripted()


def _scripted_cnn(answer):
    """A regressor whose answer in a frame is ``answer(frame)`` (a pose or None) with ``COVARIANCE`` × 4."""
    from hybridpose.core import Measurement

    class Scripted:
        hybrid_config = {}

        def predict(self, frame, roi=None):
            pose = answer(frame)
            found = pose is not None
            return Measurement(pose, COVARIANCE * 4 if found else np.eye(6), 0.9 if found else 0.0, "regressor:scripted",
                               frame.timestamp)

    return Scripted()


def _hybrid_run(tracker, cnn, frames: int, image, **config):
    from hybridpose import HybridConfig, HybridEstimator, registry

    est = HybridEstimator(tracker, cnn, registry.create("fusion", "ukf"),
                          HybridConfig(start_contrast=0, keypoint_memory=False, **config))
    return est, [est.step(Frame(image, CAM, k / 30.0, k)) for k in range(frames)]


def test_the_hybrid_does_not_trust_a_track_that_slid_off_its_print(printed_cube):
    """A tracker that slides 2° a frame about the image's vertical through the part, fully confident,
    and a fusion that follows it (no CNN checks): the hybrid keeps tracking but stops trusting the
    track where its pose no longer shows the part's print; with the watch off it trusts every frame."""
    from hybridpose import HybridConfig
    from hybridpose.core import Measurement
    from hybridpose.metrics import rotation_error_deg

    image = _scene(printed_cube)
    sliding = _scripted_tracker(printed_cube, lambda frame, prior: Measurement(
        _turned_about_centre(printed_cube, POSE, 2.0 * max(frame.index - 2, 0)), COVARIANCE, 0.85, "tracker:sliding",
        frame.timestamp))

    def statuses(floor):
        _, out = _hybrid_run(sliding, _scripted_cnn(lambda frame: POSE), 16, image, check_period=0, probation_frames=0,
                             track_print_floor=floor)
        return [(e.status, rotation_error_deg(e.pose, POSE)) for e in out]

    watched = statuses(HybridConfig().track_print_floor)
    assert watched[0][0] == "init" and all(s == "tracking" for s, _ in watched[1:4])
    assert all(err < 15.0 for s, err in watched if s in ("init", "tracking"))  # the print fades 12-16° off
    assert any(s == "lost" for s, _ in watched) and max(err for _, err in watched) > 20.0
    assert all(s == "tracking" for s, _ in statuses(0.0)[1:])
    with pytest.raises(ValueError, match="track_print_floor: expected a correlation in"):
        HybridConfig(track_print_floor=1.5)


def _turned_about_centre(obj, pose, deg):
    """``pose`` turned ``deg`` about the camera's y axis through ``obj``'s centre."""
    return turned_about(pose, np.radians(deg) * np.array([0.0, 1.0, 0.0]), obj.bbox_corners.mean(0))


@pytest.mark.parametrize("arrangement", ["own", "another"])
def test_a_lost_track_is_taken_up_only_where_the_print_shows_the_fit_itself(printed_cube, arrangement):
    """A scripted tracker loses the part for a second, then fits its outline again: at the part's own
    pose (its print shows it) the track is taken up; at another of the cube's equivalent poses (the
    same outline, other faces where the print is) it stays lost — a fit whose print another face
    arrangement explains better slid onto the outline elsewhere."""
    from hybridpose.core import Measurement
    from hybridpose.starts import print_backs

    image = _scene(printed_cube)
    quarter_turn = next(S for S in printed_cube.symmetries if abs(np.trace(S.R) - 1.0) < 1e-6)  # 90°
    refit = POSE if arrangement == "own" else POSE @ quarter_turn

    def fit(frame, prior):
        if 3 <= frame.index < 30:  # a second lost: the fusion's spread has grown past a quarter turn
            return Measurement(None, np.eye(6), 0.0, "tracker:scripted", frame.timestamp)
        return Measurement(POSE if frame.index < 3 else refit, COVARIANCE, 0.85, "tracker:scripted", frame.timestamp)

    # the watch off (track_print_floor): the take-up alone is under test
    est, out = _hybrid_run(_scripted_tracker(printed_cube, fit), _scripted_cnn(lambda f: POSE if f.index == 0 else None),
                           33, image, check_period=0, probation_frames=0, track_print_floor=0)
    statuses = [e.status for e in out]
    assert statuses[:3] == ["init", "tracking", "tracking"] and set(statuses[3:30]) == {"lost"}
    assert statuses[30:] == (["tracking"] * 3 if arrangement == "own" else ["lost"] * 3)
    frame = Frame(image, CAM, 0.0, 0)
    assert print_backs(None, frame, refit) and print_backs(est._print, frame, refit) == (arrangement == "own")


@pytest.mark.parametrize("printed", [True, False])
def test_a_check_does_not_move_a_printed_track_off_its_print(printed_cube, printed):
    """A scripted tracker holds the truth at a middling quality (so the CNN checks it every frame), a
    CNN answers 25° off and the fit from there scores higher: on a plain model the checks restart the
    track there, as they must where the track drifted; on the printed model the print shows the
    check's fit worse than the track, and the track stays."""
    from dataclasses import replace

    from hybridpose.core import Measurement
    from hybridpose.metrics import rotation_error_deg
    from hybridpose.starts import print_prefers

    obj = printed_cube if printed else replace(printed_cube, texture=None, face_uv=None)
    off = _turned_about_centre(printed_cube, POSE, 25.0)
    image = _scene(printed_cube)

    def fit(frame, prior):
        near_truth = rotation_error_deg(prior, POSE) < 10.0
        return Measurement(POSE if near_truth else off, COVARIANCE, 0.65 if near_truth else 0.95, "tracker:scripted",
                           frame.timestamp)

    _, out = _hybrid_run(_scripted_tracker(obj, fit), _scripted_cnn(lambda f: POSE if f.index == 0 else off), 6, image,
                         track_print_floor=0)
    errors = [rotation_error_deg(e.pose, POSE) for e in out]
    assert errors[0] < 1.0
    assert (max(errors) < 2.0) if printed else (errors[-1] > 20.0)
    frame = Frame(image, CAM, 0.0, 0)
    at = lambda p: Measurement(p, COVARIANCE, 0.9, "x", 0.0)  # noqa: E731
    printed_view = PrintView(ModelView(printed_cube))
    assert not print_prefers(printed_view, frame, at(off), at(POSE)) and print_prefers(printed_view, frame, at(POSE), at(off))
    assert print_prefers(None, frame, at(off), at(POSE))
