"""TimeJumpDetector: a stream's time going back for good (a bag loop) against one stray old message."""

import pytest

from beams_common.intake.time_jumps import StampOrder, TimeJumpDetector


def _classify_all(detector: TimeJumpDetector, stamps: list[float]) -> list[StampOrder]:
    """Classify stamps in turn, the newest being the last FORWARD one (or a JUMP's, which starts anew)."""
    newest, orders = None, []
    for stamp in stamps:
        order = detector.classify(stamp, newest)
        if order in (StampOrder.FORWARD, StampOrder.JUMP):
            newest = stamp
        orders.append(order)
    return orders


def test_a_loop_is_a_jump_at_its_second_message_and_a_stray_is_dropped():
    f, s, h, j = StampOrder.FORWARD, StampOrder.STALE, StampOrder.HELD, StampOrder.JUMP
    detector = TimeJumpDetector(tolerance_s=0.5, confirmations=2)
    # forward, reordered within the tolerance, a stray 9 s back, forward again
    assert _classify_all(detector, [10.0, 10.1, 9.8, 1.0, 10.2]) == [f, f, s, h, f]
    # a loop: back, and back again playing forward: the second message confirms it
    assert _classify_all(detector, [10.3, 0.0, 0.02, 0.04]) == [f, h, j, f]


def test_held_messages_must_play_forward_and_confirmations_are_a_setting():
    h, j = StampOrder.HELD, StampOrder.JUMP
    detector = TimeJumpDetector(confirmations=3)
    # two strays going backwards among themselves do not count together
    assert [detector.classify(t, 100.0) for t in (5.0, 4.0, 4.5, 4.6)] == [h, h, h, j]
    detector.classify(5.0, 100.0)
    detector.clear()
    assert detector.classify(6.0, 100.0) is h
    assert TimeJumpDetector(confirmations=1).classify(1.0, 2.0) is j
    assert TimeJumpDetector().classify(2.0, 2.0) is StampOrder.STALE  # equal: not after the newest
    for bad in ({"tolerance_s": -1.0}, {"tolerance_s": float("nan")}, {"confirmations": 0}):
        with pytest.raises(ValueError):
            TimeJumpDetector(**bad)
