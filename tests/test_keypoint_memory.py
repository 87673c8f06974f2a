"""The keypoint memory (regressors.keypoint_memory) against MuJoCo renders of a printed cube over clutter:
found from its print alone, found again from views it learned where its CAD model has no print, and
silent where the part is not in the frame. The estimator asks it before the CNN."""
from dataclasses import replace

import cv2
import numpy as np
import pytest

from hybridpose import registry
from hybridpose.core import Frame, Measurement
from hybridpose.edges import ModelView
from hybridpose.edges.print_match import PrintView
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
def printed_cube(print_on_cube):
    """A 6-cm cube whose faces are unwrapped into the six cells of a 3 × 2 print of smoothed noise and
    blobs (a print with corners and texture everywhere, as a label or a photo has)."""
    rng = np.random.default_rng(7)
    image = cv2.resize(rng.integers(0, 255, (24, 36, 3)).astype(np.uint8), (768, 512), interpolation=cv2.INTER_CUBIC)
    for _ in range(60):
        centre = (int(rng.integers(0, 768)), int(rng.integers(0, 512)))
        cv2.circle(image, centre, int(rng.integers(6, 30)), tuple(int(c) for c in rng.integers(0, 255, 3)), -1)
    return print_on_cube(image, symmetries=())


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
    memory = KeypointMemory.for_part(ModelView(printed_cube), CAM, PrintView(ModelView(printed_cube)))
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
    memory = KeypointMemory.for_part(ModelView(plain), CAM, None)
    first = _frame(printed_cube, POSE)
    assert memory.views == 0 and memory.find(first) is None
    assert memory.learn(first, POSE) > 30 and memory.views == 1
    # the same view is not learned twice; one turned further than the step is
    assert not memory.wants(turned(POSE, [0.0, LEARN_STEP_DEG / 2, 0.0]))
    assert memory.wants(turned(POSE, [0.0, 1.5 * LEARN_STEP_DEG, 0.0]))
    moved = turned(POSE, [6.0, -8.0, 4.0], [0.02, 0.01, 0.03])
    assert _near(memory.find(_frame(printed_cube, moved, seed=2, index=1)), moved)


