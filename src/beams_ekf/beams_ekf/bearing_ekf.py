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

The state is a list of blocks (`state_blocks`, docs/state_blocks.md): the pose (`PoseStates`), then the
sensor's and the odometry's, which a re-initialisation keeps (ToTal's fix after a kidnapping, a reset).
"""

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from math import atan2, cos, hypot, isfinite, sin
from operator import attrgetter
from typing import Any

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from beams_common.config.parameters import ParameterSpec, ParameterTable
from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.pose2d import Pose2D, compose
from beams_ekf.consistency import chi2_quantile
from beams_ekf.pose_filter import BearingOutcome, BearingReason, rejected
from beams_ekf.state_blocks import BearingPart, Sighting, StateBlock


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

    def robot_frame_variances(self, increment: Pose2D) -> tuple[float, float, float]:
        """Variances (along, across, heading) of an odometry increment (dx, dy, dtheta), robot frame."""
        distance_m, floor = hypot(increment[0], increment[1]), self.floor_variance
        translation, rate = self.translation_m2_per_m * distance_m + floor, self.cross_track_m2_per_m
        cross = translation if rate is None else rate * distance_m + floor
        heading = self.rotation_rad2_per_rad * abs(increment[2]) + self.rotation_rad2_per_m * distance_m
        heading += floor
        return translation, cross, heading


def gate_threshold(probability: float) -> float:
    """Chi-square (1 dof) quantile that a consistent innovation stays under with `probability`."""
    return chi2_quantile(probability, 1)


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


# The wheels' random error, variance per metre rolled, of the simulated robot (sim_world's OdometryDrift:
# noise 1 mm/sqrt(m) is 1.0e-6; the random part of the half-normal slip, 0.005^2 (1 - 2/pi) of a step's
# squared length, adds at most 0.09e-6 at the 1 cm steps of 0.5 m/s and 50 Hz), and its wheel base (m):
# the default process noise, for a filter that estimates the odometry's systematic errors.
WHEEL_VARIANCE_M2_PER_M = 1.1e-6
WHEEL_BASE_M = 0.3
_WHEEL_NOISE = ProcessNoise.wheel_noise(WHEEL_VARIANCE_M2_PER_M, WHEEL_BASE_M)
# variances per unit travelled: from none to far more than any wheel
_VARIANCE_RATE = {"minimum": 0.0, "maximum": 1.0e3, "runtime": True}
# the filter's parameters, the pose's process noise and the gate: changeable while the filter runs (they
# enter the next prediction and the next bearing's gate)
BEARING_EKF_SPECS = ParameterTable(
    "ekf_node",
    (
        ParameterSpec(
            "translation_variance_m2_per_m",
            _WHEEL_NOISE.translation_m2_per_m,
            "Odometry position variance per metre travelled.",
            **_VARIANCE_RATE,
        ),
        ParameterSpec(
            "rotation_variance_rad2_per_rad",
            _WHEEL_NOISE.rotation_rad2_per_rad,
            "Odometry heading variance per radian turned.",
            **_VARIANCE_RATE,
        ),
        ParameterSpec(
            "rotation_variance_rad2_per_m",
            _WHEEL_NOISE.rotation_rad2_per_m,
            "Odometry heading variance per metre travelled.",
            **_VARIANCE_RATE,
        ),
        ParameterSpec(
            "cross_track_variance_m2_per_m",
            _WHEEL_NOISE.cross_track_m2_per_m,
            "Odometry cross-track variance per metre travelled.",
            **_VARIANCE_RATE,
        ),
        ParameterSpec(
            "gate_probability",
            0.999,
            "Chi-square (1 dof) probability of the per-bearing validation gate.",
            minimum=0.5,
            maximum=0.999999,
            runtime=True,
        ),
    ),
)


def process_noise_of(values: Mapping[str, Any]) -> ProcessNoise:
    """The process noise of ekf_node's validated parameter values."""
    return ProcessNoise(
        translation_m2_per_m=float(values["translation_variance_m2_per_m"]),
        rotation_rad2_per_rad=float(values["rotation_variance_rad2_per_rad"]),
        rotation_rad2_per_m=float(values["rotation_variance_rad2_per_m"]),
        cross_track_m2_per_m=float(values["cross_track_variance_m2_per_m"]),
    )


@dataclass(frozen=True)
class PoseStates(StateBlock):
    """The robot pose (x, y, theta) in the map frame, moved by the odometry (`BearingEkf.predict`)."""

    noise: ProcessNoise
    size = 3
    learnt = False

    def process_noise(self, increment: Pose2D, mean: np.ndarray) -> np.ndarray:
        """The robot-frame noise M of an increment rotated into the map frame by G = d compose / d u."""
        m_along, m_across, m_heading = self.noise.robot_frame_variances(increment)
        c, s = cos(float(mean[2])), sin(float(mean[2]))
        cc, ss, cs = c * c, s * s, c * s
        xx, yy, xy = cc * m_along + ss * m_across, ss * m_along + cc * m_across, cs * (m_along - m_across)
        return np.array([[xx, xy, 0.0], [xy, yy, 0.0], [0.0, 0.0, m_heading]])

    def bearing(self, mean: np.ndarray, sighting: Sighting, memory: Any) -> BearingPart:
        return BearingPart(sighting.d_pose)


# a block's odometry hooks (StateBlock's do nothing)
_HOOKS = attrgetter("corrected_increment", "process_noise")


class BearingEkf:
    """EKF over the pose (x, y, theta) in the map frame and the `blocks` after it (None: skipped);
    beacons identified by id, so no data association. The first PoseFilter (pose_filter.py)."""

    def __init__(
        self,
        beacons_xy: Mapping[int, Sequence[float]],
        sensor_offset_m: tuple[float, float] = (0.0, 0.0),
        process_noise: ProcessNoise | None = None,
        gate_probability: float = BEARING_EKF_SPECS.default("gate_probability"),
        blocks: Iterable[StateBlock | None] = (),
    ) -> None:
        blocks = [PoseStates(process_noise or ProcessNoise()), *(b for b in blocks if b is not None)]
        ends = np.cumsum([block.size for block in blocks])
        self._parts = [(b, slice(int(end - b.size), int(end))) for b, end in zip(blocks, ends, strict=True)]
        self._pose = self._parts[0][1]
        self._heading = self._pose.stop - 1  # theta, the pose's last state
        self.dim = int(ends[-1])
        self._kept = np.array([i for b, p in self._parts if b.learnt for i in range(p.start, p.stop)], int)
        self._ekf = ExtendedKalmanFilter(dim_x=self.dim, dim_z=1)  # x and P; predict and update below
        # the pose's rows of the prediction's Jacobian F (F is the identity in the other rows)
        self._motion_rows, self._rotation, self._identity = np.eye(3, self.dim), np.eye(3), np.eye(self.dim)
        # the blocks past the pose that correct the odometry's increment or add to its noise
        self._moving = [(b, p) for b, p in self._parts[1:] if _HOOKS(type(b)) != _HOOKS(StateBlock)]
        self._memory = [block.new_memory() for block in blocks]
        self._initialised = False
        self.excluded_beacons: set[int] = set()
        # whether the learnt blocks hold something learnt (kept across re-initialisations and resets)
        self._learnt = False
        self.configure(beacons_xy, sensor_offset_m, blocks[0].noise, gate_probability)

    def configure(
        self,
        beacons_xy: Mapping[int, Sequence[float]],
        sensor_offset_m: tuple[float, float],
        process_noise: ProcessNoise,
        gate_probability: float,
    ) -> None:
        """Beacon geometry, process noise and gate; the estimate stays (PoseFilter.configure). ValueError
        when a block cannot run with the map (estimated beacons not in it or leaving fewer than 3 fixed)."""
        for block, _ in self._parts:
            problem = block.problem(int(k) for k in beacons_xy)
            if problem:
                raise ValueError(problem)
        old = getattr(self, "beacons_xy", None)
        self.beacons_xy = {int(k): (float(v[0]), float(v[1])) for k, v in beacons_xy.items()}
        self.sensor_offset_m = (float(sensor_offset_m[0]), float(sensor_offset_m[1]))
        self._parts[0] = (PoseStates(process_noise), self._pose)
        self.gate = gate_threshold(gate_probability)
        for block, part in self._parts if old is not None and self._learnt else ():
            stale = block.stale(old, self.beacons_xy)
            if not stale:
                continue
            at, x, p = np.arange(part.start, part.stop)[stale], self._ekf.x, self._ekf.P
            x[at, 0] = block.prior_mean[stale]
            p[at, :], p[:, at] = 0.0, 0.0
            p[np.ix_(at, at)] = block.prior_covariance[np.ix_(stale, stale)]

    @property
    def initialised(self) -> bool:
        """True once a pose has been given."""
        return self._initialised

    @property
    def pose(self) -> Pose2D:
        """Current estimate (x, y, theta) in the map frame."""
        x, y, theta = self._ekf.x[self._pose, 0].tolist()
        return (x, y, theta)

    @property
    def covariance(self) -> np.ndarray:
        """3x3 covariance of (x, y, theta) (a copy)."""
        return self._ekf.P[self._pose, self._pose].copy()

    def block(self, kind: type[StateBlock]) -> Any:
        """The filter's block of that kind, or None."""
        return next((block for block, _ in self._parts if isinstance(block, kind)), None)

    def estimate(self, kind: type[StateBlock]) -> tuple[np.ndarray, np.ndarray] | None:
        """The states of the block of that kind and their covariance (copies), or None without it."""
        part = next((part for block, part in self._parts if isinstance(block, kind)), None)
        return None if part is None else (self._ekf.x[part, 0].copy(), self._ekf.P[part, part].copy())

    def initialise(self, pose: Pose2D, covariance: np.ndarray) -> None:
        """Start (or restart) from a pose and its 3x3 covariance (ToTal's fix or an operator's pose).

        The learnt blocks start from their prior the first time; afterwards, a restart (after a kidnapping,
        a lost filter, a reset, a callback exception) keeps what the bearings taught them, with their joint
        covariance (the odometry and the sensor did not change), uncorrelated with the new pose.
        """
        covariance = np.asarray(covariance, dtype=float).reshape(3, 3)
        if not (all(isfinite(v) for v in pose) and np.all(np.isfinite(covariance))):
            raise ValueError("initial pose and covariance must be finite")
        if np.any(np.linalg.eigvalsh(0.5 * (covariance + covariance.T)) <= 0.0):
            raise ValueError("initial covariance must be positive definite")
        x, p, kept = np.zeros((self.dim, 1)), np.zeros((self.dim, self.dim)), np.ix_(self._kept, self._kept)
        learnt = self._ekf.x[self._kept, 0], self._ekf.P[kept]
        x[self._pose, 0] = (pose[0], pose[1], wrap_to_pi(pose[2]))
        p[self._pose, self._pose] = 0.5 * (covariance + covariance.T)
        keep = self._learnt and all(np.all(np.isfinite(v)) for v in learnt)
        if keep:
            x[self._kept, 0], p[kept] = learnt
        for block, part in self._parts[1:]:
            if not (keep and block.learnt):
                x[part, 0] = block.prior_mean
                p[part, part] = block.prior_covariance
        self._ekf.x, self._ekf.P = x, p
        self._initialised = True
        self._learnt = True

    def learnt_states(self) -> tuple[list[str], np.ndarray, np.ndarray] | None:
        """The learnt blocks (each its repr), their states and joint covariance (copies); None before
        anything was learnt (or since `reset(forget_learnt=True)`)."""
        if not self._learnt:
            return None
        blocks = [repr(block) for block, _ in self._parts if block.learnt]
        return blocks, self._ekf.x[self._kept, 0].copy(), self._ekf.P[np.ix_(self._kept, self._kept)].copy()

    def resume_learnt(self, blocks: list[str], mean: np.ndarray, covariance: np.ndarray) -> None:
        """Take learnt states back (ekf_node's checkpoint), kept by the next `initialise`; ValueError when
        the blocks are not this filter's (`learnt_states`' repr) or the covariance is no covariance."""
        own = [repr(block) for block, _ in self._parts if block.learnt]
        if blocks != own:
            raise ValueError(f"learnt by other state blocks: {blocks}, the filter's are {own}")
        covariance = np.asarray(covariance, float)
        if (
            np.any(np.abs(covariance - covariance.T) > 1e-12)
            or np.linalg.eigvalsh(covariance).min(initial=0.0) < -1e-12
        ):
            raise ValueError("the learnt states' covariance is not symmetric positive semi-definite")
        self._ekf.x[self._kept, 0] = mean
        self._ekf.P[np.ix_(self._kept, self._kept)] = covariance
        self._learnt = True

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """A copy of (x, P), to come back to with `restore`."""
        return self._ekf.x.copy(), self._ekf.P.copy()

    def restore(self, state: tuple[np.ndarray, np.ndarray]) -> None:
        """Go back to a state given by `state` (to replay a late measurement)."""
        self._ekf.x = state[0].copy()
        self._ekf.P = state[1].copy()

    def reset(self, forget_learnt: bool = False) -> None:
        """Forget the pose estimate; the filter waits for `initialise`, which keeps what the learnt blocks
        learnt (the odometry and the sensor did not change). `forget_learnt`: forget that too, and what
        the blocks remember of the bearings (the data start again: a bag played in a loop)."""
        self._initialised = False
        if forget_learnt:
            self._learnt = False
            self._memory = [block.new_memory() for block, _ in self._parts]

    def predict(self, increment: Pose2D) -> None:
        """Move by a robot-frame odometry increment (dx, dy, dtheta); P <- F P F' + Q (first order). F is
        the identity but in the pose's rows A (d compose / d (pose, the states correcting the increment)),
        so only the pose's rows and columns change: A P there, its transpose (P symmetric), A P A'."""
        x, p, a, rotation, pose = self._ekf.x, self._ekf.P, self._motion_rows, self._rotation, self._pose
        # the increment is expressed in the robot frame at the prior heading
        px, py, theta = x[pose, 0].tolist()
        c, s = cos(theta), sin(theta)
        rotation[0, 0], rotation[0, 1], rotation[1, 0], rotation[1, 1] = c, -s, s, c
        moved, noises = increment, []
        for block, part in self._moving:
            # the true motion is the reported one corrected by the blocks (odometry_errors)
            moved, d_moved = block.corrected_increment(moved, x[part, 0])
            a[:, part] = 0.0 if d_moved is None else rotation.dot(d_moved)
            noises.append((part, block.process_noise(increment, x[part, 0])))
        a[0, 2], a[1, 2] = -s * moved[0] - c * moved[1], c * moved[0] - s * moved[1]
        rows = a.dot(p)
        p[pose, :], p[:, pose] = rows, rows.T
        p[pose, pose] = rows.dot(a.T) + self._parts[0][0].process_noise(increment, x[pose, 0])
        for part, noise in noises:
            if noise is not None:
                p[part, part] += noise
        x[pose, 0] = compose((px, py, theta), moved)

    def add_time_noise(self, position_variance_m2: float, heading_variance_rad2: float) -> None:
        """Inflate the covariance (e.g. for an odometry gap during which the robot may have slipped)."""
        position, heading = position_variance_m2, heading_variance_rad2
        self._ekf.P[self._pose, self._pose] += np.diag((position, position, heading))

    def predicted_bearing(
        self, beacon_id: int, lever: Pose2D | None = None, uncorrected_window_rad: float = 0.0
    ) -> tuple[float, np.ndarray]:
        """h(x) and its 1 x dim Jacobian for one beacon, the turret at `lever` in the robot frame; plus
        the power bias f(w) (eq. 7.17) of a bearing no calibration corrected, at its window (0: none).
        Which states the bearing leaves alone (their gain zero) is kept for `update_bearing`."""
        lever = lever if lever is not None else (self.sensor_offset_m[0], self.sensor_offset_m[1], 0.0)
        x = self._ekf.x
        sighting = Sighting(beacon_id, self.pose, lever, self.beacons_xy[beacon_id], uncorrected_window_rad)
        for block, part in self._parts:
            block.shift(x[part, 0], sighting)
        try:
            expected, sighting.d_pose = bearing_measurement(sighting.pose, sighting.beacon_xy, sighting.lever)
        except ZeroDivisionError:
            raise ZeroDivisionError(f"the sensor is on beacon {beacon_id}") from None
        jacobian, learning = np.zeros((1, self.dim)), []
        for (block, part), memory in zip(self._parts, self._memory, strict=True):
            jacobian[0, part], shift, learns = block.bearing(x[part, 0], sighting, memory)
            learning.append(learns)
            if shift is not None:
                expected = wrap_to_pi(expected + shift)
        # once every block has seen the bearing: pose_only freezes every learnt block
        judged = zip(self._parts, learning, strict=True)
        self._frozen = [p for (b, p), learns in judged if not learns or (sighting.pose_only and b.learnt)]
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
        if beacon_id in self.excluded_beacons:
            return BearingOutcome(False, nis, residual, BearingReason.EXCLUDED)
        if nis > self.gate:
            return BearingOutcome(False, nis, residual, BearingReason.GATED)
        gain = self._joseph_update(jacobian, variance_rad2, residual, innovation_variance, self._frozen)
        self._ekf.x[self._heading, 0] = wrap_to_pi(float(self._ekf.x[self._heading, 0]))
        # rounding drifts P from symmetric: after a wide prior (sigma 4 m) by more than the 1e-9 the
        # published-estimate invariant allows (else every later estimate is refused)
        self._ekf.P = 0.5 * (self._ekf.P + self._ekf.P.T)
        return BearingOutcome(
            True,
            nis,
            residual,
            pose_gain=gain[self._pose, 0],
            innovation_variance=innovation_variance,
            pose_jacobian=jacobian[0, self._pose],
        )

    def _joseph_update(
        self,
        jacobian: np.ndarray,
        variance_rad2: float,
        residual: float,
        innovation_variance: float,
        frozen: list[slice],
    ) -> np.ndarray:
        """x += K r, P = (I - K H) P (I - K H)' + K R K' (filterpy's form), K = P H' / S; the gain rows
        of the `frozen` states (consider parameters; the power bias for a bearing that cannot teach it;
        every learnt block for a bearing whose bias is not modelled yet) are zero (Schmidt-Kalman): the
        Joseph form stays right for that gain. Returns K."""
        p = self._ekf.P
        gain = (p @ jacobian.T) / innovation_variance
        for part in frozen:
            gain[part] = 0.0
        reduce = self._identity - gain @ jacobian
        self._ekf.x = self._ekf.x + gain * residual
        self._ekf.P = reduce @ p @ reduce.T + variance_rad2 * (gain @ gain.T)
        return gain
