"""The simulated robot (trajectory, odometry) and the offline match that chains it to the sensor."""

import math

import numpy as np
import pytest

from beams_common.geometry.angles import wrap_to_pi
from beams_sim.occlusion import (
    TRUTH_LEAD_S,
    TRUTH_MAX_EXTRAPOLATION_S,
    OtherRobots,
    sight_line_blocked,
    truth_buffer,
    truth_covers,
)
from beams_sim.sensor_sim import SensorSimConfig, SimulatedBeacon
from beams_sim.simulated_match import SimulatedMatch, simulate_match
from beams_sim.world import (
    TABLE_LENGTH_M,
    TABLE_WIDTH_M,
    EurobotTrajectory,
    MotionLimits,
    OdometryDrift,
    OdometrySimulator,
)

LIMITS = MotionLimits()
GRID_S = 0.001


@pytest.fixture(scope="module", params=[0, 1, 2])
def match_trajectory(request: pytest.FixtureRequest) -> EurobotTrajectory:
    return EurobotTrajectory.random(seed=request.param)


def dense_states(trajectory: EurobotTrajectory) -> tuple[np.ndarray, np.ndarray]:
    times = np.arange(0.0, trajectory.duration_s + GRID_S / 2, GRID_S)
    return times, trajectory.states_at(times)


def in_start_frame(trajectory: EurobotTrajectory, t: float) -> tuple[float, float, float]:
    """The true pose at t seen from the start pose: where perfect odometry would be."""
    x0, y0, theta0 = trajectory.pose_at(0.0)
    x, y, theta = trajectory.pose_at(t)
    c, s = math.cos(theta0), math.sin(theta0)
    return (c * (x - x0) + s * (y - y0), -s * (x - x0) + c * (y - y0), float(wrap_to_pi(theta - theta0)))


# ---- trajectory ----


def test_default_match_respects_limits_and_stays_on_the_table(match_trajectory: EurobotTrajectory) -> None:
    _, states = dense_states(match_trajectory)
    speed, yaw_rate = states[:, 4], states[:, 5]
    assert match_trajectory.duration_s == 90.0
    assert speed.min() >= 0.0 and speed.max() <= LIMITS.max_speed_mps * (1 + 1e-6)
    assert np.abs(yaw_rate).max() <= LIMITS.max_yaw_rate_radps * 1.002
    r = LIMITS.robot_radius_m
    assert states[:, 0].min() >= r and states[:, 0].max() <= TABLE_LENGTH_M - r
    assert states[:, 1].min() >= r and states[:, 1].max() <= TABLE_WIDTH_M - r
    # A real match: most of the time moving, over tens of metres, using the speed and yaw-rate range.
    assert states[-1, 3] > 20.0
    assert speed.max() > 0.49 and np.abs(yaw_rate).max() > 1.5
    assert match_trajectory.twist_at(0.0)[0] < 0.01 and match_trajectory.twist_at(90.0) == (0.0, 0.0)


def test_motion_is_smooth_and_pose_agrees_with_twist(match_trajectory: EurobotTrajectory) -> None:
    times, states = dense_states(match_trajectory)
    x, y, heading, _, speed, yaw_rate = states.T
    acceleration = np.diff(speed) / GRID_S
    assert np.abs(acceleration).max() <= LIMITS.max_acceleration_mps2 * 1.001
    assert np.abs(np.diff(yaw_rate) / GRID_S).max() < 20.0  # continuous curvature: bounded yaw acceleration
    # Unicycle kinematics: the robot moves along its heading at its speed, turns at its yaw rate.
    middle_heading = 0.5 * (heading[1:] + heading[:-1])
    middle_speed = 0.5 * (speed[1:] + speed[:-1])
    np.testing.assert_allclose(np.diff(x) / GRID_S, middle_speed * np.cos(middle_heading), atol=2e-3)
    np.testing.assert_allclose(np.diff(y) / GRID_S, middle_speed * np.sin(middle_heading), atol=2e-3)
    np.testing.assert_allclose(np.diff(heading) / GRID_S, 0.5 * (yaw_rate[1:] + yaw_rate[:-1]), atol=2e-2)
    assert len(times) == 90001


def test_trajectory_is_deterministic_from_its_seed() -> None:
    times = np.linspace(0.0, 90.0, 901)
    first = EurobotTrajectory.random(seed=5).states_at(times)
    np.testing.assert_array_equal(first, EurobotTrajectory.random(seed=5).states_at(times))
    assert np.abs(first - EurobotTrajectory.random(seed=6).states_at(times)).max() > 0.1


