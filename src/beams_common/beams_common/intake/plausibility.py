"""Semantic plausibility of the inputs: well-formed values that cannot be true, each check returning a reason:
a stamp against the receiving clock (`stamp_problem`: a bearing at the wrong instant put the EKF 0.3 m off
while it said 2 mm), an odometry increment against the robot's limits (`odometry_step_problem`), a pose
covariance's bound (`MAX_POSE_SIGMA_M`, `MAX_POSE_SIGMA_RAD`), a position on the table (`off_table_problem`).
"""

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from beams_common.config.parameters import ParameterSpec
from beams_common.geometry.pose2d import Pose2D

# Stamps are quantised and jittered: an increment may exceed speed x interval by this much (m, rad).
ODOMETRY_STEP_SLACK_M = 0.02
ODOMETRY_STEP_SLACK_RAD = 0.05
# An operator's pose: a standard deviation up to the size of a Eurobot table's diagonal (3.6 m) and a
# full turn of heading still means "roughly here"; beyond it the pose is no information at all.
MAX_POSE_SIGMA_M = 4.0
MAX_POSE_SIGMA_RAD = 2.0 * math.pi
# The beacons stand on the table's border (section 7.3.1, table 7.2), so a robot on the table has its
# centre inside their bounding box; the margin (m) admits beacons set a little inside the border.
TABLE_MARGIN_M = 0.2


def off_table_problem(x_m: float, y_m: float, beacons_xy: Any, margin_m: float = TABLE_MARGIN_M) -> str:
    """Why a position (map frame) is off the beacons' table (their bounding box, n x 2 m, grown by
    margin_m), or ''."""
    low, high = beacons_xy.min(axis=0) - margin_m, beacons_xy.max(axis=0) + margin_m
    if low[0] <= x_m <= high[0] and low[1] <= y_m <= high[1]:
        return ""
    return (
        f"the position ({x_m:.4g}, {y_m:.4g}) m is outside the beacons' table: x in [{low[0]:.3f}, "
        f"{high[0]:.3f}] m, y in [{low[1]:.3f}, {high[1]:.3f}] m (their bounding box, {margin_m} m margin)"
    )


# triangulation_node's and ekf_node's (runtime) checks. The age: one revolution (0.1 s, thesis ch. 2) plus
# 0.15 s of transport on a loaded computer; the lead: room for a coarse NTP synchronisation.
STAMP_SPECS = (
    ParameterSpec(
        "max_stamp_age_s",
        0.25,
        "Largest age (s) of an input's stamp at reception (a revolution's newest bearing, an odometry "
        "message, at ekf_node an accepted ToTal pose) on the node's clock; older inputs are refused as late, "
        "with the reason on /diagnostics (<kind>_stamp_refused; two in a row degrade the status). 0 "
        "switches the check off (a replay whose stamps are not on the node's clock).",
        minimum=0.0,
        maximum=60.0,
        runtime=True,
    ),
    ParameterSpec(
        "max_stamp_lead_s",
        0.1,
        "Largest lead (s) of an input's stamp ahead of the node's clock; inputs from further in the future "
        "are refused, as for the age. 0 switches the check off.",
        minimum=0.0,
        maximum=60.0,
        runtime=True,
    ),
)
# A Eurobot robot (rules: perimeter <= 1.2 m unfolded) drives below ~1.5 m/s and turns below ~2 turns/s;
# the defaults leave room above both.
MOTION_SPECS = (
    ParameterSpec(
        "max_speed_m_per_s",
        2.0,
        "The robot's maximum speed (m/s): an odometry increment beyond it (plus 2 cm) is a jump, refused.",
        minimum=0.01,
        maximum=20.0,
        runtime=True,
    ),
    ParameterSpec(
        "max_yaw_rate_rad_per_s",
        4.0 * math.pi,
        "The robot's maximum yaw rate (rad/s): an odometry increment turning faster (plus 0.05 rad) is a "
        "jump, refused.",
        minimum=0.01,
        maximum=100.0,
        runtime=True,
    ),
)


@dataclass(frozen=True)
class StampTolerance:
    """How far a stamp may lie behind (`max_age_s`) or ahead of (`max_lead_s`) the receiving clock (s);
    0 switches that side of the check off (a replay whose stamps are not on the node's clock)."""

    max_age_s: float = STAMP_SPECS[0].default
    max_lead_s: float = STAMP_SPECS[1].default


