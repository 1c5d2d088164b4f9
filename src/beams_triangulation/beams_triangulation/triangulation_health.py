"""triangulation_node's status (`beams_common.status.health`): whether ToTal is fixing the robot at all
(waiting, lost past MAX_SILENCE_S, degraded, tracking: docs/status.md)."""

from collections.abc import Mapping
from typing import Any

import numpy as np

from beams_common.status.health import (
    FAULT_HOLD_S,
    RecentFaults,
    Verdict,
    bearing_rate_monitor,
    judge,
    odometry_rate_monitor,
)
from beams_common.status.protection_level import Integrity, ProtectionLevel

# Ten revolutions without an accepted pose: ToTal has not fixed the robot for a second.
MAX_SILENCE_S = 1.0
WAITING_FOR_BEARINGS = "waiting for bearings (beams/bearings)"
WAITING_FOR_POSE = "waiting for a pose the gates accept from beams/bearings"


class TriangulationHealth:
    """The rates, recent refusals and accepted poses of triangulation_node."""

    def __init__(self, values: Mapping[str, Any], now_s: float, *, use_odometry: bool) -> None:
        self.faults = RecentFaults(FAULT_HOLD_S)
        self.use_odometry = use_odometry
        self._first_revolution_s: float | None = None
        self._last_accepted_s: float | None = None
        self._covariance: np.ndarray | None = None  # the last accepted pose's
        self.protection: ProtectionLevel | None = None
        self.configure(values, now_s)

    def configure(self, values: Mapping[str, Any], now_s: float) -> None:
        """New rate ranges and integrity settings (a runtime change): the rates are measured again from
        now."""
        self.integrity = Integrity(values)
        if self._covariance is not None:
            self.protection = self.integrity.level(self._covariance)
        self.bearing_rate = bearing_rate_monitor(values)
        self.odometry_rate = odometry_rate_monitor(values)
        self.bearing_rate.start(now_s)
        self.odometry_rate.start(now_s)

    def on_bearings(self, now_s: float) -> None:
        if self._first_revolution_s is None:
            self._first_revolution_s = now_s
        self.bearing_rate.tick(now_s)

    def on_odometry(self, now_s: float) -> None:
        self.odometry_rate.tick(now_s)

    def on_pose(self, now_s: float, accepted: bool, covariance: np.ndarray) -> None:
        """A pose published; an accepted one's protection level (fault-free: no redundancy) is the
        node's."""
        if accepted:
            self._last_accepted_s, self._covariance = now_s, covariance
            self.protection = self.integrity.level(covariance)

    def fault(self, kind: str, now_s: float, reason: str) -> None:
        """An input refused as implausible: the status is degraded for FAULT_HOLD_S."""
        self.faults.note(kind, now_s, reason)

    def verdict(self, now_s: float) -> Verdict:
        """The status now."""
        if self._first_revolution_s is None:
            return judge(WAITING_FOR_BEARINGS)
        since_s = now_s - (self._last_accepted_s or self._first_revolution_s)
        lost = [f"no accepted pose for {since_s:.1f} s"] if since_s > MAX_SILENCE_S else []
        if self._last_accepted_s is None and not lost:  # no pose yet: nothing to track
            return judge(WAITING_FOR_POSE)
        degraded = [self.bearing_rate.problem(now_s)]
        if self.use_odometry:
            degraded.append(self.odometry_rate.problem(now_s))
        degraded.append(self.integrity.problem(self.protection))
        degraded = [p for p in degraded if p] + self.faults.active(now_s)
        return judge("", lost, degraded)
