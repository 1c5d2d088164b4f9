"""ekf_node's status (`beams_common.status.health`): tracking only while its consistency checks pass.

- waiting: no pose has initialised the filter (or it was reset); for odometry first, without any: a
  ToTal fix is refused until odometry covers its stamp.
- lost: the bearings' innovations contradict the estimate (`NisMonitor`'s chi-square test over its
  window), most recent bearings are gated out (kidnapped), or odometry stopped for longer than
  ODOMETRY_SILENCE_S (the estimate no longer follows the robot). The next ToTal fix re-initialises.
- degraded: an input rate out of its range (bearings ~10 Hz, odometry at its rate, like
  diagnostic_updater's frequency status), inputs refused as implausible within the last FAULT_HOLD_S
  (stamps late or early against the receiving clock, odometry jumps, a calibration that made the
  bearings worse), no bearing accepted for more than MAX_BEARING_SILENCE_S of data time (odometry
  alone: the covariance grows), or a pose the bearings have not confirmed since an event that broke the
  estimate's continuity (an operator's pose, an odometry jump or silence, a time jump, a
  re-initialisation from ToTal after a kidnap or a lost test: `consistency.PoseConfirmation`), a beacon
  excluded (`consistency.BeaconExclusion`), or a protection level above its alert limit
  (`protection_level`: unavailable for navigation).
- tracking: none of the above: the estimate is the filter's own, verified by its bearings.

The receiving clock is the node's (ROS time: /clock under use_sim_time); pure, times passed in.
"""

from collections.abc import Mapping
from math import isfinite
from typing import Any

from beams_common.status.health import (
    FAULT_HOLD_S,
    RecentFaults,
    Verdict,
    bearing_rate_monitor,
    judge,
    odometry_rate_monitor,
)
from beams_common.status.protection_level import Integrity, ProtectionLevel
from beams_ekf.consistency import ODOMETRY_SILENCE_S
from beams_ekf.localiser import Localiser
from beams_ekf.outcomes import Estimate

# No bearing accepted for this long (s, data time): odometry alone carries the estimate.
MAX_BEARING_SILENCE_S = 1.0
# Innovations inconsistent (the NIS test) this long (s) after a calibration was applied suspect it: the status
# names it, and stays degraded naming it for FAULT_HOLD_S past the re-initialisation the lost status asks
# for (longer would blame a good file for the faults that follow it).
CALIBRATION_WATCH_S = 10.0
WAITING_FOR_POSE = "waiting for an initial pose (beams/pose, /initialpose or the set_pose service)"
WAITING_FOR_ODOMETRY = (
    "waiting for odometry (odom): ToTal's poses (beams/pose) are taken once odometry covers their stamps; "
    "an operator's pose (/initialpose, the set_pose service) initialises without"
)