def stamp_problem(what: str, stamp_s: float, received_s: float, tolerance: StampTolerance) -> str:
    """Why `what` stamped `stamp_s` cannot have been measured when received at `received_s` (the node's
    clock, s), or ''. For a revolution pass its newest bearing's stamp (the others are older by up to one
    revolution, legitimately)."""
    if not (math.isfinite(stamp_s) and math.isfinite(received_s)):
        return ""  # non-finite stamps are validation's refusal, not this one
    age_s = received_s - stamp_s
    if tolerance.max_age_s > 0.0 and age_s > tolerance.max_age_s:
        return (
            f"{what} stamped {age_s:.3f} s behind the receiving clock (tolerance "
            f"{tolerance.max_age_s:g} s): a late stamp, refused"
        )
    if tolerance.max_lead_s > 0.0 and -age_s > tolerance.max_lead_s:
        return (
            f"{what} stamped {-age_s:.3f} s ahead of the receiving clock (tolerance "
            f"{tolerance.max_lead_s:g} s): a stamp from the future, refused"
        )
    return ""


# A single revolution or odometry message late by a scheduling hiccup of a loaded computer is refused
# but does not degrade a node's status; this many in a row of one input do (1 s late stamps: 0.1 s).
STAMP_FAULT_CONFIRMATIONS = 2


class StampCheck:
    """`stamp_problem` for a node's inputs, by kind (bearings, odometry), with the run of consecutive
    refusals of each: `check` says whether the input is refused and whether its fault is confirmed
    (STAMP_FAULT_CONFIRMATIONS in a row), which is what a status should show."""

    def __init__(self, tolerance: StampTolerance) -> None:
        self.tolerance = tolerance
        self._runs: dict[str, int] = {}

    def check(self, kind: str, what: str, stamp_s: float, received_s: float) -> tuple[str, bool]:
        """(why the input is refused or '', whether the refusals of this kind are confirmed)."""
        problem = stamp_problem(what, stamp_s, received_s, self.tolerance)
        self._runs[kind] = self._runs.get(kind, 0) + 1 if problem else 0
        return problem, self._runs[kind] >= STAMP_FAULT_CONFIRMATIONS


@dataclass(frozen=True)
class MotionLimits:
    """What the robot can do: its maximum speed (m/s) and yaw rate (rad/s)."""

    max_speed_m_per_s: float = MOTION_SPECS[0].default
    max_yaw_rate_rad_per_s: float = MOTION_SPECS[1].default

    def max_step(self, interval_s: float) -> tuple[float, float]:
        """The largest plausible translation (m) and rotation (rad) over `interval_s`, with the slack of
        stamp quantisation; the rotation never exceeds pi (an increment is wrapped)."""
        interval_s = max(interval_s, 0.0)
        return (
            self.max_speed_m_per_s * interval_s + ODOMETRY_STEP_SLACK_M,
            min(self.max_yaw_rate_rad_per_s * interval_s + ODOMETRY_STEP_SLACK_RAD, math.pi),
        )


def odometry_step_problem(interval_s: float, step: Pose2D, limits: MotionLimits) -> str:
    """Why an odometry increment `step` (robot frame at its start: dx, dy m, dtheta rad, wrapped) over
    `interval_s` is not motion the robot can make, or ''."""
    translation_m = math.hypot(step[0], step[1])
    rotation_rad = abs(step[2])
    max_translation_m, max_rotation_rad = limits.max_step(interval_s)
    if translation_m > max_translation_m:
        return (
            f"odometry moved {translation_m:.3f} m in {interval_s:.3f} s, more than the robot's "
            f"{limits.max_speed_m_per_s:g} m/s allows ({max_translation_m:.3f} m): a jump, not motion"
        )
    if rotation_rad > max_rotation_rad:
        return (
            f"odometry turned {rotation_rad:.3f} rad in {interval_s:.3f} s, more than the robot's "
            f"{limits.max_yaw_rate_rad_per_s:g} rad/s allows ({max_rotation_rad:.3f} rad): a jump, not motion"
        )
    return ""


def stamp_tolerance_of(values: Mapping[str, Any]) -> StampTolerance:
    """The StampTolerance of validated parameter values (STAMP_SPECS)."""
    return StampTolerance(float(values["max_stamp_age_s"]), float(values["max_stamp_lead_s"]))


def motion_limits_of(values: Mapping[str, Any]) -> MotionLimits:
    """The MotionLimits of validated parameter values (MOTION_SPECS)."""
    return MotionLimits(float(values["max_speed_m_per_s"]), float(values["max_yaw_rate_rad_per_s"]))
