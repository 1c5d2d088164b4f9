"""Motion compensation: bearings of one revolution brought to one instant with the odometry increment."""

import math

import numpy as np
import pytest

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.pose2d import between
from beams_common.geometry.pose_buffer import arc_increment
from beams_triangulation.motion_compensation import (
    compensate_bearings,
    interpolate_pose,
    motion_variance_rad2,
    triangulate_compensated,
)
from beams_triangulation.total import expected_bearings, triangulate

BEACONS = EUROBOT_BEACON_MAP.xy
OFFSET = (0.05, -0.02)
ODOM_IN_MAP = (0.5, 0.2, 0.4)  # where the odometry frame stands in the map


def _truth(t):
    """A Eurobot robot at full speed and full yaw rate (0.5 m/s, 2 rad/s) on a circle."""
    heading = 0.3 + 2.0 * t
    return (1.5 + 0.25 * math.sin(heading), 1.0 - 0.25 * math.cos(heading), heading)


def _revolution(stamps, target):
    bearings = np.array(
        [expected_bearings(BEACONS[i : i + 1], _truth(stamps[i]), OFFSET)[0] for i in range(3)]
    )
    odom = np.array([between(ODOM_IN_MAP, _truth(t)) for t in stamps])
    return bearings, odom, between(ODOM_IN_MAP, _truth(target))


def _errors(fix, t):
    true = _truth(t)
    heading_error = abs(math.remainder(fix.heading - true[2], 2 * math.pi))
    return math.hypot(fix.x - true[0], fix.y - true[1]), heading_error


def test_compensation_recovers_the_pose_at_the_target_instant():
    stamps, target = (0.0, 0.031, 0.072), 0.05
    bearings, odom, odom_target = _revolution(stamps, target)
    raw_position, raw_heading = _errors(triangulate(BEACONS, bearings, OFFSET), target)
    rotated = compensate_bearings(bearings, odom, odom_target)
    rotation_only = _errors(triangulate(BEACONS, rotated, OFFSET), target)
    full = _errors(triangulate_compensated(BEACONS, bearings, odom, odom_target, OFFSET), target)
    # Uncompensated, 11 deg of rotation per revolution ruin the fix (thesis 5.7).
    assert raw_position > 0.05 and raw_heading > 0.01
    assert rotation_only[0] < raw_position / 5
    assert full[0] < 2e-5 and full[1] < 2e-5


def test_more_iterations_converge():
    stamps, target = (0.0, 0.04, 0.09), 0.09
    bearings, odom, odom_target = _revolution(stamps, target)
    fixes = [
        triangulate_compensated(BEACONS, bearings, odom, odom_target, OFFSET, iterations=k) for k in range(4)
    ]
    errors = [_errors(fix, target)[0] for fix in fixes]
    assert errors == sorted(errors, reverse=True)
    assert errors[3] < 1e-6


def test_no_motion_changes_nothing():
    bearings = np.array([0.3, -1.2, 2.9])
    odom = np.tile([0.4, 0.1, 1.0], (3, 1))
    np.testing.assert_allclose(compensate_bearings(bearings, odom, (0.4, 0.1, 1.0)), bearings, atol=1e-15)
    full = compensate_bearings(bearings, odom, (0.4, 0.1, 1.0), BEACONS, (1.0, 1.0, 0.2), OFFSET)
    np.testing.assert_allclose(full, bearings, atol=1e-15)


def test_pure_rotation_shifts_each_bearing_by_the_turn():
    odom = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1], [0.0, 0.0, 0.2]])
    corrected = compensate_bearings([1.0, 2.0, 3.0], odom, (0.0, 0.0, 0.2))
    np.testing.assert_allclose(corrected, [1.0 - 0.2, 2.0 - 0.1, 3.0], atol=1e-15)


def test_interpolate_pose_between_odometry_samples():
    stamps = [0.0, 0.02, 0.04]
    poses = [[0.0, 0.0, 3.1], [0.01, 0.0, -3.1], [0.02, 0.01, -3.0]]
    middle = interpolate_pose(stamps, poses, 0.01)
    assert middle[:2] == pytest.approx((0.005, 0.0))
    # Heading interpolated across the +-pi cut, not through zero.
    assert abs(math.remainder(middle[2] - math.pi, 2 * math.pi)) < 1e-12
    assert interpolate_pose(stamps, poses, 0.04) == pytest.approx((0.02, 0.01, -3.0))
    assert interpolate_pose(stamps, poses, 0.05) is None
    assert interpolate_pose([], np.zeros((0, 3)), 0.0) is None


def test_motion_variance_covers_the_uncompensated_error():
    stamps, target = (0.0, 0.031, 0.072), 0.036
    bearings, _, _ = _revolution(stamps, target)
    ideal = expected_bearings(BEACONS, _truth(target), OFFSET)
    error = np.abs(np.remainder(bearings - ideal + np.pi, 2 * np.pi) - np.pi)
    ranges = np.hypot(*(BEACONS - np.array(_truth(target)[:2])).T)
    bound = np.sqrt(motion_variance_rad2(np.array(stamps) - target, ranges, 0.5, 2.0))
    assert np.all(error <= bound)
    assert error.max() > 0.05  # 2 rad/s for 36 ms: the uncompensated error is real
    assert motion_variance_rad2([0.0], [1.0], 0.5, 2.0)[0] == 0.0


@pytest.mark.parametrize(("speed", "yaw_rate"), [(0.5, 2.0), (0.5, 0.0), (0.0, -1.5), (-0.3, 0.7)])
def test_arc_increment_is_exact_for_a_constant_twist(speed, yaw_rate):
    dt = 0.08
    turn = yaw_rate * dt
    if yaw_rate:  # on the circle of radius v / omega
        radius = speed / yaw_rate
        expected = (radius * math.sin(turn), radius * (1.0 - math.cos(turn)), turn)
    else:
        expected = (speed * dt, 0.0, 0.0)
    assert arc_increment(speed, yaw_rate, dt) == pytest.approx(expected, abs=1e-15)
