"""The one intake of a pose offered to the EKF (ToTal's fix, /initialpose, `~/set_pose`), shared by ekf_node
and the offline replay; refused with kind, reason and counter key `<source>_poses_<kind>`: `wrong_frame` (an
empty frame id is the map's: RViz leaves it empty), `invalid` (non-finite, a zero quaternion), `covariance`
(the x, y, yaw block, eq. 6.30: asymmetric, negative, or beyond `plausibility.MAX_POSE_SIGMA_M` /
`MAX_POSE_SIGMA_RAD`), `off_table` (given the beacons: `plausibility.off_table_problem`). A semi-definite
covariance (RViz's zeros) is kept as None: the filter's default.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from beams_common.geometry.pose2d import Pose2D, yaw_of_quaternion
from beams_common.intake.plausibility import MAX_POSE_SIGMA_M, MAX_POSE_SIGMA_RAD, off_table_problem
from beams_common.intake.validation import SYMMETRY_TOLERANCE, bounded, clearly_conditioned

# The (x, y, yaw) rows and columns of a row-major 6x6 ROS covariance.
PLANAR_INDICES = (0, 1, 5)
# Below minus this, a normalised covariance's smallest eigenvalue is negative, not rounding (~1e-16).
PSD_TOLERANCE = 1e-9
# An orientation quaternion shorter than this has no direction.
MIN_QUATERNION_NORM = 1e-6


class PoseSource(StrEnum):
    """Where a pose comes from (the value is the counter's prefix: `<value>_poses_<kind>`)."""

    TOTAL = "total"  # ToTal's accepted fix on beams/pose
    OPERATOR = "operator"  # /initialpose or ~/set_pose


class PoseRefusal(StrEnum):
    """Why a pose was not kept (the value is the counter's suffix)."""

    WRONG_FRAME = "wrong_frame"
    INVALID = "invalid"
    COVARIANCE = "covariance"
    OFF_TABLE = "off_table"


@dataclass(frozen=True)
class KeptPose:
    """A pose the filter may take: finite, in the map frame, with its covariance (3x3 x, y, yaw:
    symmetric, positive definite, bounded) or None when the filter's default replaces it."""

    source: PoseSource
    stamp_s: float
    pose: Pose2D
    covariance: np.ndarray | None

    @property
    def operator(self) -> bool:
        return self.source is PoseSource.OPERATOR


@dataclass(frozen=True)
class RefusedPose:
    """A pose not kept: its source, the kind of refusal and the reason in words."""

    source: PoseSource
    refusal: PoseRefusal
    reason: str

    @property
    def counter_key(self) -> str:
        """The diagnostic counter of this refusal (`<source>_poses_<kind>`)."""
        return f"{self.source}_poses_{self.refusal}"


PoseIntake = KeptPose | RefusedPose


def planar_pose_problem(stamp_s: float, pose: Sequence[float]) -> str:
    """Rule 2 on a planar pose (x, y, yaw) and its stamp: why it is not finite, or ''."""
    if len(pose) != 3 or not all(math.isfinite(float(v)) for v in (stamp_s, *pose)):
        return bounded(f"pose {tuple(pose)} at {float(stamp_s)} s is not finite")
    return ""


def pose_covariance_problem(covariance_3x3: Any) -> str:
    """Rule 3 (with rule 2's finiteness of the entries) on a planar (x, y, yaw) covariance, or ''."""
    return _judged_covariance(covariance_3x3)[0]


def _judged_covariance(covariance_3x3: Any) -> tuple[str, bool]:
    """(rule 3's problem or '', whether the covariance is positive definite: one that passes but is only
    semi-definite carries no information in some direction)."""
    matrix = np.asarray(covariance_3x3, dtype=float)
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        return "covariance is not three by three finite numbers", False
    scale = float(np.max(np.abs(matrix)))
    if scale == 0.0:
        return "", False  # no information given: the default replaces it
    normalised = matrix / scale  # entries in [-1, 1]: no overflow whatever the magnitude
    # asymmetry relative to the entries' own scale, sqrt(a_ii a_jj) (a 6 % asymmetry of a 1e-8 m^2 block
    # next to a 1 rad^2 variance is not rounding)
    root = np.sqrt(np.abs(np.diag(normalised)))
    own_scale = np.maximum(np.outer(root, root), np.finfo(float).tiny)
    if float(np.max(np.abs(normalised - normalised.T) / own_scale)) > SYMMETRY_TOLERANCE:
        return "covariance is not symmetric", False
    smallest = 1.0 if clearly_conditioned(normalised) else float(np.linalg.eigvalsh(normalised)[0])
    if np.any(np.diag(matrix) < 0.0) or smallest < -PSD_TOLERANCE:
        return bounded(
            f"covariance is not positive semi-definite (smallest eigenvalue {smallest * scale:.3g}): "
            f"variances {np.diag(matrix).tolist()}"
        ), False
    sigma = np.sqrt(np.maximum(np.diag(matrix), 0.0))
    if max(sigma[0], sigma[1]) > MAX_POSE_SIGMA_M or sigma[2] > MAX_POSE_SIGMA_RAD:
        return (
            f"covariance standard deviations ({sigma[0]:.3g} m, {sigma[1]:.3g} m, {sigma[2]:.3g} rad) beyond "
            f"{MAX_POSE_SIGMA_M:g} m (the table) or {MAX_POSE_SIGMA_RAD:.3g} rad (a turn): no information"
        ), False
    return "", smallest > 0.0


def pose_intake(
    source: PoseSource,
    frame_id: str,
    map_frame: str,
    stamp_s: float,
    position: Sequence[float],
    quaternion: Sequence[float],
    covariance_6x6: Sequence[float],
    beacons_xy: Any = None,
) -> PoseIntake:
    """The rules (see the module docstring) on a pose's fields: position (x, y, z, m), orientation
    quaternion (x, y, z, w), row-major 6x6 covariance, and with `beacons_xy` (n x 2, m) the table; what
    is kept or why it is refused."""
    if frame_id and frame_id != map_frame:
        reason = f"{source} pose in frame {frame_id!r} (expected {map_frame!r})"
        return RefusedPose(source, PoseRefusal.WRONG_FRAME, bounded(reason))
    values = [float(v) for v in (*position, *quaternion)]
    if not all(math.isfinite(v) for v in values):
        reason = f"{source} pose: position {tuple(position)} or orientation {tuple(quaternion)} not finite"
        return RefusedPose(source, PoseRefusal.INVALID, bounded(reason))
    norm = math.hypot(*values[3:])  # hypot: no overflow on huge entries
    if norm < MIN_QUATERNION_NORM:
        return RefusedPose(source, PoseRefusal.INVALID, f"{source} pose: orientation quaternion of zero norm")
    if beacons_xy is not None and (off_table := off_table_problem(values[0], values[1], beacons_xy)):
        return RefusedPose(source, PoseRefusal.OFF_TABLE, f"{source} pose: {off_table}")
    entries = np.asarray(covariance_6x6, dtype=float).ravel()
    if entries.size != 36 or not np.all(np.isfinite(entries)):  # z, roll, pitch too: a corrupt message
        return RefusedPose(source, PoseRefusal.INVALID, f"{source} pose: covariance has a non-finite entry")
    planar = entries.reshape(6, 6)[np.ix_(PLANAR_INDICES, PLANAR_INDICES)]
    # the rotation a non-unit quaternion stands for is its normalised one (and huge entries then
    # cannot overflow the yaw's products)
    pose = (values[0], values[1], yaw_of_quaternion(*(v / norm for v in values[3:])))
    return planar_pose_intake(source, stamp_s, pose, planar)


def pose_message_intake(
    source: PoseSource, frame_id: str, map_frame: str, stamp_s: float, message: Any, beacons_xy: Any = None
) -> PoseIntake:
    """`pose_intake` of a geometry_msgs/PoseWithCovariance (an rclpy or a rosbags message), its header's
    frame id and stamp (s)."""
    position, q = message.pose.position, message.pose.orientation
    xyz, quaternion = (position.x, position.y, position.z), (q.x, q.y, q.z, q.w)
    return pose_intake(source, frame_id, map_frame, stamp_s, xyz, quaternion, message.covariance, beacons_xy)


def planar_pose_intake(source: PoseSource, stamp_s: float, pose: Pose2D, covariance_3x3: Any) -> PoseIntake:
    """Rules 2 and 3 on a planar pose (x, y, yaw), its stamp and its 3x3 covariance (what `pose_intake`
    reads from a message; ToTal's result before it is one, in the offline replay)."""
    problem = planar_pose_problem(stamp_s, pose)
    if problem:
        return RefusedPose(source, PoseRefusal.INVALID, f"{source} {problem}")
    matrix = np.asarray(covariance_3x3, dtype=float)
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        return RefusedPose(source, PoseRefusal.INVALID, f"{source} pose: covariance has a non-finite entry")
    problem, definite = _judged_covariance(matrix)
    if problem:
        return RefusedPose(source, PoseRefusal.COVARIANCE, f"{source} pose: {problem}")
    # a semi-definite covariance carries no information in some direction: the default replaces it
    return KeptPose(source, float(stamp_s), tuple(float(v) for v in pose), matrix if definite else None)
