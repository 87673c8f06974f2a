"""Contract tests over every registered fusion backend: the same synthetic measurements, the same
assertions (convergence, velocity, outlier gating, covariance health, reset, bad input)."""
import numpy as np
import pytest

from hybridpose.core import Measurement
from hybridpose.fusion import pose_mahalanobis2
from hybridpose.geometry import Pose
from hybridpose.registry import available, create

FUSIONS = available("fusion")
FPS = 30.0
MEAS_COV = np.diag([np.radians(0.5) ** 2] * 3 + [0.002**2] * 3)
START = Pose.from_rotvec_t([0.4, -0.3, 0.2], [0.02, -0.01, 0.7])


def _meas(pose, t, cov=MEAS_COV):
    return Measurement(pose=pose, covariance=cov, quality=1.0, source="test", timestamp=t)


def _noisy(pose, rng, cov=MEAS_COV):
    return pose.retract(rng.multivariate_normal(np.zeros(6), cov))


def _rot_deg(a, b):
    return np.degrees(np.linalg.norm(a.local(b)[:3]))


def test_expected_backends_are_registered():
    assert {"ukf", "none"} <= set(FUSIONS)


@pytest.mark.parametrize("name", FUSIONS)
def test_every_fusion_gives_every_member_of_the_contract_the_estimator_reads(name):
    from hybridpose.contracts import check_backend

    fusion = create("fusion", name)
    check_backend("fusion", fusion)  # before reset, where reading its estimate would raise
    assert fusion.initial_twist_covariance.shape == (6, 6)


@pytest.mark.parametrize("name", FUSIONS)
def test_static_object_converges(name):
    rng = np.random.default_rng(0)
    # a quiet motion model, as for an object known to be still
    f = create("fusion", name, angular_accel_rad_s2=0.05, linear_accel_m_s2=0.01)
    f.reset(_noisy(START, rng, 25 * MEAS_COV), 25 * MEAS_COV, 0.0)
    errs = []
    for k in range(1, 90):
        f.predict(k / FPS)
        assert f.update(_meas(_noisy(START, rng), k / FPS))
        errs.append(_rot_deg(f.estimate.pose, START))
    # one measurement's median error is 0.77° (σ = 0.5° per axis); a filter averages far below it
    assert np.median(errs[-30:]) < (0.85 if name == "none" else 0.4)
    cov = f.estimate.covariance
    assert np.all(np.diag(cov)[:3] < 4 * MEAS_COV[0, 0])


@pytest.mark.parametrize("name", FUSIONS)
def test_constant_motion_is_followed_with_the_right_velocity(name):
    twist = np.array([0.4, -0.2, 0.3, 0.03, -0.02, 0.01])  # rad/s, m/s, body frame
    f = create("fusion", name)
    f.reset(START, MEAS_COV, 0.0)
    for k in range(1, 60):
        t = k / FPS
        f.predict(t)
        assert f.update(_meas(START.retract(twist * t), t))
    e = f.estimate
    truth = START.retract(twist * 59 / FPS)
    assert _rot_deg(e.pose, truth) < 0.1 and np.linalg.norm(e.pose.t - truth.t) < 1e-3
    assert np.allclose(e.velocity, twist, atol=0.02), e.velocity
    # the prediction one frame ahead holds the truth inside its covariance
    ahead = f.predict(60 / FPS)
    assert pose_mahalanobis2(ahead.pose, ahead.covariance, START.retract(twist * 60 / FPS), np.zeros((6, 6))) < 12.6


@pytest.mark.parametrize("name", [n for n in FUSIONS if n != "none"])  # "none" holds the last pose
def test_the_default_motion_model_keeps_a_braking_approach_inside_the_gate(name):
    # the distance sweep's braking: 3 m/s² along the line of sight, seen by a tracker whose pose is
    # good to 0.2 mm and 0.05°; a motion model too quiet for it refuses every measurement
    cov = np.diag([np.radians(0.05) ** 2] * 3 + [0.0002**2] * 3)
    f = create("fusion", name)
    f.reset(START, cov, 0.0, twist=np.r_[0, 0, 0, START.R.T @ [0, 0, -1.2]])  # body twist: -1.2 m/s in depth
    for k in range(1, 30):
        t = k / FPS
        f.predict(t)
        depth = START.t[2] - 1.2 * t + 0.5 * 3.0 * t**2
        assert f.update(_meas(Pose(START.R, np.r_[START.t[:2], depth]), t, cov)), (k, f.last_mahalanobis2)


