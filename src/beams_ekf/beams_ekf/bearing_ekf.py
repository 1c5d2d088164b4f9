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

Optionally (`odometry_errors`), the state also holds the odometry's systematic errors (k_s, k_theta, h)
of `odometry_errors.OdometryErrorStates`: each prediction then applies the increment they correct, and
the bearings estimate them through the pose's cross-covariance with them.

Optionally (`power_bias`), the state also holds the power bias of uncalibrated bearings
(`power_bias_states.PowerBiasStates`, eq. 7.19 on a Chebyshev basis of the angular window): a bearing the
driver did not correct is predicted as h(x) + f(w), estimated (self-calibration) or, as Schmidt-Kalman
consider parameters, only carried in the covariance (their gain rows zero, the Joseph update).

Optionally (`turret_offset`, `beacons`), the correction of the configured turret offset and of some beacons'
coordinates are states too (`turret_offset_states`, `beacon_states`).

The states past the pose describe the sensor and the odometry, not where the robot is: a re-initialisation
(ToTal's fix after a kidnapping or a lost filter, an operator's pose, a reset) keeps what they learnt, with
their covariance. An uncalibrated bearing whose power bias cannot be modelled yet (the window fit not
ready, `power_bias_states.WindowFit`) updates the pose alone: it carries an unknown bias, and letting it
teach the constants (odometry errors, turret offset, beacons) baked that bias into them, overconfidently
(mean NEES over the first 10 s up to 10.5 on one seed of ten, 4.0 at most without).
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from math import atan2, cos, hypot, isfinite, sin, sqrt

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2

from beams_common.angles import wrap_to_pi
from beams_common.pose2d import Pose2D, compose
from beams_ekf.beacon_states import COORDINATES, BeaconStates
from beams_ekf.odometry_errors import OdometryErrorStates, corrected_increment
from beams_ekf.pose_filter import BearingOutcome, BearingReason, rejected
from beams_ekf.power_bias_states import BASIS_SIZE, PowerBiasStates, WindowFit
from beams_ekf.turret_offset_states import OFFSET_SIZE, TurretOffsetStates


@dataclass(frozen=True)
class ProcessNoise:
    """Odometry error growth, as variances per unit travelled (random-walk model of wheel odometry).

    Along- and cross-track variances grow with the distance (scale error, slip); the heading variance
    with the rotation (wheel-base error) and with the distance (unequal wheel radii, slip). The defaults
    stand for the systematic errors too, as white noise (they are not: see `odometry_errors`);
    `wheel_noise` gives the random part alone, for a filter that estimates the systematic errors.
    """

    translation_m2_per_m: float = 3.0e-5
    rotation_rad2_per_rad: float = 3.0e-5
    rotation_rad2_per_m: float = 3.0e-5
    # floor per prediction, so a filter that only sees still odometry never becomes overconfident
    floor_variance: float = 1.0e-10
    # cross-track variance per metre; None: the same as along the track
    cross_track_m2_per_m: float | None = None

    @classmethod
    def wheel_noise(cls, wheel_variance_m2_per_m: float, wheel_base_m: float) -> "ProcessNoise":
        """The increment's variances when each wheel's distance has a random error of variance
        `wheel_variance_m2_per_m` per metre it rolls (independent wheels), and nothing else: the arc
        length s = (l + r) / 2 gets half of it per metre driven, the turn (r - l) / B gets 2 / B^2 of it
        per metre driven and 1 / B per radian turned on the spot (each wheel rolls B / 2 per radian);
        no cross-track noise (the odometry integrates arcs: wheels do not slide sideways)."""
        if not (wheel_variance_m2_per_m >= 0.0 and wheel_base_m > 0.0):
            raise ValueError(
                f"need a wheel variance >= 0 and a wheel base > 0, got "
                f"{wheel_variance_m2_per_m}, {wheel_base_m}"
            )
        return cls(
            translation_m2_per_m=0.5 * wheel_variance_m2_per_m,
            rotation_rad2_per_rad=wheel_variance_m2_per_m / wheel_base_m,
            rotation_rad2_per_m=2.0 * wheel_variance_m2_per_m / wheel_base_m**2,
            cross_track_m2_per_m=0.0,
        )

    def __post_init__(self) -> None:
        if self.cross_track_m2_per_m is not None and not (
            isfinite(self.cross_track_m2_per_m) and self.cross_track_m2_per_m >= 0.0
        ):
            raise ValueError(
                f"process noise cross_track_m2_per_m must be finite and >= 0, got {self.cross_track_m2_per_m}"
            )
        for name in (
            "translation_m2_per_m",
            "rotation_rad2_per_rad",
            "rotation_rad2_per_m",
            "floor_variance",
        ):
            value = getattr(self, name)
            if not (isfinite(value) and value >= 0.0):
                raise ValueError(f"process noise {name} must be finite and >= 0, got {value}")

    def robot_frame_variances(self, increment: Pose2D) -> tuple[float, float, float]:
        """Variances (along, across, heading) of an odometry increment (dx, dy, dtheta), robot frame."""
        distance_m = hypot(increment[0], increment[1])
        rotation_rad = abs(increment[2])
        translation = self.translation_m2_per_m * distance_m + self.floor_variance
        cross = (
            translation
            if self.cross_track_m2_per_m is None
            else self.cross_track_m2_per_m * distance_m + self.floor_variance
        )
        heading = (
            self.rotation_rad2_per_rad * rotation_rad
            + self.rotation_rad2_per_m * distance_m
            + self.floor_variance
        )
        return translation, cross, heading


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


