"""Planar poses (x, y, theta) in SE(2): the algebra odometry, motion compensation and the EKF share."""

import math

from beams_common.geometry.angles import wrap_to_pi

Pose2D = tuple[float, float, float]


def compose(a: Pose2D, b: Pose2D) -> Pose2D:
    """a (+) b: pose b, given in frame a, expressed in a's parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap_to_pi(a[2] + b[2]))


def inverse(a: Pose2D) -> Pose2D:
    """(-)a, so that compose(a, inverse(a)) is the identity."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], wrap_to_pi(-a[2]))


def between(a: Pose2D, b: Pose2D) -> Pose2D:
    """(-)a (+) b: pose b expressed in the frame of pose a (the odometry increment from a to b)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return (c * dx + s * dy, -s * dx + c * dy, wrap_to_pi(b[2] - a[2]))


def interpolate(a: Pose2D, b: Pose2D, fraction: float) -> Pose2D:
    """The pose a fraction of the way from a to b (linear in position, shortest arc in heading)."""
    return (
        a[0] + fraction * (b[0] - a[0]),
        a[1] + fraction * (b[1] - a[1]),
        wrap_to_pi(a[2] + fraction * wrap_to_pi(b[2] - a[2])),
    )


def is_finite_pose(pose: Pose2D) -> bool:
    """True when the three components are finite numbers."""
    return math.isfinite(pose[0]) and math.isfinite(pose[1]) and math.isfinite(pose[2])


def yaw_of_quaternion(qx: float, qy: float, qz: float, qw: float) -> float:
    """Yaw (rad) of a unit quaternion (the z-y-x Euler angle)."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
