"""The keypoint memory (regressors.keypoint_memory) against MuJoCo renders of a printed cube over clutter:
found from its print alone, found again from views it learned where its CAD model has no print, and
silent where the part is not in the frame. The estimator asks it before the CNN."""
from dataclasses import replace

import cv2
import numpy as np
import pytest
import trimesh

from hybridpose import registry
from hybridpose.core import LOST_COVARIANCE, Frame, Measurement
from hybridpose.edges import ModelView
from hybridpose.estimator import HybridEstimator
from hybridpose.geometry import Camera, Pose, rotvec_to_matrix
from hybridpose.hybrid_config import HybridConfig
from hybridpose.metrics import rotation_error_deg
from hybridpose.objects import ObjectModel
from hybridpose.regressors.keypoint_memory import LEARN_STEP_DEG, SOURCE, KeypointMemory
from hybridpose.render import Appearance, Renderer
from hybridpose.render.appearance import clutter_background

CAM = Camera.default().scaled((480, 360))
LIGHT = dict(ambient=0.8, fill_lights=(((0.0, 0.0, 1.0), 0.4),))


@pytest.fixture(scope="module")
def printed_cube():
    """A 6-cm cube whose faces are unwrapped into the six cells of a 3 × 2 print of smoothed noise and
    blobs (a print with corners and texture everywhere, as a label or a photo has)."""
    rng = np.random.default_rng(7)
    image = cv2.resize(rng.integers(0, 255, (24, 36, 3)).astype(np.uint8), (768, 512), interpolation=cv2.INTER_CUBIC)
    for _ in range(60):
        centre = (int(rng.integers(0, 768)), int(rng.integers(0, 512)))
        cv2.circle(image, centre, int(rng.integers(6, 30)), tuple(int(c) for c in rng.integers(0, 255, 3)), -1)
    mesh = trimesh.creation.box((0.06, 0.06, 0.06))
    uv = np.zeros((len(mesh.faces), 3, 2))
    for k, normal in enumerate(np.asarray(mesh.face_normals)):
        axis = int(np.argmax(np.abs(normal)))
        cell = 2 * axis + (normal[axis] > 0)
        a, b = [i for i in range(3) if i != axis]
        local = (mesh.vertices[mesh.faces[k]][:, [a, b]] + 0.03) / 0.06
        uv[k] = (np.c_[(cell % 3 + local[:, 0]) / 3, (cell // 3 + local[:, 1]) / 2]) * 0.98 + 0.01
    return ObjectModel("printed-cube", mesh, symmetries=(), texture=image, face_uv=uv)


def _frame(obj, pose, seed=1, index=0):
    background = clutter_background(CAM.width, CAM.height, np.random.default_rng(seed))
    with Renderer(obj, CAM) as r:
        rgb = r.render(pose, appearance=Appearance(background=background, **LIGHT)).rgb
    return Frame(rgb, CAM, index / 30.0, index)


def _near(m, truth, deg=3.0, metres=0.01) -> bool:
    return (m is not None and rotation_error_deg(m.pose, truth) <= deg
            and np.linalg.norm(m.pose.t - truth.t) <= metres)


POSE = Pose.from_rotvec_t([0.5, -0.4, 0.3], [0.01, -0.005, 0.3])


def turned(pose: Pose, deg, shift_m=(0.0, 0.0, 0.0)) -> Pose:
    """``pose`` turned by the rotation vector ``deg`` (degrees, camera frame) about the object's origin, then shifted."""
    return Pose(rotvec_to_matrix(np.radians(deg)) @ pose.R, pose.t + np.asarray(shift_m))


def test_a_printed_part_is_found_in_clutter_from_its_print_alone(printed_cube):
    memory = KeypointMemory.for_part(ModelView(printed_cube), CAM)
    assert memory.views > 20 and memory.points > 500
    m = memory.find(_frame(printed_cube, POSE))
    assert _near(m, POSE) and m.source == "regressor:keypoints" and 0 < m.quality <= 1
    assert np.all(np.linalg.eigvalsh(m.covariance) > 0)
    # the clutter alone holds no pose of the part
    empty = Frame(clutter_background(CAM.width, CAM.height, np.random.default_rng(1)), CAM, 0.0, 0)
    assert memory.find(empty) is None


def test_a_plain_model_is_found_again_from_the_views_it_learned(printed_cube):
    """The CAD model carries no print, the part does: the memory starts empty and learns its look."""
    plain = ObjectModel("cube", printed_cube.mesh, symmetries=())
    memory = KeypointMemory.for_part(ModelView(plain), CAM)
    first = _frame(printed_cube, POSE)
    assert memory.views == 0 and memory.find(first) is None
    assert memory.learn(first, POSE) > 30 and memory.views == 1
    # the same view is not learned twice; one turned further than the step is
    assert not memory.wants(turned(POSE, [0.0, LEARN_STEP_DEG / 2, 0.0]))
    assert memory.wants(turned(POSE, [0.0, 1.5 * LEARN_STEP_DEG, 0.0]))
    moved = turned(POSE, [6.0, -8.0, 4.0], [0.02, 0.01, 0.03])
    assert _near(memory.find(_frame(printed_cube, moved, seed=2, index=1)), moved)


class Blind:
    """A regressor that never finds the part."""

    name = "blind"
    hybrid_config = {}

    def predict(self, frame, roi=None):
        return Measurement(None, LOST_COVARIANCE, 0.0, "regressor:blind", frame.timestamp)


@pytest.mark.parametrize("memory", [True, False])
def test_the_hybrid_asks_the_memory_before_the_cnn(printed_cube, memory):
    """A printed part with a CNN that never finds it: the print's memory starts the track; without
    the memory nothing does."""
    frames = [_frame(printed_cube, turned(POSE, [0.0, 0.6 * k, 0.0]), index=k)
              for k in range(3)]
    est = HybridEstimator(registry.create("tracker", "combined", object=printed_cube), Blind(),
                          registry.create("fusion", "ukf"), HybridConfig(keypoint_memory=memory))
    estimates = [est.step(f) for f in frames]
    if memory:
        assert "regressor:keypoints" in estimates[0].sources and estimates[-1].status == "tracking"
        assert rotation_error_deg(estimates[-1].pose, turned(POSE, [0.0, 1.2, 0.0])) < 2
    else:
        assert [e.status for e in estimates] == ["init"] * 3 and est.memory is None
    assert est.regressor_calls == (0 if memory else 3)
    est.reset()
    assert est.memory is None


def test_the_hybrid_learns_only_where_the_track_is_sure(printed_cube):
    """A plain model of the printed part: the memory learns from the track once it has run
    ``learn_after`` frames, not before."""
    plain = ObjectModel("cube", printed_cube.mesh, symmetries=())
    frames = [_frame(printed_cube, turned(POSE, [0.0, 0.6 * k, 0.0]), index=k)
              for k in range(5)]

    class Oracle(Blind):
        def predict(self, frame, roi=None):
            truth = turned(POSE, [0.0, 0.6 * frame.index, 0.0])
            return Measurement(truth, np.diag([1e-3] * 3 + [1e-5] * 3), 1.0, "regressor:oracle", frame.timestamp)

    for learn_after, learned in ((2, True), (10, False)):
        est = HybridEstimator(registry.create("tracker", "combined", object=plain), Oracle(),
                              registry.create("fusion", "ukf"), HybridConfig(learn_after=learn_after, check_period=0))
        statuses = [est.step(f).status for f in frames]
        assert statuses[-1] == "tracking"
        assert (est.memory.views > 0) == learned


def test_the_memory_setting_is_checked():
    with pytest.raises(ValueError, match="learn_after"):
        HybridConfig(learn_after=-1)
    assert replace(HybridConfig(), keypoint_memory=False).keypoint_memory is False


def test_on_black_space_the_hybrid_keeps_no_memory(printed_cube):
    """A part on black space: its keypoints are its shading, which the sun moves; no memory is made."""
    dark = np.zeros((CAM.height, CAM.width, 3), np.uint8)
    with Renderer(printed_cube, CAM) as r:
        rgb = r.render(POSE, appearance=Appearance(background=dark, **LIGHT)).rgb
    est = HybridEstimator(registry.create("tracker", "combined", object=printed_cube), Blind(),
                          registry.create("fusion", "ukf"))
    est.step(Frame(rgb, CAM, 0.0, 0))
    assert est.memory is None and est.regressor_calls == 1


class ScriptedMemory:
    """A memory that finds the part at ``pose`` on every frame and learns nothing."""

    def __init__(self, pose):
        self.pose = pose

    def find(self, frame, roi=None):
        return Measurement(self.pose, np.diag([1e-4] * 3 + [1e-6] * 3), 0.5, SOURCE, frame.timestamp)

    def wants(self, pose):
        return False


class HalfSureTracker:
    """Fits any start to ``pose`` with quality 0.5: a right fit of a part a hand holds up."""

    lost_quality, tells_covered, object = None, False, None

    def __init__(self, pose):
        self.pose = pose

    def init(self, frame, pose):
        pass

    def reset(self):
        pass

    def track(self, frame, prior=None, **options):
        return Measurement(self.pose, np.diag([1e-6] * 3 + [1e-8] * 3), 0.5, "tracker:half-sure", frame.timestamp)


@pytest.mark.parametrize("bar, starts", [(None, True), (0.62, False)])
def test_a_start_from_the_memory_needs_the_tracker_only_to_hold_it(bar, starts):
    """The memory's pose already agrees with dozens of points on the part: a fit of 0.5 (under the
    CNN's start bar) starts from it by default (``memory_start_quality``), not with the CNN's bar."""
    config = HybridConfig(check_period=0) if bar is None else HybridConfig(check_period=0, memory_start_quality=bar)
    assert HybridConfig().memory_start_quality < 0.5 < HybridConfig().start_quality
    est = HybridEstimator(HalfSureTracker(POSE), Blind(), registry.create("fusion", "ukf"), config)
    black = np.zeros((CAM.height, CAM.width, 3), np.uint8)
    assert est.step(Frame(black, CAM, 0.0, 0)).status == "init" and est.memory is None
    est.memory = ScriptedMemory(POSE)
    est.step(Frame(black, CAM, 1 / 30, 1))
    assert (est.status == "tracking") == starts
    with pytest.raises(ValueError, match="memory_start_quality"):
        HybridConfig(memory_start_quality=1.5)
