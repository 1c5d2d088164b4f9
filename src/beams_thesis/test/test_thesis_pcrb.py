"""The posterior Cramer-Rao bound on cases with a known answer, and its noise model against the
simulator's odometry."""

import itertools
import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.pose2d import between, compose
from beams_ekf.bearing_ekf import bearing_measurement
from beams_ekf.odometry_errors import (
    OdometryErrorStates,
    arc_increment,
    arc_of_increment,
    corrected_increment,
)
from beams_sim.world import EurobotTrajectory, OdometryDrift, OdometrySimulator
from beams_thesis.pcrb import (
    PcrbTrack,
    WheelNoiseModel,
    bearing_information,
    gaussian_information_step,
    information_step,
    odometry_step,
    trajectory_pcrb,
)


def _spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T + n * np.eye(n))


@given(st.integers(0, 10_000))
@settings(max_examples=30, deadline=None)
def test_gaussian_step_is_tichavskys_recursion_for_an_invertible_q(seed):
    """With D11 = F' Q^-1 F, D12 = -F' Q^-1, D22 = Q^-1 + I_z the two forms agree."""
    rng = np.random.default_rng(seed)
    j, q, i_z = _spd(rng, 3), _spd(rng, 3, 0.1), _spd(rng, 3, 0.5)
    f = np.eye(3) + 0.3 * rng.normal(size=(3, 3))
    q_inv = np.linalg.inv(q)
    expected = information_step(j, f.T @ q_inv @ f, -f.T @ q_inv, q_inv + i_z)
    np.testing.assert_allclose(gaussian_information_step(j, f, q, i_z), expected, rtol=1e-8)


def rms_position_m(track: PcrbTrack, times_s: np.ndarray) -> float:
    """sqrt(mean(trace of the position bound)) over the instants: the RMS position error floor."""
    bounds = track.at(times_s)
    return float(np.sqrt(np.mean(bounds[:, 0, 0] + bounds[:, 1, 1])))


def test_linear_gaussian_bound_is_the_kalman_covariance():
    """For a linear-Gaussian system the PCRB is the Kalman filter's covariance (filterpy's)."""
    rng = np.random.default_rng(4)
    f = np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.1], [0.0, 0.0, 1.0]])
    q = np.diag([1e-4, 0.0, 1e-3])  # singular on purpose
    h = rng.normal(size=(2, 3))
    r = np.diag([0.04, 0.09])
    kf = KalmanFilter(dim_x=3, dim_z=2)
    kf.F, kf.Q, kf.H, kf.R, kf.P = f, q, h, r, np.diag([1.0, 2.0, 0.5])
    information = np.linalg.inv(kf.P)
    for _ in range(50):
        kf.predict()
        kf.update(rng.normal(size=2))
        information = gaussian_information_step(information, f, q, h.T @ np.linalg.inv(r) @ h)
        np.testing.assert_allclose(np.linalg.inv(information), kf.P, rtol=1e-6, atol=1e-12)


def test_static_robot_bound_is_the_inverse_of_the_summed_information():
    """A robot standing still (no odometry noise): the bound is (prior + sum of H'H/R)^-1."""
    pose = (1.2, 0.7, 0.4)
    offset = (0.03, -0.01)
    times = np.arange(0.0, 1.0, 0.02)
    bearings = [(0.005 + 0.1 * k + 0.03 * (i - 1), i, 3e-7 * i) for k in range(10) for i in (1, 2, 3)]
    prior = np.diag([1e-4, 1e-4, 3e-4])
    track = trajectory_pcrb(
        times,
        np.tile(pose, (len(times), 1)),
        np.zeros((len(times) - 1, 3)),
        bearings,
        EUROBOT_BEACON_MAP.as_dict(),
        lambda t: pose,
        offset,
        prior,
        WheelNoiseModel(0.0, 0.0),
    )
    information = np.linalg.inv(prior)
    for _, beacon_id, variance in bearings:
        _, jacobian = bearing_measurement(pose, EUROBOT_BEACON_MAP.as_dict()[beacon_id], (*offset, 0.0))
        information += bearing_information(jacobian, variance)
    np.testing.assert_allclose(track.bounds[-1], np.linalg.inv(information), rtol=1e-9)
    # the first instant has the prior and the one bearing stamped before the second odometry sample
    _, first = bearing_measurement(pose, EUROBOT_BEACON_MAP.as_dict()[1], (*offset, 0.0))
    first_information = np.linalg.inv(prior) + bearing_information(first, 3e-7)
    np.testing.assert_allclose(track.bounds[0], np.linalg.inv(first_information), rtol=1e-9)
    assert rms_position_m(track, times[-1:]) == pytest.approx(
        math.sqrt(np.trace(np.linalg.inv(information)[:2, :2]))
    )


