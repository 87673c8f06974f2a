"""A printed part's last-resort starts (regressors.colour_starts): orientations spread up to the part's
symmetries (scipy's rotations as the oracle), placed where the print's colours stand out, and the
hybrid starting from them where its keypoint memory finds nothing — and not starting without the part."""
from dataclasses import replace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hybridpose import registry
from hybridpose.core import Frame
from hybridpose.estimator import HybridEstimator
from hybridpose.geometry import Camera, Pose
from hybridpose.hybrid_config import HybridConfig
from hybridpose.metrics import rotation_error_deg
from hybridpose.objects import load_builtin
from hybridpose.regressors.colour_starts import MIN_REGION_PX, SOURCE, ColourStarts
from hybridpose.regressors.keypoint_memory import KeypointMemory
from hybridpose.render import Appearance, Renderer
from hybridpose.render.appearance import clutter_background

CAM = Camera.default().scaled((480, 360))
LIGHT = dict(ambient=0.8, fill_lights=(((0.0, 0.0, 1.0), 0.4),))
POSE = Pose.from_rotvec_t([0.5, -0.4, 0.3], [0.01, -0.005, 0.3])


@pytest.fixture(scope="module")
def smooth_cube(print_on_cube):
    """A 6-cm cube printed with a smooth wash of colours (a 4 × 6 grid of random colours, upsampled):
    few corners for SIFT, colours the clutter mostly lacks. Its shape's symmetries (a cube's 23 turns) are kept."""
    rng = np.random.default_rng(3)
    return print_on_cube(cv2.resize(rng.integers(0, 255, (4, 6, 3)).astype(np.uint8), (768, 512),
                                    interpolation=cv2.INTER_CUBIC))


def _frame(obj, pose, seed=1, index=0, draw=True):
    background = clutter_background(CAM.width, CAM.height, np.random.default_rng(seed))
    if not draw:
        return Frame(background, CAM, index / 30.0, index)
    with Renderer(obj, CAM) as r:
        rgb = r.render(pose, appearance=Appearance(background=background, **LIGHT)).rgb
    return Frame(rgb, CAM, index / 30.0, index)


def _nearest_deg(R, candidates, symmetries) -> np.ndarray:
    """For each rotation of ``R`` (N, 3, 3), the angle (deg) to the nearest of ``candidates`` up to ``symmetries``."""
    equivalents = [Rotation.identity()] + [Rotation.from_matrix(S.R) for S in symmetries]
    targets = Rotation.concatenate([Rotation.from_matrix(C) * E for C in candidates for E in equivalents])
    R = Rotation.from_matrix(R)
    return np.array([np.degrees((targets.inv() * r).magnitude().min()) for r in R])


def test_the_orientations_cover_the_part_up_to_its_symmetries(smooth_cube):
    starts = ColourStarts(smooth_cube)
    assert len(starts) == 32 == len(starts.rotations)
    # no two candidates within 20° of each other, up to the cube's turns
    for k, R in enumerate(starts.rotations):
        others = np.delete(starts.rotations, k, axis=0)
        assert _nearest_deg(R[None], others, smooth_cube.symmetries)[0] >= 20.0 - 1e-6
    # any orientation lies near one (a start's fit turns ~10° into the truth)
    spread = _nearest_deg(Rotation.random(300, random_state=0).as_matrix(), starts.rotations, smooth_cube.symmetries)
    assert np.median(spread) < 15 and spread.max() < 31
    # a part with no symmetry needs every one of the 26 directions × 4 turns
    assert len(ColourStarts(replace(smooth_cube, symmetries=()))) == 104


def test_the_candidates_sit_where_the_print_is(smooth_cube):
    frame = _frame(smooth_cube, POSE)
    candidates = ColourStarts(smooth_cube).candidates(frame)
    assert len(candidates) == 32 and all(c.source == SOURCE for c in candidates)
    centre_px = CAM.project(smooth_cube.center[None], POSE)[0]
    for c in candidates:
        centre = c.pose @ smooth_cube.center[None]
        np.testing.assert_allclose(CAM.project(smooth_cube.center[None], c.pose)[0], centre_px, atol=30)
        assert 0.6 < centre[0, 2] / POSE.t[2] < 1.5
        assert np.all(np.isfinite(c.covariance)) and c.covariance.shape == (6, 6)
    # a frame of one colour singles nothing out: no candidates
    blank = Frame(np.full((CAM.height, CAM.width, 3), 90, np.uint8), CAM, 0.0, 0)
    assert ColourStarts(smooth_cube).candidates(blank) == []
    # nor does a region under MIN_REGION_PX (here the whole part, 40 px across: more often a patch of a print)
    far = Pose(POSE.R, POSE.t * 3)
    assert np.ptp(CAM.project(smooth_cube.bbox_corners, far), 0).max() < MIN_REGION_PX
    assert ColourStarts(smooth_cube).candidates(_frame(smooth_cube, far)) == []
    with pytest.raises(ValueError, match="texture"):
        ColourStarts(load_builtin("cube"))


def _hybrid(obj, **config):
    return HybridEstimator(registry.create("tracker", "combined", object=obj), registry.create("regressor", "none"),
                           registry.create("fusion", "ukf"), HybridConfig(**config))


def test_the_hybrid_starts_from_the_prints_colours_where_its_keypoints_find_nothing(smooth_cube, monkeypatch):
    """The memory blinded and no network: the colour starts alone start the track, at the cube's own
    pose (its print tells which face is which); switched off, or asked for a print no pose shows that
    well, nothing starts."""
    monkeypatch.setattr(KeypointMemory, "find", lambda self, frame, roi=None: None)
    frame = _frame(smooth_cube, POSE)
    e = _hybrid(smooth_cube).step(frame)
    assert e.status == "init" and SOURCE in e.sources
    assert rotation_error_deg(e.pose, POSE) < 5 and np.linalg.norm(e.pose.t - POSE.t) < 0.01
    assert _hybrid(smooth_cube, colour_start_every=0).step(frame).pose is None
    # a colour start must show the print well (colour_start_print): no right pose scores 1
    assert _hybrid(smooth_cube, colour_start_print=1.0).step(frame).pose is None


def test_the_colour_starts_start_nothing_without_the_part(smooth_cube, monkeypatch):
    """Clutter alone: the colour region is somewhere, the start checks refuse every candidate; tried
    every ``colour_start_every`` frames only."""
    monkeypatch.setattr(KeypointMemory, "find", lambda self, frame, roi=None: None)
    tried = []
    candidates = ColourStarts.candidates
    monkeypatch.setattr(ColourStarts, "candidates", lambda self, f: tried.append(f.index) or candidates(self, f))
    est = _hybrid(smooth_cube, colour_start_every=2)
    statuses = [est.step(_frame(smooth_cube, POSE, seed=5, index=k, draw=False)).status for k in range(3)]
    assert statuses == ["init"] * 3 and tried == [0, 2]


def test_the_colour_start_setting_is_checked():
    with pytest.raises(ValueError, match="colour_start_every"):
        HybridConfig(colour_start_every=-1)
    with pytest.raises(ValueError, match="colour_start_every"):
        HybridConfig(colour_start_every=1.5)
    with pytest.raises(ValueError, match="colour_start_print"):
        HybridConfig(colour_start_print=1.5)
