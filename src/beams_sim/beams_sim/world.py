"""The simulated robot: a differential-drive robot on the Eurobot table, and its drifting wheel odometry.

Frames (REP-105): map (the 3 m x 2 m table, beacons of EUROBOT_BEACON_MAP on its border), odom (the robot's
pose at t = 0 unless told otherwise) and base_link. `EurobotTrajectory` is the ground truth: by default a 90 s
match (thesis section 2.1) along a uniform cubic B-spline through random control points (continuous curvature,
so a continuous yaw rate) within the speed and acceleration limits, from rest to rest, the robot's footprint
on the table. `OdometrySimulator` turns it into what wheel encoders report, exact on arcs, so that with no
drift the odometry follows the truth to a fraction of a millimetre."""

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from beams_common.geometry.angles import wrap_to_pi
from beams_sim.parameters import ODOMETRY_DRIFT, SIM_WORLD_PARAMETERS

TABLE_LENGTH_M = 3.0
TABLE_WIDTH_M = 2.0
MATCH_DURATION_S = SIM_WORLD_PARAMETERS.default("duration_s")
Pose2D = tuple[float, float, float]
START_POSE: Pose2D = tuple(SIM_WORLD_PARAMETERS.default("start_pose"))

# Uniform cubic B-spline: position on a segment is [u^3 u^2 u 1] @ _BSPLINE @ [Q0 Q1 Q2 Q3].
_BSPLINE = np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 0, 3, 0], [1, 4, 1, 0]], dtype=float) / 6.0
_SAMPLES_PER_SEGMENT = 1024


@dataclass(frozen=True)
class MotionLimits:
    """What the robot may do: speeds, accelerations and the footprint that must stay on the table."""

    max_speed_mps: float = SIM_WORLD_PARAMETERS.default("max_speed_mps")
    max_yaw_rate_radps: float = SIM_WORLD_PARAMETERS.default("max_yaw_rate_radps")
    max_acceleration_mps2: float = 0.6
    max_lateral_acceleration_mps2: float = 1.0
    robot_radius_m: float = SIM_WORLD_PARAMETERS.default("robot_radius_m")

    def __post_init__(self) -> None:
        SIM_WORLD_PARAMETERS.require(
            max_speed_mps=self.max_speed_mps,
            max_yaw_rate_radps=self.max_yaw_rate_radps,
            robot_radius_m=self.robot_radius_m,
        )
        accelerations = (self.max_acceleration_mps2, self.max_lateral_acceleration_mps2)
        if not all(v > 0.0 and math.isfinite(v) for v in accelerations):
            raise ValueError(f"motion limits must be positive and finite, got {self}")


