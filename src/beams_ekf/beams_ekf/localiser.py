"""The complete positioning scheme of thesis fig. 8.1 without ROS: odometry + BeAMS bearings in the EKF,
ToTal (or an operator) to initialise it.

`Localiser` has one door per input, each answering an outcome: `on_odometry(stamp_s, pose)` (checked by
`validation.odometry_problem`), `on_bearings(intake)` (a revolution through
`beams_common.intake.bearing_intake`) and `on_pose(intake)` (ToTal's fix or an operator's through
`beams_common.intake.pose_intake`). ekf_node and every offline driver (`beams_thesis.replay`,
`beams_tools.replay_pipelines`, the benches) use these, so the offline figures are the node's. The EKF state
is kept at the newest odometry instant, a bearing applied at its own stamp (`late_bearings`). A pose
initialises the filter, brought to the filter's instant by the odometry since its stamp (a ToTal fix, stamped
at its revolution ~0.1-0.2 s before it arrives, is refused when the odometry history does not cover it: taken
as current, it put the live filter 0.2 m and 7 deg off, confidently), and re-initialises it when the robot was
kidnapped (most recent bearings gated out while ToTal is confident of a pose inconsistent with the estimate:
identified beacons make this possible, thesis ch. 8 "System deployment") or the filter is lost (`NisMonitor`).
Time going backwards (a bag played in a loop; `beams_common.intake.time_jumps`) resets everything, what the
filter learnt of the sensor included; odometry gaps inflate the covariance; an odometry increment beyond the
robot's speed or yaw rate (`beams_common.intake.plausibility`) is never predicted with: the sample becomes the
new reference and the covariance grows by the most the robot could have moved (`Localiser._rereference`).
After an event that breaks the estimate's continuity (an operator's pose, an odometry jump, an odometry
silence of ODOMETRY_SILENCE_S, a time jump, a re-initialisation from ToTal after a kidnap or a lost test)
the estimate is unconfirmed until its bearings confirm it (`consistency.PoseConfirmation`; ekf_node's
status is degraded meanwhile); the first initialisation from ToTal is the bearings' own pose.
"""

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from beams_common.geometry.bearing import Bearing
from beams_common.geometry.pose2d import Pose2D, between, compose, inverse
from beams_common.intake.bearing_intake import RevolutionIntake, revolution_intake
from beams_common.intake.plausibility import MotionLimits, odometry_step_problem
from beams_common.intake.pose_intake import PoseIntake, RefusedPose
from beams_common.intake.time_jumps import StampOrder, TimeJumpDetector
from beams_common.intake.validation import odometry_problem
from beams_ekf.bearing_ekf import BearingEkf
from beams_ekf.consistency import (
    ODOMETRY_SILENCE_S,
    BeaconExclusion,
    KidnapEvidence,
    NisMonitor,
    PoseConfirmation,
)
from beams_ekf.late_bearings import LateBearings
from beams_ekf.outcomes import Estimate, OdometryOutcome, PoseOutcome
from beams_ekf.pose_filter import BearingOutcome, BearingReason, PoseFilter
from beams_ekf.separations import BeaconSeparations
from beams_ekf.settings import FilterSettings, LocaliserConfig

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
class LocaliserCounters:
    """Counts for diagnostics (names are the diagnostic keys)."""

    counts: Counter = field(default_factory=Counter)
    last_bearing_stamp_s: float | None = None


