"""What the Localiser answers: the outcome of an odometry sample and of a pose, and its estimate.

The values of the outcomes are counter names (no spaces): `odometry_<value>` for an odometry sample not
used, `poses_<value>` for a pose refused, the value itself for a (re-)initialisation.
"""

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from beams_common.geometry.pose2d import Pose2D, compose, inverse


class OdometryOutcome(StrEnum):
    """What one odometry sample did."""

    INVALID = "invalid"  # a non-finite stamp or pose: refused
    STALE = "stale"  # not after the newest sample (reordered): dropped
    HELD = "held"  # stamped far in the past, a stray unless the next ones confirm a time jump: dropped
    REFERENCE = "reference"  # the first sample (or the first after a reset or a time jump)
    PREDICTED = "predicted"  # the filter moved by the odometry since the previous sample
    # an increment beyond the robot's speed or yaw rate: not predicted with, the sample is the
    # new reference and the covariance grows by the largest motion the robot could have made
    JUMPED = "jumped"

    @property
    def used(self) -> bool:
        """True when the sample entered the odometry history (it is the filter's newest instant)."""
        return self in (OdometryOutcome.REFERENCE, OdometryOutcome.PREDICTED, OdometryOutcome.JUMPED)


class PoseOutcome(StrEnum):
    """What one pose (ToTal's accepted fix or an operator's) did."""

    INVALID = "invalid"  # non-finite, or a covariance the filter refuses
    OUTSIDE_HISTORY = "outside_history"  # a ToTal fix the odometry history does not cover
    INITIALISED = "initialisations"
    KIDNAP_REINITIALISED = "kidnap_reinitialisations"
    LOST_REINITIALISED = "lost_reinitialisations"
    IGNORED = "ignored"  # a ToTal fix while the filter tracks

    @property
    def taken(self) -> bool:
        """True when the pose (re-)initialised the filter."""
        return self in (
            PoseOutcome.INITIALISED,
            PoseOutcome.KIDNAP_REINITIALISED,
            PoseOutcome.LOST_REINITIALISED,
        )


@dataclass
class Estimate:
    """The filter's output at its instant."""

    stamp_s: float
    pose: Pose2D
    covariance: np.ndarray
    # robot-frame velocity (v_x, v_y, omega) from the last two odometry samples
    twist: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # the odometry pose (odom frame) at stamp_s; None before any odometry
    odom_pose: Pose2D | None = None
    # the fault hypotheses of the protection level (`Integrity.level`): the estimate's shift from each
    # solution without a recent bearing or beacon (n, 3) and that solution's covariance (n, 3, 3); None:
    # no bearing accepted since the (re-)initialisation
    fault_shifts: np.ndarray | None = None
    fault_covariances: np.ndarray | None = None

    @property
    def map_to_odom(self) -> Pose2D | None:
        """The map -> odom transform (REP-105: the localisation's correction of the odometry's drift) that
        puts the odometry pose on the estimate; None without odometry."""
        return None if self.odom_pose is None else compose(self.pose, inverse(self.odom_pose))