@pytest.mark.parametrize("memory", [True, False])
def test_the_hybrid_asks_the_memory_before_the_cnn(printed_cube, memory):
    """A printed part and no network at all (``none``): the print's memory starts the track; without
    the memory nothing does."""
    frames = [_frame(printed_cube, turned(POSE, [0.0, 0.6 * k, 0.0]), index=k)
              for k in range(3)]
    est = HybridEstimator(registry.create("tracker", "combined", object=printed_cube), registry.create("regressor", "none"),
                          registry.create("fusion", "ukf"),
                          HybridConfig(keypoint_memory=memory, colour_start_every=0))  # the memory alone
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

    class Oracle:
        hybrid_config = {}

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
    est = HybridEstimator(registry.create("tracker", "combined", object=printed_cube), registry.create("regressor", "none"),
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
    est = HybridEstimator(HalfSureTracker(POSE), registry.create("regressor", "none"), registry.create("fusion", "ukf"),
                          config)
    black = np.zeros((CAM.height, CAM.width, 3), np.uint8)
    assert est.step(Frame(black, CAM, 0.0, 0)).status == "init" and est.memory is None
    est.memory = ScriptedMemory(POSE)
    est.step(Frame(black, CAM, 1 / 30, 1))
    assert (est.status == "tracking") == starts
    with pytest.raises(ValueError, match="memory_start_quality"):
        HybridConfig(memory_start_quality=1.5)


class HalfSureCues(HalfSureTracker):
    """:class:`HalfSureTracker` reporting its cues' verdicts, as ``combined`` does."""

    cue_qualities = {"edges": 0.5, "region": 0.5}


def test_a_plain_parts_start_from_the_memory_keeps_the_memory_bar_in_a_lit_scene(printed_cube):
    """``plain_start_quality`` holds the network's starts of a plain part in a lit scene, not the memory's:
    its pose already agrees with dozens of keypoints on the part."""
    plain = replace(printed_cube, texture=None, face_uv=None)
    tracker = HalfSureCues(POSE)
    tracker.object = plain
    est = HybridEstimator(tracker, registry.create("regressor", "none"), registry.create("fusion", "ukf"),
                          HybridConfig(check_period=0, start_contrast=0))
    assert HybridConfig().memory_start_quality < 0.5 < HybridConfig().plain_start_quality
    grey = np.full((CAM.height, CAM.width, 3), 120, np.uint8)
    assert est.step(Frame(grey, CAM, 0.0, 0)).status == "init"
    est.memory = ScriptedMemory(POSE)
    est.step(Frame(grey, CAM, 1 / 30, 1))
    assert est.status == "tracking"


def _write_obj(obj: ObjectModel, folder) -> str:
    """``obj`` as an OBJ with its print (``.mtl`` naming a PNG), as a CAD tool exports a printed part."""
    cv2.imwrite(str(folder / "print.png"), cv2.cvtColor(obj.texture, cv2.COLOR_RGB2BGR))
    (folder / "part.mtl").write_text("newmtl Material\nKd 1 1 1\nmap_Kd print.png\n")
    lines = ["mtllib part.mtl", *(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in obj.mesh.vertices)]
    lines += [f"vt {u:.9g} {v:.9g}" for u, v in obj.face_uv.reshape(-1, 2)]
    lines.append("usemtl Material")
    lines += [f"f {a + 1}/{3 * k + 1} {b + 1}/{3 * k + 2} {c + 1}/{3 * k + 3}" for k, (a, b, c) in enumerate(obj.mesh.faces)]
    (folder / "part.obj").write_text("\n".join(lines) + "\n")
    return str(folder / "part.obj")


def test_track_finds_a_printed_part_with_no_network(printed_cube, tmp_path):
    """``hybridpose track --regressor none`` on a printed part's mesh file: its print alone starts the track."""
    import csv
    import json

    from hybridpose.cli import main

    (tmp_path / "png").mkdir()
    poses = [turned(POSE, [0.0, 0.8 * k, 0.0]) for k in range(4)]
    for k, pose in enumerate(poses):
        rgb = _frame(printed_cube, pose, index=k).image
        cv2.imwrite(str(tmp_path / "png" / f"{k:06d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    (tmp_path / "camera.json").write_text(json.dumps(CAM.to_dict()))
    rc = main(["track", str(tmp_path / "png"), "--object", _write_obj(printed_cube, tmp_path), "--camera",
               str(tmp_path / "camera.json"), "--regressor", "none", "--out", str(tmp_path / "run")])
    assert rc == 0
    with open(tmp_path / "run" / "poses.csv") as f:
        rows = list(csv.DictReader(f))
    assert "regressor:keypoints" in rows[0]["sources"] and rows[-1]["status"] == "tracking"
    last = Pose.from_quat_t([float(rows[-1][k]) for k in ("qw", "qx", "qy", "qz")],
                            [float(rows[-1][k]) for k in ("tx_m", "ty_m", "tz_m")])
    assert rotation_error_deg(last, poses[-1]) < 2.0 and np.linalg.norm(last.t - poses[-1].t) < 0.005


def test_the_same_print_gives_the_same_matches(printed_cube):
    """FLANN's KD-trees split at random: two memories of the same print must still match a frame's
    keypoints to the same points (a benchmark's figures otherwise move from one run to the next)."""
    frame = _frame(printed_cube, POSE)
    memories = [KeypointMemory.for_part(ModelView(printed_cube), CAM, PrintView(ModelView(printed_cube)))
                for _ in range(2)]
    for memory in memories:
        memory.find(frame)  # builds its index
    uv, descriptors = memories[0]._detect(cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY), None)
    (uv_a, X_a), (uv_b, X_b) = (m._matches(uv, descriptors) for m in memories)
    assert len(uv_a) > 50
    np.testing.assert_array_equal(uv_a, uv_b)
    np.testing.assert_array_equal(X_a, X_b)


def test_the_prints_colours_point_at_the_part_in_clutter(printed_cube):
    from hybridpose.regressors.print_colours import PrintColours

    colours = PrintColours(printed_cube.texture)
    for seed, pose in ((1, POSE), (2, turned(POSE, (0, 40, 0), (0.04, 0.02, 0.05)))):
        frame = _frame(printed_cube, pose, seed=seed)
        x, y, w, h = colours.box(frame.image)
        centre = CAM.project(printed_cube.bbox_corners.mean(0)[None], pose)[0]
        assert x <= centre[0] <= x + w and y <= centre[1] <= y + h
        assert w * h < CAM.width * CAM.height
    # a frame of one colour singles nothing out
    assert colours.box(np.full((CAM.height, CAM.width, 3), 90, np.uint8)) is None
    with pytest.raises(ValueError, match="texture"):
        PrintColours(printed_cube.texture[..., 0])


def test_where_the_whole_frame_gives_nothing_the_memory_looks_where_the_prints_colours_stand_out(printed_cube, monkeypatch):
    memory = KeypointMemory.for_part(ModelView(printed_cube), CAM, PrintView(ModelView(printed_cube)))
    frame = _frame(printed_cube, POSE)
    looked, find = [], memory._find

    def whole_frame_blind(f, roi):
        looked.append(roi)
        return None if roi is None else find(f, roi)

    monkeypatch.setattr(memory, "_find", whole_frame_blind)
    m = memory.find(frame)
    assert looked[0] is None and looked[1] is not None and len(looked) == 2
    assert _near(m, POSE)
    # a caller's own region is searched as given, nowhere else
    looked.clear()
    memory.find(frame, (0, 0, 50, 50))
    assert looked == [(0, 0, 50, 50)]
