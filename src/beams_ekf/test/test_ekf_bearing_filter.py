"""The EKF itself: measurement model and Jacobians, update, wrapping, gating, process noise."""

from math import atan2, cos, pi, sin, sqrt

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.pose2d import compose
from beams_ekf.beacon_states import BeaconStates
from beams_ekf.bearing_ekf import BearingEkf, ProcessNoise, gate_threshold, turret_pose
from beams_ekf.odometry_errors import OdometryErrorStates
from beams_ekf.parameters import filter_settings
from beams_ekf.power_bias_states import PowerBiasStates
from beams_ekf.turret_offset_states import TurretOffsetStates

EUROBOT_BEACONS = EUROBOT_BEACON_MAP.as_dict()

POSE = (1.2, 0.7, 0.4)
OFFSET = (0.03, -0.02)


def _filter(pose=POSE, sigma=(0.01, 0.01, 0.01), offset=OFFSET, **kwargs) -> BearingEkf:
    ekf = BearingEkf(EUROBOT_BEACONS, offset, **kwargs)
    ekf.initialise(pose, np.diag(np.square(sigma)))
    return ekf


def _true_bearing(pose, beacon_id, offset=OFFSET) -> float:
    sensor = compose(pose, (offset[0], offset[1], 0.0))
    xb, yb = EUROBOT_BEACONS[beacon_id]
    return wrap_to_pi(atan2(yb - sensor[1], xb - sensor[0]) - pose[2])


@pytest.mark.parametrize("beacon_id", [1, 2, 3])
def test_predicted_bearing_matches_geometry_with_turret_offset(beacon_id):
    expected, _ = _filter().predicted_bearing(beacon_id)
    assert abs(wrap_to_pi(expected - _true_bearing(POSE, beacon_id))) < 1e-12


@pytest.mark.parametrize("lever", [None, (0.05, -0.01, 0.2), (-0.1, 0.03, -1.0)])
def test_measurement_jacobian_matches_finite_differences(lever):
    ekf = _filter()
    _, jacobian = ekf.predicted_bearing(2, lever)
    step = 1e-6
    numeric = []
    for axis in range(3):
        shifted = list(POSE)
        shifted[axis] += step
        plus, _ = _filter(tuple(shifted)).predicted_bearing(2, lever)
        shifted[axis] -= 2 * step
        minus, _ = _filter(tuple(shifted)).predicted_bearing(2, lever)
        numeric.append(wrap_to_pi(plus - minus) / (2 * step))
    np.testing.assert_allclose(jacobian[0], numeric, rtol=1e-6, atol=1e-8)


def test_predict_moves_by_the_increment_and_grows_the_covariance():
    ekf = _filter(sigma=(1e-3, 1e-3, 1e-3))
    before = ekf.covariance
    ekf.predict((0.1, 0.0, 0.2))
    assert np.allclose(ekf.pose, compose(POSE, (0.1, 0.0, 0.2)))
    # heading uncertainty couples into position when moving
    assert np.trace(ekf.covariance) > np.trace(before)
    assert ekf.covariance[0, 2] != 0.0


def _filterpy_predict(ekf: BearingEkf, increment) -> tuple[np.ndarray, np.ndarray]:
    """x and P after filterpy's EKF.predict with the whole F and Q of the state blocks (P <- F P F' + Q)."""
    x, p = ekf.state()
    c, s = cos(x[2, 0]), sin(x[2, 0])
    f, q, moved = np.eye(ekf.dim), np.zeros((ekf.dim, ekf.dim)), increment
    for block, part in ekf._parts:
        moved, d_moved = block.corrected_increment(moved, x[part, 0])
        if d_moved is not None:
            f[:3, part] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ d_moved
        noise = block.process_noise(increment, x[part, 0])
        if noise is not None:
            q[part, part] = noise
    f[:3, :3] = [[1.0, 0.0, -s * moved[0] - c * moved[1]], [0.0, 1.0, c * moved[0] - s * moved[1]], [0, 0, 1]]
    reference = ExtendedKalmanFilter(dim_x=ekf.dim, dim_z=1)
    reference.x, reference.P, reference.F, reference.Q = x, p, f, q

    def compose_pose(u) -> None:
        reference.x = reference.x.copy()
        reference.x[:3, 0] = compose(tuple(reference.x[:3, 0].tolist()), u)

    reference.predict_x = compose_pose
    reference.predict(u=moved)
    return reference.x, reference.P


