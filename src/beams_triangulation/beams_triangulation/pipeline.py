"""The per-revolution pipeline triangulation_node (and the offline replay) runs: `TriangulationPipeline`;
`triangulation_settings` maps the node's parameters to its settings."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from beams_common.geometry.beacon_map import BeaconMap
from beams_common.geometry.bearing import Bearing
from beams_common.geometry.pose2d import between
from beams_common.intake.bearing_intake import RevolutionIntake, revolution_intake
from beams_common.intake.plausibility import MotionLimits, motion_limits_of, odometry_step_problem
from beams_common.intake.validation import odometry_problem
from beams_triangulation.gating import GateConfig
from beams_triangulation.motion_compensation import odometry_buffer
from beams_triangulation.parameters import TRIANGULATION_PARAMETERS
from beams_triangulation.revolution import RevolutionEstimator, RevolutionPose


@dataclass(frozen=True)
class TriangulationSettings:
    """What triangulation_node takes from its parameters (besides the beacon geometry)."""

    gates: GateConfig = field(default_factory=GateConfig)
    # bring each revolution's bearings to one instant with `odom` (and refuse the uncovered ones)
    use_odometry: bool = TRIANGULATION_PARAMETERS.default("use_odometry")
    odometry_history_s: float = TRIANGULATION_PARAMETERS.default("odometry_history_s")
    max_odometry_extrapolation_s: float = TRIANGULATION_PARAMETERS.default("max_odometry_extrapolation_s")
    # the robot's maximum speed and yaw rate: an odometry increment beyond them is a jump
    motion_limits: MotionLimits = field(default_factory=MotionLimits)


def triangulation_settings(parameters: Mapping[str, Any]) -> TriangulationSettings:
    """The settings of triangulation_node's parameter values by name (a missing one takes its default);
    ParameterError (a ValueError) for a value the node refuses, alone or with the others."""
    values = TRIANGULATION_PARAMETERS.validate(parameters)
    return TriangulationSettings(
        gates=GateConfig(float(values["max_inverse_abs_d"]), float(values["max_position_std_m"])),
        use_odometry=bool(values["use_odometry"]),
        odometry_history_s=float(values["odometry_history_s"]),
        max_odometry_extrapolation_s=float(values["max_odometry_extrapolation_s"]),
        motion_limits=motion_limits_of(values),
    )


Tag = Any  # what the caller attaches to a revolution (its number live, its due instant offline)


class TriangulationPipeline:
    """triangulation_node's logic on its two inputs, without ROS (the offline replay runs it too). With
    odometry in use, a revolution newer than the newest odometry waits for it, at most until the next
    revolution, so that its bearings are interpolated rather than extrapolated whatever order the streams
    arrive in: the node and the replay give the same poses. Each call returns the (tag, outcome) pairs of the
    revolutions it completed, oldest first."""

    def __init__(
        self,
        beacon_map: BeaconMap,
        settings: TriangulationSettings = TriangulationSettings(),
        turret_offset_m: Sequence[float] = (0.0, 0.0),
    ) -> None:
        self.settings = settings
        self.estimator = RevolutionEstimator(beacon_map, settings.gates, turret_offset_m)
        self.odometry = odometry_buffer(settings.odometry_history_s, settings.max_odometry_extrapolation_s)
        self.rejected_odometry = 0  # non-finite samples dropped
        # odometry increments beyond the motion limits, and the reason of the last sample's ('' when none)
        self.odometry_jumps = 0
        self.last_odometry_jump = ""
        self._pending: tuple[Tag, RevolutionIntake] | None = None
        # revolutions estimated before the odometry covered them (`flush`): extrapolated or uncompensated,
        # so an offline replay, which has all the odometry, estimates them otherwise (a starved node)
        self.revolutions_before_odometry = 0

    def configure(
        self,
        beacon_map: BeaconMap,
        gates: GateConfig,
        turret_offset_m: Sequence[float],
        motion_limits: MotionLimits | None = None,
    ) -> None:
        """New beacon geometry, gates or motion limits (a runtime parameter change, a calibration
        reload); the odometry and the waiting revolution stay."""
        limits = motion_limits or self.settings.motion_limits
        self.settings = replace(self.settings, gates=gates, motion_limits=limits)
        self.estimator = RevolutionEstimator(beacon_map, gates, turret_offset_m)

    def on_odometry(
        self, stamp_s: float, pose: Sequence[float], twist: tuple[float, float]
    ) -> list[tuple[Tag, RevolutionPose]]:
        """`take_odometry` for a caller that only wants the revolutions it completed."""
        return self.take_odometry(stamp_s, pose, twist)[1]

    def take_odometry(
        self, stamp_s: float, pose: Sequence[float], twist: tuple[float, float]
    ) -> tuple[str, list[tuple[Tag, RevolutionPose]]]:
        """An odometry sample (odom frame): (why it was refused, '' when taken; the revolutions it
        completed). A jump (`plausibility.odometry_step_problem`) starts the odometry over, so that no
        revolution is compensated across it (`last_odometry_jump`, odometry_jumps)."""
        self.last_odometry_jump = ""
        if not self.settings.use_odometry:
            return "", []
        problem = odometry_problem(stamp_s, pose, twist)
        if problem:
            self.rejected_odometry += 1
            return problem, []
        latest = self.odometry.latest
        if latest is not None and stamp_s > latest[0]:
            step = between(latest[1], tuple(pose))
            self.last_odometry_jump = odometry_step_problem(
                stamp_s - latest[0], step, self.settings.motion_limits
            )
            if self.last_odometry_jump:
                self.odometry_jumps += 1
                self.odometry.clear()
        self.odometry.add_valid(stamp_s, tuple(pose), twist)  # the odometry rule ran above
        if self._pending is not None and self._covered(self._pending[1]):
            return "", self._release()
        return "", []

    def on_revolution(self, tag: Tag, bearings: Sequence[Bearing]) -> list[tuple[Tag, RevolutionPose]]:
        """A revolution's bearings through the bearing intake, then `on_intake`."""
        return self.on_intake(tag, revolution_intake(bearings, self.estimator.known_ids))

    def on_intake(self, tag: Tag, intake: RevolutionIntake) -> list[tuple[Tag, RevolutionPose]]:
        """A revolution the bearing intake sorted out: the waiting revolution goes first, with the
        odometry there is."""
        completed = self.flush()
        if self.settings.use_odometry and not self._covered(intake):
            self._pending = (tag, intake)
            return completed
        return [*completed, (tag, self._estimate(intake))]

    def flush(self) -> list[tuple[Tag, RevolutionPose]]:
        """The waiting revolution (if any), estimated now, before odometry covers it (the next revolution
        came first, the streams stop or time jumps): counted in `revolutions_before_odometry`."""
        if self._pending is not None:
            self.revolutions_before_odometry += 1
        return self._release()

    def _release(self) -> list[tuple[Tag, RevolutionPose]]:
        """The waiting revolution (if any), estimated with the odometry there is."""
        if self._pending is None:
            return []
        tag, intake = self._pending
        self._pending = None
        return [(tag, self._estimate(intake))]

    def _covered(self, intake: RevolutionIntake) -> bool:
        """True when no odometry can still help: the newest odometry is at or after every bearing of the
        revolution, or the stamps are not usable (bad input is reported at once)."""
        stamps = [b.stamp_s for b in (*intake.kept, *(r.bearing for r in intake.refused))]
        if not (stamps and all(map(math.isfinite, stamps))):
            return True
        newest_s = self.odometry.newest_stamp_s
        return newest_s is not None and newest_s >= max(stamps)

    def _estimate(self, intake: RevolutionIntake) -> RevolutionPose:
        odometry_at = self.odometry.pose_at if self.settings.use_odometry else None
        return self.estimator.update_intake(intake, odometry_at)
