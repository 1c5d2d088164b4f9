"""InterleaveDetector: one source (with restarts, gaps, wraps) never looks like two; two always do."""

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from beams_common.intake.stream_interleave import InterleaveDetector

REVOLUTION_MODULUS = 2**32


def revolutions() -> InterleaveDetector:
    return InterleaveDetector(max_step=50, modulus=REVOLUTION_MODULUS)


def feed(detector: InterleaveDetector, values, period_s: float = 0.05) -> float:
    now_s = 0.0
    for value in values:
        now_s += period_s
        detector.observe(value, now_s)
    return now_s


def test_the_issue_two_drivers_in_one_namespace():
    """Two drivers' revolutions, started 3 s apart, interleaved as DDS delivers them: said within 6
    messages (0.3 s at two 10 Hz sources), not before 4."""
    detector = revolutions()
    now_s = feed(detector, [30, 0, 31, 1])
    assert not detector.interleaved(now_s)
    now_s = feed(detector, [32, 2])
    assert detector.interleaved(now_s)


@given(
    start=st.integers(0, REVOLUTION_MODULUS - 1),
    steps=st.lists(st.integers(1, 3), min_size=1, max_size=200),
)
def test_one_source_with_dropped_revolutions_and_a_wrap_is_never_interleaved(start, steps):
    detector = revolutions()
    value, now_s = start, 0.0
    for step in steps:
        value = (value + step) % REVOLUTION_MODULUS
        now_s += 0.1
        detector.observe(value, now_s)
        assert detector.switches(now_s) == 0


@given(
    before=st.lists(st.integers(1, 2), min_size=1, max_size=60),
    restart_value=st.integers(0, 1000),
    after=st.lists(st.integers(1, 2), min_size=1, max_size=60),
    first=st.integers(0, 1000),
)
def test_one_source_restarted_is_never_interleaved(before, restart_value, after, first):
    """A driver respawned: its counter starts again lower; at most one switch (its new run catching up
    with the old one), never the two that say two sources."""
    detector = revolutions()
    value, now_s = first, 0.0
    for step in before:
        value += step
        now_s += 0.1
        detector.observe(value, now_s)
    value = restart_value
    for step in [0, *after]:
        value += step
        now_s += 0.1
        detector.observe(value, now_s)
        assert not detector.interleaved(now_s)


@given(
    offset_a=st.integers(0, 10_000),
    offset_b=st.integers(0, 10_000),
    pattern=st.lists(st.booleans(), min_size=20, max_size=60).filter(lambda p: 8 <= sum(p) <= len(p) - 8),
)
def test_two_counting_sources_are_said_whatever_their_offsets(offset_a, offset_b, pattern):
    """Two drivers at any counter offsets, their messages mixed in any order with at least eight from
    each and alternating at least twelve times: interleaved."""
    alternations = sum(1 for x, y in itertools.pairwise(pattern) if x != y)
    if alternations < 12:
        return
    detector = revolutions()
    counters = {True: offset_a, False: offset_b}
    now_s = 0.0
    for source in pattern:
        counters[source] += 1
        now_s += 0.05
        detector.observe(counters[source], now_s)
    assert detector.interleaved(now_s), (offset_a, offset_b, pattern)


def test_stamps_from_two_clocks_interleave_and_the_error_ends_with_the_second_source():
    """Odometry from a live robot and from a bag played over it (another clock)."""
    detector = InterleaveDetector(max_step=1.0)
    live, bag, now_s = 1000.0, 20.0, 0.0
    for _ in range(10):
        live, bag, now_s = live + 0.02, bag + 0.02, now_s + 0.02
        detector.observe(live, now_s)
        detector.observe(bag, now_s)
    assert detector.interleaved(now_s)
    for _ in range(150):  # 3 s of the live source alone: the window (2 s) forgets the switches
        live, now_s = live + 0.02, now_s + 0.02
        detector.observe(live, now_s)
    assert not detector.interleaved(now_s)


def test_a_duplicated_stamp_and_non_finite_values_do_not_say_two_sources():
    detector = InterleaveDetector(max_step=1.0)
    now_s = feed(detector, [1.0, 1.0, 1.02, 1.04, float("nan"), float("inf"), 1.06, 1.08])
    assert detector.switches(now_s) == 0


def test_invalid_settings_are_refused():
    with pytest.raises(ValueError):
        InterleaveDetector(max_step=0.0)