def test_scalar_and_vector_queries_agree_and_clamp_outside_the_match() -> None:
    trajectory = EurobotTrajectory.random(seed=3, duration_s=20.0)
    times = np.array([-1.0, 0.0, 3.2345, 19.9999, 20.0, 25.0])
    poses = trajectory.poses_at(times)
    for t, pose in zip(times, poses, strict=True):
        np.testing.assert_allclose(trajectory.pose_at(float(t)), pose, atol=1e-12)
    assert trajectory.pose_at(-1.0) == trajectory.pose_at(0.0) == pytest.approx((0.4, 1.0, 0.0), abs=1e-9)
    assert trajectory.pose_at(25.0) == trajectory.pose_at(20.0)
    assert trajectory.twist_at(25.0) == (0.0, 0.0)
    assert all(-math.pi < pose[2] <= math.pi for pose in poses)


def test_waypoints_give_the_b_spline_and_are_validated() -> None:
    straight = EurobotTrajectory.through_waypoints([(0.5, 1.0), (1.5, 1.0), (2.5, 1.0)], duration_s=10.0)
    _, states = dense_states(straight)
    np.testing.assert_allclose(states[:, 1], 1.0, atol=1e-12)
    np.testing.assert_allclose(states[:, 2], 0.0, atol=1e-12)
    # Starts on the first point; the spline of a straight polygon ends 1/6 of a segment short of the last.
    assert straight.pose_at(0.0)[0] == pytest.approx(0.5)
    assert straight.pose_at(10.0)[0] == pytest.approx(2.5 - 1.0 / 6.0, abs=1e-3)
    with pytest.raises(ValueError, match="leaves the table"):
        EurobotTrajectory.through_waypoints([(0.5, 1.0), (2.95, 1.0), (2.95, 1.9)])
    with pytest.raises(ValueError, match="3 or more"):
        EurobotTrajectory.through_waypoints([(0.5, 1.0), (1.5, 1.0)])
    with pytest.raises(ValueError, match=r"max_speed_mps = -1\.0 is below its minimum"):
        MotionLimits(max_speed_mps=-1.0)
    with pytest.raises(ValueError, match="off the table"):
        EurobotTrajectory.random(seed=0, start_pose=(0.1, 1.0, 0.0))
    with pytest.raises(ValueError, match="uniformly spaced"):
        EurobotTrajectory(np.array([0.0, 1.0, 3.0]), np.zeros((3, 2)), *np.zeros((4, 3)))


def test_static_robot_stands_still() -> None:
    trajectory = EurobotTrajectory.static((1.0, 0.5, 2.0), duration_s=30.0)
    assert trajectory.pose_at(12.3) == pytest.approx((1.0, 0.5, 2.0))
    assert trajectory.twist_at(12.3) == (0.0, 0.0)


# ---- odometry ----


def test_perfect_odometry_follows_the_truth_in_the_odom_frame(match_trajectory: EurobotTrajectory) -> None:
    samples = OdometrySimulator(match_trajectory, OdometryDrift.none()).run(50.0)
    assert samples.stamp_s.size == 4500 and samples.stamp_s[-1] == pytest.approx(90.0)
    for index in (1000, 4499):
        truth = in_start_frame(match_trajectory, float(samples.stamp_s[index]))
        assert math.dist(samples.pose(index)[:2], truth[:2]) < 1e-3
        assert abs(wrap_to_pi(samples.pose(index)[2] - truth[2])) < 1e-4


def test_wheel_scale_error_scales_distance_on_a_straight_line() -> None:
    straight = EurobotTrajectory.through_waypoints([(0.5, 1.0), (1.5, 1.0), (2.5, 1.0)], duration_s=10.0)
    drift = OdometryDrift(0.02, 0.02, 0.0, 0.0, 0.0)
    samples = OdometrySimulator(straight, drift).run(50.0)
    assert samples.x_m[-1] == pytest.approx(1.02 * straight.distance_at(10.0), rel=1e-9)
    assert np.abs(samples.y_m).max() < 1e-12 and np.abs(samples.theta_rad).max() < 1e-12
    assert samples.speed_mps.max() == pytest.approx(1.02 * 0.5, rel=1e-3)


