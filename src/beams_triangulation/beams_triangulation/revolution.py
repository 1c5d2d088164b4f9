"""One revolution's bearings to a gated pose: the intake, the triplet, ToTal (motion-compensated), the
covariance and the gates. A conflicting or invalid bearing gives no pose; a repeated sighting or a beacon
off the map (another team's) is set aside and the others still count."""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass

import numpy as np

from beams_common.geometry.beacon_map import BeaconMap
from beams_common.geometry.bearing import Bearing
from beams_common.geometry.pose_buffer import twist_between
from beams_common.intake.bearing_intake import BearingRefusal, RevolutionIntake, revolution_intake
from beams_triangulation.gating import (
    REASON_NO_TRIPLET,
    REASON_NOT_COMPENSATED,
    GateConfig,
    NoPose,
    PoseEstimate,
    best_triplet,
    gated_estimate,
)
from beams_triangulation.motion_compensation import motion_variance_rad2, triangulate_compensated
from beams_triangulation.total import triangulate

DEFAULT_GATES = GateConfig()
OdometryAt = Callable[[float], Sequence[float] | None]
# the last pose (x, y, theta) and its stamp (s), for the motion seen between revolutions
PreviousPose = tuple[tuple[float, float, float], float]


@dataclass(frozen=True)
class RevolutionPose:
    """The outcome of one revolution: the estimate (or why there is none), the instant it refers to,
    and whether the bearings were motion-compensated with odometry."""

    result: PoseEstimate | NoPose
    stamp_s: float
    compensated: bool


def bad_input(intake: RevolutionIntake) -> str:
    """Why ToTal gives the revolution no pose for its input (the first refusal), or '' when only repeated
    sightings or unknown beacons (or nothing) were set aside."""
    if intake.too_many:
        return intake.too_many
    if intake.conflicting_ids:
        return f"duplicated beacon id in one revolution: beacon(s) {intake.conflicting_ids} at one instant"
    invalid = intake.refused_as(BearingRefusal.INVALID_MEASUREMENT)
    return invalid[0].reason if invalid else ""


def estimate_revolution(
    bearings: Sequence[Bearing],
    beacon_map: BeaconMap,
    config: GateConfig = DEFAULT_GATES,
    turret_offset_m: Sequence[float] = (0.0, 0.0),
    odometry_at: OdometryAt | None = None,
    previous: PreviousPose | None = None,
) -> RevolutionPose:
    """One revolution's bearings through the bearing intake, then `estimate_intake`."""
    intake = revolution_intake(bearings, beacon_map.ids)
    return estimate_intake(intake, beacon_map, config, turret_offset_m, odometry_at, previous)


def estimate_intake(
    intake: RevolutionIntake,
    beacon_map: BeaconMap,
    config: GateConfig = DEFAULT_GATES,
    turret_offset_m: Sequence[float] = (0.0, 0.0),
    odometry_at: OdometryAt | None = None,
    previous: PreviousPose | None = None,
) -> RevolutionPose:
    """A revolution the intake sorted out to a gated pose at the mean instant of the bearings used. With
    odometry_at(t) (the odom pose, None outside its samples) the bearings are brought to that instant first
    (`motion_compensation`), the pose rejected when it does not cover them (REASON_NOT_COMPENSATED); without,
    the motion from the `previous` pose inflates the bearing variances (`motion_variance_rad2`), not the fix.
    """
    problem = bad_input(intake)
    if problem:
        repeated = BearingRefusal.REPEATED_BEACON
        sighted = [*intake.kept, *(r.bearing for r in intake.refused if r.refusal is not repeated)]
        mean_stamp = float(np.mean([b.stamp_s for b in sighted])) if sighted else math.nan
        return RevolutionPose(NoPose(problem, bad_input=True), mean_stamp, False)
    bearings = intake.kept
    ids = [b.beacon_id for b in bearings]
    angles = np.array([b.bearing_rad for b in bearings], dtype=float)
    variances = np.array([b.variance_rad2 for b in bearings], dtype=float)
    stamps = np.array([b.stamp_s for b in bearings], dtype=float)
    mean_stamp = float(stamps.mean()) if len(stamps) else math.nan
    if len(ids) < 3:
        too_few = NoPose(f"{len(ids)} beacon(s) seen {ids}: ToTal needs three")
        return RevolutionPose(too_few, mean_stamp, False)
    beacons_xy = beacon_map.subset(ids)
    chosen = (0, 1, 2) if len(ids) == 3 else best_triplet(beacons_xy, angles, variances)
    if chosen is None:
        return RevolutionPose(NoPose(REASON_NO_TRIPLET), mean_stamp, False)
    picked = list(chosen)
    used_ids = tuple(ids[i] for i in picked)
    target = float(stamps[picked].mean())
    odometry = _odometry_at_stamps(odometry_at, stamps[picked], target)
    if odometry is not None:
        odom_at_bearings, odom_at_target = odometry
        fix = triangulate_compensated(
            beacons_xy[picked], angles[picked], odom_at_bearings, odom_at_target, turret_offset_m
        )
    else:
        fix = triangulate(beacons_xy[picked], angles[picked], turret_offset_m)
    if not fix.ok:
        return RevolutionPose(NoPose(fix.reason), target, odometry is not None)
    used_variances = variances[picked]
    motion = None
    if odometry is None and previous is not None:
        motion = twist_between(*previous, (fix.x, fix.y, fix.heading), target)
    if motion is not None:
        ranges = np.hypot(beacons_xy[picked, 0] - fix.x, beacons_xy[picked, 1] - fix.y)
        used_variances = used_variances + motion_variance_rad2(stamps[picked] - target, ranges, *motion)
    estimate = gated_estimate(fix, beacons_xy[picked], used_variances, used_ids, config, turret_offset_m)
    if odometry_at is not None and odometry is None:
        _reject_uncompensated(estimate)
    return RevolutionPose(estimate, target, odometry is not None)


