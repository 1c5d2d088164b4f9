"""The complete positioning scheme of thesis fig. 8.1 without ROS: odometry + BeAMS bearings in the EKF,
ToTal (or an operator) to initialise it.

`Localiser` owns the timing: the EKF state is kept at the newest odometry instant, with the states at
the odometry samples of the last `odometry_history_s`; a bearing (stamped when the turret pointed at its
beacon, so usually before the newest odometry) is applied at its own stamp by going back to the state
of the odometry sample before it, the turret placed where the interpolated odometry puts it, and
predicting again through the later samples (see `Localiser.on_bearings`); a pose (ToTal's accepted fix or an
operator's /initialpose) initialises the filter, brought to the filter's instant by the odometry motion
since its stamp (a ToTal fix is stamped at its revolution, ~0.1-0.2 s before it arrives, so a fix the
odometry history does not cover is refused: taken as current, it put the live filter 0.2 m and 7 deg
off, confidently), and re-initialises it when the robot was kidnapped (most of the recent bearings gated
out while ToTal is confident of a pose inconsistent with the estimate: identified beacons make this
possible, thesis ch. 8 "System deployment") or the filter is lost (`NisMonitor`: the bearings'
innovations, over a sliding window, too large for the covariance: the next ToTal fix restarts it).
Time going backwards (a rosbag played in a loop: consecutive odometry messages in the past, not one
stray; `beams_common.time_jumps`) resets everything, what the filter learnt of the sensor included
(the data start again); odometry gaps inflate the covariance instead of freezing the filter; an odometry
increment beyond the robot's speed or yaw rate (a +100 m jump, `beams_common.plausibility`)
is never predicted with: the sample becomes the new reference and the covariance grows by the most the
robot could have moved (`Localiser._rereference`).
After any event that breaks the estimate's continuity (an operator's pose, an odometry jump, an odometry
silence of CONTINUITY_GAP_S, a time jump, a re-initialisation from ToTal after a kidnap or a lost test)
the estimate is unconfirmed until its bearings confirm it (`consistency.PoseConfirmation`,
`Localiser.unconfirmed`: ekf_node's status is degraded meanwhile); the first initialisation from ToTal
is the bearings' own pose and needs none.

This module is the timing and the replay of late bearings; the consistency monitors are in
`consistency` (NisMonitor, KidnapEvidence), the settings in `settings` (built from the parameters by
`parameters.filter_settings`), the answers in `outcomes`. ekf_node and the offline replay (`bag_replay`)
share what lies between their inputs and the filter: the bearing intake (`beams_common.bearing_intake`,
`Localiser.on_intake`), the pose intake (`beams_common.pose_intake`, `Localiser.offer_pose`: an operator's
stamp by `operator_pose_stamp_s`, a covariance without information by the default) and `build_localiser`.
"""

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from beams_common.bearing import Bearing
from beams_common.bearing_intake import RevolutionIntake, bearing_refusal, revolution_intake
from beams_common.plausibility import MotionLimits, odometry_step_problem
from beams_common.pose2d import Pose2D, between, compose, inverse
from beams_common.pose_buffer import PoseBuffer
from beams_common.pose_intake import KeptPose, PoseIntake, RefusedPose, planar_pose_problem
from beams_common.time_jumps import StampOrder, TimeJumpDetector
from beams_common.validation import odometry_problem
from beams_ekf.bearing_ekf import BearingEkf, turret_pose
from beams_ekf.consistency import CONTINUITY_GAP_S, KidnapEvidence, NisMonitor, PoseConfirmation
from beams_ekf.outcomes import Estimate, OdometryOutcome, PoseOutcome
from beams_ekf.pose_filter import BearingOutcome, BearingReason, PoseFilter, rejected
from beams_ekf.settings import FilterSettings, LocaliserConfig

# bearings waiting for odometry beyond this many are dropped, oldest first (a dead odometry source)
MAX_PENDING_BEARINGS = 64
# ToTal's re-initialisations that break the estimate's continuity (the first initialisation does not:
# `consistency.PoseConfirmation`)
_CONTINUITY_EVENTS = {
    PoseOutcome.KIDNAP_REINITIALISED: "a re-initialisation from ToTal after a kidnap",
    PoseOutcome.LOST_REINITIALISED: "a re-initialisation from ToTal after the lost test",
}