@pytest.mark.parametrize("name", FUSIONS)
def test_a_gross_outlier_is_rejected(name):
    rng = np.random.default_rng(1)
    f = create("fusion", name)
    f.reset(START, MEAS_COV, 0.0)
    for k in range(1, 20):
        f.predict(k / FPS)
        f.update(_meas(_noisy(START, rng), k / FPS))
    before = f.predict(20 / FPS).pose
    flipped = START @ Pose.from_rotvec_t([0, 0, np.pi], [0, 0, 0])  # an end-for-end CNN answer
    assert not f.update(_meas(flipped, 20 / FPS))
    assert f.last_mahalanobis2 > f.gate_chi2
    assert f.estimate.pose.allclose(before)
    assert f.update(_meas(_noisy(START, rng), 20 / FPS))  # a good one right after is taken


@pytest.mark.parametrize("name", FUSIONS)
def test_covariance_stays_symmetric_positive_definite_and_grows_without_measurements(name):
    rng = np.random.default_rng(2)
    f = create("fusion", name)
    f.reset(START, MEAS_COV, 0.0)
    for k in range(1, 40):
        e = f.predict(k / FPS)
        if k % 3:
            f.update(_meas(_noisy(START, rng), k / FPS))
        cov = f.estimate.covariance
        assert np.allclose(cov, cov.T) and np.linalg.eigvalsh(cov).min() > 0
        assert np.all(np.isfinite(e.pose.matrix)) and np.allclose(e.pose.R @ e.pose.R.T, np.eye(3), atol=1e-9)
    traces = []
    for k in range(40, 70):  # the object is lost: predictions only
        traces.append(np.trace(f.predict(k / FPS).covariance))
    assert np.all(np.diff(traces) > 0)


@pytest.mark.parametrize("name", FUSIONS)
def test_reset_starts_over_and_a_lost_measurement_is_ignored(name):
    f = create("fusion", name)
    with pytest.raises(RuntimeError, match="before reset"):
        f.predict(0.1)
    f.reset(START, MEAS_COV, 0.0)
    f.predict(0.5)
    other = Pose.from_rotvec_t([0.0, 1.0, 0.0], [0.1, 0.0, 1.0])
    f.reset(other, MEAS_COV, 2.0, twist=np.zeros(6))
    e = f.estimate
    assert e.pose.allclose(other) and e.timestamp == 2.0 and np.allclose(e.velocity, 0)
    f.predict(2.1)
    lost = Measurement(pose=None, covariance=np.eye(6), quality=0.0, source="test", timestamp=2.1)
    assert lost.lost and not f.update(lost)


@pytest.mark.parametrize("name", FUSIONS)
def test_bad_input_gets_clear_errors(name):
    f = create("fusion", name)
    with pytest.raises(TypeError, match="pose"):
        f.reset(START.matrix, MEAS_COV, 0.0)
    with pytest.raises(ValueError, match="covariance"):
        f.reset(START, -MEAS_COV, 0.0)
    with pytest.raises(ValueError, match="covariance"):
        f.reset(START, np.full((6, 6), np.nan), 0.0)
    f.reset(START, MEAS_COV, 1.0)
    with pytest.raises(ValueError, match="before the current"):
        f.predict(0.5)
    with pytest.raises(ValueError, match="call predict"):
        f.update(_meas(START, 1.5))
    with pytest.raises(ValueError, match="angular_accel_rad_s2"):
        create("fusion", name, angular_accel_rad_s2=-1.0)


def test_measurement_refuses_nan_and_non_psd_covariances_and_a_pose_when_lost():
    with pytest.raises(ValueError, match="NaN"):
        _meas(START, 0.0, np.full((6, 6), np.nan))
    with pytest.raises(ValueError, match="positive semi-definite"):
        _meas(START, 0.0, -MEAS_COV)
    with pytest.raises(ValueError, match="lost"):
        Measurement(pose=START, covariance=MEAS_COV, quality=0.1, source="t", timestamp=0.0, lost=True)
    assert Measurement(pose=None, covariance=MEAS_COV, quality=0.0, source="t", timestamp=0.0).lost