class Localiser:
    """Odometry history + a PoseFilter (BearingEkf by default) + initialisation, kidnap and time-jump
    logic; `default_pose_covariance` replaces a pose's covariance without information (FilterSettings')."""

    def __init__(
        self,
        ekf: PoseFilter,
        config: LocaliserConfig | None = None,
        motion_limits: MotionLimits | None = None,
        default_pose_covariance: np.ndarray | None = None,
    ) -> None:
        self.ekf = ekf
        config = self.config = config or LocaliserConfig()
        self.motion_limits = motion_limits or MotionLimits()
        if default_pose_covariance is None:
            default_pose_covariance = FilterSettings().default_pose_covariance
        self.default_pose_covariance = default_pose_covariance
        # why the last odometry jump was refused ('' before any)
        self.last_odometry_jump = ""
        self.stats = LocaliserCounters()
        self._late = LateBearings(ekf, self.config, self.stats.counts, self._track_gating)
        self.history = self._late.history
        self.kidnap = KidnapEvidence(
            config.kidnap_window_bearings,
            config.kidnap_gated_bearings,
            config.kidnap_probability,
            config.kidnap_distance_m,
            config.kidnap_heading_rad,
        )
        self._time_jumps = TimeJumpDetector(config.time_jump_tolerance_s, config.time_jump_confirmations)
        self.nis_monitor = NisMonitor(config.lost_nis_window_bearings, config.lost_nis_probability, ekf.gate)
        self.confirmation = PoseConfirmation(config.confirming_bearings)
        self.exclusion = BeaconExclusion(ekf, config.exclusion_gated_bearings, config.readmission_bearings)
        self._late.exclusion = self.exclusion
        self._stamp_s: float | None = None
        # the protection level's fault hypotheses: the solution without each beacon
        self.separations = BeaconSeparations(len(ekf.beacons_xy))

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
        reload), motion limits and default pose covariance; the estimate and the odometry history stay."""
        self.motion_limits = settings.motion_limits
        self.default_pose_covariance = settings.default_pose_covariance
        self.ekf.configure(beacons_xy, sensor_offset_m, settings.process_noise, settings.gate_probability)
        self.separations = BeaconSeparations(len(self.ekf.beacons_xy))
        self.exclusion.clear()

    def reset(self, reason: str = "reset", forget_learnt: bool = False) -> None:
        """Forget the estimate and the odometry; the filter waits for a pose. What a BearingEkf learnt of
        the sensor and the odometry is kept (`BearingEkf.initialise`) unless `forget_learnt` (the data
        start again: a time jump)."""
        if forget_learnt and isinstance(self.ekf, BearingEkf):
            self.ekf.reset(forget_learnt=True)
        else:
            self.ekf.reset()
        self._late.clear()
        self.kidnap.clear()
        self.nis_monitor.clear()
        self._stamp_s = None
        self._time_jumps.clear()
        self.confirmation.clear()  # the next initialisation from ToTal is a first one
        self.separations.clear()
        self.exclusion.clear()
        # a bearing of the data before a time jump would make the silence since the last one negative
        self.stats.last_bearing_stamp_s = None
        self.stats.counts[reason] += 1

    # -- odometry -------------------------------------------------------------------------------------
    def on_odometry(self, stamp_s: float, odom_pose: Pose2D) -> OdometryOutcome:
        """One odometry sample (odom frame): predict with the motion since the previous one, then apply the
        bearings that waited for it. Returns what happened."""
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
        increment = None if latest is None else between(latest[1], odom_pose)
        jump = (
            ""
            if increment is None
            else odometry_step_problem(stamp_s - latest[0], increment, self.motion_limits)
        )
        if jump:
            self._rereference(stamp_s, odom_pose, stamp_s - latest[0], jump)
            return OdometryOutcome.JUMPED
        if latest is None or not self.ekf.initialised:
            self._late.append(stamp_s, odom_pose)
            self._stamp_s = stamp_s if self.ekf.initialised else None
            return OdometryOutcome.REFERENCE
        if stamp_s - latest[0] > self.config.odometry_gap_s:
            self.stats.counts["odometry_gaps"] += 1
        if stamp_s - latest[0] > ODOMETRY_SILENCE_S:
            # the estimate stood still: an odometry source restarted within its speed limit (a
            # simulator's new match) or a robot pushed meanwhile is not followed
            self._break_continuity(f"an odometry silence of {stamp_s - latest[0]:.1f} s")
        step = (stamp_s - latest[0], increment)
        self._late.predict(*step)
        self.separations.moved(increment, self.ekf.pose[2])
        self._late.append(stamp_s, odom_pose, step)
        self._stamp_s = stamp_s
        self._late.apply_pending(stamp_s)
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
        self._late.append(stamp_s, odom_pose)
        self._stamp_s = stamp_s
        self._late.apply_pending(stamp_s)

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
    def on_bearings(self, intake: RevolutionIntake) -> list[BearingOutcome]:
        """A revolution the bearing intake sorted out (`beams_common.intake.bearing_intake.revolution_intake`,
        the triangulation's rules): its refusals counted (`bearings_<refusal>`, and the revolution's:
        `revolutions_too_many_bearings`, `revolutions_conflicting_beacon`,
        `revolutions_with_invalid_bearings`; ekf_node reports these counts with the reasons), the bearings
        kept applied each at its own stamp (`late_bearings`). Returns their outcomes, in `intake.kept`'s
        order."""
        self.stats.counts.update(key for key, _ in intake.revolution_refusals())
        self.stats.counts.update(intake.counts())
        return self._late.apply(intake.kept)

    def _track_gating(self, bearing: Bearing, outcome: BearingOutcome) -> None:
        """Record whether a new bearing was gated (kidnap evidence) and the last accepted one."""
        if outcome.accepted:
            self.stats.last_bearing_stamp_s = bearing.stamp_s
            self.separations.bearing(bearing.beacon_id, outcome)
        if outcome.accepted or outcome.reason in (BearingReason.GATED, BearingReason.EXCLUDED):
            # a beacon is to blame only when the estimate is the bearings' own (confirmed, not kidnapped)
            trusted = self.confirmation.confirmed and not self.kidnap.suspected
            change = self.exclusion.add(bearing.beacon_id, outcome, trusted)
            if change:
                self.stats.counts[f"beacons_{change}"] += 1
        if outcome.accepted or outcome.reason is BearingReason.GATED:
            self.kidnap.add(not outcome.accepted)
            if self.confirmation.add(bearing.beacon_id, not outcome.accepted):
                self.stats.counts["pose_confirmations"] += 1
            if self.nis_monitor.add(outcome.nis):
                self.stats.counts["lost_detections"] += 1

    # -- poses ----------------------------------------------------------------------------------------
    def on_pose(self, intake: PoseIntake) -> PoseOutcome:
        """A pose through the pose intake (`beams_common.intake.pose_intake`: ToTal's fix or an operator's).
        Returns what it did: a refusal is counted under its key (`<source>_poses_<kind>`, INVALID; ekf_node
        shows this count with the reason).

        A kept pose's covariance without information (None) is replaced by `default_pose_covariance`. An
        operator's pose always (re)initialises, stamped "now" (`operator_pose_stamp_s`; one older than the
        odometry history is taken as current: it has no meaningful stamp); ToTal's initialises a filter
        that has no estimate, and re-initialises one that is kidnapped (kidnap suspected and the fix
        elsewhere) or lost (the NisMonitor's test), provided the odometry history covers its stamp
        ("outside_history" otherwise: the next fix will be covered).
        """
        if isinstance(intake, RefusedPose):
            self.stats.counts[intake.counter_key] += 1
            return PoseOutcome.INVALID
        operator, stamp_s = intake.operator, intake.stamp_s
        latest = self.history.latest
        if operator:
            stamp_s = operator_pose_stamp_s(stamp_s, None if latest is None else latest[0])
        covariance = self.default_pose_covariance if intake.covariance is None else intake.covariance
        motion = self._motion_since(stamp_s)
        if motion is None and not operator:
            # the robot moved since the fix by an unknown amount (0.1 m in 0.2 s at 0.5 m/s)
            self.stats.counts["poses_outside_history"] += 1
            return PoseOutcome.OUTSIDE_HISTORY
        pose_now = intake.pose if motion is None else compose(intake.pose, motion)
        if operator or not self.ekf.initialised:
            return self._initialise(stamp_s, pose_now, covariance, PoseOutcome.INITIALISED, operator)
        if self.kidnap.suspected and self.kidnap.elsewhere(
            pose_now, covariance, self.ekf.pose, self.ekf.covariance
        ):
            return self._initialise(stamp_s, pose_now, covariance, PoseOutcome.KIDNAP_REINITIALISED)
        if self.nis_monitor.lost and self.exclusion.agrees_again:
            # while an excluded beacon disagrees, ToTal's fix (which uses it) is no better than the estimate
            return self._initialise(stamp_s, pose_now, covariance, PoseOutcome.LOST_REINITIALISED)
        return PoseOutcome.IGNORED

    def _initialise(
        self,
        stamp_s: float,
        pose: Pose2D,
        covariance: np.ndarray,
        outcome: PoseOutcome,
        operator: bool = False,
    ) -> PoseOutcome:
        before = (self.ekf.pose, self.ekf.covariance) if self.ekf.initialised else None
        try:
            self.ekf.initialise(pose, covariance)
        except ValueError:
            self.stats.counts["poses_invalid"] += 1
            return PoseOutcome.INVALID
        self.kidnap.clear()
        self.nis_monitor.clear()
        # ToTal's fix after the lost test uses every beacon, a faulty one included: the solutions go on
        self.separations.initialised(
            pose, covariance, before if outcome is PoseOutcome.LOST_REINITIALISED else None
        )
        self.exclusion.clear()
        event = _CONTINUITY_EVENTS.get(outcome)
        if operator:
            self._break_continuity("an operator's pose")
        elif event:
            self._break_continuity(event)
        self._late.restart_states()
        latest = self.history.latest
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
        covariance = self.ekf.covariance
        estimate = Estimate(stamp_s, self.ekf.pose, covariance, self._odometry_twist(), odom_pose)
        hypotheses = self.separations.hypotheses(covariance)
        if hypotheses is not None:
            estimate.fault_shifts, estimate.fault_covariances = hypotheses
        return estimate

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
    return Localiser(ekf, settings.localiser, settings.motion_limits, settings.default_pose_covariance)


def revolution_of(localiser: Localiser, bearings: Iterable[Bearing]) -> RevolutionIntake:
    """The bearing intake of plain bearings against the localiser's beacons (`revolution_intake`, ekf_node's
    rules): what an offline driver hands to `Localiser.on_bearings` for one revolution."""
    return revolution_intake(list(bearings), localiser.ekf.beacons_xy)