class EurobotTrajectory:
    """The robot's true motion in the map frame, sampled finely and interpolated: pose_at(t) and twist_at(t)
    (forward speed, yaw rate); before 0 and after duration_s the robot stands at its first / last pose."""

    def __init__(
        self,
        times_s: np.ndarray,
        xy: np.ndarray,
        heading_rad: np.ndarray,
        distance_m: np.ndarray,
        speed_mps: np.ndarray,
        yaw_rate_radps: np.ndarray,
    ) -> None:
        """Uniformly spaced samples (times_s[0] = 0); heading unwrapped, distance_m the arc length so far."""
        times_s = np.asarray(times_s, dtype=float)
        if times_s.size < 2 or times_s[0] != 0.0 or not times_s[1] > 0.0:
            raise ValueError("trajectory samples need at least two increasing instants starting at 0")
        self._step_s = float(times_s[1] - times_s[0])
        if not np.allclose(np.diff(times_s), self._step_s, rtol=1e-9, atol=0.0):
            raise ValueError("trajectory samples must be uniformly spaced in time")
        self.duration_s = float(times_s[-1])
        self._columns = np.column_stack([xy, heading_rad, distance_m, speed_mps, yaw_rate_radps])
        self._columns.setflags(write=False)
        self._last = self._columns.shape[0] - 1

    # ---- constructors ----

    @classmethod
    def random(
        cls,
        seed: int = 0,
        duration_s: float = MATCH_DURATION_S,
        limits: MotionLimits | None = None,
        start_pose: Pose2D = START_POSE,
        sample_rate_hz: float = 1000.0,
    ) -> "EurobotTrajectory":
        """A match through random control points drawn from the seed (deterministic)."""
        limits = limits or MotionLimits()
        if not _inside_table(np.array([start_pose[:2]]), limits.robot_radius_m):
            radius = limits.robot_radius_m
            raise ValueError(f"start pose {start_pose} is off the table for a robot of radius {radius} m")
        rng = np.random.default_rng(seed)
        for _attempt in range(100):
            points = _random_control_points(rng, start_pose, duration_s, limits)
            trajectory = cls.through_waypoints(points, duration_s, limits, sample_rate_hz, check_table=False)
            if trajectory.stays_on_table(limits.robot_radius_m):
                return trajectory
        raise RuntimeError(f"seed {seed}: no path on the table in 100 draws (limits {limits})")

    @classmethod
    def through_waypoints(
        cls,
        control_points_xy: Sequence[Sequence[float]] | np.ndarray,
        duration_s: float = MATCH_DURATION_S,
        limits: MotionLimits | None = None,
        sample_rate_hz: float = 1000.0,
        check_table: bool = True,
    ) -> "EurobotTrajectory":
        """The B-spline of these control points (it starts on the first, heading to the second), driven
        as fast as the limits allow from rest, stopping on the path when duration_s is reached (or at
        its end, then standing still)."""
        limits = limits or MotionLimits()
        points = np.asarray(control_points_xy, dtype=float)
        if points.ndim != 2 or points.shape[1] != 2 or points.shape[0] < 3 or not np.all(np.isfinite(points)):
            raise ValueError(f"waypoints: need 3 or more finite (x, y) points, got shape {points.shape}")
        if not duration_s > 0.0:
            raise ValueError(f"duration_s must be positive, got {duration_s}")
        path = _SplinePath(points)
        profile = _time_profile(path.arc_m, path.curvature, limits, duration_s)
        trajectory = cls._sample(path, profile, duration_s, sample_rate_hz)
        if check_table and not trajectory.stays_on_table(limits.robot_radius_m):
            raise ValueError(
                f"waypoints: the path leaves the table (robot radius {limits.robot_radius_m} m); "
                "keep control points further from the border"
            )
        return trajectory

    @classmethod
    def static(cls, pose: Pose2D, duration_s: float = MATCH_DURATION_S) -> "EurobotTrajectory":
        """A robot standing still at pose."""
        x, y, theta = (float(v) for v in pose)
        times = np.array([0.0, float(duration_s)])
        still = np.zeros(2)
        return cls(times, np.array([[x, y], [x, y]]), np.full(2, theta), still, still, still)

    @classmethod
    def _sample(
        cls, path: "_SplinePath", profile: "_SpeedProfile", duration_s: float, rate_hz: float
    ) -> "EurobotTrajectory":
        """Resample the timed path on a uniform grid, evaluating the spline exactly at each instant."""
        grid = np.linspace(0.0, duration_s, max(2, round(duration_s * rate_hz) + 1))
        distance, speed = profile.at(grid)
        u = np.interp(distance, path.arc_m, path.u)
        xy, tangent, curvature = path.evaluate(u)
        heading = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
        return cls(grid, xy, heading, distance, speed, speed * curvature)

    # ---- queries ----

    def pose_at(self, t: float) -> Pose2D:
        """True pose (x, y, theta) in the map frame at time t (theta in (-pi, pi])."""
        x, y, heading = self._row(t, 0, 3)
        return (x, y, math.pi - (math.pi - heading) % (2.0 * math.pi))

    def twist_at(self, t: float) -> tuple[float, float]:
        """True (forward speed m/s, yaw rate rad/s) at time t."""
        v, omega = self._row(t, 4, 6)
        return (v, omega)

    def distance_at(self, t: float) -> float:
        """Arc length (m) travelled since t = 0."""
        return self._row(t, 3, 4)[0]

    def heading_unwrapped_at(self, t: float) -> float:
        """Continuous heading (rad), counting whole turns (the wheels' rotation integral)."""
        return self._row(t, 2, 3)[0]

    def states_at(self, times_s: np.ndarray) -> np.ndarray:
        """(n, 6) array: x, y, unwrapped heading, distance, speed, yaw rate at each instant (vectorised)."""
        t = np.clip(np.asarray(times_s, dtype=float), 0.0, self.duration_s)
        position = t / self._step_s
        index = np.minimum(position.astype(np.int64), self._last - 1)
        fraction = (position - index)[:, None]
        below, above = self._columns[index], self._columns[index + 1]
        return below + fraction * (above - below)

    def poses_at(self, times_s: np.ndarray) -> np.ndarray:
        """(n, 3) poses (x, y, theta in (-pi, pi]) at each instant (vectorised)."""
        states = self.states_at(times_s)
        return np.column_stack([states[:, :2], wrap_to_pi(states[:, 2])])

    def stays_on_table(self, robot_radius_m: float) -> bool:
        """True when the robot's disc stays on the 3 m x 2 m table at every sample."""
        return _inside_table(self._columns[:, :2], robot_radius_m)

    def _row(self, t: float, first: int, end: int) -> list[float]:
        """Columns first..end-1 interpolated at one instant (scalar path: called per edge by the sensor
        simulator)."""
        position = min(max(t, 0.0), self.duration_s) / self._step_s
        index = min(int(position), self._last - 1)
        fraction = position - index
        # the two rows as floats: numpy arithmetic on 6-element rows costs more than the loop (a list of
        # every row kept instead held about 90 MiB for sim_world_node's 300 s trajectory)
        below, above = self._columns[index : index + 2, first:end].tolist()
        return [b + fraction * (a - b) for b, a in zip(below, above, strict=True)]


