"""KeyThrottle: each key at most once a period, the held-back count, keys independent."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from beams_common.status.log_throttle import KeyThrottle


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def test_a_key_is_admitted_once_a_period_and_says_how_many_were_held_back():
    clock = FakeClock()
    throttle = KeyThrottle(1.0, clock)
    assert throttle.admit("a") == 0
    assert throttle.admit("a") is None
    clock.now_s += 0.5
    assert throttle.admit("a") is None
    clock.now_s += 0.5
    assert throttle.admit("a") == 2
    clock.now_s += 5.0
    assert throttle.admit("a") == 0


def test_a_flood_of_one_key_never_hides_another():
    throttle = KeyThrottle(1.0, FakeClock())
    assert throttle.admit("flood") == 0
    for _ in range(100):
        assert throttle.admit("flood") is None
    assert throttle.admit("rare") == 0


def test_a_negative_period_is_refused():
    with pytest.raises(ValueError, match="throttle period"):
        KeyThrottle(-1.0)


@given(st.lists(st.tuples(st.sampled_from("abc"), st.floats(0.0, 2.0)), max_size=60))
def test_admitted_plus_held_back_accounts_for_every_event(events):
    """Invariant over any sequence: per key, admissions are >= period apart, and the counts reported at
    admissions plus those still held back equal the events minus the admissions."""
    clock = FakeClock()
    throttle = KeyThrottle(1.0, clock)
    admitted: dict[str, list[float]] = {}
    reported: dict[str, int] = {}
    total: dict[str, int] = {}
    for key, step_s in events:
        clock.now_s += step_s
        total[key] = total.get(key, 0) + 1
        held = throttle.admit(key)
        if held is not None:
            times = admitted.setdefault(key, [])
            assert not times or clock.now_s - times[-1] >= 1.0
            times.append(clock.now_s)
            reported[key] = reported.get(key, 0) + held
    for key, count in total.items():
        pending = throttle._held_back.get(key, 0)
        assert len(admitted[key]) + reported.get(key, 0) + pending == count
