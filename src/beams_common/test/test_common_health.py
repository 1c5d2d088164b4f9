"""The status model: rates against their range, faults held, the worst check wins, conditions, expiry."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from beams_common.status.health import (
    STATUS_VALIDITY_S,
    RateMonitor,
    RecentFaults,
    Status,
    judge,
    status_in_force,
)


def test_the_verdict_is_waiting_then_lost_then_degraded_then_tracking():
    assert judge("no pose yet", ["nis"], ["rate"]).status is Status.WAITING
    lost = judge("", ["innovations too large"], ["bearings at 3 Hz"])
    assert lost.status is Status.LOST and lost.level == "error"
    assert lost.message == "lost: innovations too large; bearings at 3 Hz"
    degraded = judge("", [], ["bearings at 3 Hz"])
    assert degraded.status is Status.DEGRADED and degraded.level == "warn"
    assert judge().status is Status.TRACKING and judge().message == "tracking" and judge().level == "ok"


SECOND_STATUS = ("error", "2 publishers on /beams/ekf/status (this node's output): /ekf_node (x2)")


def test_an_error_condition_makes_any_verdict_lost_with_its_reason_first_and_its_end_restores_it():
    """The one judgement /diagnostics and the status topic say: the node's verdict under its conditions."""
    for verdict in (judge(), judge("waiting for odometry"), judge("", [], ["bearings at 3 Hz"])):
        assert verdict.under([]) is verdict  # no condition: the node's own verdict
        under = verdict.under([SECOND_STATUS])
        assert (under.status, under.level) == (Status.LOST, "error")
        assert under.reasons == (SECOND_STATUS[1], *verdict.reasons)
        assert under.message.startswith("lost: 2 publishers on /beams/ekf/status")
    # an ERROR among WARNs: lost, the ERROR's reason first whatever the order given
    mixed = judge("", [], ["rate"]).under([("warn", "odometry slow"), SECOND_STATUS])
    assert mixed.reasons == (SECOND_STATUS[1], "odometry slow", "rate")
    # a WARN condition degrades a tracking verdict and only adds its reason to a worse one
    assert judge().under([("warn", "odometry slow")]) == judge("", [], ["odometry slow"])
    lost = judge("", ["nis"]).under([("warn", "slow")])
    assert (lost.status, lost.reasons) == (Status.LOST, ("slow", "nis"))


def test_a_status_holds_until_its_validity_ends_then_it_is_lost():
    """A hung node's latched status: what a consumer takes it for once valid_until has passed."""
    assert STATUS_VALIDITY_S == 2.0
    said_s = 100.0
    for status in Status:
        assert status_in_force(status, said_s + STATUS_VALIDITY_S, said_s + 1.99) is status
        assert status_in_force(status, said_s + STATUS_VALIDITY_S, said_s + STATUS_VALIDITY_S) is status
        assert status_in_force(status, said_s + STATUS_VALIDITY_S, said_s + 2.01) is Status.LOST


def test_a_10_hz_input_passes_and_a_slow_or_doubled_one_fails_after_one_window():
    monitor = RateMonitor("bearings", window_s=2.0, min_hz=5.0, max_hz=15.0)
    monitor.start(0.0)
    times = [0.1 * k for k in range(1, 41)]  # 10 Hz for 4 s
    for t in times[:5]:
        monitor.tick(t)
    assert monitor.problem(0.5) == ""  # no verdict before a window has passed
    for t in times[5:]:
        monitor.tick(t)
    assert monitor.problem(4.0) == ""
    assert "below 5 Hz" in monitor.problem(6.5)  # silent since 4 s
    for k in range(40):  # two publishers: 20 Hz
        monitor.tick(7.0 + 0.05 * k)
    assert "above 15 Hz" in monitor.problem(9.0)


@given(st.floats(0.5, 50.0), st.floats(1.0, 5.0))
def test_the_rate_of_a_regular_input_is_measured_within_one_message(rate_hz, window_s):
    monitor = RateMonitor("x", window_s, 0.0)
    monitor.start(0.0)
    period = 1.0 / rate_hz
    count = int(3 * window_s * rate_hz) + 2
    for k in range(count):
        monitor.tick(k * period)
    now = (count - 1) * period
    assert monitor.rate_hz(now) == pytest.approx(rate_hz, abs=1.0 / window_s + 1e-9)


def test_a_clock_going_back_restarts_the_monitor():
    monitor = RateMonitor("odometry", 1.0, 10.0)
    for k in range(30):
        monitor.tick(100.0 + 0.02 * k)
    monitor.tick(0.0)  # a bag loop
    assert monitor.problem(0.5) == ""


def test_a_fault_is_held_then_forgotten_and_repeats_keep_it():
    faults = RecentFaults(hold_s=2.0)
    faults.note("late", 10.0, "bearings 1 s late")
    assert faults.active(11.9) == ["bearings 1 s late"]
    faults.note("late", 11.9, "bearings 1.1 s late")
    assert faults.active(13.5) == ["bearings 1.1 s late"]
    assert faults.active(14.0) == []
    faults.note("jump", 20.0, "odometry jumped")
    faults.clear("jump")
    assert faults.active(20.0) == []
    faults.note("calibration", 30.0, "calibration made the bearings worse", hold_s=10.0)
    assert faults.active(39.0) == ["calibration made the bearings worse"] and faults.active(40.0) == []
    with pytest.raises(ValueError):
        RecentFaults(0.0)
    with pytest.raises(ValueError):
        RateMonitor("x", 1.0, 10.0, 5.0)