def _inside_table(xy: np.ndarray, robot_radius_m: float) -> bool:
    """True when discs of this radius centred on every point (n, 2) lie on the table."""
    low = np.array([robot_radius_m, robot_radius_m])
    high = np.array([TABLE_LENGTH_M, TABLE_WIDTH_M]) - robot_radius_m
    return bool(np.all(xy >= low) and np.all(xy <= high))


class _SplinePath:
    """A uniform cubic B-spline sampled finely: parameter u, positions, arc length, curvature."""

    def __init__(self, control_points: np.ndarray) -> None:
        # A phantom point mirrored behind the first makes the curve start exactly on it, towards the second.
        phantom = 2.0 * control_points[0] - control_points[1]
        self._points = np.vstack([phantom, control_points, control_points[-1]])
        self.segments = self._points.shape[0] - 3
        self.u = np.linspace(0.0, self.segments, self.segments * _SAMPLES_PER_SEGMENT + 1)
        _, tangent, self.curvature = self.evaluate(self.u)
        speed = np.hypot(tangent[:, 0], tangent[:, 1])
        self.arc_m = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(self.u))])

    def evaluate(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (n, 2), derivative d/du (n, 2) and signed curvature (n,) at parameters u."""
        segment = np.minimum(np.floor(u).astype(np.int64), self.segments - 1)
        local = (u - segment)[:, None]
        # each segment's polynomial once (rows: u^3, u^2, u, 1), then looked up per sample: a 600 s match
        # at 1 kHz is 600 000 samples, and an einsum over all of them made sim_world_node's start 2.8 s
        # (segments, 4, 2): the four control points of each segment
        windows = np.stack([self._points[k : k + self.segments] for k in range(4)], axis=1)
        per_segment = np.einsum("ij,sjd->sid", _BSPLINE, windows)
        a, b, c, d = (per_segment[segment, k] for k in range(4))
        position = ((a * local + b) * local + c) * local + d
        first = (3.0 * a * local + 2.0 * b) * local + c
        second = 6.0 * a * local + 2.0 * b
        cross = first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0]
        norm = np.maximum(np.hypot(first[:, 0], first[:, 1]), 1e-12)
        return position, first, cross / norm**3


@dataclass(frozen=True)
class _SpeedProfile:
    """Arc length, instant and speed at the path's samples, up to the stopping point."""

    arc_m: np.ndarray
    time_s: np.ndarray
    speed_mps: np.ndarray

    def at(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(arc length, speed) at instants, with the constant acceleration of each interval (exact)."""
        t = np.clip(times_s, 0.0, self.time_s[-1])
        index = np.clip(np.searchsorted(self.time_s, t, side="right") - 1, 0, self.time_s.size - 2)
        tau = t - self.time_s[index]
        v0 = self.speed_mps[index]
        acceleration = (self.speed_mps[index + 1] - v0) / np.diff(self.time_s)[index]
        travelled = tau * (v0 + 0.5 * acceleration * tau)
        distance = np.minimum(self.arc_m[index] + travelled, self.arc_m[index + 1])
        return distance, np.where(times_s >= self.time_s[-1], 0.0, v0 + acceleration * tau)


def _time_profile(
    arc_m: np.ndarray, curvature: np.ndarray, limits: MotionLimits, duration_s: float
) -> _SpeedProfile:
    """Speed along the path within the limits, from rest, braking to rest within duration_s: the forward and
    backward passes of the time-optimal profile in closed form on v^2, v^2(s) <= min_j (limit_j^2 + 2 a |s -
    s_j|)."""
    a = limits.max_acceleration_mps2
    bend = np.maximum(np.abs(curvature), 1e-9)
    limit = np.minimum.reduce(
        [
            np.full_like(arc_m, limits.max_speed_mps),
            limits.max_yaw_rate_radps / bend,
            np.sqrt(limits.max_lateral_acceleration_mps2 / bend),
        ]
    )
    limit_sq = limit**2
    limit_sq[0] = 0.0  # start at rest
    limit_sq[-1] = 0.0  # the path's end is a stop
    forward = 2.0 * a * arc_m + np.minimum.accumulate(limit_sq - 2.0 * a * arc_m)
    backward = -2.0 * a * arc_m + np.minimum.accumulate((limit_sq + 2.0 * a * arc_m)[::-1])[::-1]
    profile_sq = np.minimum(forward, backward)

    def timed(stop_index: int) -> _SpeedProfile:
        """Time along the profile when braking to rest at sample stop_index."""
        s = arc_m[: stop_index + 1]
        speed = np.sqrt(np.maximum(np.minimum(profile_sq[: stop_index + 1], 2.0 * a * (s[-1] - s)), 0.0))
        mean_speed = 0.5 * (speed[1:] + speed[:-1])
        # Constant acceleration between samples: dt = ds / mean speed (exact), guarded at rest.
        dt = np.diff(s) / np.maximum(mean_speed, 1e-9)
        return _SpeedProfile(s, np.concatenate([[0.0], np.cumsum(dt)]), speed)

    low, high = 1, arc_m.size - 1
    if timed(high).time_s[-1] <= duration_s:
        return timed(high)
    while high - low > 1:  # the latest stopping sample reached within duration_s
        middle = (low + high) // 2
        low, high = (middle, high) if timed(middle).time_s[-1] <= duration_s else (low, middle)
    return timed(low)


def _random_control_points(
    rng: np.random.Generator, start_pose: Pose2D, duration_s: float, limits: MotionLimits
) -> np.ndarray:
    """Control points inside the table's safe area, each 0.35-0.8 m from the last, turning at most 110 deg."""
    margin = limits.robot_radius_m + 0.1
    low, high = np.array([margin, margin]), np.array([TABLE_LENGTH_M - margin, TABLE_WIDTH_M - margin])
    x, y, heading = start_pose
    points = [np.array([x, y], dtype=float)]
    # Enough path for the match even at full speed, plus the turns' slow-downs.
    needed_m = limits.max_speed_mps * duration_s + 2.0
    length = 0.0
    while length < needed_m:
        for _try in range(200):
            turn = rng.uniform(-np.radians(110.0), np.radians(110.0)) if len(points) > 1 else 0.0
            step = rng.uniform(0.35, 0.8)
            candidate = points[-1] + step * np.array([np.cos(heading + turn), np.sin(heading + turn)])
            if np.all(candidate >= low) and np.all(candidate <= high):
                break
        else:
            # Cornered: head for the table's centre.
            candidate = points[-1] + 0.5 * (np.array([TABLE_LENGTH_M / 2, TABLE_WIDTH_M / 2]) - points[-1])
        heading = math.atan2(candidate[1] - points[-1][1], candidate[0] - points[-1][0])
        length += float(np.hypot(*(candidate - points[-1])))
        points.append(candidate)
    return np.array(points)


# ---- odometry ----


@dataclass(frozen=True)
class OdometryDrift:
    """Systematic and random errors of wheel odometry (defaults: a small robot, roughly calibrated): each
    wheel's reported / travelled distance - 1, nominal / true wheel base - 1, each wheel's per-sample slip as
    a fraction of its travel (half-normal: a slipping wheel turns more than the ground moves), and the random
    walk of each wheel's distance."""

    left_scale_error: float = ODOMETRY_DRIFT["left_scale_error"][0]
    right_scale_error: float = ODOMETRY_DRIFT["right_scale_error"][0]
    wheel_base_error: float = ODOMETRY_DRIFT["wheel_base_error"][0]
    slip_std: float = ODOMETRY_DRIFT["slip_std"][0]
    noise_m_per_sqrt_m: float = ODOMETRY_DRIFT["noise_m_per_sqrt_m"][0]

    def __post_init__(self) -> None:
        SIM_WORLD_PARAMETERS.require(**{f"odometry_{name}": getattr(self, name) for name in ODOMETRY_DRIFT})

    @classmethod
    def none(cls) -> "OdometryDrift":
        """Perfect odometry (checks, and the reference the drift is measured against)."""
        return cls(0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class PoseTwistSamples:
    """Poses and twists at successive instants: odometry (pose in odom, measured twist in base_link) or
    ground truth (pose in map, true twist in base_link)."""

    stamp_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    theta_rad: np.ndarray
    speed_mps: np.ndarray
    yaw_rate_radps: np.ndarray

    def pose(self, index: int) -> Pose2D:
        return (float(self.x_m[index]), float(self.y_m[index]), float(self.theta_rad[index]))


class OdometrySimulator:
    """Wheel odometry of a differential-drive robot following a trajectory, with drift (deterministic):
    `advance(t)` step by step and `run(rate_hz)` at once give the same samples."""

    def __init__(
        self,
        trajectory: EurobotTrajectory,
        drift: OdometryDrift | None = None,
        seed: int = 0,
        wheel_base_m: float = SIM_WORLD_PARAMETERS.default("wheel_base_m"),
        initial_pose_odom: Pose2D = (0.0, 0.0, 0.0),
    ) -> None:
        SIM_WORLD_PARAMETERS.require(wheel_base_m=wheel_base_m)
        self.trajectory = trajectory
        self.drift = drift or OdometryDrift()
        self.wheel_base_m = float(wheel_base_m)
        self._rng = np.random.default_rng(seed)
        self._t = 0.0
        self._pose = np.array(initial_pose_odom, dtype=float)
        self._pose[2] = wrap_to_pi(self._pose[2])

    @property
    def pose(self) -> Pose2D:
        """The latest odometry pose in the odom frame."""
        return (float(self._pose[0]), float(self._pose[1]), float(self._pose[2]))

    def advance(self, t: float) -> PoseTwistSamples:
        """Integrate the odometry up to instant t (>= the previous one); one sample."""
        if t < self._t:
            raise ValueError(f"odometry time went backwards: {t} after {self._t}")
        return self._integrate(np.array([self._t, t]))

    def run(self, rate_hz: float = 50.0, until_s: float | None = None) -> PoseTwistSamples:
        """Samples at rate_hz from the current instant to until_s (default: the trajectory's end)."""
        end = self.trajectory.duration_s if until_s is None else until_s
        count = math.floor((end - self._t) * rate_hz + 1e-9)
        return self._integrate(self._t + np.arange(count + 1) / rate_hz)

    def _integrate(self, times: np.ndarray) -> PoseTwistSamples:
        """Samples at times[1:], integrating from times[0] (the current state)."""
        states = self.trajectory.states_at(times)
        distance, turn = np.diff(states[:, 3]), np.diff(states[:, 2])
        step_s = np.diff(times)
        reported_distance, reported_turn = self._wheel_measurements(distance, turn)
        heading_before = self._pose[2] + np.concatenate([[0.0], np.cumsum(reported_turn)[:-1]])
        # Exact on an arc: the chord is 2 sin(dtheta/2)/dtheta of the arc, along the mid heading.
        chord = reported_distance * np.sinc(reported_turn / (2.0 * np.pi))
        middle = heading_before + 0.5 * reported_turn
        x = self._pose[0] + np.cumsum(chord * np.cos(middle))
        y = self._pose[1] + np.cumsum(chord * np.sin(middle))
        theta = self._pose[2] + np.cumsum(reported_turn)
        if times.size > 1:
            self._pose = np.array([x[-1], y[-1], wrap_to_pi(theta[-1])])
            self._t = float(times[-1])
        with np.errstate(divide="ignore", invalid="ignore"):
            speed = np.where(step_s > 0, reported_distance / step_s, 0.0)
            yaw_rate = np.where(step_s > 0, reported_turn / step_s, 0.0)
        return PoseTwistSamples(times[1:], x, y, np.asarray(wrap_to_pi(theta)), speed, yaw_rate)

    def _wheel_measurements(self, distance: np.ndarray, turn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(reported distance, reported heading change) per step, from the true ones."""
        drift = self.drift
        true_base = self.wheel_base_m / (1.0 + drift.wheel_base_error)
        wheels = np.column_stack([distance - 0.5 * true_base * turn, distance + 0.5 * true_base * turn])
        # One (n, 4) draw per call: the same stream whether stepping one sample or many at a time.
        draws = self._rng.standard_normal((distance.size, 4))
        travel = np.abs(wheels)
        slip = drift.slip_std * np.abs(draws[:, :2])
        noise = drift.noise_m_per_sqrt_m * np.sqrt(travel) * draws[:, 2:]
        scale = 1.0 + np.array([drift.left_scale_error, drift.right_scale_error])
        reported = wheels * scale * (1.0 + slip) + noise
        left, right = reported[:, 0], reported[:, 1]
        return 0.5 * (left + right), (right - left) / self.wheel_base_m


def trajectory_of(values: Mapping[str, Any]) -> EurobotTrajectory:
    """The match the validated parameters describe; ValueError or RuntimeError when it cannot be built
    (waypoints off the table, a start pose too close to the border)."""
    limits = MotionLimits(
        **{name: values[name] for name in ("max_speed_mps", "max_yaw_rate_radps", "robot_radius_m")}
    )
    duration_s = values["duration_s"]
    if values["trajectory"] == "static":
        return EurobotTrajectory.static(values["static_pose"], duration_s)
    if values["trajectory"] == "waypoints":
        points = list(zip(values["waypoints_x"], values["waypoints_y"], strict=True))
        return EurobotTrajectory.through_waypoints(points, duration_s, limits)
    start_pose = tuple(map(float, values["start_pose"]))
    return EurobotTrajectory.random(values["trajectory_seed"], duration_s, limits, start_pose)


def drift_of(values: Mapping[str, Any]) -> OdometryDrift:
    """The odometry errors the validated parameters describe."""
    return OdometryDrift(**{name: values[f"odometry_{name}"] for name in ODOMETRY_DRIFT})
