"""The stamped pose buffer (interpolation, extrapolation, trimming, ordering, time jumps)."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.pose2d import is_finite_pose
from beams_common.geometry.pose_buffer import PoseBuffer
from beams_common.intake.validation import odometry_problem


def _close(a, b, tolerance=1e-9) -> bool:
    return (
        abs(a[0] - b[0]) < tolerance
        and abs(a[1] - b[1]) < tolerance
        and abs(wrap_to_pi(a[2] - b[2])) < tolerance
    )


def _history() -> PoseBuffer:
    history = PoseBuffer(span_s=1.0, max_extrapolation_s=0.05)
    for k in range(5):
        history.append(0.02 * k, (0.01 * k, 0.0, 0.1 * k))
    return history


def test_pose_at_interpolates_between_samples():
    pose = _history().pose_at(0.03)
    assert _close(pose, (0.015, 0.0, 0.15))


def test_pose_at_sample_time_returns_the_sample():
    assert _close(_history().pose_at(0.04), (0.02, 0.0, 0.2))


def test_pose_at_outside_the_history_is_none():
    history = _history()
    assert history.pose_at(-0.001) is None
    assert history.pose_at(0.08 + 0.051) is None


def test_pose_at_extrapolates_a_little_with_the_last_velocity():
    assert _close(_history().pose_at(0.10), (0.05, 0.0, 0.5))


def test_append_refuses_time_going_back():
    history = _history()
    with pytest.raises(ValueError, match="not after"):
        history.append(0.08, (0.0, 0.0, 0.0))


def test_history_keeps_only_its_span():
    history = PoseBuffer(span_s=0.1, max_extrapolation_s=0.05)
    for k in range(100):
        history.append(0.01 * k, (0.0, 0.0, 0.0))
    # one sample older than the span is kept so the span's start can be interpolated
    assert 0.99 - 0.1 - 0.01 - 1e-9 <= history.oldest_time_s < 0.99 - 0.1
    assert history.pose_at(0.99 - 0.1) is not None


def test_last_step_and_index():
    history = _history()
    step_s, motion = history.last_step()
    assert abs(step_s - 0.02) < 1e-12
    assert abs(motion[2] - 0.1) < 1e-12
    assert history.index_at_or_before(0.05) == 2
    assert history.index_at_or_before(-1.0) is None


@pytest.mark.parametrize(("span_s", "extrapolation_s"), [(0.0, 0.1), (1.0, -0.1)])
def test_invalid_history_parameters(span_s, extrapolation_s):
    with pytest.raises(ValueError):
        PoseBuffer(span_s, extrapolation_s)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from([0.02, -0.5, math.nan, math.inf]),  # stamp step (s) from the previous sample
            st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=3, max_size=3),
            st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=2, max_size=2),
        ),
        max_size=20,
    )
)
def test_add_stores_exactly_what_the_odometry_rule_lets_through(samples):
    """A raw stream with NaN, inf and stamps going back anywhere: `add` refuses a sample exactly when
    `validation.odometry_problem` (the one rule) does, and the buffer then holds only finite poses."""
    checked = PoseBuffer(span_s=10.0, max_extrapolation_s=0.05)
    trusted = PoseBuffer(span_s=10.0, max_extrapolation_s=0.05)
    stamp_s = 100.0
    for step_s, pose, twist in samples:
        stamp_s += step_s
        refused = bool(odometry_problem(stamp_s, pose, twist))
        assert checked.add(stamp_s, tuple(pose), tuple(twist)) is not refused
        if not refused:  # the intake ran: the trusted feed takes it the same way
            trusted.add_valid(stamp_s, tuple(pose), tuple(twist))
        if not math.isfinite(stamp_s):
            stamp_s = 100.0
    assert [checked.sample(k)[:2] for k in range(len(checked))] == [
        trusted.sample(k)[:2] for k in range(len(trusted))
    ]
    assert all(is_finite_pose(checked.sample(k)[1]) for k in range(len(checked)))