class EkfHealth:
    """The inputs' rates and the recent refusals of ekf_node, judged with the filter's own tests."""

    def __init__(self, values: Mapping[str, Any], now_s: float) -> None:
        self.faults = RecentFaults(FAULT_HOLD_S)
        self._last_odometry_s: float | None = None
        self._calibration: tuple[float, str] | None = None  # (applied at, what)
        self.configure(values, now_s)

    def configure(self, values: Mapping[str, Any], now_s: float) -> None:
        """New rate ranges and integrity settings (a runtime change): the rates are measured again from
        now."""
        self.integrity = Integrity(values)
        self.bearing_rate = bearing_rate_monitor(values)
        self.odometry_rate = odometry_rate_monitor(values)
        self.bearing_rate.start(now_s)
        if self._last_odometry_s is not None:
            self.odometry_rate.start(now_s)

    def on_bearings(self, now_s: float) -> None:
        """A beams/bearings message received (refused or not: the rate is the publisher's)."""
        self.bearing_rate.tick(now_s)

    def on_odometry(self, now_s: float) -> None:
        """An odometry message received; the odometry checks start with the first one (the filter also
        runs without odometry, the robot then taken as still)."""
        if self._last_odometry_s is None:
            self.odometry_rate.start(now_s)
        self._last_odometry_s = now_s
        self.odometry_rate.tick(now_s)

    def fault(self, kind: str, now_s: float, reason: str, hold_s: float = FAULT_HOLD_S) -> None:
        """An input refused as implausible (or a calibration flagged): the status is degraded for
        hold_s."""
        self.faults.note(kind, now_s, reason, hold_s)

    def calibration_applied(self, now_s: float, what: str) -> None:
        """A calibration applied at now_s: the innovations that follow judge it (CALIBRATION_WATCH_S)."""
        self._calibration = (now_s, what)

    def reset(self) -> None:
        """The filter was reset: the odometry checks wait for odometry again."""
        self._last_odometry_s = None
        self.faults.clear()

    def verdict(
        self,
        now_s: float,
        *,
        nis_lost: bool,
        kidnap_suspected: bool,
        bearing_silence_s: float,
        unconfirmed: str = "",
        protection: ProtectionLevel | None = None,
        excluded: str = "",
    ) -> Verdict:
        """The status of an initialised filter now, from its tests (NIS, kidnap), the time since the last
        accepted bearing (data time), why the bearings have not yet confirmed the estimate
        (`Localiser.unconfirmed`, '' when they have), the estimate's protection level, a beacon excluded
        (`BeaconExclusion.problem`) and this monitor's rates and faults."""
        lost = []
        if nis_lost:
            lost.append("innovations too large for the covariance (NIS test): waiting for a ToTal pose")
            applied_s, what = self._calibration or (-float("inf"), "")
            if now_s - applied_s <= CALIBRATION_WATCH_S:
                reason = (
                    f"innovations inconsistent {now_s - applied_s:.1f} s after {what} was applied: check it"
                )
                self.fault("calibration_inconsistent", now_s, reason)
        if kidnap_suspected:
            lost.append("most recent bearings gated out (robot moved?): waiting for a ToTal pose")
        if self._last_odometry_s is not None and now_s - self._last_odometry_s > ODOMETRY_SILENCE_S:
            lost.append(f"no odometry for {now_s - self._last_odometry_s:.1f} s: the estimate stands still")
        degraded = [p for p in (unconfirmed, excluded, self.integrity.problem(protection)) if p]
        degraded += [p for p in (self.bearing_rate.problem(now_s), self._odometry_rate_problem(now_s)) if p]
        degraded += self.faults.active(now_s)
        if bearing_silence_s > MAX_BEARING_SILENCE_S:
            silence = f"for {bearing_silence_s:.1f} s" if isfinite(bearing_silence_s) else "yet"
            degraded.append(f"no accepted bearing {silence}: odometry only")
        return judge("", lost, degraded)

    def judge(
        self, now_s: float, localiser: Localiser, estimate: Estimate | None
    ) -> tuple[ProtectionLevel | None, float, Verdict]:
        """(protection level, bearing silence (s), verdict) of a Localiser's `estimate` (None: none yet): the
        one reading of its tests that ekf_node and the offline replay share."""
        if estimate is None:  # ToTal's fix is brought to the filter's instant by the odometry since its stamp
            return (
                None,
                float("inf"),
                judge(WAITING_FOR_ODOMETRY if localiser.history.latest is None else WAITING_FOR_POSE),
            )
        level = self.integrity.level(estimate.covariance, estimate.fault_shifts, estimate.fault_covariances)
        last_s = localiser.stats.last_bearing_stamp_s
        silence_s = estimate.stamp_s - last_s if last_s is not None else float("inf")
        verdict = self.verdict(
            now_s,
            nis_lost=localiser.nis_monitor.lost,
            kidnap_suspected=localiser.kidnap.suspected,
            bearing_silence_s=silence_s,
            unconfirmed=localiser.unconfirmed,
            protection=level,
            excluded=localiser.exclusion.problem,
        )
        return level, silence_s, verdict

    def _odometry_rate_problem(self, now_s: float) -> str:
        return self.odometry_rate.problem(now_s) if self._last_odometry_s is not None else ""