_LAYOUTS = (
    (OdometryErrorStates(), PowerBiasStates()),  # ekf_node's default
    (OdometryErrorStates(walk_variance_per_m=1e-4), TurretOffsetStates(), BeaconStates((4, 5))),
    (),
)


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from(_LAYOUTS),
    st.tuples(*(st.floats(-3.0, 3.0),) * 3),
    st.tuples(st.floats(-0.05, 0.05), st.floats(-0.01, 0.01), st.floats(-0.3, 0.3)),
    st.integers(0, 2**32 - 1),
)
def test_predict_is_filterpys_predict_with_the_whole_jacobian(blocks, pose, increment, seed):
    """The prediction touching only the pose's rows and columns gives filterpy's x and P (random states
    and covariances, every block layout)."""
    ekf = BearingEkf({**EUROBOT_BEACONS, 4: (1.5, -0.062), 5: (1.5, 2.062)}, OFFSET, blocks=blocks)
    rng = np.random.default_rng(seed)
    root = rng.normal(size=(ekf.dim, ekf.dim)) * rng.uniform(1e-4, 1.0, ekf.dim)
    x = rng.normal(size=(ekf.dim, 1)) * 0.1
    x[:3, 0] = pose
    ekf.initialise(pose, np.eye(3))
    ekf.restore((x, root @ root.T + 1e-9 * np.eye(ekf.dim)))
    expected_x, expected_p = _filterpy_predict(ekf, increment)
    ekf.predict(increment)
    x_after, p_after = ekf.state()
    assert np.allclose(x_after, expected_x, rtol=0.0, atol=1e-12)
    assert np.allclose(p_after, expected_p, rtol=1e-12, atol=1e-12)


def test_process_noise_grows_with_distance_and_rotation():
    noise = ProcessNoise(1e-4, 2e-4, 3e-4, floor_variance=0.0)
    assert noise.robot_frame_variances((0.0, 0.0, 0.0)) == (0.0, 0.0, 0.0)
    along, across, heading = noise.robot_frame_variances((0.3, 0.4, -0.5))
    assert along == across == pytest.approx(1e-4 * 0.5)
    assert heading == pytest.approx(2e-4 * 0.5 + 3e-4 * 0.5)


def test_process_noise_rejects_negative_values():
    with pytest.raises(ValueError, match="translation"):
        filter_settings({"translation_variance_m2_per_m": -1.0})


def test_update_pulls_the_estimate_towards_the_truth_and_shrinks_the_innovation_variance():
    truth = POSE
    ekf = _filter(pose=(1.21, 0.69, 0.41), sigma=(0.02, 0.02, 0.02))
    errors = []
    for _ in range(20):
        for beacon_id in (1, 2, 3):
            outcome = ekf.update_bearing(beacon_id, _true_bearing(truth, beacon_id), 1e-8)
            assert outcome.accepted
        errors.append(np.hypot(ekf.pose[0] - truth[0], ekf.pose[1] - truth[1]))
    assert errors[-1] < 1e-5 < 0.014
    assert abs(wrap_to_pi(ekf.pose[2] - truth[2])) < 1e-5


def test_residual_is_wrapped_across_pi():
    # the robot faces away from beacon 3 so its bearing is near +-pi
    pose = (2.0, 1.0, pi)
    ekf = _filter(pose=pose, offset=(0.0, 0.0))
    expected, _ = ekf.predicted_bearing(3)
    assert abs(abs(expected) - pi) < 1e-3
    measured = wrap_to_pi(expected + 2e-4)
    outcome = ekf.update_bearing(3, measured, 1e-8)
    assert outcome.accepted
    assert abs(outcome.residual_rad - 2e-4) < 1e-9


