"""A small synthetic match for the EKF's own tests: a smooth trajectory, drifting wheel odometry and Gaussian
bearings at the instants a 10 Hz turret points at each beacon, each of exactly the variance it publishes
(where `beams_sim.simulated_match` runs the edge-level pipeline)."""

from dataclasses import dataclass
from math import atan2, cos, hypot, pi, sin

import numpy as np

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
from beams_common.geometry.pose2d import Pose2D, between, compose


@dataclass(frozen=True)
class BearingEvent:
    """One bearing as the driver publishes it: it arrives at `arrival_s`, refers to `stamp_s`."""

    arrival_s: float
    stamp_s: float
    beacon_id: int
    bearing_rad: float
    variance_rad2: float
    # the angular window (rad, 0: unknown) and whether a calibration corrected the bearing
    angular_window_rad: float = 0.0
    calibrated: bool = True


@dataclass(frozen=True)
class SyntheticMatch:
    """Ground truth (map frame), odometry (odom frame) and bearings, with arrival times."""

    times_s: np.ndarray  # (n,) common clock of truth and odometry
    truth: np.ndarray  # (n, 3) map poses
    odometry: np.ndarray  # (n, 3) odom poses, (0, 0, 0) at the start
    bearings: list[BearingEvent]

    def truth_at(self, stamp_s: float) -> Pose2D:
        """Ground-truth pose at any instant (linear interpolation)."""
        x = float(np.interp(stamp_s, self.times_s, self.truth[:, 0]))
        y = float(np.interp(stamp_s, self.times_s, self.truth[:, 1]))
        heading = float(np.interp(stamp_s, self.times_s, np.unwrap(self.truth[:, 2])))
        return (x, y, wrap_to_pi(heading))


def lissajous_pose(t_s: float) -> Pose2D:
    """A smooth figure on the table (speed <= 0.45 m/s), heading along the velocity (differential drive)."""
    x = 1.5 + 1.1 * sin(0.33 * t_s)
    y = 1.0 + 0.7 * sin(0.47 * t_s + 0.6)
    vx, vy = 1.1 * 0.33 * cos(0.33 * t_s), 0.7 * 0.47 * cos(0.47 * t_s + 0.6)
    return (x, y, atan2(vy, vx))


def _sensor_bearing(pose: Pose2D, beacon_xy: tuple[float, float], offset_m: tuple[float, float]) -> float:
    """Bearing of a beacon from the turret at `offset_m` on the robot, in the sensor frame."""
    sensor = compose(pose, (offset_m[0], offset_m[1], 0.0))
    return wrap_to_pi(atan2(beacon_xy[1] - sensor[1], beacon_xy[0] - sensor[0]) - pose[2])


def _pointing_time(revolution_start_s: float, period_s: float, bearing_at) -> float:
    """Instant in [start, start + period) when the turret angle 2 pi (t - start) / T meets the bearing."""
    t = revolution_start_s
    for _ in range(3):  # fixed point: the bearing changes little during a revolution
        t = revolution_start_s + period_s * (bearing_at(t) % (2.0 * pi)) / (2.0 * pi)
    return t


def synthetic_match(
    duration_s: float = 30.0,
    seed: int = 1,
    *,
    bearing_sigma_rad: float = 3.0e-4,
    sensor_offset_m: tuple[float, float] = (0.0, 0.0),
    odometry_rate_hz: float = 50.0,
    revolution_period_s: float = 0.1,
    scale_error: float = 0.02,
    rotation_error: float = 0.01,
    odometry_noise_m: float = 3.0e-3,
    odometry_noise_rad: float = 5.0e-3,
    beacons_xy: dict[int, tuple[float, float]] | None = None,
) -> SyntheticMatch:
    """The synthetic match (deterministic from the seed)."""
    beacons_xy = beacons_xy or EUROBOT_BEACON_MAP.as_dict()
    rng = np.random.default_rng(seed)
    times_s = np.arange(0.0, duration_s, 1.0 / odometry_rate_hz)
    truth = np.array([lissajous_pose(t) for t in times_s])
    # true increments corrupted by a scale error, a rotation (wheel-base) error and a noise whose variance
    # grows with the distance (odometry_noise_m and odometry_noise_rad: standard deviations per sqrt(m))
    odometry = np.zeros_like(truth)
    pose: Pose2D = (0.0, 0.0, 0.0)
    for k in range(1, len(truth)):
        dx, dy, dtheta = between(tuple(truth[k - 1]), tuple(truth[k]))
        root_distance = hypot(dx, dy) ** 0.5
        step = (
            (1.0 + scale_error) * dx + odometry_noise_m * root_distance * rng.standard_normal(),
            (1.0 + scale_error) * dy + odometry_noise_m * root_distance * rng.standard_normal(),
            (1.0 + rotation_error) * dtheta + odometry_noise_rad * root_distance * rng.standard_normal(),
        )
        pose = compose(pose, step)
        odometry[k] = pose
    bearings = []
    for start_s in np.arange(0.0, duration_s - revolution_period_s, revolution_period_s):
        for beacon_id, xy in beacons_xy.items():
            stamp_s = _pointing_time(
                float(start_s),
                revolution_period_s,
                lambda t, xy=xy: _sensor_bearing(lissajous_pose(t), xy, sensor_offset_m),
            )
            measured = _sensor_bearing(lissajous_pose(stamp_s), xy, sensor_offset_m)
            bearings.append(
                BearingEvent(
                    float(start_s) + revolution_period_s,
                    stamp_s,
                    beacon_id,
                    wrap_to_pi(measured + bearing_sigma_rad * rng.standard_normal()),
                    bearing_sigma_rad**2,
                )
            )
    return SyntheticMatch(times_s, truth, odometry, bearings)
