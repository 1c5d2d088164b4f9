"""Bearings applied at their own stamps (thesis fig. 8.1's update at the measurement instant): the
odometry history with the filter's state at each sample, and the replay of a late bearing from there.

A bearing is stamped when the turret pointed at its beacon, so usually before the newest odometry. The
filter goes back to its state at the odometry sample before the stamp, applies the bearings of each
odometry interval in stamp order (those already applied there again, so any arrival order gives the same
estimate), the turret where the interpolated odometry puts it at the stamp, and predicts again through the
later samples. Applying a bearing at the newest instant instead would let it shrink the covariance of the
odometry noise accrued after it was measured: the filter would become overconfident. A bearing stamped
after the newest odometry waits for the odometry that covers it.
"""

from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from beams_common.geometry.bearing import Bearing
from beams_common.geometry.pose2d import Pose2D, between
from beams_common.geometry.pose_buffer import PoseBuffer
from beams_ekf.bearing_ekf import turret_pose
from beams_ekf.pose_filter import BearingOutcome, BearingReason, PoseFilter, rejected
from beams_ekf.settings import LocaliserConfig

# bearings waiting for odometry beyond this many are dropped, oldest first (a dead odometry source)
MAX_PENDING_BEARINGS = 64


@dataclass
class _Slot:
    """What is kept with an odometry sample: the filter state there (before the bearings of the interval
    that starts at the sample) and those bearings, to filter again from there with the step to it."""

    state: tuple[np.ndarray, np.ndarray]
    step: tuple[float, Pose2D] | None = None
    bearings: list[Bearing] = field(default_factory=list)


