"""Semantic plausibility (issue 18): stamps against the receiving clock, odometry increments against the
robot's limits, an operator's covariance against the table."""

import math

from hypothesis import given
from hypothesis import strategies as st

from beams_common.intake.plausibility import (
    MotionLimits,
    StampCheck,
    StampTolerance,
    odometry_step_problem,
    stamp_problem,
)

TOLERANCE = StampTolerance()
RECEIVED_S = 1_790_000_000.0  # an epoch-scale clock, as a live node's


def test_the_legitimate_latency_of_a_revolution_passes():
    # the newest bearing of a revolution is at most one revolution (0.1 s) old at its publication, and
    # arrives a few milliseconds to ~0.1 s later on a loaded computer
    for age_s in (0.0, 0.003, 0.1, 0.15, 0.2, 0.24):
        assert stamp_problem("revolution 7", RECEIVED_S - age_s, RECEIVED_S, TOLERANCE) == ""
    # and a few milliseconds of clock skew ahead
    assert stamp_problem("revolution 7", RECEIVED_S + 0.05, RECEIVED_S, TOLERANCE) == ""


def test_the_issue_s_late_and_early_stamps_are_refused_with_the_offset():
    # issue 18: bearings stamped 0.3-3 s late or 0.5 s early (on top of their legitimate latency >= 0)
    for late_s in (0.3, 0.45, 1.0, 3.0):
        problem = stamp_problem("revolution 7", RECEIVED_S - late_s, RECEIVED_S, TOLERANCE)
        assert f"{late_s:.3f} s behind" in problem and "revolution 7" in problem
    problem = stamp_problem("revolution 7", RECEIVED_S + 0.5, RECEIVED_S, TOLERANCE)
    assert "0.500 s ahead" in problem


@given(
    st.floats(0.0, 1e4),
    st.floats(-1e4, 1e4),
    st.floats(0.0, 10.0),
    st.floats(0.0, 10.0),
)
def test_a_stamp_is_refused_exactly_beyond_the_tolerance_on_either_side(received_s, offset_s, age, lead):
    tolerance = StampTolerance(age, lead)
    problem = stamp_problem("x", received_s - offset_s, received_s, tolerance)
    measured = received_s - (received_s - offset_s)  # the offset as floating point computes it
    expected = (age > 0.0 and measured > age) or (lead > 0.0 and -measured > lead)
    assert bool(problem) == expected


def test_a_zero_tolerance_switches_that_side_off_and_non_finite_stamps_are_left_to_validation():
    off = StampTolerance(0.0, 0.0)
    assert stamp_problem("x", 0.0, RECEIVED_S, off) == ""  # a replay stamped 1970 on a live clock
    assert stamp_problem("x", math.nan, RECEIVED_S, TOLERANCE) == ""


def test_motion_within_the_limits_passes_and_a_100_m_jump_is_refused():
    limits = MotionLimits()
    # 50 Hz odometry of a robot at its top speed, turning at its top rate
    step = (limits.max_speed_m_per_s * 0.02, 0.0, limits.max_yaw_rate_rad_per_s * 0.02)
    assert odometry_step_problem(0.02, step, limits) == ""
    problem = odometry_step_problem(0.02, (100.0, 0.0, 0.0), limits)
    assert "moved 100.000 m in 0.020 s" in problem and "2 m/s" in problem
    assert "turned" in odometry_step_problem(0.02, (0.0, 0.0, 1.0), limits)
    # a long odometry gap allows proportionally more (a robot that drove on while odometry was silent)
    assert odometry_step_problem(2.0, (3.0, 0.0, 0.0), limits) == ""


@given(
    st.floats(1e-3, 1.0),
    st.floats(0.0, 3.0),
    st.floats(-math.pi, math.pi),
    st.floats(-math.pi, math.pi),
)
def test_an_increment_is_refused_exactly_when_speed_or_yaw_rate_is_exceeded(
    interval_s, distance, direction, turn
):
    limits = MotionLimits(1.5, 6.0)
    step = (distance * math.cos(direction), distance * math.sin(direction), turn)
    max_m, max_rad = limits.max_step(interval_s)
    expected = math.hypot(step[0], step[1]) > max_m or abs(turn) > max_rad
    assert bool(odometry_step_problem(interval_s, step, limits)) == expected


def test_one_late_input_is_refused_and_a_run_of_them_confirmed_per_kind():
    check = StampCheck(TOLERANCE)
    sequence = [  # (kind, age s, refused, confirmed)
        ("bearings", 0.05, False, False),
        ("bearings", 0.28, True, False),  # one scheduling hiccup: refused, not confirmed
        ("bearings", 0.05, False, False),
        ("bearings", 1.0, True, False),
        ("odometry", 0.01, False, False),  # another kind does not break the run
        ("bearings", 1.0, True, True),  # a relay restamping 1 s late: confirmed at the second
        ("bearings", 1.0, True, True),
        ("bearings", 0.02, False, False),
    ]
    for kind, age_s, refused, confirmed in sequence:
        problem, is_confirmed = check.check(kind, "x", RECEIVED_S - age_s, RECEIVED_S)
        assert (bool(problem), is_confirmed) == (refused, confirmed), (kind, age_s)
