"""An input's or output's rate (beams_common.status.health.RateMonitor, diagnostic_updater's FrequencyStatus)
shown on a node's /diagnostics: the rate as a value, a rate out of range as a condition
(Diagnostics.set_condition) that holds the status with the reason: ERROR when nothing came in the
window, WARN otherwise."""

from beams_common.ros.node_support import Diagnostics
from beams_common.status.health import RateMonitor


class RateStatus:
    """`monitor`'s rate under the key `<name>_rate_hz`, its problem as the condition `<name> rate`."""

    def __init__(self, diagnostics: Diagnostics, name: str, monitor: RateMonitor) -> None:
        self.diagnostics = diagnostics
        self.name = name
        self.monitor = monitor

    def start(self, now_s: float) -> None:
        self.monitor.start(now_s)
        self.update(now_s)

    def tick(self, now_s: float, count: int = 1) -> None:
        for _ in range(count):
            self.monitor.tick(now_s)

    def update(self, now_s: float) -> None:
        problem = self.monitor.problem(now_s)
        rate_hz = self.monitor.rate_hz(now_s)
        self.diagnostics.set(f"{self.name}_rate_hz", rate_hz)
        if not problem:
            self.diagnostics.clear_condition(f"{self.name} rate")
        else:
            level = "error" if rate_hz == 0.0 else "warn"  # nothing at all: the source is gone
            self.diagnostics.set_condition(f"{self.name} rate", level, problem)

    def stop(self) -> None:
        """Nothing expected any more (a deactivated driver): no verdict until the next start."""
        self.diagnostics.clear_condition(f"{self.name} rate")
