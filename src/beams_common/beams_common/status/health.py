"""A localisation node's status that means something: tracking only while its checks pass.

GNSS integrity monitoring calls a wrong position under a healthy status "hazardously misleading
information"; a BeAMS node says one of four statuses (`Status`), each with its reasons:

- waiting: no estimate yet (nothing to use);
- tracking: every consistency check passes and the node's own sensor has verified the estimate (the
  EKF's bearings have confirmed its pose since the last break of its continuity: an operator's pose is
  no sensor's): the estimate may be used as its covariance says;
- degraded: an estimate exists but a check fails (an input rate out of range, inputs refused as
  implausible lately, a calibration that made the fixes worse, a pose not yet confirmed by the
  bearings): use with care, its covariance may lie;
- lost: the estimate must not be used (the innovations contradict it, no odometry moves it).

The pieces every node composes: `RateMonitor` (an input's rate over a sliding window against its
expected range, as diagnostic_updater's FrequencyStatus does), `RecentFaults` (a refusal remembered for a
hold time, so that a fault repeated every revolution keeps the status degraded between occurrences), and
`Verdict` (the status and the reasons, the worst check winning). Pure: times are the node's receiving
clock in seconds, passed in.
"""

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from beams_common.config.parameters import ParameterSpec
from beams_common.intake.validation import bounded

# The window (s) over which the input rates are measured (diagnostic_updater's default window is five
# publications of a 1 Hz status: ~5 s; two seconds is twenty revolutions) and how long (s) a refusal
# keeps the status degraded after it happened.
RATE_WINDOW_S = 2.0
FAULT_HOLD_S = 2.0


class Status(StrEnum):
    """The node's status, as /diagnostics' `status` value and message prefix say it."""

    WAITING = "waiting"
    TRACKING = "tracking"
    DEGRADED = "degraded"
    LOST = "lost"


# the diagnostic level of each status (waiting is WARN: a node without an estimate is not an error)
DIAGNOSTIC_LEVEL = {
    Status.WAITING: "warn",
    Status.TRACKING: "ok",
    Status.DEGRADED: "warn",
    Status.LOST: "error",
}


@dataclass(frozen=True)
class Verdict:
    """A status and why (empty reasons only when tracking)."""

    status: Status
    reasons: tuple[str, ...] = ()

    @property
    def message(self) -> str:
        """`tracking`, or `<status>: <reason>; <reason>` (bounded)."""
        return bounded(f"{self.status}: {'; '.join(self.reasons)}" if self.reasons else str(self.status))

    @property
    def level(self) -> str:
        return DIAGNOSTIC_LEVEL[self.status]

    def under(self, conditions: Sequence[tuple[str, str]]) -> "Verdict":
        """This verdict under the node's conditions ((level, reason), Diagnostics': a second publisher, a
        callback's exception): one at ERROR makes it lost, its reasons first; one at WARN degrades a
        tracking one. The one judgement /diagnostics and the status topic both say."""
        errors = [reason for level, reason in conditions if level == "error"]
        warnings = [reason for level, reason in conditions if level == "warn"]
        if not errors and not warnings:
            return self
        status = Status.LOST if errors else Status.DEGRADED if self.status is Status.TRACKING else self.status
        return Verdict(status, (*errors, *warnings, *self.reasons))


# A status said holds this long (s, the node's clock) after its stamp (LocalisationStatus.valid_until): a
# node says it at least once a second, so a status past it is a node that stopped (hung or dead).
STATUS_VALIDITY_S = 2.0


def status_in_force(status: Status, valid_until_s: float, now_s: float) -> Status:
    """What a consumer takes a received status for at now_s: itself until its validity ends, then lost."""
    return status if now_s <= valid_until_s else Status.LOST


def judge(waiting: str = "", lost: list[str] | None = None, degraded: list[str] | None = None) -> Verdict:
    """The verdict of a node's checks: waiting (its reason) before anything else, then lost when any
    lost reason holds, degraded when any degraded reason holds, else tracking. A lost verdict lists the
    degraded reasons too (everything the user should know)."""
    if waiting:
        return Verdict(Status.WAITING, (waiting,))
    lost, degraded = lost or [], degraded or []
    if lost:
        return Verdict(Status.LOST, (*lost, *degraded))
    if degraded:
        return Verdict(Status.DEGRADED, tuple(degraded))
    return Verdict(Status.TRACKING)


