"""SE(2) algebra shared by odometry, motion compensation and the EKF."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.pose2d import between, compose, interpolate, inverse, yaw_of_quaternion

A, B = (0.3, -1.2, 2.8), (1.1, 0.4, -2.9)


def test_compose_and_between_are_inverse():
    assert compose(A, between(A, B)) == pytest.approx(B, abs=1e-12)
    assert between(A, compose(A, B)) == pytest.approx(B, abs=1e-12)
    assert compose(A, inverse(A)) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


coordinate = st.floats(-10.0, 10.0)
poses = st.tuples(coordinate, coordinate, st.floats(-3.0 * math.pi, 3.0 * math.pi))


@given(poses, poses)
def test_between_inverts_compose_everywhere(a, b):
    assert between(a, compose(a, b))[:2] == pytest.approx(b[:2], abs=1e-8)
    assert abs(wrap_to_pi(between(a, compose(a, b))[2] - b[2])) < 1e-8


def test_compose_known_value():
    # a robot at (1, 2) facing +y moving 1 m forward ends at (1, 3)
    assert compose((1.0, 2.0, math.pi / 2), (1.0, 0.0, 0.0)) == pytest.approx((1.0, 3.0, math.pi / 2))


def test_interpolation_takes_the_short_arc_across_pi():
    start, end = (0.0, 0.0, math.pi - 0.1), (1.0, 2.0, -math.pi + 0.1)
    middle = interpolate(start, end, 0.5)
    assert middle[:2] == pytest.approx((0.5, 1.0))
    assert abs(wrap_to_pi(middle[2] - math.pi)) < 1e-12


@pytest.mark.parametrize("yaw", [-3.0, -1.0, 0.0, 0.5, 3.1])
def test_yaw_of_a_rotation_about_z(yaw):
    assert yaw_of_quaternion(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)) == pytest.approx(yaw)


def test_scalar_and_array_wrapping_agree_on_the_boundary():
    assert wrap_to_pi(math.pi) == math.pi and wrap_to_pi(-math.pi) == math.pi
    assert wrap_to_pi(3 * math.pi) == pytest.approx(math.pi)
    assert float(wrap_to_pi([-math.pi])[0]) == math.pi