def test_gate_rejects_an_outlier_and_accepts_a_consistent_bearing():
    ekf = _filter(sigma=(1e-3, 1e-3, 1e-3), gate_probability=0.99)
    _, jacobian = ekf.predicted_bearing(1)
    sigma = sqrt(float((jacobian @ ekf.covariance @ jacobian.T)[0, 0]) + 1e-7)
    good = ekf.update_bearing(1, _true_bearing(POSE, 1) + 2.0 * sigma, 1e-7)
    assert good.accepted and good.nis == pytest.approx(4.0, rel=1e-6)
    before = ekf.pose
    bad = ekf.update_bearing(2, _true_bearing(POSE, 2) + 0.2, 1e-7)
    assert not bad.accepted and bad.reason == "gated" and bad.nis > gate_threshold(0.99)
    assert ekf.pose == before


def test_gate_threshold_is_the_chi_square_quantile():
    assert gate_threshold(0.95) == pytest.approx(3.841458820694124)
    with pytest.raises(ValueError, match="gate_probability"):
        filter_settings({"gate_probability": 1.0})


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 7, 12, 27, 60, 200])
def test_chi_square_quantile_is_scipys(dof):
    """chi2_quantile stands in for scipy.stats' chi2.ppf (whose import is a second of ekf_node's start):
    the same to 1e-12 over the parameters' ranges (gate, kidnap, lost NIS: 0.5 to 1 - 1e-12) and below."""
    from scipy.stats import chi2

    from beams_ekf.consistency import chi2_quantile

    for probability in (1e-9, 0.01, 0.3, 0.5, 0.9, 0.95, 0.99, 0.999, 1 - 1e-6, 1 - 1e-9, 1 - 1e-12):
        assert chi2_quantile(probability, dof) == pytest.approx(chi2.ppf(probability, dof), rel=1e-12)
    for wrong in ((0.0, dof), (1.0, dof), (float("nan"), dof), (0.5, 0)):
        with pytest.raises(ValueError, match="chi-square quantile"):
            chi2_quantile(*wrong)


@pytest.mark.parametrize(
    ("beacon_id", "bearing", "variance", "reason"),
    [
        (9, 0.0, 1e-6, "unknown_beacon"),
        (1, float("nan"), 1e-6, "invalid_measurement"),
        (1, 0.0, 0.0, "invalid_measurement"),
        (1, 0.0, float("inf"), "invalid_measurement"),
    ],
)
def test_invalid_bearings_are_refused_without_touching_the_state(beacon_id, bearing, variance, reason):
    ekf = _filter()
    before = ekf.pose
    outcome = ekf.update_bearing(beacon_id, bearing, variance)
    assert not outcome.accepted and outcome.reason == reason
    assert ekf.pose == before


def test_uninitialised_filter_refuses_bearings_and_initialise_validates():
    ekf = BearingEkf(EUROBOT_BEACONS)
    assert ekf.update_bearing(1, 0.0, 1e-6).reason == "uninitialised"
    with pytest.raises(ValueError, match="positive definite"):
        ekf.initialise(POSE, np.diag([1.0, 1.0, 0.0]))
    with pytest.raises(ValueError, match="finite"):
        ekf.initialise((float("nan"), 0.0, 0.0), np.eye(3))


def test_turret_pose_is_the_offset_on_the_robot():
    assert np.allclose(turret_pose((1.0, 0.0, pi / 2), (0.1, 0.0)), (1.0, 0.1, pi / 2))


def test_state_restore_round_trip():
    ekf = _filter()
    before, saved = ekf.pose, ekf.state()
    ekf.predict((0.2, 0.0, 0.1))
    ekf.restore(saved)
    assert ekf.pose == before
