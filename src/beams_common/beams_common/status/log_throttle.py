"""Rate limits for log lines, by key: a flood of one message never hides another.

Pure (no ROS): the nodes' throttled logging (beams_common.ros.node_logging) stands on it.
"""

import time
from collections.abc import Callable


class KeyThrottle:
    """At most one admitted event per key every `period_s` seconds (on `clock`, monotonic by default).

    `admit(key)` returns None while the key is throttled, else how many of its events were held back
    since the previous admitted one (0 the first time), so a log line can say "(12 more since)".
    """

    def __init__(self, period_s: float = 1.0, clock: Callable[[], float] = time.monotonic) -> None:
        if not period_s >= 0.0:
            raise ValueError(f"a throttle period is >= 0 s, got {period_s!r}")
        self.period_s = period_s
        self._clock = clock
        self._last_admitted_s: dict[str, float] = {}
        self._held_back: dict[str, int] = {}

    def admit(self, key: str) -> int | None:
        now_s = self._clock()
        last_s = self._last_admitted_s.get(key)
        # a clock that went back (a test's fake clock, never the monotonic one) admits at once
        if last_s is not None and 0.0 <= now_s - last_s < self.period_s:
            self._held_back[key] = self._held_back.get(key, 0) + 1
            return None
        self._last_admitted_s[key] = now_s
        return self._held_back.pop(key, 0)