def test_wheel_base_error_scales_every_turn(match_trajectory: EurobotTrajectory) -> None:
    drift = OdometryDrift(0.0, 0.0, 0.03, 0.0, 0.0)
    samples = OdometrySimulator(match_trajectory, drift).run(50.0)
    reported_turn = np.sum(samples.yaw_rate_radps) / 50.0
    true_turn = match_trajectory.heading_unwrapped_at(90.0) - match_trajectory.heading_unwrapped_at(0.0)
    assert reported_turn == pytest.approx(true_turn / 1.03, rel=1e-9, abs=1e-12)


def test_default_drift_is_realistic_and_seeded(match_trajectory: EurobotTrajectory) -> None:
    samples = OdometrySimulator(match_trajectory, seed=4).run(50.0)
    truth = in_start_frame(match_trajectory, 90.0)
    position_error = math.dist(samples.pose(-1)[:2], truth[:2])
    assert 0.005 < position_error < 0.5  # centimetres to decimetres after a 90 s match
    assert abs(wrap_to_pi(samples.pose(-1)[2] - truth[2])) < 0.4
    again = OdometrySimulator(match_trajectory, seed=4).run(50.0)
    np.testing.assert_array_equal(samples.x_m, again.x_m)


def test_stepping_gives_the_same_samples_as_a_whole_run() -> None:
    trajectory = EurobotTrajectory.random(seed=8, duration_s=5.0)
    whole = OdometrySimulator(trajectory, seed=2).run(50.0)
    stepper = OdometrySimulator(trajectory, seed=2)
    stepped = [stepper.advance(float(t)) for t in whole.stamp_s]
    np.testing.assert_allclose([s.x_m[0] for s in stepped], whole.x_m, atol=1e-12)
    np.testing.assert_allclose([s.theta_rad[0] for s in stepped], whole.theta_rad, atol=1e-12)
    with pytest.raises(ValueError, match="backwards"):
        stepper.advance(1.0)


# ---- the offline match ----


def bearing_errors(match: SimulatedMatch) -> dict[int, np.ndarray]:
    """Decoded minus true bearing (rad, wrapped) of every bearing, per beacon id."""
    errors: dict[int, list[float]] = {}
    for revolution in match.revolutions:
        for bearing in revolution.bearings:
            error = wrap_to_pi(bearing.bearing - match.true_bearing(bearing.beacon_id, bearing.stamp_s))
            errors.setdefault(bearing.beacon_id, []).append(float(error))
    return {beacon_id: np.array(values) for beacon_id, values in errors.items()}


@pytest.fixture(scope="module")
def short_match() -> SimulatedMatch:
    return simulate_match(20.0, seed=3)


def test_match_has_every_revolution_and_synchronised_truth_and_odometry(short_match: SimulatedMatch) -> None:
    period = SensorSimConfig().period_s
    assert len(short_match.revolutions) == math.floor(20.0 / period)
    starts = np.array([r.start_time_s for r in short_match.revolutions])
    np.testing.assert_allclose(np.diff(starts), period, rtol=1e-12)
    truth, odometry = short_match.ground_truth, short_match.odometry
    np.testing.assert_allclose(truth.stamp_s, np.arange(1001) / 50.0, atol=1e-9)
    np.testing.assert_array_equal(truth.stamp_s, odometry.stamp_s)
    assert odometry.pose(0) == (0.0, 0.0, 0.0)
    assert (truth.x_m[0], truth.y_m[0], truth.theta_rad[0]) == pytest.approx(short_match.initial_pose)
    seen = sum(len(r.bearings) for r in short_match.revolutions)
    assert seen >= 0.95 * 3 * len(short_match.revolutions)


def test_match_bearings_agree_with_the_truth_within_their_predicted_spread(
    short_match: SimulatedMatch,
) -> None:
    errors, sigmas = [], []
    for revolution in short_match.revolutions:
        for bearing in revolution.bearings:
            truth = short_match.true_bearing(bearing.beacon_id, bearing.stamp_s)
            errors.append(float(wrap_to_pi(bearing.bearing - truth)))
            sigmas.append(math.sqrt(bearing.variance))
            # Windows across the zero reference are stamped just before the revolution's start.
            margin_s = 0.05 * revolution.period_s
            start_s = revolution.start_time_s
            assert start_s - margin_s <= bearing.stamp_s <= start_s + revolution.period_s + margin_s
    normalized = np.array(errors) / np.array(sigmas)
    assert np.median(np.abs(normalized)) < 1.5  # 0.67 for a perfect Gaussian fit
    assert np.mean(np.abs(normalized) < 5.0) > 0.98