class RateMonitor:
    """An input's rate over the last `window_s` of the receiving clock against [min_hz, max_hz] (max_hz
    0: no upper bound), like diagnostic_updater's FrequencyStatus. No verdict until one window has passed
    since `start(now_s)` (the node's start or a reset), so a starting system is not judged on its first
    message."""

    def __init__(self, what: str, window_s: float, min_hz: float, max_hz: float = 0.0) -> None:
        if not (window_s > 0.0 and min_hz >= 0.0 and max_hz >= 0.0):
            raise ValueError(f"rate monitor {what}: need window_s > 0, rates >= 0")
        if max_hz and max_hz < min_hz:
            raise ValueError(f"rate monitor {what}: max_hz {max_hz} below min_hz {min_hz}")
        self.what, self.window_s, self.min_hz, self.max_hz = what, window_s, min_hz, max_hz
        self._times: deque[float] = deque()
        self._start_s: float | None = None

    def start(self, now_s: float) -> None:
        """Forget the events and judge again only after one window from now."""
        self._times.clear()
        self._start_s = now_s

    def tick(self, now_s: float) -> None:
        """One message received at now_s."""
        if self._start_s is None:
            self._start_s = now_s
        if self._times and now_s < self._times[-1]:  # the clock went back (a bag loop, /clock reset)
            self.start(now_s)
        self._times.append(now_s)
        self._drop_old(now_s)

    def rate_hz(self, now_s: float) -> float:
        """Messages per second over the last window."""
        self._drop_old(now_s)
        return len(self._times) / self.window_s

    def problem(self, now_s: float) -> str:
        """Why the rate is out of range, or '' (also before a window has passed since the start)."""
        if self._start_s is None or now_s - self._start_s < self.window_s or not math.isfinite(now_s):
            return ""
        rate = self.rate_hz(now_s)
        if rate < self.min_hz:
            return f"{self.what} at {rate:.1f} Hz over {self.window_s:g} s, below {self.min_hz:g} Hz"
        if self.max_hz and rate > self.max_hz:
            return (
                f"{self.what} at {rate:.1f} Hz over {self.window_s:g} s, above {self.max_hz:g} Hz "
                "(a second publisher?)"
            )
        return ""

    def _drop_old(self, now_s: float) -> None:
        while self._times and self._times[0] <= now_s - self.window_s:
            self._times.popleft()


class RecentFaults:
    """Refusals remembered for `hold_s` of the receiving clock (or their own hold), by kind: a fault
    repeated every revolution keeps its reason active between occurrences, and a fault that stopped
    clears after its hold."""

    def __init__(self, hold_s: float) -> None:
        if not hold_s > 0.0:
            raise ValueError(f"hold_s must be > 0, got {hold_s}")
        self.hold_s = hold_s
        self._faults: dict[str, tuple[float, float, str]] = {}  # kind: (noted at, hold, reason)

    def note(self, kind: str, now_s: float, reason: str, hold_s: float | None = None) -> None:
        """A fault of `kind` happened at now_s (its newest reason is kept), active for hold_s (default:
        the monitor's)."""
        self._faults[kind] = (now_s, self.hold_s if hold_s is None else hold_s, reason)

    def clear(self, kind: str | None = None) -> None:
        """Forget one kind of fault, or all of them."""
        if kind is None:
            self._faults.clear()
        else:
            self._faults.pop(kind, None)

    def active(self, now_s: float) -> list[str]:
        """The reasons of the faults still within their hold (a clock gone back keeps them)."""
        return [reason for at_s, hold_s, reason in self._faults.values() if now_s - at_s < hold_s]


# The expected input rates of the localisation nodes (changeable at runtime): a BeAMS turret turns at
# ~10 Hz (thesis ch. 2), one bearings message per revolution; half and one and a half times that.
BEARING_RATE_SPECS = (
    ParameterSpec(
        "min_bearing_rate_hz",
        5.0,
        "Fewest beams/bearings messages (revolutions) per second, over 2 s, for the status to be tracking "
        "(the turret turns at ~10 Hz); 0 switches the check off.",
        minimum=0.0,
        maximum=1000.0,
        runtime=True,
    ),
    ParameterSpec(
        "max_bearing_rate_hz",
        15.0,
        "Most beams/bearings messages per second, over 2 s, for the status to be tracking (two drivers in "
        "one namespace double the rate); 0 switches the check off.",
        minimum=0.0,
        maximum=1000.0,
        runtime=True,
    ),
)
ODOMETRY_RATE_SPEC = ParameterSpec(
    "min_odometry_rate_hz",
    10.0,
    "Fewest odometry messages per second, over 2 s, for the status to be tracking, once odometry came "
    "(wheel odometry runs at 20-100 Hz); 0 switches the check off.",
    minimum=0.0,
    maximum=10000.0,
    runtime=True,
)


def bearing_rate_monitor(values: Mapping[str, Any]) -> RateMonitor:
    """The RateMonitor of beams/bearings from validated parameter values (BEARING_RATE_SPECS)."""
    minimum, maximum = float(values["min_bearing_rate_hz"]), float(values["max_bearing_rate_hz"])
    return RateMonitor("bearings", RATE_WINDOW_S, minimum, max(maximum, minimum) if maximum else 0.0)


def odometry_rate_monitor(values: Mapping[str, Any]) -> RateMonitor:
    """The RateMonitor of the odometry from validated parameter values (ODOMETRY_RATE_SPEC)."""
    return RateMonitor("odometry", RATE_WINDOW_S, float(values["min_odometry_rate_hz"]))


def rates_check(values: Mapping[str, Any]) -> str | None:
    """A ParameterTable `together` check: max_bearing_rate_hz (when not 0) at least min_bearing_rate_hz."""
    minimum, maximum = values.get("min_bearing_rate_hz", 0.0), values.get("max_bearing_rate_hz", 0.0)
    if maximum and maximum < minimum:
        return f"max_bearing_rate_hz {maximum} is below min_bearing_rate_hz {minimum}"
    return None
