"""A RateMonitor shown on a node's /diagnostics: the rate as a value, a verdict other than ok as a
condition (Diagnostics.set_condition) that holds the status at its level with the reason."""

from beams_common.rate_monitor import RateMonitor
from beams_common.ros.node_support import Diagnostics


class RateStatus:
    """`monitor`'s rate under the key `<name>_rate_hz`, its verdict as the condition `<name> rate`."""

    def __init__(self, diagnostics: Diagnostics, name: str, monitor: RateMonitor) -> None:
        self.diagnostics = diagnostics
        self.name = name
        self.monitor = monitor

    def start(self, now_s: float) -> None:
        self.monitor.start(now_s)
        self.update(now_s)

    def tick(self, now_s: float, count: int = 1) -> None:
        self.monitor.tick(now_s, count)

    def update(self, now_s: float) -> None:
        level, message = self.monitor.check(now_s)
        self.diagnostics.set(f"{self.name}_rate_hz", self.monitor.rate_hz(now_s))
        if level == "ok":
            self.diagnostics.clear_condition(f"{self.name} rate")
        else:
            self.diagnostics.set_condition(f"{self.name} rate", level, message)

    def stop(self) -> None:
        """Nothing expected any more (a deactivated driver): no verdict until the next start."""
        self.diagnostics.clear_condition(f"{self.name} rate")
