"""The PoseFilter protocol: what the Localiser needs of a filter over the robot's pose (x, y, theta) in the
map frame, so that a new filter (a UKF, a particle filter) is a new module beside bearing_ekf.py, not an
edit to the localiser (as robot_localization's FilterBase has Ekf and Ukf beside it).

The Localiser owns the timing (odometry history, late bearings replayed from a saved state, kidnap and
time jumps); a filter owns the estimate: it is initialised from a pose, moved by odometry increments
(predict), corrected by one bearing at a time (update_bearing, which gates), and saves and restores its
state so that a late bearing can be applied at its own stamp. BearingEkf (thesis fig. 8.1) is the first
implementation; test_ekf_pose_filter_plugin.py runs the Localiser with a second one.
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Protocol

import numpy as np

from beams_common.geometry.pose2d import Pose2D


class BearingReason(StrEnum):
    """What became of one bearing (the value is the counter's suffix: `bearings_<value>`): the filter's
    answers (update_bearing) and the Localiser's (when it applies a bearing)."""

    ACCEPTED = "accepted"
    GATED = "gated"
    # of a beacon the Localiser excluded (`consistency.BeaconExclusion`): judged (its NIS), not applied
    EXCLUDED = "excluded"
    UNINITIALISED = "uninitialised"
    UNKNOWN_BEACON = "unknown_beacon"
    INVALID_MEASUREMENT = "invalid_measurement"
    SENSOR_ON_BEACON = "sensor_on_beacon"
    # a filter that does not use bearings (a dead-reckoning plugin)
    NOT_USED = "not_used"
    # the Localiser's: stamped after the newest odometry (waits for it), or before the odometry history
    DEFERRED = "deferred"
    OUTSIDE_HISTORY = "outside_history"


@dataclass(frozen=True)
class BearingOutcome:
    """What one bearing did to the filter: accepted, or why not."""

    accepted: bool
    # squared Mahalanobis distance of the innovation (chi-square, 1 dof, under the model)
    nis: float
    residual_rad: float
    reason: BearingReason = BearingReason.ACCEPTED
    # an accepted bearing's gain on (x, y, theta), its Jacobian on them and its innovation variance S: its
    # share of the fault hypotheses (beams_ekf.separations); None: unknown
    pose_gain: np.ndarray | None = None
    innovation_variance: float = float("nan")
    pose_jacobian: np.ndarray | None = None


def rejected(reason: BearingReason) -> BearingOutcome:
    """A bearing not used, for `reason` (no innovation)."""
    return BearingOutcome(False, float("nan"), float("nan"), reason)


class PoseFilter(Protocol):
    """A filter over (x, y, theta) in the map frame fed with odometry increments and bearings."""

    # the beacons it knows ({id: (x, y)}, map frame, m) and the turret's offset in base_link (m)
    beacons_xy: dict[int, tuple[float, float]]
    sensor_offset_m: tuple[float, float]
    # the chi-square (1 dof) threshold beyond which update_bearing gates a bearing (the lost test caps
    # each bearing's NIS there)
    gate: float
    # beacons whose bearings update_bearing judges (EXCLUDED, with their NIS) without applying them
    excluded_beacons: set[int]

    @property
    def initialised(self) -> bool:
        """True once a pose has been given (and no reset since)."""

    @property
    def pose(self) -> Pose2D:
        """The estimate (x, y, theta)."""

    @property
    def covariance(self) -> np.ndarray:
        """The 3x3 covariance of the estimate."""

    def initialise(self, pose: Pose2D, covariance: np.ndarray) -> None:
        """Start (or restart) from a pose and its covariance; ValueError for a non-finite or not positive
        definite one."""

    def reset(self) -> None:
        """Forget the estimate: wait for initialise."""

    def state(self) -> Any:
        """A copy of the filter's state, to come back to with restore (late bearings)."""

    def restore(self, state: Any) -> None:
        """Go back to a state given by state()."""

    def predict(self, increment: Pose2D) -> None:
        """Move by a robot-frame odometry increment (dx, dy, dtheta)."""

    def add_time_noise(self, position_variance_m2: float, heading_variance_rad2: float) -> None:
        """Grow the uncertainty for a time without odometry (a gap)."""

    def update_bearing(
        self,
        beacon_id: int,
        bearing_rad: float,
        variance_rad2: float,
        lever: Pose2D | None = None,
        uncorrected_window_rad: float = 0.0,
    ) -> BearingOutcome:
        """Correct with one bearing (sensor frame) of the given variance; `lever` is the turret's pose
        relative to the robot's estimate when the bearing was taken; `uncorrected_window_rad` > 0 is the
        angular window of a bearing no calibration corrected (it carries the power bias, eq. 7.17)."""

    def configure(
        self,
        beacons_xy: Mapping[int, Sequence[float]],
        sensor_offset_m: tuple[float, float],
        process_noise: Any,
        gate_probability: float,
    ) -> None:
        """New beacon geometry, process noise and gate (a runtime parameter change, a calibration)."""
