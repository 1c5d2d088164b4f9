"""Is an input (or output) coming at its rate? diagnostic_updater's FrequencyStatus, pure (no ROS).

Events are counted in a sliding window; the rate is their count over the window. Its verdict, as
FrequencyStatus gives it: no event in the window is 'error' ("no events"), a rate below
min_hz * (1 - tolerance) or above max_hz * (1 + tolerance) is 'warn', otherwise 'ok'. Nothing is judged
until a whole window has passed since `start` (a node starting, a driver activated), and a clock that
goes back (a replayed bag restarted) starts the window again.
"""

from collections import deque


class RateMonitor:
    """Sliding-window event rate against an expected range (see the module docstring)."""

    def __init__(
        self,
        min_hz: float,
        max_hz: float,
        *,
        tolerance: float = 0.1,
        window_s: float = 2.0,
        what: str = "events",
    ) -> None:
        if not (0.0 < min_hz <= max_hz and 0.0 <= tolerance < 1.0 and window_s > 0.0):
            raise ValueError(
                f"rate monitor: need 0 < min_hz <= max_hz, 0 <= tolerance < 1 and window_s > 0, got "
                f"{min_hz!r}, {max_hz!r}, {tolerance!r}, {window_s!r}"
            )
        self.min_hz, self.max_hz, self.tolerance, self.window_s, self.what = (
            min_hz,
            max_hz,
            tolerance,
            window_s,
            what,
        )
        self._events: deque[float] = deque()
        self._started_s: float | None = None

    def start(self, now_s: float) -> None:
        """Begin (again) at `now_s`: the events so far are forgotten, the verdict waits a full window."""
        self._events.clear()
        self._started_s = now_s

    def tick(self, now_s: float, count: int = 1) -> None:
        """`count` events at `now_s`."""
        if self._started_s is None or (self._events and now_s < self._events[-1]) or now_s < self._started_s:
            self.start(now_s)
        self._events.extend([now_s] * count)

    def rate_hz(self, now_s: float) -> float:
        self._forget_before(now_s - self.window_s)
        return len(self._events) / self.window_s

    def check(self, now_s: float) -> tuple[str, str]:
        """('ok' | 'warn' | 'error', what the rate is against what is expected)."""
        if self._started_s is None or now_s < self._started_s:
            self.start(now_s)
        if now_s - self._started_s < self.window_s:
            return "ok", f"{self.what}: measuring the rate"
        rate_hz = self.rate_hz(now_s)
        expected = f"expected {self.min_hz:.3g}-{self.max_hz:.3g} Hz"
        if rate_hz == 0.0:
            return "error", f"no {self.what} for {self.window_s:g} s ({expected})"
        if rate_hz < self.min_hz * (1.0 - self.tolerance):
            return "warn", f"{self.what} too slow: {rate_hz:.3g} Hz ({expected})"
        if rate_hz > self.max_hz * (1.0 + self.tolerance):
            return "warn", f"{self.what} too fast: {rate_hz:.3g} Hz ({expected})"
        return "ok", f"{self.what} at {rate_hz:.3g} Hz"

    def _forget_before(self, oldest_s: float) -> None:
        while self._events and self._events[0] <= oldest_s:
            self._events.popleft()
