"""From one revolution's bearings to a gated pose: triplet choice, ToTal, covariance and the two gates.

A pose is accepted when ToTal's reliability measure 1/|D| (thesis 6.3.5, eq. 6.27) is below a threshold
and the position standard deviation propagated from the bearing variances (`pose_covariance`) is below
a limit. Defaults, from the error maps of the Eurobot layout (`error_map`, bearing sigma 0.1 deg as
the driver's variance model gives): the position std stays under 5 cm on 94% of the table and grows
without bound near the critical circumference, which crosses the table; 1/|D| < 2 m^-2 holds on 94%
of it as well and catches the blow-up even when the published variances are wrong. Rejected poses keep
their numbers and get the reason, so that `topic echo` shows why. With odometry in use, a revolution the
odometry does not cover (at start-up, before the first odometry, or when odometry stops) is not
motion-compensated: its pose is published rejected (a robot turning at 2 rad/s makes it centimetres
off while its covariance says millimetres).

`TriangulationPipeline` is what the node runs on its two inputs; the offline replay runs it too
(parameters.triangulation_settings maps the node's parameters to its settings).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from beams_common.beacon_map import BeaconMap
from beams_common.bearing import Bearing
from beams_common.validation import bearing_problem, one_sighting_per_beacon, revolution_size_problem
from beams_triangulation.motion_compensation import (
    motion_variance_rad2,
    triangulate_compensated,
)
from beams_triangulation.pose_covariance import pose_covariance, pose_covariance_many, position_std_m
from beams_triangulation.total import ToTalFix, triangulate, triangulate_many

DEFAULT_MAX_INVERSE_ABS_D = 2.0
DEFAULT_MAX_POSITION_STD_M = 0.05
REASON_NO_TRIPLET = "no beacon triplet gives a fix: robot on the critical circumference of every triplet"
REASON_NOT_COMPENSATED = "odometry does not cover the revolution: bearings not motion-compensated"


@dataclass(frozen=True)
class GateConfig:
    """The two acceptance gates: 1/|D| (m^-2) and sqrt(var x + var y) (m)."""

    max_inverse_abs_d: float = DEFAULT_MAX_INVERSE_ABS_D
    max_position_std_m: float = DEFAULT_MAX_POSITION_STD_M

    def __post_init__(self) -> None:
        if not (self.max_inverse_abs_d > 0.0 and self.max_position_std_m > 0.0):
            raise ValueError(f"gate thresholds must be positive, got {self}")


@dataclass(slots=True)
class PoseEstimate:
    """A ToTal pose with its covariance (x, y, theta; 3x3) and the gate's verdict.

    Not frozen on purpose: a frozen dataclass's __init__ costs 2 us here, a fifth of the scalar budget.
    """

    x: float
    y: float
    heading: float
    covariance: np.ndarray
    inverse_abs_d: float
    beacon_ids: tuple[int, int, int]
    accepted: bool
    reason: str

    @property
    def position_std_m(self) -> float:
        """sqrt(var x + var y) (m), the quantity the position gate compares."""
        return math.sqrt(self.covariance[0, 0] + self.covariance[1, 1])


@dataclass(frozen=True)
class NoPose:
    """Why one revolution gave no pose at all (too few beacons, bad input, robot on the critical circle).

    bad_input: the message itself was wrong (unknown or duplicated id, NaN, negative variance), as
    opposed to what happens in normal operation (a beacon hidden, the critical circumference).
    """

    reason: str
    bad_input: bool = False


def gate(inverse_abs_d: float, covariance: np.ndarray, config: GateConfig) -> tuple[bool, str]:
    """(accepted, reason): the 1/|D| gate first (the thesis's criterion), then the propagated std."""
    if not inverse_abs_d < config.max_inverse_abs_d:
        return False, f"1/|D| = {inverse_abs_d:.3g} m^-2 above the gate {config.max_inverse_abs_d:g}"
    std = math.sqrt(covariance[0, 0] + covariance[1, 1])
    if not std < config.max_position_std_m:
        return False, f"position std {std:.3g} m above the gate {config.max_position_std_m:g} m"
    return True, ""


def best_triplet(
    beacons_xy: np.ndarray, bearings_rad: np.ndarray, variances_rad2: np.ndarray, by: str = "covariance"
) -> tuple[int, int, int] | None:
    """Indices of the triplet to trust among more than three beacons, or None when none gives a fix.

    Every triplet is solved at once by the vectorised ToTal. by="covariance" (default) picks the
    smallest propagated position std; by="inverse_abs_d" the largest |D|, the thesis's measure (eq.
    6.27). On the Eurobot table with a fourth beacon at (3.062, -0.062) and 0.1 deg noise the first
    measures better (RMS 8.3 mm against 10.4 mm, 95th percentile 13 mm against 20 mm): 1/|D| also
    vanishes when the robot is on the line through two beacons, where the error does not.
    """
    triplets = np.array(list(itertools.combinations(range(len(bearings_rad)), 3)))
    batch = triangulate_many(beacons_xy[triplets], bearings_rad[triplets])
    if not batch.ok.any():
        return None
    if by == "inverse_abs_d":
        score = batch.inverse_abs_d
    else:
        covariance = pose_covariance_many(
            beacons_xy[triplets], (batch.x, batch.y, batch.heading), variances_rad2[triplets]
        )
        score = np.where(batch.ok, np.nan_to_num(position_std_m(covariance), nan=np.inf), np.inf)
    return tuple(int(i) for i in triplets[int(np.argmin(score))])


def _validate(
    beacon_ids: Sequence[int],
    bearings: np.ndarray,
    variances: np.ndarray,
    stamps: np.ndarray,
    beacon_map: BeaconMap,
) -> str:
    """The reason the input cannot give a pose (`validation.bearing_problem`, the EKF's rule too, on each
    bearing; a beacon seen twice at one instant), or an empty string."""
    if len(set(beacon_ids)) != len(beacon_ids):
        return f"duplicated beacon id in one revolution: {list(beacon_ids)}"
    for values in zip(beacon_ids, bearings, variances, stamps, strict=True):
        problem = bearing_problem(*values, beacon_map.ids)
        if problem:
            return problem
    return ""


def estimate_pose(
    beacon_ids: Sequence[int],
    bearings_rad: Sequence[float],
    variances_rad2: Sequence[float],
    beacon_map: BeaconMap,
    config: GateConfig = GateConfig(),
    turret_offset_m: Sequence[float] = (0.0, 0.0),
) -> PoseEstimate | NoPose:
    """Bearings taken from one pose (sensor frame) to a gated robot pose in the map frame.

    Three beacons: ToTal on them; more: the triplet with the smallest propagated std (`best_triplet`);
    fewer or bad input: NoPose.
    The covariance propagates the bearing variances through the Jacobian of the solution.
    """
    if not len(beacon_ids) == len(bearings_rad) == len(variances_rad2):
        counts = (len(beacon_ids), len(bearings_rad), len(variances_rad2))
        return NoPose("{} ids, {} bearings and {} variances: the lists must match".format(*counts), True)
    bearings = [
        Bearing(0.0, *values) for values in zip(beacon_ids, bearings_rad, variances_rad2, strict=True)
    ]
    return estimate_revolution(bearings, beacon_map, config, turret_offset_m).result


def gated_estimate(
    fix: ToTalFix,
    beacons_xy: np.ndarray,
    variances_rad2: Sequence[float],
    beacon_ids: tuple[int, int, int],
    config: GateConfig,
    turret_offset_m: Sequence[float] = (0.0, 0.0),
) -> PoseEstimate:
    """Covariance and gate decision for one ToTal fix (the scalar path the benchmark times)."""
    covariance = pose_covariance(beacons_xy, (fix.x, fix.y, fix.heading), variances_rad2, turret_offset_m)
    accepted, reason = gate(fix.inverse_abs_d, covariance, config)
    return PoseEstimate(
        fix.x, fix.y, fix.heading, covariance, fix.inverse_abs_d, beacon_ids, accepted, reason
    )


def drop_repeated_beacons(bearings: Sequence[Bearing]) -> list[Bearing]:
    """One bearing per beacon (`validation.one_sighting_per_beacon`, the EKF's rule too): a beacon seen
    twice at different instants keeps the sighting closest in time to the revolution's median instant.
    Two sightings at the same instant are not physical and stay, for the validation to refuse."""
    sightings = one_sighting_per_beacon(bearings)
    conflicting = set(sightings.conflicting_ids)
    return [*sightings.kept, *(b for b in sightings.dropped if b.beacon_id in conflicting)]


@dataclass(frozen=True)
class RevolutionPose:
    """The outcome of one revolution: the estimate (or why there is none), the instant it refers to,
    and whether the bearings were motion-compensated with odometry."""

    result: PoseEstimate | NoPose
    stamp_s: float
    compensated: bool


def estimate_revolution(
    bearings: Sequence[Bearing],
    beacon_map: BeaconMap,
    config: GateConfig = GateConfig(),
    turret_offset_m: Sequence[float] = (0.0, 0.0),
    odometry_at: Callable[[float], Sequence[float] | None] | None = None,
    motion: tuple[float, float] | None = None,
) -> RevolutionPose:
    """One revolution's bearings to a gated pose at the mean instant of the bearings used.

    odometry_at(t) gives the odometry pose (odom frame) at instant t, or None outside its samples: with
    it the bearings are brought to that instant before ToTal (`motion_compensation`); when it does not
    cover them, the pose is rejected (REASON_NOT_COMPENSATED). Without odometry (or when it does not
    cover the bearings), motion=(speed m/s, yaw rate rad/s) seen between revolutions inflates the
    bearing variances (`motion_variance_rad2`).
    """
    too_many = revolution_size_problem(len(bearings))  # before any per-bearing work
    if too_many:
        return RevolutionPose(NoPose(too_many, bad_input=True), math.nan, False)
    bearings = drop_repeated_beacons(bearings)
    ids = [b.beacon_id for b in bearings]
    angles = np.array([b.bearing_rad for b in bearings], dtype=float)
    variances = np.array([b.variance_rad2 for b in bearings], dtype=float)
    stamps = np.array([b.stamp_s for b in bearings], dtype=float)
    mean_stamp = float(stamps.mean()) if len(stamps) else math.nan
    problem = _validate(ids, angles, variances, stamps, beacon_map)
    if problem:
        return RevolutionPose(NoPose(problem, bad_input=True), mean_stamp, False)
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
    if odometry is None and motion is not None:
        ranges = np.hypot(beacons_xy[picked, 0] - fix.x, beacons_xy[picked, 1] - fix.y)
        used_variances = used_variances + motion_variance_rad2(stamps[picked] - target, ranges, *motion)
    estimate = gated_estimate(fix, beacons_xy[picked], used_variances, used_ids, config, turret_offset_m)
    if odometry_at is not None and odometry is None:
        _reject_uncompensated(estimate)
    return RevolutionPose(estimate, target, odometry is not None)


def _reject_uncompensated(estimate: PoseEstimate) -> None:
    """Reject a pose that odometry in use could not motion-compensate (the gate's reason kept first)."""
    estimate.reason = "; ".join(filter(None, (estimate.reason, REASON_NOT_COMPENSATED)))
    estimate.accepted = False


def _odometry_at_stamps(odometry_at, stamps: np.ndarray, target: float):
    """(odometry poses at the stamps (k, 3), odometry pose at the target) or None if not all covered."""
    if odometry_at is None:
        return None
    poses = [odometry_at(float(t)) for t in (*stamps, target)]
    if any(p is None for p in poses):
        return None
    return np.array(poses[:-1], dtype=float), poses[-1]
