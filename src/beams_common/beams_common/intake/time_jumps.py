"""Telling a stream's time going back for good (a bag in a loop, a restarted simulation) from one stray
message stamped in the past: a jump is taken when `confirmations` consecutive messages, increasing among
themselves, all lie before the newest stamp by more than the tolerance; the reset starts from the last one.
"""

from enum import Enum


class StampOrder(Enum):
    """Where a new stamp lies against the newest one of the stream."""

    FORWARD = "forward"  # after the newest: use it
    STALE = "stale"  # not after it, within the tolerance (reordered): drop it
    HELD = "held"  # back beyond the tolerance, not (yet) confirmed: drop it
    JUMP = "jump"  # back beyond the tolerance, confirmed: reset, then use it


class TimeJumpDetector:
    """Classifies each stamp of a stream against the stream's newest stamp (see the module docstring)."""

    def __init__(self, tolerance_s: float = 0.0, confirmations: int = 2) -> None:
        if not tolerance_s >= 0.0:
            raise ValueError(f"time jump tolerance must be >= 0 s, got {tolerance_s}")
        if confirmations < 1:
            raise ValueError(f"time jump confirmations must be >= 1, got {confirmations}")
        self.tolerance_s = float(tolerance_s)
        self.confirmations = int(confirmations)
        self._held: list[float] = []

    def classify(self, stamp_s: float, newest_s: float | None) -> StampOrder:
        """The order of stamp_s against newest_s (None: an empty stream, every stamp is forward)."""
        if newest_s is None or stamp_s > newest_s:
            self._held.clear()
            return StampOrder.FORWARD
        if stamp_s >= newest_s - self.tolerance_s:
            return StampOrder.STALE
        if self._held and stamp_s <= self._held[-1]:
            self._held.clear()  # not a stream playing forward again: start counting anew
        self._held.append(stamp_s)
        if len(self._held) < self.confirmations:
            return StampOrder.HELD
        self._held.clear()
        return StampOrder.JUMP

    def clear(self) -> None:
        """Forget the stamps held so far (the stream was reset for another reason)."""
        self._held.clear()
