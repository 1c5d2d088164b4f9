"""The EKF's fault hypotheses for its protection level: one per beacon, the estimate's separation from the
solution without that beacon's bearings (solution separation, docs/protection_level.md).

The solution without beacon b is not run as a filter of its own: its separation Delta_b = x - x_b and the
covariance it lacks D_b = P_b - P (pose blocks; the other states and their cross-covariances taken as the
estimate's) are carried to first order, at a few 3x3 operations per bearing and per odometry step. A
bearing of beacon b (gain K on x, y, theta, residual nu, innovation variance S) moved x by K nu and took
K S K' from P; x_b never had it: Delta_b += K nu, D_b += K S K'. A bearing of another beacon (Jacobian h on
the pose) corrects x_b too, with its own gain K_b = (K S + D_b h) / S_b, S_b = S + h' D_b h, from its
residual nu + h' Delta_b: Delta_b += K nu - K_b (nu + h' Delta_b), D_b += K K' S - K_b K_b' S_b. An odometry
step moves both by the same increment, its noise added to both: Delta_b = F Delta_b, D_b = F D_b F' (F the
motion's Jacobian on the pose: a heading separation becomes a position one as the robot travels).

A persistent fault (a bent mount, a reflection, a beacon moved during the run) thus shows its whole pull
on the estimate, not only the last revolution's: the filter accumulates a bias that stays inside its gate.
Each beacon's hypothesis covers one faulty bearing of it as well (the solution without all its bearings is
fault-free then too). Dropped at every (re)initialisation: a fault already in the initial pose is not
covered.
"""

import math

import numpy as np

from beams_common.geometry.angles import wrap_to_pi
from beams_common.geometry.pose2d import Pose2D
from beams_ekf.pose_filter import BearingOutcome

# a lost estimate re-initialised by at most this (m) keeps its separations: beyond, the solutions
# linearised about it were as wrong as it was
CARRIED_JUMP_M = 0.1


class BeaconSeparations:
    """Delta_b and D_b of each beacon that contributed since the last initialisation (module docstring)."""

    def __init__(self, starting_bearings: int = 3) -> None:
        # the solutions start from the estimate after this many bearings since an initialisation: from
        # the initial pose itself, a still robot's solution without one of three beacons would keep the
        # initial covariance along the direction the other two leave unobserved
        self.starting_bearings = starting_bearings
        self._to_start = starting_bearings
        self._beacons: list[int] = []
        self._shifts = np.zeros((0, 3))
        self._covariances = np.zeros((0, 3, 3))

    @property
    def beacons(self) -> list[int]:
        """The beacons of the hypotheses' rows."""
        return list(self._beacons)

    def clear(self) -> None:
        """Forget every beacon's separation (an initialisation)."""
        self.__init__(self.starting_bearings)

    def bearing(self, beacon_id: int, outcome: BearingOutcome) -> None:
        """An accepted bearing's outcome: its pose gain K, its pose Jacobian h, its residual nu and its
        innovation variance S."""
        gain, jacobian = outcome.pose_gain, outcome.pose_jacobian
        if gain is None or jacobian is None:
            return
        residual_rad, innovation = outcome.residual_rad, outcome.innovation_variance
        if self._to_start > 0:
            self._to_start -= 1
            return
        if beacon_id not in self._beacons:
            self._beacons.append(beacon_id)
            self._shifts = np.vstack([self._shifts, np.zeros(3)])
            self._covariances = np.concatenate([self._covariances, np.zeros((1, 3, 3))])
        k = self._beacons.index(beacon_id)
        shift, taken = gain * residual_rad, innovation * np.outer(gain, gain)
        own = (self._shifts[k] + shift, self._covariances[k] + taken)
        spread = self._covariances @ jacobian
        variances = innovation + spread @ jacobian
        gains = (innovation * gain + spread) / variances[:, None]
        self._shifts += shift - gains * (residual_rad + self._shifts @ jacobian)[:, None]
        self._covariances += taken - variances[:, None, None] * gains[:, :, None] * gains[:, None, :]
        self._shifts[k], self._covariances[k] = own

    def moved(self, increment: Pose2D, heading_rad: float) -> None:
        """An odometry step (robot frame) from the heading heading_rad."""
        dx, dy, _ = increment
        if self._beacons and (dx or dy):
            c, s = math.cos(heading_rad), math.sin(heading_rad)
            moved = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
            self._shifts = self._shifts @ moved.T
            self._covariances = moved @ self._covariances @ moved.T

    def initialised(
        self, pose: Pose2D, covariance: np.ndarray, lost: tuple[Pose2D, np.ndarray] | None = None
    ) -> None:
        """The estimate (re)initialised at pose: the solutions start again, unless it was `lost` (its pose
        and covariance before) and moves by at most CARRIED_JUMP_M: then they go on, Delta_b += the jump,
        D_b += the covariance's change."""
        jump = None if lost is None else np.subtract(pose, lost[0])
        if jump is None or math.hypot(jump[0], jump[1]) > CARRIED_JUMP_M:
            self.clear()
            return
        self._shifts += jump
        self._shifts[:, 2] = wrap_to_pi(self._shifts[:, 2])
        self._covariances += lost[1] - covariance

    def hypotheses(self, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(shifts Delta_b, one row per beacon; the covariances P + D_b of the solutions without them), or
        None before any bearing. An excluded beacon keeps its separation: the refiltering without it undid
        its pull over the odometry history only (late_bearings), and what it pulled before stays."""
        if not self._beacons:
            return None
        return self._shifts.copy(), covariance + self._covariances
