"""Bringing the bearings of one revolution to a single instant (thesis 5.7; Loevsky and Shimshoni): a robot
at 2 rad/s sweeps 11 deg in a revolution. Each bearing moves by the odometry increment since its stamp,
the rotation exactly, the translation through the predicted bearings from an approximate pose (second-order
error; `triangulate_compensated` iterates twice). Without odometry: `motion_variance_rad2`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.pose2d import between, compose
from beams_common.geometry.pose_buffer import PoseBuffer
from beams_common.intake.time_jumps import TimeJumpDetector
from beams_triangulation.total import ToTalFix, triangulate


def interpolate_pose(stamps_s: ArrayLike, poses: ArrayLike, t: float) -> tuple[float, float, float] | None:
    """Pose at instant t, linear between the odometry samples around it (heading on the circle); None outside
    them (a bearing beyond the odometry cannot be compensated honestly)."""
    stamps = np.asarray(stamps_s, dtype=float)
    samples = np.asarray(poses, dtype=float)
    if stamps.size == 0 or not stamps[0] <= t <= stamps[-1]:
        return None
    upper = int(np.searchsorted(stamps, t, side="left"))
    if stamps[upper] == t:
        return tuple(float(v) for v in samples[upper])
    lower = upper - 1
    weight = (t - stamps[lower]) / (stamps[upper] - stamps[lower])
    before, after = samples[lower], samples[upper]
    x, y = before[:2] + weight * (after[:2] - before[:2])
    return float(x), float(y), wrap_to_pi(before[2] + weight * wrap_to_pi(after[2] - before[2]))


def _predicted_bearing(
    beacon: Sequence[float], robot_map: Sequence[float], turret_offset_m: Sequence[float]
) -> float:
    """Bearing of a beacon in the turret frame of a robot at robot_map (x, y, theta)."""
    turret = compose(robot_map, (turret_offset_m[0], turret_offset_m[1], 0.0))
    return math.atan2(beacon[1] - turret[1], beacon[0] - turret[0]) - robot_map[2]


def compensate_bearings(
    bearings_rad: ArrayLike,
    odom_at_bearings: ArrayLike,
    odom_at_target: Sequence[float],
    beacons_xy: ArrayLike | None = None,
    approx_pose_map: Sequence[float] | None = None,
    turret_offset_m: Sequence[float] = (0.0, 0.0),
) -> np.ndarray:
    """Bearings (k,) measured at the odometry poses odom_at_bearings (k, 3), moved to odom_at_target, wrapped:
    the rotation only, or with approx_pose_map (the robot's map pose at the target instant) and beacons_xy (k,
    2) the translation too."""
    bearings = np.asarray(bearings_rad, dtype=float)
    odometry = np.asarray(odom_at_bearings, dtype=float).reshape(-1, 3)
    corrected = np.empty_like(bearings)
    for i, (bearing, odom_pose) in enumerate(zip(bearings, odometry, strict=True)):
        # Robot pose at the bearing's instant, in the robot frame at the target instant.
        increment = between(odom_at_target, odom_pose)
        if approx_pose_map is None:
            corrected[i] = bearing + increment[2]
            continue
        beacon = np.asarray(beacons_xy, dtype=float)[i]
        then_map = compose(approx_pose_map, increment)
        corrected[i] = bearing + (
            _predicted_bearing(beacon, approx_pose_map, turret_offset_m)
            - _predicted_bearing(beacon, then_map, turret_offset_m)
        )
    return np.asarray(wrap_to_pi(corrected), dtype=float).reshape(bearings.shape)


def triangulate_compensated(
    beacons_xy: ArrayLike,
    bearings_rad: ArrayLike,
    odom_at_bearings: ArrayLike,
    odom_at_target: Sequence[float],
    turret_offset_m: Sequence[float] = (0.0, 0.0),
    iterations: int = 2,
) -> ToTalFix:
    """ToTal on bearings brought to the target instant: rotation first, then `iterations` passes of the
    full correction, each using the previous fix for the ranges. The fix refers to the target instant.
    """
    beacons = np.asarray(beacons_xy, dtype=float)
    bearings = compensate_bearings(bearings_rad, odom_at_bearings, odom_at_target)
    fix = triangulate(beacons, bearings, turret_offset_m)
    for _ in range(iterations):
        if not fix.ok:
            break
        bearings = compensate_bearings(
            bearings_rad,
            odom_at_bearings,
            odom_at_target,
            beacons,
            (fix.x, fix.y, fix.heading),
            turret_offset_m,
        )
        fix = triangulate(beacons, bearings, turret_offset_m)
    return fix


def motion_variance_rad2(
    time_offsets_s: ArrayLike,
    ranges_m: ArrayLike,
    speed_mps: float,
    yaw_rate_rad_s: float,
) -> np.ndarray:
    """Variance (rad^2) to add to each bearing for the motion that could not be compensated: the square of the
    worst case |omega| tau + |v| tau / r of a bearing taken tau seconds from the pose's instant at range r
    (speed and yaw rate from the last two poses, no odometry being available)."""
    tau = np.abs(np.asarray(time_offsets_s, dtype=float))
    ranges = np.maximum(np.asarray(ranges_m, dtype=float), 1e-3)
    return (abs(yaw_rate_rad_s) * tau + abs(speed_mps) * tau / ranges) ** 2


# Odometry stamps going back by more than this (s) are a new start (a bag loop, a restarted simulation).
ODOMETRY_TIME_JUMP_S = 1.0


def odometry_buffer(
    span_s: float, max_extrapolation_s: float, time_jump_confirmations: int = 2
) -> PoseBuffer:
    """The odometry poses (odom frame) the compensation reads: a stamp in the past is dropped unless
    `time_jump_confirmations` consecutive ones go back by more than ODOMETRY_TIME_JUMP_S (a bag
    loop, not a stray message: beams_common.intake.time_jumps), which starts the buffer over."""
    jumps = TimeJumpDetector(ODOMETRY_TIME_JUMP_S, time_jump_confirmations)
    return PoseBuffer(span_s, max_extrapolation_s, jumps)
