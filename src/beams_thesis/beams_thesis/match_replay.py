"""The EKF and ToTal on a simulated match (beams_sim.simulated_match), offline: the decoded revolutions'
bearings and ToTal's gated fixes as the nodes would receive them, replayed through a Localiser
(beams_thesis.replay). System-level, so it lives above the three packages it joins."""

import math
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from beams_common.geometry.beacon_map import BeaconMap
from beams_common.geometry.pose2d import Pose2D, interpolate
from beams_ekf.localiser import Localiser
from beams_thesis.replay import PoseEvent, ReplayResult, replay
from beams_thesis.synthetic import BearingEvent
from beams_triangulation.revolution import estimate_revolution

# ToTal's first fix is about this good (thesis table 6.1 scale): the replays start from it
START_SIGMA = (0.01, 0.01, math.radians(1.0))


def bearing_events(
    revolutions: Iterable, variance_rad2: Callable[[int, float], float] | None = None, calibrated: bool = True
) -> list[BearingEvent]:
    """The bearings of decoded revolutions (beams_driver.decoder.DecodedRevolution), arriving when their
    revolution ends; `variance_rad2(beacon_id, angular_window_rad)` replaces the published variance;
    `calibrated` False: no calibration corrected them (the driver's flag)."""
    events = []
    for revolution in revolutions:
        arrival_s = revolution.start_time_s + revolution.period_s
        for b in revolution.bearings:
            variance = b.variance if variance_rad2 is None else variance_rad2(b.beacon_id, b.angular_window)
            variance = float(variance)
            events.append(
                BearingEvent(
                    arrival_s, b.stamp_s, b.beacon_id, b.bearing, variance, b.angular_window, calibrated
                )
            )
    return events


def total_fix_events(
    revolutions: Sequence,
    beacon_map: BeaconMap,
    turret_offset_m: tuple[float, float],
    odometry_times_s: np.ndarray,
    odometry_poses: np.ndarray,
) -> list[PoseEvent]:
    """ToTal's accepted fixes of decoded revolutions as triangulation_node gives them (motion-compensated
    with the odometry, gated), each arriving when its revolution ends."""

    def odometry_at(t: float) -> Pose2D | None:
        k = int(np.searchsorted(odometry_times_s, t, side="right"))
        if not 0 < k < len(odometry_times_s):
            return None
        t0, t1 = odometry_times_s[k - 1], odometry_times_s[k]
        return interpolate(tuple(odometry_poses[k - 1]), tuple(odometry_poses[k]), (t - t0) / (t1 - t0))

    events = []
    for revolution in revolutions:
        bearings = [b.as_bearing() for b in revolution.bearings]
        outcome = estimate_revolution(
            bearings, beacon_map, turret_offset_m=turret_offset_m, odometry_at=odometry_at
        )
        result = outcome.result
        if getattr(result, "accepted", False):
            pose = (result.x, result.y, result.heading)
            arrival_s = revolution.start_time_s + revolution.period_s
            events.append(PoseEvent(arrival_s, outcome.stamp_s, pose, result.covariance))
    return events


def match_odometry(match) -> np.ndarray:
    """(k, 3) odometry poses (odom frame) of a beams_sim.simulated_match.SimulatedMatch."""
    o = match.odometry
    return np.column_stack([o.x_m, o.y_m, o.theta_rad])


def match_fixes(match) -> list[PoseEvent]:
    """ToTal's accepted fixes of a SimulatedMatch (`total_fix_events`)."""
    return total_fix_events(
        match.revolutions,
        match.beacon_map,
        match.turret_offset_m,
        match.odometry.stamp_s,
        match_odometry(match),
    )


def offset_start(match) -> tuple[Pose2D, np.ndarray]:
    """A start pose off the truth by one START_SIGMA in each component (deterministic), its covariance."""
    x, y, theta = match.initial_pose
    return (x + START_SIGMA[0], y - START_SIGMA[1], theta + START_SIGMA[2]), np.diag(np.square(START_SIGMA))


def replay_match(
    localiser: Localiser,
    match,
    initial_pose: Pose2D,
    initial_covariance: np.ndarray,
    fixes: Iterable[PoseEvent] = (),
    calibrated: bool = True,
    variance_rad2: Callable[[int, float], float] | None = None,
) -> ReplayResult:
    """`replay` of a SimulatedMatch: its odometry, its published bearings (`calibrated` False: as an
    uncalibrated driver flags them; `variance_rad2` as in `bearing_events`), ToTal's `fixes`."""
    return replay(
        localiser,
        match.odometry.stamp_s,
        match_odometry(match),
        bearing_events(match.revolutions, variance_rad2, calibrated),
        match.truth_at,
        initial_pose,
        initial_covariance,
        fixes,
    )
