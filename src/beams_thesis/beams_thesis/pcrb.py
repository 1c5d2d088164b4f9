"""Posterior Cramer-Rao bound (PCRB) of the pose along a known true trajectory: Tichavsky, Muravchik and
Nehorai's (1998) Fisher information recursion with additive Gaussian process noise on the true trajectory,

    J_{k+1} = (Q + F J_k^-1 F')^-1 + I_z,   I_z = sum over the bearings of H' H / R,

which holds for a singular Q too (no cross-track wheel noise). Bearings are taken as Gaussian of their true
variance: the OOK error (chapter 4) is not, and carries more information, so its bound may be lower still.
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from beams_common.geometry.pose2d import Pose2D, between
from beams_ekf.bearing_ekf import bearing_measurement, turret_pose
from beams_ekf.odometry_errors import (
    OdometryErrorStates,
    arc_increment,
    arc_of_increment,
    corrected_increment,
)


def information_step(
    information: np.ndarray, d11: np.ndarray, d12: np.ndarray, d22: np.ndarray
) -> np.ndarray:
    """J_{k+1} = D22 - D21 (J_k + D11)^-1 D12 (Tichavsky et al. 1998, eq. 21), D21 = D12'."""
    return d22 - d12.T @ np.linalg.solve(information + d11, d12)


def gaussian_information_step(
    information: np.ndarray, transition: np.ndarray, process_covariance: np.ndarray, measurement: np.ndarray
) -> np.ndarray:
    """The recursion for additive Gaussian process noise: (Q + F J^-1 F')^-1 + I_z (see the module
    docstring); Q may be singular, J_k must be invertible."""
    predicted = process_covariance + transition @ np.linalg.solve(information, transition.T)
    return np.linalg.inv(0.5 * (predicted + predicted.T)) + measurement


def bearing_information(jacobian: np.ndarray, variance_rad2: float) -> np.ndarray:
    """Fisher information H' H / R of one bearing of variance R and Jacobian H."""
    h = np.asarray(jacobian, dtype=float).reshape(1, -1)
    return h.T @ h / variance_rad2


@dataclass(frozen=True)
class WheelNoiseModel:
    """The random errors of sim_world's OdometrySimulator, per step and per wheel of travel w: the
    encoder noise (variance noise^2 |w|) and the random part of the half-normal slip (variance
    slip_std^2 (1 - 2/pi) w^2; its mean is a systematic scale error)."""

    noise_m_per_sqrt_m: float = 0.001
    slip_std: float = 0.005
    wheel_base_m: float = 0.3

    def arc_covariance(self, increment: Pose2D) -> np.ndarray:
        """2x2 covariance of the reported arc (s, Delta) of one odometry step."""
        s, turn = arc_of_increment(increment)
        wheels = np.array([s - 0.5 * self.wheel_base_m * turn, s + 0.5 * self.wheel_base_m * turn])
        left, right = (
            self.noise_m_per_sqrt_m**2 * np.abs(wheels) + self.slip_std**2 * (1.0 - 2.0 / np.pi) * wheels**2
        )
        base = self.wheel_base_m
        mixed = 0.5 * (right - left) / base
        return np.array([[0.25 * (left + right), mixed], [mixed, (left + right) / base**2]])


def _rotation(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def odometry_step(
    pose: Pose2D, increment: Pose2D, wheel_noise: WheelNoiseModel, with_errors: bool
) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of one odometry step from the true pose by the (reported ~ true) increment: pose block
    d compose / d pose, the error states' block from `corrected_increment` at their nominal values
    (they differ from the truth by ~1 %), the wheels' noise mapped through the arc."""
    dim = 6 if with_errors else 3
    rotation = _rotation(pose[2])
    transition, covariance = np.eye(dim), np.zeros((dim, dim))
    s, turn = arc_of_increment(increment)
    _, d_arc = arc_increment(s, turn)
    moved = increment
    if with_errors:
        moved, d_errors, d_arc = corrected_increment(increment, OdometryErrorStates().prior_mean)
        transition[:3, 3:] = rotation @ d_errors
    c, sn = np.cos(pose[2]), np.sin(pose[2])
    transition[0, 2] = -sn * moved[0] - c * moved[1]
    transition[1, 2] = c * moved[0] - sn * moved[1]
    noise_map = rotation @ d_arc
    covariance[:3, :3] = noise_map @ wheel_noise.arc_covariance(increment) @ noise_map.T
    return transition, covariance


@dataclass(frozen=True)
class PcrbTrack:
    """The bound at each odometry instant: times (s) and the (k, n, n) inverse information matrices."""

    times_s: np.ndarray
    bounds: np.ndarray

    def at(self, times_s: np.ndarray) -> np.ndarray:
        """Bounds (k, n, n) at the odometry instants given (each must be one of `times_s`)."""
        index = np.searchsorted(self.times_s, times_s)
        if np.any(index >= len(self.times_s)) or not np.allclose(self.times_s[index], times_s):
            raise ValueError("the bound exists only at the odometry instants")
        return self.bounds[index]


def trajectory_pcrb(
    times_s: np.ndarray,
    true_poses: np.ndarray,
    reported_increments: np.ndarray,
    bearings: Sequence[tuple[float, int, float]],
    beacons_xy: Mapping[int, Sequence[float]],
    true_pose_at: Callable[[float], Pose2D],
    turret_offset_m: tuple[float, float],
    initial_covariance: np.ndarray,
    wheel_noise: WheelNoiseModel,
    odometry_errors: OdometryErrorStates | None = None,
) -> PcrbTrack:
    """The PCRB at each odometry instant of a trajectory: times_s (k,), true_poses (k, 3), the odometry's
    robot-frame increments (k - 1, 3), bearings (stamp s, beacon id, true variance rad^2), each applied at the
    odometry sample before its stamp as the EKF applies it, and the first pose's 3x3 prior (error states, if
    any, get theirs)."""
    with_errors = odometry_errors is not None
    dim = 6 if with_errors else 3
    prior = np.zeros((dim, dim))
    prior[:3, :3] = initial_covariance
    if with_errors:
        prior[3:, 3:] = odometry_errors.prior_covariance
    # each bearing's information, attached to the odometry instant at or before its stamp
    attached: dict[int, np.ndarray] = {}
    for stamp_s, beacon_id, variance_rad2 in bearings:
        k = int(np.searchsorted(times_s, stamp_s, side="right")) - 1
        if k < 0:
            continue
        base = tuple(true_poses[k])
        lever = turret_pose(between(base, true_pose_at(stamp_s)), turret_offset_m)
        _, d_pose = bearing_measurement(base, tuple(beacons_xy[beacon_id]), lever)
        jacobian = np.zeros(dim)
        jacobian[:3] = d_pose
        attached[k] = attached.get(k, 0.0) + bearing_information(jacobian, variance_rad2)
    information = np.linalg.inv(prior) + attached.get(0, 0.0)
    bounds = np.empty((len(times_s), 3, 3))
    bounds[0] = np.linalg.inv(information)[:3, :3]
    for k in range(1, len(times_s)):
        transition, covariance = odometry_step(
            tuple(true_poses[k - 1]), tuple(reported_increments[k - 1]), wheel_noise, with_errors
        )
        information = gaussian_information_step(information, transition, covariance, attached.get(k, 0.0))
        bounds[k] = np.linalg.inv(information)[:3, :3]
    return PcrbTrack(np.asarray(times_s, dtype=float), bounds)