def test_match_is_deterministic_and_seeds_differ() -> None:
    first, again = simulate_match(2.0, seed=4), simulate_match(2.0, seed=4)
    other = simulate_match(2.0, seed=5)
    bearings = [[b.bearing for b in r.bearings] for r in first.revolutions]
    assert bearings == [[b.bearing for b in r.bearings] for r in again.revolutions]
    assert bearings != [[b.bearing for b in r.bearings] for r in other.revolutions]


def test_match_passes_imperfections_and_occlusion_to_the_sensor() -> None:
    displaced = (
        SimulatedBeacon(1, -0.062, -0.062),
        SimulatedBeacon(2, -0.02, 2.10),
        SimulatedBeacon(3, 3.06, 1.0),
    )
    match = simulate_match(
        3.0,
        seed=1,
        trajectory=EurobotTrajectory.static((1.5, 1.0, 0.3), duration_s=3.0),
        true_beacons=displaced,
        turret_offset_m=(0.05, -0.02),
        occlusion={3},
        rotation_bias_rad=lambda angle: np.full_like(angle, 0.01),
    )
    assert all(r.bearing_of(3) is None for r in match.revolutions)
    errors = bearing_errors(match)
    assert set(errors) == {1, 2}
    # The truth accounts for the displaced beacon and the offset; what remains is the injected bias.
    assert np.median(errors[2]) == pytest.approx(0.01, abs=2e-3)
    # ... and the displacement and offset were not negligible: the nominal bearing is 0.015 rad away.
    nominal_bearing = math.atan2(2.062 - 1.0, -0.062 - 1.5) - 0.3
    assert abs(match.true_bearing(2, 1.0) - nominal_bearing) > 0.01


def test_match_rejects_nonsense() -> None:
    with pytest.raises(ValueError, match="must be > 0"):
        simulate_match(0.0)


def test_rotating_robot_bearings_near_the_zero_reference() -> None:
    # A beacon pass across the zero reference must be timed on the robot's pose at that pass, not one
    # revolution away (at 2 rad/s that would be an 11 deg error).
    times = np.linspace(0.0, 10.0, 10001)
    still = np.zeros_like(times)
    # Turning in place at -2 rad/s in the middle of the table.
    centre = np.tile([1.5, 1.0], (times.size, 1))
    spinning = EurobotTrajectory(times, centre, 0.5 - 2.0 * times, still, still, np.full_like(times, -2.0))
    match = simulate_match(10.0, seed=0, trajectory=spinning)
    worst = max(np.abs(e).max() for e in bearing_errors(match).values())
    assert worst < math.radians(1.0)


def test_truth_history_covers_a_revolution_only_from_before_its_start(
    match_trajectory: EurobotTrajectory,
) -> None:
    """The driver's simulated sensor follows the ground truth as it arrives: a revolution that starts
    before the first pose received is not covered (its pose was frozen at that sample: the first fix of a
    driver started on a moving robot came out 3 cm off), and the pose between samples is the truth's."""
    history = truth_buffer()
    t_first = 10.0
    stamps = t_first + 0.02 * np.arange(50)
    for t in stamps:
        (x, y, theta), (speed, yaw_rate) = match_trajectory.pose_at(t), match_trajectory.twist_at(t)
        assert history.add(t, (x, y, theta), (speed, yaw_rate))
    assert not truth_covers(history, t_first, t_first + 0.1)
    assert not truth_covers(history, t_first + TRUTH_LEAD_S - 0.001, t_first + 0.1)
    assert truth_covers(history, t_first + TRUTH_LEAD_S, t_first + 0.1)
    # extrapolated with the last twist at most MAX_EXTRAPOLATION_S past the newest sample
    newest = stamps[-1]
    assert truth_covers(history, newest - 0.1, newest + TRUTH_MAX_EXTRAPOLATION_S - 1e-6)
    assert not truth_covers(history, newest - 0.1, newest + TRUTH_MAX_EXTRAPOLATION_S + 0.001)
    # 50 Hz samples interpolated: within 0.1 mm and 0.03 deg of the truth (h^2/8 of the angular acceleration)
    for t in (t_first + 0.31, t_first + 0.555):
        x, y, theta = history.pose_at(t)
        tx, ty, ttheta = match_trajectory.pose_at(t)
        assert math.hypot(x - tx, y - ty) < 1e-4 and abs(wrap_to_pi(theta - ttheta)) < math.radians(0.03)
    # extrapolation 20 ms past the newest sample: within 1 mm of the truth
    x, y, _ = history.pose_at(newest + 0.02)
    tx, ty, _ = match_trajectory.pose_at(newest + 0.02)
    assert math.hypot(x - tx, y - ty) < 1e-3
    # non-finite samples are refused; time going back starts the history again
    assert not history.add(t_first + 2.0, (math.nan, 0.0, 0.0), (0.0, 0.0))
    assert history.add(1.0, (1.0, 1.0, 0.0), (0.0, 0.0))
    assert history.pose_at(1.0) == (1.0, 1.0, 0.0)
    assert not truth_covers(history, t_first + 0.5, t_first + 0.6) and not truth_covers(history, 1.0, 1.1)