def test_unknown_odometry_errors_only_raise_the_bound():
    """More unknowns (the odometry error states) can only loosen the bound."""
    trajectory = EurobotTrajectory.random(3, 8.0)
    times = np.arange(0.0, 8.0, 0.02)
    truth = trajectory.poses_at(times)
    increments = np.array([between(tuple(a), tuple(b)) for a, b in itertools.pairwise(truth)])
    bearings = [(t + 0.03 * i, i, 3e-7) for t in np.arange(0.0, 7.9, 0.1) for i in (1, 2, 3)]
    common = (
        times,
        truth,
        increments,
        bearings,
        EUROBOT_BEACON_MAP.as_dict(),
        trajectory.pose_at,
        (0.0, 0.0),
        np.diag([1e-4, 1e-4, 3e-4]),
        WheelNoiseModel(),
    )
    known, unknown = trajectory_pcrb(*common), trajectory_pcrb(*common, OdometryErrorStates())
    difference = unknown.bounds - known.bounds
    assert np.all(np.linalg.eigvalsh(difference) > -1e-15)
    assert rms_position_m(unknown, times) > rms_position_m(known, times)


def test_wheel_noise_model_is_the_simulators_odometry_noise():
    """Monte Carlo of sim_world's odometry on one arc step (no systematic error but the slip's mean):
    the covariance of the reported (s, Delta) is WheelNoiseModel's."""
    drift = OdometryDrift(0.0, 0.0, 0.0, slip_std=0.005, noise_m_per_sqrt_m=0.001)
    simulator = OdometrySimulator(EurobotTrajectory.static((1.0, 1.0, 0.0), 1.0), drift, seed=2)
    n, distance, turn = 200_000, 0.01, 0.03
    reported_s, reported_turn = simulator._wheel_measurements(np.full(n, distance), np.full(n, turn))
    samples = np.column_stack([reported_s, reported_turn])
    increment, _ = arc_increment(distance, turn)
    expected = WheelNoiseModel(0.001, 0.005, 0.3).arc_covariance(increment)
    np.testing.assert_allclose(np.cov(samples.T), expected, rtol=0.02, atol=1e-3 * expected[1, 1])


def test_arc_round_trip_and_jacobians():
    increment, jacobian = arc_increment(0.2, 0.7)
    assert arc_of_increment(increment) == pytest.approx((0.2, 0.7))
    # the exact odometry integration of sim_world: the chord along the mid heading
    chord = 0.2 * np.sinc(0.7 / (2 * np.pi))
    assert increment == pytest.approx((chord * math.cos(0.35), chord * math.sin(0.35), 0.7))
    step = 1e-7
    numeric = np.column_stack(
        [
            (np.subtract(arc_increment(0.2 + step, 0.7)[0], increment)) / step,
            (np.subtract(arc_increment(0.2, 0.7 + step)[0], increment)) / step,
        ]
    )
    np.testing.assert_allclose(jacobian, numeric, atol=1e-6)
    # the series near a zero turn joins the closed form
    d = 0.99e-4
    assert arc_increment(0.2, d)[0] == pytest.approx(
        (0.2 * math.sin(d) / d, 0.2 * (1 - math.cos(d)) / d, d), rel=1e-9
    )


def test_corrected_increment_and_its_jacobians():
    reported = arc_increment(0.1, 0.05)[0]
    errors = np.array([0.98, 1.01, 0.02])
    moved, d_errors, _ = corrected_increment(reported, errors)
    assert moved == pytest.approx(arc_increment(0.098, 1.01 * 0.05 + 0.02 * 0.1)[0])
    step = 1e-7
    for i in range(3):
        shifted = errors.copy()
        shifted[i] += step
        numeric = np.subtract(corrected_increment(reported, shifted)[0], moved) / step
        np.testing.assert_allclose(d_errors[:, i], numeric, atol=1e-6)
    # F of an odometry step: the pose block is d compose / d pose
    pose = (1.0, 0.5, 0.3)
    transition, covariance = odometry_step(pose, reported, WheelNoiseModel(), with_errors=False)
    base = np.array(compose(pose, reported))
    numeric = np.subtract(compose((1.0, 0.5, 0.3 + step), reported), base) / step
    np.testing.assert_allclose(transition[:, 2], numeric, atol=1e-6)
    assert np.all(np.linalg.eigvalsh(covariance) > -1e-18) and np.linalg.matrix_rank(covariance) == 2
