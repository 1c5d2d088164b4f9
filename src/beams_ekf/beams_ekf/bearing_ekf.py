"""Extended Kalman filter fusing odometry increments with single BeAMS bearings (thesis ch. 8, fig. 8.1).

State: the robot pose (x, y, theta) in the map frame. Prediction: the robot-frame increment between
two odometry poses, with a process noise that grows with the distance and the rotation travelled.
Update: one bearing at a time, measured by the turret whose centre sits at `sensor_offset_m` in
base_link (thesis ch. 7, the turret offset (dx, dy)):

    h(x) = atan2(yb - ys, xb - xs) - theta,  (xs, ys) = (x, y) + Rot(theta) * offset

with R the variance the driver published (exact angular-window model of section 4.2.3, or the bound
p0*phi0^2/6 of theorem 3.1), the innovation wrapped to (-pi, pi] and gated on its Mahalanobis
distance (chi-square with one degree of freedom).

A bearing stamped between two states of the filter is applied at the earlier one, the turret at the
pose the interpolated odometry gives it at the stamp, expressed in that state's robot frame: an
effective "lever" pose (px, py, ptheta) that the same measurement model handles (see `turret_pose`).
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from math import atan2, cos, hypot, isfinite, sin, sqrt

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2

from beams_common.angles import wrap_to_pi
from beams_common.pose2d import Pose2D, compose
from beams_ekf.pose_filter import BearingOutcome


@dataclass(frozen=True)
class ProcessNoise:
    """Odometry error growth, as variances per unit travelled (random-walk model of wheel odometry).

    Along- and cross-track variances grow with the distance (scale error, slip); the heading variance
    with the rotation (wheel-base error) and with the distance (unequal wheel radii, slip).
    """

    translation_m2_per_m: float = 3.0e-5
    rotation_rad2_per_rad: float = 3.0e-5
    rotation_rad2_per_m: float = 3.0e-5
    # floor per prediction, so a filter that only sees still odometry never becomes overconfident
    floor_variance: float = 1.0e-10

    def __post_init__(self) -> None:
        for name in ("translation_m2_per_m", "rotation_rad2_per_rad", "rotation_rad2_per_m",
                     "floor_variance"):
            value = getattr(self, name)
            if not (isfinite(value) and value >= 0.0):
                raise ValueError(f"process noise {name} must be finite and >= 0, got {value}")

    def robot_frame_variances(self, increment: Pose2D) -> tuple[float, float, float]:
        """Variances (along, across, heading) of an odometry increment (dx, dy, dtheta), robot frame."""
        distance_m = hypot(increment[0], increment[1])
        rotation_rad = abs(increment[2])
        translation = self.translation_m2_per_m * distance_m + self.floor_variance
        heading = (self.rotation_rad2_per_rad * rotation_rad + self.rotation_rad2_per_m * distance_m
                   + self.floor_variance)
        return translation, translation, heading


def gate_threshold(probability: float) -> float:
    """Chi-square (1 dof) quantile that a consistent innovation stays under with `probability`."""
    if not 0.0 < probability < 1.0:
        raise ValueError(f"gate probability must be in (0, 1), got {probability}")
    return float(chi2.ppf(probability, df=1))


def turret_pose(robot_pose: Pose2D, sensor_offset_m: tuple[float, float]) -> Pose2D:
    """Pose of the turret (its zero reference along the robot's x axis) for a robot pose.

    With `robot_pose` the robot at a bearing's stamp expressed in the filter's robot frame, this is the
    "lever" the measurement model takes (the robot moved since the bearing was taken).
    """
    return compose(robot_pose, (sensor_offset_m[0], sensor_offset_m[1], 0.0))


class _OdometryEkf(ExtendedKalmanFilter):
    """filterpy's EKF with the nonlinear odometry composition as its state transition."""

    def predict_x(self, u: Pose2D = (0.0, 0.0, 0.0)) -> None:
        pose = compose((float(self.x[0, 0]), float(self.x[1, 0]), float(self.x[2, 0])), u)
        self.x = np.array([[pose[0]], [pose[1]], [pose[2]]])


class BearingEkf:
    """EKF over (x, y, theta) in the map frame; beacons identified by id, so no data association.

    The first PoseFilter (pose_filter.py).
    """

    def __init__(
        self,
        beacons_xy: Mapping[int, Sequence[float]],
        sensor_offset_m: tuple[float, float] = (0.0, 0.0),
        process_noise: ProcessNoise | None = None,
        gate_probability: float = 0.999,
    ) -> None:
        self.configure(beacons_xy, sensor_offset_m, process_noise or ProcessNoise(), gate_probability)
        self._ekf = _OdometryEkf(dim_x=3, dim_z=1)
        self._initialised = False

    def configure(self, beacons_xy: Mapping[int, Sequence[float]], sensor_offset_m: tuple[float, float],
                  process_noise: ProcessNoise, gate_probability: float) -> None:
        """Beacon geometry, process noise and gate; the estimate stays (PoseFilter.configure)."""
        self.beacons_xy = {int(k): (float(v[0]), float(v[1])) for k, v in beacons_xy.items()}
        self.sensor_offset_m = (float(sensor_offset_m[0]), float(sensor_offset_m[1]))
        self.process_noise = process_noise
        self.gate = gate_threshold(gate_probability)

    @property
    def initialised(self) -> bool:
        """True once a pose has been given."""
        return self._initialised

    @property
    def pose(self) -> Pose2D:
        """Current estimate (x, y, theta) in the map frame."""
        x = self._ekf.x
        return (float(x[0, 0]), float(x[1, 0]), float(x[2, 0]))

    @property
    def covariance(self) -> np.ndarray:
        """3x3 covariance of (x, y, theta) (a copy)."""
        return self._ekf.P.copy()

    def initialise(self, pose: Pose2D, covariance: np.ndarray) -> None:
        """Start (or restart) from a pose and its 3x3 covariance (ToTal's fix or an operator's pose)."""
        covariance = np.asarray(covariance, dtype=float).reshape(3, 3)
        if not (all(isfinite(v) for v in pose) and np.all(np.isfinite(covariance))):
            raise ValueError("initial pose and covariance must be finite")
        if np.any(np.linalg.eigvalsh(0.5 * (covariance + covariance.T)) <= 0.0):
            raise ValueError("initial covariance must be positive definite")
        self._ekf.x = np.array([[pose[0]], [pose[1]], [wrap_to_pi(pose[2])]])
        self._ekf.P = 0.5 * (covariance + covariance.T)
        self._initialised = True

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """A copy of (x, P), to come back to with `restore`."""
        return self._ekf.x.copy(), self._ekf.P.copy()

    def restore(self, state: tuple[np.ndarray, np.ndarray]) -> None:
        """Go back to a state given by `state` (to replay a late measurement)."""
        self._ekf.x = state[0].copy()
        self._ekf.P = state[1].copy()

    def reset(self) -> None:
        """Forget the estimate; the filter waits for `initialise`."""
        self._initialised = False

    def predict(self, increment: Pose2D) -> None:
        """Move by a robot-frame odometry increment (dx, dy, dtheta); P <- F P F' + G M G' (first order)."""
        # the increment is expressed in the robot frame at the prior heading
        theta = float(self._ekf.x[2, 0])
        c, s = cos(theta), sin(theta)
        dx, dy = increment[0], increment[1]
        # Jacobian of compose(x, u) with respect to the state x
        self._ekf.F = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
        # the robot-frame noise M rotated into the map frame by G = d compose / d u
        m_along, m_across, m_heading = self.process_noise.robot_frame_variances(increment)
        cc, ss, cs = c * c, s * s, c * s
        self._ekf.Q = np.array([
            [cc * m_along + ss * m_across, cs * (m_along - m_across), 0.0],
            [cs * (m_along - m_across), ss * m_along + cc * m_across, 0.0],
            [0.0, 0.0, m_heading],
        ])
        self._ekf.predict(u=increment)

    def add_time_noise(self, position_variance_m2: float, heading_variance_rad2: float) -> None:
        """Inflate the covariance (e.g. for an odometry gap during which the robot may have slipped)."""
        added = np.diag([position_variance_m2, position_variance_m2, heading_variance_rad2])
        self._ekf.P = self._ekf.P + added

    def predicted_bearing(self, beacon_id: int, lever: Pose2D | None = None) -> tuple[float, np.ndarray]:
        """h(x) and its 1x3 Jacobian for one beacon, the turret at `lever` in the robot frame."""
        xb, yb = self.beacons_xy[beacon_id]
        lx, ly, lth = lever if lever is not None else (self.sensor_offset_m[0], self.sensor_offset_m[1], 0.0)
        x = self._ekf.x
        theta = float(x[2, 0])
        c, s = cos(theta), sin(theta)
        dx = xb - (float(x[0, 0]) + c * lx - s * ly)
        dy = yb - (float(x[1, 0]) + s * lx + c * ly)
        q = dx * dx + dy * dy
        if q < 1e-12:
            raise ZeroDivisionError(f"the sensor is on beacon {beacon_id}")
        # d(xs)/d(theta) = -s lx - c ly and d(ys)/d(theta) = c lx - s ly
        d_theta = (dy * (-s * lx - c * ly) - dx * (c * lx - s * ly)) / q - 1.0
        jacobian = np.array([[dy / q, -dx / q, d_theta]])
        return wrap_to_pi(atan2(dy, dx) - theta - lth), jacobian

    def update_bearing(
        self, beacon_id: int, bearing_rad: float, variance_rad2: float, lever: Pose2D | None = None
    ) -> BearingOutcome:
        """Update with one bearing (sensor frame) of variance R, gated at the chi-square threshold."""
        if not self._initialised:
            return BearingOutcome(False, float("nan"), float("nan"), "uninitialised")
        if beacon_id not in self.beacons_xy:
            return BearingOutcome(False, float("nan"), float("nan"), "unknown beacon")
        if not (isfinite(bearing_rad) and isfinite(variance_rad2) and variance_rad2 > 0.0):
            return BearingOutcome(False, float("nan"), float("nan"), "invalid measurement")
        try:
            expected, jacobian = self.predicted_bearing(beacon_id, lever)
        except ZeroDivisionError:
            return BearingOutcome(False, float("nan"), float("nan"), "sensor on beacon")
        residual = wrap_to_pi(bearing_rad - expected)
        innovation_variance = float((jacobian @ self._ekf.P @ jacobian.T)[0, 0]) + variance_rad2
        nis = residual * residual / innovation_variance
        if nis > self.gate:
            return BearingOutcome(False, nis, residual, "gated")
        # the innovation is already wrapped, so filterpy's residual only has to return it
        self._ekf.update(
            np.array([bearing_rad]),
            HJacobian=lambda _x: jacobian,
            Hx=lambda _x: expected,
            R=np.array([[variance_rad2]]),
            residual=lambda _z, _hx: np.array([[residual]]),
        )
        self._ekf.x[2, 0] = wrap_to_pi(float(self._ekf.x[2, 0]))
        return BearingOutcome(True, nis, residual)

    def position_sigma_m(self) -> float:
        """Square root of the trace of the position covariance (m)."""
        p = self._ekf.P
        return sqrt(max(float(p[0, 0] + p[1, 1]), 0.0))
