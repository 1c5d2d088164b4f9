"""RateMonitor: FrequencyStatus's verdicts on event sequences (ok, too slow, too fast, none, restart)."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from beams_common.rate_monitor import RateMonitor


def run(monitor: RateMonitor, rate_hz: float, duration_s: float, start_s: float = 0.0) -> float:
    """Events at rate_hz from start_s for duration_s; returns the time of the end."""
    count = int(rate_hz * duration_s + 1e-9)
    for index in range(1, count + 1):
        monitor.tick(start_s + index / rate_hz)
    return start_s + duration_s


def bearings() -> RateMonitor:
    return RateMonitor(9.0, 11.0, tolerance=0.1, window_s=2.0, what="revolutions")


def test_a_10_hz_turret_is_ok_and_measured():
    monitor = bearings()
    monitor.start(0.0)
    end_s = run(monitor, 10.0, 5.0)
    assert monitor.rate_hz(end_s) == pytest.approx(10.0)
    assert monitor.check(end_s) == ("ok", "revolutions at 10 Hz")


def test_nothing_is_judged_before_a_whole_window():
    monitor = bearings()
    monitor.start(0.0)
    assert monitor.check(1.9)[0] == "ok" and "measuring" in monitor.check(1.9)[1]
    assert monitor.check(2.0) == ("error", "no revolutions for 2 s (expected 9-11 Hz)")


def test_slow_fast_and_stopped_sequences_in_turn():
    monitor = bearings()
    monitor.start(0.0)
    end_s = run(monitor, 10.0, 3.0)
    end_s = run(monitor, 5.0, 3.0, end_s)
    assert monitor.check(end_s) == ("warn", "revolutions too slow: 5 Hz (expected 9-11 Hz)")
    end_s = run(monitor, 20.0, 3.0, end_s)
    assert monitor.check(end_s) == ("warn", "revolutions too fast: 20 Hz (expected 9-11 Hz)")
    assert monitor.check(end_s + 2.5)[0] == "error"  # the source stopped
    end_s = run(monitor, 10.0, 3.0, end_s + 2.5)
    assert monitor.check(end_s)[0] == "ok"


def test_a_clock_gone_back_starts_again():
    monitor = bearings()
    monitor.start(100.0)
    run(monitor, 10.0, 3.0, 100.0)
    monitor.tick(5.0)  # a bag restarted
    assert "measuring" in monitor.check(5.5)[1]


def test_invalid_ranges_are_refused():
    with pytest.raises(ValueError, match="min_hz <= max_hz"):
        RateMonitor(10.0, 5.0)


@given(rate_hz=st.floats(0.5, 200.0), window_s=st.floats(0.5, 5.0))
def test_a_steady_rate_is_measured_within_one_event_per_window(rate_hz, window_s):
    monitor = RateMonitor(1.0, 100.0, window_s=window_s)
    monitor.start(0.0)
    end_s = run(monitor, rate_hz, 3.0 * window_s + 1.0)
    assert abs(monitor.rate_hz(end_s) - rate_hz) <= 1.0 / window_s + 1e-9
    level, _ = monitor.check(end_s)
    margin_hz = 1.0 / window_s + 1e-9
    if 0.9 + margin_hz < rate_hz < 110.0 - margin_hz:
        assert level == "ok"
    elif rate_hz * window_s >= 1.0 and (rate_hz < 0.9 - margin_hz or rate_hz > 110.0 + margin_hz):
        assert level == "warn"