class LateBearings:
    """The odometry history of a PoseFilter and its bearings applied at their stamps (module docstring).

    Every outcome is counted in `counts` (`bearings_<reason>`); `judged(bearing, outcome)` hears each new
    bearing the filter judged, in the order the filter took them (the consistency monitors' input)."""

    def __init__(
        self,
        ekf: PoseFilter,
        config: LocaliserConfig,
        counts: Counter,
        judged: Callable[[Bearing, BearingOutcome], None],
    ) -> None:
        self.ekf = ekf
        self.config = config
        self.history = PoseBuffer(config.odometry_history_s, config.max_odometry_extrapolation_s)
        self._counts = counts
        self._judged = judged
        # bearings stamped after the newest odometry, waiting for the odometry that covers them
        self._pending: list[Bearing] = []
        # the Localiser's BeaconExclusion: a beacon it suspects is chosen and excluded once a replay is done
        self.exclusion: Any = None
        # capped NIS of the bearings `refilter` filters again (its score); None outside it, so that the
        # replays of late bearings keep nothing
        self._replayed_nis: list[float] | None = None

    def clear(self) -> None:
        """Forget the odometry and the waiting bearings."""
        self.history.clear()
        self._pending.clear()

    def append(self, stamp_s: float, odom_pose: Pose2D, step: tuple[float, Pose2D] | None = None) -> None:
        """A new newest odometry sample, with the filter's state when it has one and the step to it."""
        slot = _Slot(self.ekf.state(), step) if self.ekf.initialised else None
        self.history.append(stamp_s, odom_pose, slot)

    def restart_states(self) -> None:
        """The filter was (re-)initialised: the states kept for late bearings belong to the old estimate;
        the newest sample carries the new one."""
        for index in range(len(self.history)):
            self.history.set_payload(index, None)
        if self.history.latest is not None:
            self.history.set_payload(-1, _Slot(self.ekf.state()))

    def predict(self, step_s: float, increment: Pose2D) -> None:
        """Predict over one odometry step (duration, robot-frame increment); a long silence of odometry (the
        robot may have slipped) also grows the covariance with its duration."""
        self.ekf.predict(increment)
        if step_s > self.config.odometry_gap_s:
            duration_s = min(step_s, self.config.max_gap_inflation_s)
            self.ekf.add_time_noise(
                self.config.gap_position_variance_m2_per_s * duration_s,
                self.config.gap_heading_variance_rad2_per_s * duration_s,
            )

    def apply_pending(self, newest_s: float) -> None:
        """Apply the waiting bearings the odometry now covers."""
        ready = [b for b in self._pending if b.stamp_s <= newest_s]
        if ready:
            self._pending = [b for b in self._pending if b.stamp_s > newest_s]
            self.apply(ready)

    def apply(self, bearings: Sequence[Bearing]) -> list[BearingOutcome]:
        """Apply bearings the intake kept (typically one revolution's), each at its own stamp; outcomes in
        the given order."""
        if not self.ekf.initialised:
            return [self._count(rejected(BearingReason.UNINITIALISED)) for _ in bearings]
        if len(self.history) == 0:  # no odometry: the robot is taken as still
            judged = [self._count(self._apply(bearing, (0.0, 0.0, 0.0))) for bearing in bearings]
        else:
            judged = self._apply_at_stamps(bearings)
        if self.exclusion is not None and self.exclusion.suspect is not None:
            self._exclude_best()
        return judged

    def _apply_at_stamps(self, bearings: Sequence[Bearing]) -> list[BearingOutcome]:
        outcomes: dict[int, BearingOutcome] = {}
        scheduled: dict[int, list[tuple[Bearing, int]]] = {}  # history index -> (bearing, input index)
        first_state = self._first_state_index()
        for n, bearing in enumerate(bearings):
            index = self._replay_index(bearing.stamp_s, first_state)
            if index is None and self._ahead_of_odometry(bearing.stamp_s):
                outcomes[n] = self._defer(bearing)
            elif index is None:
                outcomes[n] = self._count(rejected(BearingReason.OUTSIDE_HISTORY))
            else:
                scheduled.setdefault(index, []).append((bearing, n))
        if scheduled:
            self._replay(scheduled, outcomes)
        return [outcomes[n] for n in range(len(bearings))]

    def _exclude_best(self) -> None:
        """Exclude the beacon whose exclusion leaves the others' bearings over the history most consistent
        (the lowest mean capped NIS), the suspect on a tie: a beacon whose error grew from inside the gate
        has pulled the estimate until another's bearings were gated, and that one is then the suspect."""
        scores = {}
        for beacon in self.ekf.beacons_xy:
            self.ekf.excluded_beacons = {beacon}
            scores[beacon] = self.refilter()
        suspect = self.exclusion.suspect
        best = min(scores, key=lambda b: (scores[b], b != suspect))
        self.exclusion.exclude(best)
        self.refilter()
        self._counts["beacons_excluded"] += 1

    def refilter(self) -> float:
        """Filter the whole history again from its oldest state: the bearings of a beacon excluded since
        (`PoseFilter.excluded_beacons`) are then judged without being applied, their pull on the estimate
        over the history undone (the solution without that beacon, as far back as the history goes).
        Returns the mean NIS, capped at the gate, of the other bearings filtered again (inf: none)."""
        self._replayed_nis = nis = []
        first = self._first_state_index() - len(self.history)
        if self.ekf.initialised and first < 0:
            self._replay({first: []}, {})
        self._replayed_nis = None
        return sum(nis) / len(nis) if nis else float("inf")

    def _ahead_of_odometry(self, stamp_s: float) -> bool:
        """True for a stamp after the newest odometry (past extrapolation) but within the history span."""
        newest_s = self.history.latest[0]
        return newest_s < stamp_s <= newest_s + self.config.odometry_history_s

    def _defer(self, bearing: Bearing) -> BearingOutcome:
        """Keep a bearing until odometry reaches its stamp (the oldest goes when too many wait)."""
        self._pending.append(bearing)
        if len(self._pending) > MAX_PENDING_BEARINGS:
            self._pending.pop(0)
            self._counts["bearings_dropped_pending"] += 1
        return self._count(rejected(BearingReason.DEFERRED))

    def _replay_index(self, stamp_s: float, first_valid: int) -> int | None:
        """History index (negative, from the newest) to apply a bearing at stamp_s, or None."""
        if self.history.pose_at(stamp_s) is None:
            return None
        index = self.history.index_at_or_before(stamp_s)
        # before the initialisation there is no state: use the first one (the turret lever spans the gap)
        index = first_valid if index is None or index < first_valid else index
        return index - len(self.history)

    def _first_state_index(self) -> int:
        """Index of the oldest history sample carrying a filter state."""
        for index in range(len(self.history) - 1, -1, -1):
            if self.history.sample(index)[2] is None:
                return index + 1
        return 0

    def _replay(
        self, scheduled: dict[int, list[tuple[Bearing, int]]], outcomes: dict[int, BearingOutcome]
    ) -> None:
        """Go back to the earliest scheduled sample and filter forward through the history."""
        first = min(scheduled)
        for index in range(first, 0):
            _, pose0, slot = self.history.sample(index)
            if index == first:
                self.ekf.restore(slot.state)
            else:
                self.predict(*slot.step)
                slot.state = self.ekf.state()
            new = scheduled.get(index, [])
            if not (new or slot.bearings):
                continue
            # the bearings already applied in this interval are applied again, without being counted
            merged = [(b, None) for b in slot.bearings] + new
            merged.sort(key=lambda item: item[0].stamp_s)
            kept: list[Bearing] = []
            for bearing, n in merged:
                then = self.history.pose_at(bearing.stamp_s)
                if then is None:
                    # stamped before the oldest odometry kept (a bearing applied at the first state, the
                    # history since trimmed past it): it can no longer be placed, so it leaves the slot
                    if n is not None:
                        outcomes[n] = self._count(rejected(BearingReason.OUTSIDE_HISTORY))
                    continue
                outcome = self._apply(bearing, between(pose0, then))
                scoring = self._replayed_nis is not None and n is None
                if scoring and outcome.reason in (BearingReason.ACCEPTED, BearingReason.GATED):
                    self._replayed_nis.append(min(outcome.nis, self.ekf.gate))
                kept.append(bearing)
                if n is not None:
                    outcomes[n] = self._count(outcome)
                    self._judged(bearing, outcome)
            slot.bearings = kept

    def _apply(self, bearing: Bearing, robot_then: Pose2D) -> BearingOutcome:
        """Update with a bearing taken with the robot at `robot_then` in the current state's robot frame."""
        lever = turret_pose(robot_then, self.ekf.sensor_offset_m)
        window = 0.0 if bearing.calibrated else bearing.angular_window_rad  # an uncorrected power bias
        return self.ekf.update_bearing(
            bearing.beacon_id, bearing.bearing_rad, bearing.variance_rad2, lever, window
        )

    def _count(self, outcome: BearingOutcome) -> BearingOutcome:
        self._counts[f"bearings_{outcome.reason}"] += 1
        return outcome