def estimate_pose(
    beacon_ids: Sequence[int],
    bearings_rad: Sequence[float],
    variances_rad2: Sequence[float],
    beacon_map: BeaconMap,
    config: GateConfig = DEFAULT_GATES,
    turret_offset_m: Sequence[float] = (0.0, 0.0),
) -> PoseEstimate | NoPose:
    """Bearings taken from one pose (sensor frame) to a gated robot pose in the map frame: ToTal on three
    beacons, on the triplet of smallest propagated std among more (`best_triplet`); NoPose for fewer or bad
    input."""
    if not len(beacon_ids) == len(bearings_rad) == len(variances_rad2):
        counts = (len(beacon_ids), len(bearings_rad), len(variances_rad2))
        return NoPose("{} ids, {} bearings and {} variances: the lists must match".format(*counts), True)
    bearings = [
        Bearing(0.0, *values) for values in zip(beacon_ids, bearings_rad, variances_rad2, strict=True)
    ]
    return estimate_revolution(bearings, beacon_map, config, turret_offset_m).result


def _reject_uncompensated(estimate: PoseEstimate) -> None:
    """Reject a pose that odometry in use could not motion-compensate (the gate's reason kept first)."""
    estimate.reason = "; ".join(filter(None, (estimate.reason, REASON_NOT_COMPENSATED)))
    estimate.accepted = False


def _odometry_at_stamps(odometry_at: OdometryAt | None, stamps: np.ndarray, target: float):
    """(odometry poses at the stamps (k, 3), odometry pose at the target) or None if not all covered."""
    if odometry_at is None:
        return None
    poses = [odometry_at(float(t)) for t in (*stamps, target)]
    if any(p is None for p in poses):
        return None
    return np.array(poses[:-1], dtype=float), poses[-1]


class RevolutionEstimator:
    """`estimate_intake` for a stream of revolutions, remembering the last pose so that, without
    odometry, the motion seen between revolutions inflates the variances (what the node runs)."""

    def __init__(
        self,
        beacon_map: BeaconMap,
        config: GateConfig | None = None,
        turret_offset_m: Sequence[float] = (0.0, 0.0),
    ) -> None:
        self.beacon_map = beacon_map
        self.config = config or GateConfig()
        self.turret_offset_m = (float(turret_offset_m[0]), float(turret_offset_m[1]))
        self._last: PreviousPose | None = None

    @property
    def known_ids(self) -> Collection[int]:
        """The beacons of the map, for the bearing intake."""
        return self.beacon_map.ids

    def update(self, bearings: Sequence[Bearing], odometry_at: OdometryAt | None = None) -> RevolutionPose:
        """The gated pose of one revolution's bearings (the intake, then `update_intake`)."""
        return self.update_intake(revolution_intake(bearings, self.known_ids), odometry_at)

    def update_intake(
        self, intake: RevolutionIntake, odometry_at: OdometryAt | None = None
    ) -> RevolutionPose:
        """The gated pose of one revolution the intake sorted out (see `estimate_intake`)."""
        settings = (self.beacon_map, self.config, self.turret_offset_m)
        outcome = estimate_intake(intake, *settings, odometry_at, self._last)
        estimate = outcome.result
        if isinstance(estimate, PoseEstimate):
            self._last = ((estimate.x, estimate.y, estimate.heading), outcome.stamp_s)
        return outcome
