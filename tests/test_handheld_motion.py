"""The estimator's motion model off black space: a hand stops and turns within a few frames, and the
fusion's gate must not refuse the tracker's right fit where the hand turns (``HybridConfig.handheld_accel_*``,
``Fusion.motion_noise``)."""
import numpy as np
import pytest

from hybridpose import registry
from hybridpose.core import Frame, Measurement
from hybridpose.estimator import HybridEstimator
from hybridpose.geometry import Camera, Pose
from hybridpose.hybrid_config import HybridConfig

CAM = Camera.default().scaled((160, 120))
LIT = np.full((CAM.height, CAM.width, 3), 128, np.uint8)  # a lit room: no black space
DARK = np.zeros((CAM.height, CAM.width, 3), np.uint8)
TURN = 10  # the hand moves the part 1 cm a frame across the view (12 px at 0.5 m) until this frame, then back


def part_at(k: int) -> Pose:
    return Pose(np.eye(3), np.array([0.01 * (k if k < TURN else 2 * (TURN - 1) - k), 0.0, 0.5]))


class FollowingTracker:
    """Fits each frame at the part's true pose (quality 0.9, 0.3 mm / 0.06°): a tracker that holds."""

    lost_quality, tells_covered, object = None, False, None

    def init(self, frame, pose):
        pass

    def reset(self):
        pass

    def track(self, frame, prior=None, **options):
        return Measurement(part_at(frame.index), np.diag([1e-6] * 3 + [1e-7] * 3), 0.9, "tracker:following",
                           frame.timestamp)


class FoundAtStart:
    """A keypoint memory that finds the part at its first pose."""

    def find(self, frame, roi=None):
        return Measurement(part_at(0), np.diag([1e-4] * 3 + [1e-6] * 3), 0.5, "regressor:keypoints", frame.timestamp)

    def wants(self, pose):
        return False


def run(image, config: HybridConfig, frames: int = TURN + 4):
    est = HybridEstimator(FollowingTracker(), registry.create("regressor", "none"), registry.create("fusion", "ukf"),
                          config)
    est.memory = FoundAtStart()
    return est, [est.step(Frame(image, CAM, k / 30.0, k)) for k in range(frames)]


def test_off_black_space_the_fusion_takes_a_hands_turn():
    est, estimates = run(LIT, HybridConfig(check_period=0))
    assert est.fusion.motion_noise == (HybridConfig().handheld_accel_rad_s2, HybridConfig().handheld_accel_m_s2)
    after = estimates[TURN:]
    assert all(e.status == "tracking" and "tracker:following" in e.sources for e in after)
    assert all(np.linalg.norm(e.pose.t - part_at(k).t) < 0.005 for k, e in enumerate(after[1:], TURN + 1))


@pytest.mark.parametrize("image, config", [(LIT, HybridConfig(check_period=0, handheld_accel_rad_s2=None)),
                                           (DARK, HybridConfig(check_period=0))])
def test_with_the_space_motion_model_the_gate_refuses_the_turn(image, config):
    """The fusion's own model (on black space, or with the hand's turned off): a spacecraft does not
    turn back within a frame, and the gate refuses the tracker there."""
    est, estimates = run(image, config)
    own = registry.create("fusion", "ukf").motion_noise
    assert est.fusion.motion_noise == own
    assert all("tracker:following" in e.sources for e in estimates[1:TURN])
    assert "tracker:following" not in estimates[TURN].sources


def test_a_reset_gives_the_fusion_its_own_model_back_on_black_space():
    est, _ = run(LIT, HybridConfig(check_period=0), frames=2)
    est.reset()
    est.step(Frame(DARK, CAM, 0.0, 0))
    assert est.fusion.motion_noise == registry.create("fusion", "ukf").motion_noise


def test_motion_noise_is_checked():
    fusion = registry.create("fusion", "isam2")
    fusion.motion_noise = (2.0, 1.0)
    assert fusion.motion_noise == (2.0, 1.0) and fusion.angular_accel_rad_s2 == 2.0
    with pytest.raises(ValueError, match="motion_noise: expected"):
        fusion.motion_noise = (0.0, 1.0)
    with pytest.raises(ValueError, match="handheld_accel_rad_s2, handheld_accel_m_s2"):
        HybridConfig(handheld_accel_m_s2=-1.0)