@pytest.mark.parametrize(
    ("centre", "blocked"),
    [
        ((1.5, 1.0), True),  # on the line of sight
        ((1.5, 1.09), True),  # 9 cm from it, radius 10 cm
        ((1.5, 1.11), False),
        ((3.2, 1.0), False),  # on the line but behind the beacon
        ((-0.2, 1.0), False),  # on the line but behind the sensor
        ((3.09, 1.0), True),  # at the beacon itself
    ],
)
def test_sight_line_blocked_by_a_disc_between_sensor_and_beacon(centre, blocked) -> None:
    assert sight_line_blocked((0.0, 1.0), (3.0, 1.0), centre, 0.1) is blocked


def test_other_robot_hides_the_beacons_behind_it_while_it_is_on_the_table() -> None:
    """Robot A stands at (0.4, 1.0); robot B at (2.6, 1.0) is on its line of sight to beacon 3
    (3.062, 1.0): every pass over beacon 3 is hidden, beacons 1 and 2 are seen. B moved 30 cm aside
    hides nothing; B whose truth stopped arriving has left the table."""
    duration_s = 2.0
    sensor_pose = (0.4, 1.0, 0.0)
    beacons = {1: (-0.062, -0.062), 2: (-0.062, 2.062), 3: (3.062, 1.0)}

    def bearings_seen(
        b_position: tuple[float, float], truth_until_s: float
    ) -> tuple[int, list[tuple[float, set[int]]]]:
        """Windows hidden, and (start time, beacons seen) of each revolution."""
        other = OtherRobots(beacons, 0.1, lambda t: sensor_pose[:2])
        for t in np.arange(0.0, truth_until_s, 0.02):
            assert other.add("robot_b", t, *b_position, math.pi, 0.0, 0.0)
        still = EurobotTrajectory.static(sensor_pose, duration_s)
        match = simulate_match(duration_s, seed=3, trajectory=still, occlusion=other)
        return other.hidden_windows, [
            (r.start_time_s, {b.beacon_id for b in r.bearings}) for r in match.revolutions
        ]

    hidden, seen = bearings_seen((2.6, 1.0), duration_s)
    assert len(seen) >= 15 and all(ids == {1, 2} for _, ids in seen)
    assert hidden >= len(seen)
    hidden, seen = bearings_seen((2.6, 1.3), duration_s)
    # beacon 3 straddles the zero reference: the first revolution has only the tail of its window
    assert hidden == 0 and all(ids == {1, 2, 3} for _, ids in seen[1:])
    # B's last pose at 0.98 s: hidden until 0.98 + MAX_EXTRAPOLATION_S, seen after
    hidden, seen = bearings_seen((2.6, 1.0), 1.0)
    late = [ids for start_s, ids in seen if start_s > 0.98 + TRUTH_MAX_EXTRAPOLATION_S]
    early = [ids for start_s, ids in seen if start_s + 0.1 < 0.98]
    assert late and all(ids == {1, 2, 3} for ids in late)
    assert early and all(ids == {1, 2} for ids in early)
    # a beacon the map does not know is never hidden by a robot
    other = OtherRobots(beacons, 0.1, lambda t: sensor_pose[:2])
    other.add("robot_b", 0.0, 2.6, 1.0, 0.0, 0.0, 0.0)
    assert not other(7, 0.0) and other(3, 0.0)