def test_pose_mahalanobis_matches_a_monte_carlo_chi2():
    rng = np.random.default_rng(3)
    cov_a, cov_b = MEAS_COV, 4 * MEAS_COV
    d2 = [pose_mahalanobis2(START.retract(rng.multivariate_normal(np.zeros(6), cov_a)), cov_a,
                            START.retract(rng.multivariate_normal(np.zeros(6), cov_b)), cov_b) for _ in range(2000)]
    assert np.mean(d2) == pytest.approx(6.0, rel=0.08)  # E[χ²₆] = 6


def test_isam2_memory_stays_bounded_over_a_long_run():
    rng = np.random.default_rng(4)
    f = create("fusion", "isam2", lag_s=0.5)
    f.reset(START, MEAS_COV, 0.0)
    sizes = {}
    for k in range(1, 1501):
        f.predict(k / FPS)
        f.update(_meas(_noisy(START, rng), k / FPS))
        if k in (300, 1500):
            sizes[k] = (f.smoother.getFactors().nrFactors(), len(f.smoother.timestamps()))
    assert sizes[1500][0] <= sizes[300][0] + 5 and sizes[1500][1] <= sizes[300][1] + 2, sizes
    assert _rot_deg(f.estimate.pose, START) < 1.0


def test_a_fit_that_saw_nothing_of_a_direction_is_unsure_of_it_not_certain():
    """A tracker's covariance from its normal equations: no information along a direction means a
    variance as large as a lost measurement's there, never zero (which a smoother cannot invert)."""
    from hybridpose.core import LOST_COVARIANCE, covariance_from_information
    from hybridpose.registry import available, create

    rank5 = np.diag([1e6, 1e6, 1e6, 1e6, 1e6, 0.0])  # nothing along the depth axis v_z
    cov = covariance_from_information(rank5, scale=4.0)
    assert np.linalg.eigvalsh(cov).min() > 0
    assert cov[5, 5] == pytest.approx(LOST_COVARIANCE[5, 5], rel=1e-3)
    assert cov[0, 0] == pytest.approx(4.0 / 1e6, rel=1e-3)
    for name in available("fusion"):
        fusion = create("fusion", name)
        fusion.reset(Pose(np.eye(3), np.array([0.0, 0.0, 1.0])), cov, 0.0)
        assert np.all(np.isfinite(fusion.predict(0.1).covariance))


@pytest.mark.parametrize("name", FUSIONS)
def test_a_coast_of_seconds_without_a_measurement_goes_on_and_takes_a_measurement_after(name):
    """The object lost for 15 s at 30 fps (the hybrid coasting): the UKF's sigma points went
    indefinite and gtsam's smoother found its system indeterminate after ≈ 9 s."""
    f = create("fusion", name)
    start = Pose.from_rotvec_t([0.1, 0.2, 0.3], [0.0, 0.0, 0.5])
    f.reset(start, np.diag([1e-4] * 3 + [1e-6] * 3), 0.0, np.array([0.3, -0.2, 0.1, 0.01, 0.02, 0.0]))
    for k in range(1, 451):
        e = f.predict(k / 30)
        assert np.all(np.isfinite(e.pose.matrix)) and np.all(np.isfinite(e.covariance))
    seen = Measurement(start, np.diag([1e-4] * 3 + [1e-6] * 3), 0.9, "tracker:test", 15.0)
    assert f.update(seen) and _rot_deg(f.estimate.pose, start) < 1.0


def test_a_failure_of_the_smoother_other_than_an_indeterminate_system_is_not_taken_for_a_coast(monkeypatch):
    """Only gtsam's indeterminate-system error starts the belief over; any other error of the library
    (or of our code) reaches the caller."""
    f = create("fusion", "isam2")
    f.reset(Pose.from_rotvec_t([0.1, 0.2, 0.3], [0.0, 0.0, 0.5]), np.diag([1e-4] * 3 + [1e-6] * 3), 0.0)

    class Broken:
        def update(self, *args):
            raise RuntimeError("Attempting to retrieve value with key x1, which does not exist in the Values")

    monkeypatch.setattr(f, "smoother", Broken())
    with pytest.raises(RuntimeError, match="does not exist"):
        f.predict(0.1)