def operator_pose_stamp_s(stamp_s: float, newest_odometry_s: float | None) -> float:
    """The instant an operator's pose is taken at: "now" (the newest odometry) when it is stamped zero or
    after the odometry, since an operator's stamp has no meaning in the odometry's past."""
    if newest_odometry_s is not None and (stamp_s == 0.0 or stamp_s > newest_odometry_s):
        return newest_odometry_s
    return stamp_s


@dataclass
class _Slot:
    """What the localiser keeps with an odometry sample: the filter state there (before the bearings of
    the interval that starts at the sample) and those bearings, to filter again from there."""

    state: tuple[np.ndarray, np.ndarray]
    bearings: list[Bearing] = field(default_factory=list)


@dataclass
class LocaliserCounters:
    """Counts for diagnostics (names are the diagnostic keys)."""

    counts: Counter = field(default_factory=Counter)
    last_bearing_stamp_s: float | None = None


class Localiser:
    """Odometry history + a PoseFilter (BearingEkf by default) + initialisation, kidnap and time-jump
    logic."""

    def __init__(
        self,
        ekf: PoseFilter,
        config: LocaliserConfig | None = None,
        motion_limits: MotionLimits | None = None,
    ) -> None:
        self.ekf = ekf
        self.config = config or LocaliserConfig()
        self.motion_limits = motion_limits or MotionLimits()
        # why the last odometry jump was refused ('' before any)
        self.last_odometry_jump = ""
        self.history = PoseBuffer(self.config.odometry_history_s, self.config.max_odometry_extrapolation_s)
        self.stats = LocaliserCounters()
        config = self.config
        self.kidnap = KidnapEvidence(
            config.kidnap_window_bearings,
            config.kidnap_gated_bearings,
            config.kidnap_probability,
            config.kidnap_distance_m,
            config.kidnap_heading_rad,
        )
        self._time_jumps = TimeJumpDetector(
            self.config.time_jump_tolerance_s, self.config.time_jump_confirmations
        )
        self.nis_monitor = NisMonitor(
            self.config.lost_nis_window_bearings, self.config.lost_nis_probability, ekf.gate
        )
        self.confirmation = PoseConfirmation(self.config.confirming_bearings)
        self._stamp_s: float | None = None
        # bearings stamped after the newest odometry, waiting for the odometry that covers them
        self._pending: list[Bearing] = []

    @property
    def initialised(self) -> bool:
        """True once a pose initialised the filter (and no reset since)."""
        return self.ekf.initialised

    @property
    def unconfirmed(self) -> str:
        """Why the estimate is not yet confirmed by the bearings (`PoseConfirmation.problem`), or ''."""
        return self.confirmation.problem

    def _break_continuity(self, event: str) -> None:
        """An event after which the estimate is unconfirmed until the bearings confirm it."""
        self.confirmation.broken(event)
        self.stats.counts["continuity_breaks"] += 1

    def configure(
        self,
        beacons_xy: Mapping[int, Sequence[float]],
        sensor_offset_m: tuple[float, float],
        settings: FilterSettings,
    ) -> None:
        """New beacon geometry, process noise and bearing gate (a runtime parameter change, a calibration
        reload) and motion limits; the estimate and the odometry history stay."""
        self.motion_limits = settings.motion_limits
        self.ekf.configure(beacons_xy, sensor_offset_m, settings.process_noise, settings.gate_probability)

    def reset(self, reason: str = "reset", forget_learnt: bool = False) -> None:
        """Forget the estimate and the odometry; the filter waits for a pose. What a BearingEkf learnt of
        the sensor and the odometry is kept (`BearingEkf.initialise`) unless `forget_learnt` (the data
        start again: a time jump)."""
        if forget_learnt and isinstance(self.ekf, BearingEkf):
            self.ekf.reset(forget_learnt=True)
        else:
            self.ekf.reset()
        self.history.clear()
        self.kidnap.clear()
        self.nis_monitor.clear()
        self._stamp_s = None
        self._pending.clear()
        self._time_jumps.clear()
        self.confirmation.clear()  # the next initialisation from ToTal is a first one
        self.stats.counts[reason] += 1

    # -- odometry -------------------------------------------------------------------------------------
    def on_odometry(self, stamp_s: float, odom_pose: Pose2D) -> OdometryOutcome:
        """Predict with the motion since the previous odometry pose. Returns what happened."""
        if odometry_problem(stamp_s, odom_pose):  # ekf_node reports the outcome
            self.stats.counts["odometry_invalid"] += 1
            return OdometryOutcome.INVALID
        latest = self.history.latest
        order = self._time_jumps.classify(stamp_s, None if latest is None else latest[0])
        if order in (StampOrder.STALE, StampOrder.HELD):
            # held: stamped far in the past, a stray message unless the next ones confirm a jump
            self.stats.counts["odometry_stale" if order is StampOrder.STALE else "odometry_back_in_time"] += 1
            return OdometryOutcome.STALE if order is StampOrder.STALE else OdometryOutcome.HELD
        if order is StampOrder.JUMP:
            self.reset("time_jump_resets", forget_learnt=True)
            # the fix that initialises the filter again may come from either side of the jump
            self._break_continuity("a time jump (odometry stamps went back)")
            latest = None
        self.stats.counts["odometry"] += 1
        jump = (
            ""
            if latest is None
            else odometry_step_problem(stamp_s - latest[0], between(latest[1], odom_pose), self.motion_limits)
        )
        if jump:
            self._rereference(stamp_s, odom_pose, stamp_s - latest[0], jump)
            return OdometryOutcome.JUMPED
        if latest is None or not self.ekf.initialised:
            self.history.append(stamp_s, odom_pose, _Slot(self.ekf.state()) if self.ekf.initialised else None)
            self._stamp_s = stamp_s if self.ekf.initialised else None
            return OdometryOutcome.REFERENCE
        if stamp_s - latest[0] > self.config.odometry_gap_s:
            self.stats.counts["odometry_gaps"] += 1
        if stamp_s - latest[0] > CONTINUITY_GAP_S:
            # the estimate stood still: an odometry source restarted within its speed limit (a
            # simulator's new match) or a robot pushed meanwhile is not followed
            self._break_continuity(f"an odometry silence of {stamp_s - latest[0]:.1f} s")
        self._advance(latest[0], latest[1], stamp_s, odom_pose)
        self.history.append(stamp_s, odom_pose, _Slot(self.ekf.state()))
        self._stamp_s = stamp_s
        self._apply_pending(stamp_s)
        return OdometryOutcome.PREDICTED

    def _rereference(self, stamp_s: float, odom_pose: Pose2D, interval_s: float, reason: str) -> None:
        """An odometry increment the robot cannot make (`plausibility.odometry_step_problem`): a reset or a
        fault of the odometry source. The history (poses of the odometry's old frame, which would carry
        a late bearing or a ToTal fix across the jump) is dropped, the sample becomes the reference, and
        the covariance grows by the largest motion the robot could have made over the interval (its
        motion there is unknown). The estimate never follows the jump."""
        self.stats.counts["odometry_jumps"] += 1
        self.last_odometry_jump = reason
        self.history.clear()
        if not self.ekf.initialised:
            self.history.append(stamp_s, odom_pose, None)
            return
        max_translation_m, max_rotation_rad = self.motion_limits.max_step(interval_s)
        self.ekf.add_time_noise(max_translation_m**2, max_rotation_rad**2)
        self._break_continuity("an odometry jump")
        self.history.append(stamp_s, odom_pose, _Slot(self.ekf.state()))
        self._stamp_s = stamp_s
        self._apply_pending(stamp_s)

    def _apply_pending(self, newest_s: float) -> None:
        """Apply the waiting bearings the odometry now covers."""
        ready = [b for b in self._pending if b.stamp_s <= newest_s]
        if ready:
            self._pending = [b for b in self._pending if b.stamp_s > newest_s]
            self._apply_bearings(ready)  # taken in by on_intake or on_bearings already

    def _advance(self, from_s: float, from_pose: Pose2D, to_s: float, to_pose: Pose2D) -> None:
        """Predict over one odometry step; a long silence of odometry (the robot may have slipped)
        also grows the covariance with its duration."""
        self.ekf.predict(between(from_pose, to_pose))
        step_s = to_s - from_s
        if step_s > self.config.odometry_gap_s:
            duration_s = min(step_s, self.config.max_gap_inflation_s)
            self.ekf.add_time_noise(
                self.config.gap_position_variance_m2_per_s * duration_s,
                self.config.gap_heading_variance_rad2_per_s * duration_s,
            )

    def _motion_since(self, stamp_s: float) -> Pose2D | None:
        """Odometry motion from stamp_s to the filter's instant (robot frame at stamp_s); None if unknown
        (stamp_s outside the history, or no odometry yet)."""
        latest = self.history.latest
        if latest is None:
            return None
        then = self.history.pose_at(stamp_s)
        return None if then is None else between(then, latest[1])

    def pose_at(self, stamp_s: float) -> Pose2D | None:
        """The estimate carried back to stamp_s by the odometry since (map frame); None before the filter
        is initialised or when the history does not cover stamp_s (without odometry: the estimate)."""
        if not self.ekf.initialised:
            return None
        if self.history.latest is None:
            return self.ekf.pose
        motion = self._motion_since(stamp_s)
        return None if motion is None else compose(self.ekf.pose, inverse(motion))

    # -- bearings -------------------------------------------------------------------------------------
    def on_revolution(self, bearings: Sequence[Bearing]) -> RevolutionIntake:
        """One revolution's bearings (a beams/bearings message) through the bearing intake
        (`beams_common.bearing_intake.revolution_intake`, the triangulation's rules), then `on_intake`."""
        return self.on_intake(revolution_intake(bearings, self.ekf.beacons_xy))

    def on_intake(self, intake: RevolutionIntake) -> RevolutionIntake:
        """A revolution the bearing intake sorted out: its refusals counted (`bearings_<refusal>`, and the
        revolution's: `revolutions_too_many_bearings`, `revolutions_conflicting_beacon`,
        `revolutions_with_invalid_bearings`; ekf_node reports these counts with the reasons), the
        bearings kept applied (`on_bearings` without the intake's rules again). Returns the intake, for
        the caller to report."""
        self.stats.counts.update(key for key, _ in intake.revolution_refusals())
        self.stats.counts.update(intake.counts())
        self._apply_bearings(intake.kept)
        return intake

    def on_bearing(
        self, stamp_s: float, beacon_id: int, bearing_rad: float, variance_rad2: float
    ) -> BearingOutcome:
        """Apply one bearing (sensor frame) at its own stamp."""
        return self.on_bearings([Bearing(stamp_s, beacon_id, bearing_rad, variance_rad2)])[0]

    def on_bearings(self, bearings: Sequence[Bearing]) -> list[BearingOutcome]:
        """Apply bearings each at its own stamp, a bearing the intake's rule refuses
        (`bearing_intake.bearing_refusal`: unknown beacon, invalid measurement) excepted; outcomes in the
        given order. A revolution goes through `on_revolution` (one sighting per beacon too)."""
        if not self.ekf.initialised:
            return [self._count(rejected(BearingReason.UNINITIALISED)) for _ in bearings]
        outcomes: dict[int, BearingOutcome] = {}
        valid: list[tuple[int, Bearing]] = []
        for n, bearing in enumerate(bearings):
            # refused before scheduling: a bad bearing must not make the filter go back and re-filter
            refusal = bearing_refusal(bearing, self.ekf.beacons_xy)
            if refusal is None:
                valid.append((n, bearing))
            else:
                outcomes[n] = self._count(rejected(BearingReason(refusal.refusal.value)))
        applied = self._apply_bearings([b for _, b in valid])
        outcomes.update((n, outcome) for (n, _), outcome in zip(valid, applied, strict=True))
        return [outcomes[n] for n in range(len(bearings))]

    def _apply_bearings(self, bearings: Sequence[Bearing]) -> list[BearingOutcome]:
        """Apply valid bearings (typically one revolution's), each at its own stamp; outcomes in the given
        order.

        The filter goes back to its state at the odometry sample before the earliest stamp, applies the
        bearings of each odometry interval in stamp order (those already applied there again, so any
        arrival order gives the same estimate), the turret where the interpolated odometry puts it at
        the stamp, and predicts again through the later odometry samples. Applying a bearing at the
        newest instant instead would let it shrink the covariance of the odometry noise accrued after
        it was measured: the filter would become overconfident.
        """
        if not self.ekf.initialised:
            return [self._count(rejected(BearingReason.UNINITIALISED)) for _ in bearings]
        outcomes: dict[int, BearingOutcome] = {}
        valid = list(enumerate(bearings))
        if len(self.history) == 0:  # no odometry: the robot is taken as still
            outcomes.update((n, self._count(self._apply(b, (0.0, 0.0, 0.0)))) for n, b in valid)
            return [outcomes[n] for n in range(len(bearings))]
        scheduled: dict[int, list[tuple[Bearing, int]]] = {}  # history index -> (bearing, input index)
        first_state = self._first_state_index()
        for n, bearing in valid:
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

    def _ahead_of_odometry(self, stamp_s: float) -> bool:
        """True for a stamp after the newest odometry (past extrapolation) but within the history span."""
        newest_s = self.history.latest[0]
        return newest_s < stamp_s <= newest_s + self.config.odometry_history_s

    def _defer(self, bearing: Bearing) -> BearingOutcome:
        """Keep a bearing until odometry reaches its stamp (the oldest goes when too many wait)."""
        self._pending.append(bearing)
        if len(self._pending) > MAX_PENDING_BEARINGS:
            self._pending.pop(0)
            self.stats.counts["bearings_dropped_pending"] += 1
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
            t0, pose0, slot = self.history.sample(index)
            if index == first:
                self.ekf.restore(slot.state)
            else:
                t_prev, pose_prev, _ = self.history.sample(index - 1)
                self._advance(t_prev, pose_prev, t0, pose0)
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
                kept.append(bearing)
                if n is not None:
                    outcomes[n] = self._count(outcome)
                    self._track_gating(bearing, outcome)
            slot.bearings = kept

    def _apply(self, bearing: Bearing, robot_then: Pose2D) -> BearingOutcome:
        """Update with a bearing taken with the robot at `robot_then` in the current state's robot frame."""
        lever = turret_pose(robot_then, self.ekf.sensor_offset_m)
        window = 0.0 if bearing.calibrated else bearing.angular_window_rad  # an uncorrected power bias
        return self.ekf.update_bearing(
            bearing.beacon_id, bearing.bearing_rad, bearing.variance_rad2, lever, window
        )

    def _track_gating(self, bearing: Bearing, outcome: BearingOutcome) -> None:
        """Record whether a new bearing was gated (kidnap evidence) and the last accepted one."""
        if outcome.accepted:
            self.stats.last_bearing_stamp_s = bearing.stamp_s
        if outcome.accepted or outcome.reason is BearingReason.GATED:
            self.kidnap.add(not outcome.accepted)
            if self.confirmation.add(bearing.beacon_id, not outcome.accepted):
                self.stats.counts["pose_confirmations"] += 1
            if self.nis_monitor.add(outcome.nis):
                self.stats.counts["lost_detections"] += 1

    def _count(self, outcome: BearingOutcome) -> BearingOutcome:
        self.stats.counts[f"bearings_{outcome.reason}"] += 1
        return outcome

    @property
    def recent_gated_bearings(self) -> int:
        """Gated bearings among the last kidnap_window_bearings new ones (a diagnostic)."""
        return self.kidnap.recent_gated_bearings

    @property
    def kidnap_suspected(self) -> bool:
        """True when at least kidnap_gated_bearings of the last kidnap_window_bearings were gated out."""
        return self.kidnap.suspected

    # -- poses ----------------------------------------------------------------------------------------
    def on_pose(self, stamp_s: float, pose: Pose2D, covariance: np.ndarray, *, operator: bool) -> PoseOutcome:
        """A pose from ToTal (operator=False) or an operator (True). Returns what it did.

        An operator's pose always (re)initialises (one older than the odometry history is taken as
        current: it has no meaningful stamp); ToTal's initialises a filter that has no estimate, and
        re-initialises one that is kidnapped (kidnap suspected and the fix elsewhere) or lost (the
        NisMonitor's test), provided the odometry
        history covers its stamp ("outside_history" otherwise: the next fix will be covered).
        """
        if planar_pose_problem(stamp_s, pose):  # the intake's rule, for a caller without the intake
            self.stats.counts["poses_invalid"] += 1
            return PoseOutcome.INVALID
        return self._on_pose(stamp_s, pose, covariance, operator=operator)

    def _on_pose(
        self, stamp_s: float, pose: Pose2D, covariance: np.ndarray, *, operator: bool
    ) -> PoseOutcome:
        motion = self._motion_since(stamp_s)
        if motion is None and not operator:
            # the robot moved since the fix by an unknown amount (0.1 m in 0.2 s at 0.5 m/s)
            self.stats.counts["poses_outside_history"] += 1
            return PoseOutcome.OUTSIDE_HISTORY
        pose_now = pose if motion is None else compose(pose, motion)
        if operator or not self.ekf.initialised:
            return self._initialise(stamp_s, pose_now, covariance, PoseOutcome.INITIALISED, operator)
        if self.kidnap.suspected and self.kidnap.elsewhere(
            pose_now, covariance, self.ekf.pose, self.ekf.covariance
        ):
            return self._initialise(stamp_s, pose_now, covariance, PoseOutcome.KIDNAP_REINITIALISED)
        if self.nis_monitor.lost:
            return self._initialise(stamp_s, pose_now, covariance, PoseOutcome.LOST_REINITIALISED)
        return PoseOutcome.IGNORED

    def offer_pose(self, intake: PoseIntake, default_covariance: np.ndarray) -> PoseOutcome:
        """A pose through the pose intake (`beams_common.pose_intake`), for ekf_node and the offline
        replays alike: a refusal counted under its key (`<source>_poses_<kind>`, INVALID), a kept pose
        taken (`take_pose`)."""
        if isinstance(intake, RefusedPose):
            self.stats.counts[intake.counter_key] += 1
            return PoseOutcome.INVALID
        return self.take_pose(intake, default_covariance)

    def take_pose(self, kept: KeptPose, default_covariance: np.ndarray) -> PoseOutcome:
        """`on_pose` for a pose the intake kept (`beams_common.pose_intake`: finite, its covariance
        checked): a covariance without information (None) replaced by the default, an operator's stamp by
        "now" (`operator_pose_stamp_s`)."""
        stamp_s = kept.stamp_s
        if kept.operator:
            latest = self.history.latest
            stamp_s = operator_pose_stamp_s(stamp_s, None if latest is None else latest[0])
        covariance = default_covariance if kept.covariance is None else kept.covariance
        return self._on_pose(stamp_s, kept.pose, covariance, operator=kept.operator)

    def _initialise(
        self,
        stamp_s: float,
        pose: Pose2D,
        covariance: np.ndarray,
        outcome: PoseOutcome,
        operator: bool = False,
    ) -> PoseOutcome:
        try:
            self.ekf.initialise(pose, covariance)
        except ValueError:
            self.stats.counts["poses_invalid"] += 1
            return PoseOutcome.INVALID
        self.kidnap.clear()
        self.nis_monitor.clear()
        event = _CONTINUITY_EVENTS.get(outcome)
        if operator:
            self._break_continuity("an operator's pose")
        elif event:
            self._break_continuity(event)
        # the states kept for late bearings belong to the old estimate
        for index in range(len(self.history)):
            self.history.set_payload(index, None)
        latest = self.history.latest
        if latest is not None:
            self.history.set_payload(-1, _Slot(self.ekf.state()))
        self._stamp_s = latest[0] if latest is not None else stamp_s
        self.stats.counts[outcome.value] += 1
        return outcome

    # -- output ---------------------------------------------------------------------------------------
    def estimate(self) -> Estimate | None:
        """The current estimate, or None before initialisation."""
        if not self.ekf.initialised:
            return None
        stamp_s = self._stamp_s if self._stamp_s is not None else float("nan")
        latest = self.history.latest
        odom_pose = latest[1] if latest is not None and latest[0] == stamp_s else None
        return Estimate(stamp_s, self.ekf.pose, self.ekf.covariance, self._odometry_twist(), odom_pose)

    def _odometry_twist(self) -> tuple[float, float, float]:
        """Robot-frame velocity over the last odometry step (zero with fewer than two samples)."""
        step = self.history.last_step()
        if step is None:
            return (0.0, 0.0, 0.0)
        step_s, (dx, dy, dtheta) = step
        return (dx / step_s, dy / step_s, dtheta / step_s)


def build_localiser(
    beacons_xy: Mapping[int, Sequence[float]], sensor_offset_m: tuple[float, float], settings: FilterSettings
) -> Localiser:
    """The Localiser of a beacon map ({id: (x, y)}), a turret offset (m) and the filter settings."""
    ekf = BearingEkf(
        beacons_xy, sensor_offset_m, settings.process_noise, settings.gate_probability, settings.blocks
    )
    return Localiser(ekf, settings.localiser, settings.motion_limits)