def bearing_measurement(
    pose: Pose2D, beacon_xy: tuple[float, float], lever: Pose2D
) -> tuple[float, np.ndarray]:
    """h(x) = atan2(yb - ys, xb - xs) - theta - ptheta for a robot at `pose`, the turret at `lever`
    (px, py, ptheta) in its frame, and dh/d(x, y, theta) (3,). Raises ZeroDivisionError when the
    turret stands on the beacon."""
    lx, ly, lth = lever
    theta = pose[2]
    c, s = cos(theta), sin(theta)
    dx = beacon_xy[0] - (pose[0] + c * lx - s * ly)
    dy = beacon_xy[1] - (pose[1] + s * lx + c * ly)
    q = dx * dx + dy * dy
    if q < 1e-12:
        raise ZeroDivisionError("the sensor is on the beacon")
    # d(xs)/d(theta) = -s lx - c ly and d(ys)/d(theta) = c lx - s ly
    d_theta = (dy * (-s * lx - c * ly) - dx * (c * lx - s * ly)) / q - 1.0
    return wrap_to_pi(atan2(dy, dx) - theta - lth), np.array([dy / q, -dx / q, d_theta])


class _OdometryEkf(ExtendedKalmanFilter):
    """filterpy's EKF with the nonlinear odometry composition as its state transition (the states past
    the pose, if any, are constants)."""

    def predict_x(self, u: Pose2D = (0.0, 0.0, 0.0)) -> None:
        pose = compose((float(self.x[0, 0]), float(self.x[1, 0]), float(self.x[2, 0])), u)
        x = self.x.copy()
        x[:3, 0] = pose
        self.x = x


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
        odometry_errors: OdometryErrorStates | None = None,
        power_bias: PowerBiasStates | None = None,
        turret_offset: TurretOffsetStates | None = None,
        beacons: BeaconStates | None = None,
    ) -> None:
        self.beacon_states = beacons
        self.configure(beacons_xy, sensor_offset_m, process_noise or ProcessNoise(), gate_probability)
        self.odometry_errors = odometry_errors
        self.power_bias = power_bias
        self.turret_offset = turret_offset
        # state layout: pose (3), odometry errors (3), power bias (BASIS_SIZE), turret offset correction
        # (OFFSET_SIZE), beacon coordinate corrections (2 per beacon), each but the pose optional
        bias_start = 3 if odometry_errors is None else 6
        offset_start = bias_start + (0 if power_bias is None else BASIS_SIZE)
        beacons_start = offset_start + (0 if turret_offset is None else OFFSET_SIZE)
        self.dim = beacons_start + (0 if beacons is None else beacons.size)
        self._errors = slice(3, bias_start)
        self._bias = slice(bias_start, offset_start)
        self._offset = slice(offset_start, beacons_start)
        self._beacons = slice(beacons_start, self.dim)
        self._ekf = _OdometryEkf(dim_x=self.dim, dim_z=1)
        self._window_fit = WindowFit()
        self._learn_bias = False  # whether the bearing being applied updates the power bias states
        # whether the bearing being applied carries a power bias not modelled yet (it updates the pose alone)
        self._pose_only = False
        self._initialised = False
        # whether the states past the pose hold something learnt (kept across re-initialisations and resets)
        self._learnt = False

    def configure(
        self,
        beacons_xy: Mapping[int, Sequence[float]],
        sensor_offset_m: tuple[float, float],
        process_noise: ProcessNoise,
        gate_probability: float,
    ) -> None:
        """Beacon geometry, process noise and gate; the estimate stays (PoseFilter.configure). ValueError
        when the estimated beacons (`beacon_states`) are not in the map or leave fewer than 3 fixed."""
        states = getattr(self, "beacon_states", None)
        problem = None if states is None else states.problem(int(k) for k in beacons_xy)
        if problem:
            raise ValueError(problem)
        old = getattr(self, "beacons_xy", None)
        self.beacons_xy = {int(k): (float(v[0]), float(v[1])) for k, v in beacons_xy.items()}
        self.sensor_offset_m = (float(sensor_offset_m[0]), float(sensor_offset_m[1]))
        self.process_noise = process_noise
        self.gate = gate_threshold(gate_probability)
        if states is not None and old is not None and self._learnt:
            # a new map: the corrections learnt were relative to the old coordinates
            moved = [i for i in states.beacon_ids if old.get(i) != self.beacons_xy[i]]
            for beacon_id in moved:
                start = self._beacons.start + states.offset_of(beacon_id)
                block = slice(start, start + COORDINATES)
                self._ekf.x[block, 0] = 0.0
                self._ekf.P[block, :] = 0.0
                self._ekf.P[:, block] = 0.0
                self._ekf.P[block, block] = states.prior_sigma_m**2 * np.eye(COORDINATES)

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
        return self._ekf.P[:3, :3].copy()

    @property
    def odometry_error_estimate(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(k_s, k_theta, h) and their 3x3 covariance, or None without those states."""
        if self.odometry_errors is None:
            return None
        return self._ekf.x[self._errors, 0].copy(), self._ekf.P[self._errors, self._errors].copy()

    @property
    def turret_offset_estimate(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The correction (dx, dy) (m) of the configured turret offset and its 2x2 covariance, or None
        without those states."""
        if self.turret_offset is None:
            return None
        return self._ekf.x[self._offset, 0].copy(), self._ekf.P[self._offset, self._offset].copy()

    @property
    def beacon_estimate(self) -> dict[int, tuple[tuple[float, float], np.ndarray]]:
        """{id: ((x, y) learnt (m), its 2x2 covariance)} of the estimated beacons ({} without states)."""
        states = self.beacon_states
        if states is None:
            return {}
        x, p, learnt = self._ekf.x, self._ekf.P, {}
        for beacon_id in states.beacon_ids:
            start = self._beacons.start + states.offset_of(beacon_id)
            block = slice(start, start + COORDINATES)
            configured = self.beacons_xy[beacon_id]
            learnt[beacon_id] = (
                (configured[0] + float(x[start, 0]), configured[1] + float(x[start + 1, 0])),
                p[block, block].copy(),
            )
        return learnt

    @property
    def power_bias_estimate(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(beta_1, beta_2, beta_3) (rad) and their 3x3 covariance, or None without those states."""
        if self.power_bias is None:
            return None
        return self._ekf.x[self._bias, 0].copy(), self._ekf.P[self._bias, self._bias].copy()

    def initialise(self, pose: Pose2D, covariance: np.ndarray) -> None:
        """Start (or restart) from a pose and its 3x3 covariance (ToTal's fix or an operator's pose).

        The states past the pose (odometry errors, power bias, turret offset, beacons) start from their
        prior the first time; afterwards, a restart (after a kidnapping, a lost filter, a reset, a callback
        exception) keeps what the bearings taught them, with their joint covariance (the odometry and the
        sensor did not change), uncorrelated with the new pose.
        """
        covariance = np.asarray(covariance, dtype=float).reshape(3, 3)
        if not (all(isfinite(v) for v in pose) and np.all(np.isfinite(covariance))):
            raise ValueError("initial pose and covariance must be finite")
        if np.any(np.linalg.eigvalsh(0.5 * (covariance + covariance.T)) <= 0.0):
            raise ValueError("initial covariance must be positive definite")
        x, p = np.zeros((self.dim, 1)), np.zeros((self.dim, self.dim))
        x[:3, 0] = (pose[0], pose[1], wrap_to_pi(pose[2]))
        p[:3, :3] = 0.5 * (covariance + covariance.T)
        kept = self._ekf.P[3:, 3:]
        if self._learnt and np.all(np.isfinite(self._ekf.x[3:])) and np.all(np.isfinite(kept)):
            x[3:, 0] = self._ekf.x[3:, 0]
            p[3:, 3:] = self._ekf.P[3:, 3:]
        else:
            for states, block in (
                (self.odometry_errors, self._errors),
                (self.power_bias, self._bias),
                (self.turret_offset, self._offset),
                (self.beacon_states, self._beacons),
            ):
                if states is not None:
                    x[block, 0] = states.prior_mean
                    p[block, block] = states.prior_covariance
        self._ekf.x, self._ekf.P = x, p
        self._initialised = True
        self._learnt = True

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """A copy of (x, P), to come back to with `restore`."""
        return self._ekf.x.copy(), self._ekf.P.copy()

    def restore(self, state: tuple[np.ndarray, np.ndarray]) -> None:
        """Go back to a state given by `state` (to replay a late measurement)."""
        self._ekf.x = state[0].copy()
        self._ekf.P = state[1].copy()

    def reset(self, forget_learnt: bool = False) -> None:
        """Forget the pose estimate; the filter waits for `initialise`, which keeps what the states past
        the pose learnt (the odometry and the sensor did not change). `forget_learnt`: forget that too,
        and the window fit (the data start again: a bag played in a loop)."""
        self._initialised = False
        if forget_learnt:
            self._learnt = False
            self._window_fit = WindowFit()

    def predict(self, increment: Pose2D) -> None:
        """Move by a robot-frame odometry increment (dx, dy, dtheta); P <- F P F' + G M G' (first order)."""
        # the increment is expressed in the robot frame at the prior heading
        theta = float(self._ekf.x[2, 0])
        c, s = cos(theta), sin(theta)
        moved = increment
        self._ekf.F = np.eye(self.dim)
        self._ekf.Q = np.zeros((self.dim, self.dim))
        if self.odometry_errors is not None:
            # the true motion is the reported one corrected by the error states (odometry_errors)
            moved, d_errors, _ = corrected_increment(increment, self._ekf.x[self._errors, 0])
            rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            self._ekf.F[:3, self._errors] = rotation @ d_errors
            walk = self.odometry_errors.walk_variance_per_m * hypot(increment[0], increment[1])
            self._ekf.Q[self._errors, self._errors] = walk * np.eye(3)
        dx, dy = moved[0], moved[1]
        # Jacobian of compose(x, u) with respect to the pose
        self._ekf.F[:3, :3] = [[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]]
        # the robot-frame noise M rotated into the map frame by G = d compose / d u
        m_along, m_across, m_heading = self.process_noise.robot_frame_variances(increment)
        cc, ss, cs = c * c, s * s, c * s
        self._ekf.Q[:3, :3] = [
            [cc * m_along + ss * m_across, cs * (m_along - m_across), 0.0],
            [cs * (m_along - m_across), ss * m_along + cc * m_across, 0.0],
            [0.0, 0.0, m_heading],
        ]
        self._ekf.predict(u=moved)

    def add_time_noise(self, position_variance_m2: float, heading_variance_rad2: float) -> None:
        """Inflate the covariance (e.g. for an odometry gap during which the robot may have slipped)."""
        added = np.zeros(self.dim)
        added[:3] = (position_variance_m2, position_variance_m2, heading_variance_rad2)
        self._ekf.P = self._ekf.P + np.diag(added)

    def predicted_bearing(
        self, beacon_id: int, lever: Pose2D | None = None, uncorrected_window_rad: float = 0.0
    ) -> tuple[float, np.ndarray]:
        """h(x) and its 1 x dim Jacobian for one beacon, the turret at `lever` in the robot frame; plus
        the power bias f(w) (eq. 7.17) of a bearing no calibration corrected, at its window (0: none)."""
        lever = lever if lever is not None else (self.sensor_offset_m[0], self.sensor_offset_m[1], 0.0)
        x = self._ekf.x
        if self.turret_offset is not None:
            # the offset's correction, in base_link, turned into the lever's frame (the robot then)
            lc, ls = cos(lever[2]), sin(lever[2])
            dx, dy = float(x[self._offset][0, 0]), float(x[self._offset][1, 0])
            lever = (lever[0] + lc * dx - ls * dy, lever[1] + ls * dx + lc * dy, lever[2])
        beacon_xy = self.beacons_xy[beacon_id]
        in_block = None if self.beacon_states is None else self.beacon_states.offset_of(beacon_id)
        if in_block is not None:
            at = self._beacons.start + in_block
            beacon_xy = (beacon_xy[0] + float(x[at, 0]), beacon_xy[1] + float(x[at + 1, 0]))
        try:
            expected, d_pose = bearing_measurement(
                (float(x[0, 0]), float(x[1, 0]), float(x[2, 0])), beacon_xy, lever
            )
        except ZeroDivisionError:
            raise ZeroDivisionError(f"the sensor is on beacon {beacon_id}") from None
        jacobian = np.zeros((1, self.dim))
        jacobian[0, :3] = d_pose
        if in_block is not None:
            # the bearing depends on the beacon minus the turret: dh/d(beacon) = -dh/d(robot position)
            jacobian[0, at : at + COORDINATES] = -d_pose[:2]
        if self.turret_offset is not None:
            # dh/d(lever x, y) is dh/d(turret) = d_pose[:2] turned by the heading, then by the lever's angle
            c, s = cos(float(x[2, 0])), sin(float(x[2, 0]))
            d_lever = np.array([d_pose[0] * c + d_pose[1] * s, -d_pose[0] * s + d_pose[1] * c])
            lc, ls = cos(lever[2]), sin(lever[2])
            jacobian[0, self._offset] = d_lever @ np.array([[lc, -ls], [ls, lc]])
        self._learn_bias = self._pose_only = False
        if self.power_bias is not None and uncorrected_window_rad > 0.0:
            turret = compose(self.pose, lever)
            distance_m = hypot(beacon_xy[0] - turret[0], beacon_xy[1] - turret[1])
            window = self._window_fit.window_rad(beacon_id, distance_m, uncorrected_window_rad)
            # until the window fit is ready, the noisy measured window only carries the bias's uncertainty
            self._learn_bias = window is not None and self.power_bias.estimate
            self._pose_only = window is None
            basis = self.power_bias.basis(uncorrected_window_rad if window is None else window)
            jacobian[0, self._bias] = basis
            expected = wrap_to_pi(expected + float(basis @ x[self._bias, 0]))
        return expected, jacobian

    def update_bearing(
        self,
        beacon_id: int,
        bearing_rad: float,
        variance_rad2: float,
        lever: Pose2D | None = None,
        uncorrected_window_rad: float = 0.0,
    ) -> BearingOutcome:
        """Update with one bearing (sensor frame) of variance R, gated at the chi-square threshold;
        `uncorrected_window_rad` > 0: the bearing's window when no calibration corrected it (its power
        bias is then modelled)."""
        if not self._initialised:
            return rejected(BearingReason.UNINITIALISED)
        if beacon_id not in self.beacons_xy:
            return rejected(BearingReason.UNKNOWN_BEACON)
        if not (isfinite(bearing_rad) and isfinite(variance_rad2) and variance_rad2 > 0.0):
            return rejected(BearingReason.INVALID_MEASUREMENT)
        try:
            expected, jacobian = self.predicted_bearing(beacon_id, lever, uncorrected_window_rad)
        except ZeroDivisionError:
            return rejected(BearingReason.SENSOR_ON_BEACON)
        residual = wrap_to_pi(bearing_rad - expected)
        innovation_variance = float((jacobian @ self._ekf.P @ jacobian.T)[0, 0]) + variance_rad2
        nis = residual * residual / innovation_variance
        if nis > self.gate:
            return BearingOutcome(False, nis, residual, BearingReason.GATED)
        self._joseph_update(jacobian, variance_rad2, residual, innovation_variance)
        self._ekf.x[2, 0] = wrap_to_pi(float(self._ekf.x[2, 0]))
        # rounding drifts P from symmetric: after a wide prior (sigma 4 m) by more than the 1e-9 the
        # published-estimate invariant allows (else every later estimate is refused)
        self._ekf.P = 0.5 * (self._ekf.P + self._ekf.P.T)
        return BearingOutcome(True, nis, residual)

    def _joseph_update(
        self, jacobian: np.ndarray, variance_rad2: float, residual: float, innovation_variance: float
    ) -> None:
        """x += K r, P = (I - K H) P (I - K H)' + K R K' (filterpy's form), K = P H' / S; the gain rows
        of consider parameters (and of the bias states for a bearing that cannot teach them; of every
        state past the pose for a bearing whose bias is not modelled yet) are zero (Schmidt-Kalman): the
        Joseph form stays right for that gain."""
        p = self._ekf.P
        gain = (p @ jacobian.T) / innovation_variance
        if self.power_bias is not None and not self._learn_bias:
            gain[self._bias] = 0.0
        if self._pose_only:
            gain[3:] = 0.0
        reduce = np.eye(self.dim) - gain @ jacobian
        self._ekf.x = self._ekf.x + gain * residual
        self._ekf.P = reduce @ p @ reduce.T + variance_rad2 * (gain @ gain.T)

    def position_sigma_m(self) -> float:
        """Square root of the trace of the position covariance (m)."""
        p = self._ekf.P
        return sqrt(max(float(p[0, 0] + p[1, 1]), 0.0))
