"""Conversions between ROS messages and the planar quantities the BeAMS modules compute with.

Stamps in seconds, planar poses (x, y, yaw) and their 3x3 covariances; the 6x6 ROS covariance is
row-major over (x, y, z, roll, pitch, yaw) and a planar estimate says nothing of z, roll and pitch.
"""

import math
import struct
from collections.abc import Iterable
from typing import Any, NamedTuple

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose, TransformStamped
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from beams_common.geometry.pose2d import Pose2D, yaw_of_quaternion
from beams_common.interfaces.bearing_messages import BearingFields, bearing_array_message
from beams_msgs.msg import BeaconBearing, BeaconBearingArray

# Rows/columns of x, y and yaw in ROS's 6x6 covariance.
PLANAR_INDICES = (0, 1, 5)
# Variance reported for z, roll and pitch, which a planar estimate does not know (REP-105 convention).
UNKNOWN_VARIANCE = 1e6


class OdometrySample(NamedTuple):
    """What the nodes read of a nav_msgs/Odometry: stamp (s, and exact), pose (x, y, yaw), twist (vx, wz)."""

    stamp_s: float
    sec: int
    nanosec: int
    pose: Pose2D
    twist: tuple[float, float]


def odometry_sample(data: "bytes | Odometry") -> OdometrySample:
    """The OdometrySample of a serialised nav_msgs/Odometry (a raw subscription's), read at its fields'
    offsets in little-endian CDR (rclpy's conversion into 15 objects skipped); another encoding through
    rclpy's deserialisation, a message object (a test calling the callback) as it is."""
    if isinstance(data, bytes) and data[:2] == b"\x00\x01":  # the encapsulation: CDR, little endian
        body = memoryview(data)[4:]  # CDR aligns from the body's start
        sec, nanosec, length = struct.unpack_from("<iII", body)
        offset = 12 + length + (-(12 + length) % 4)
        offset += 4 + struct.unpack_from("<I", body, offset)[0]
        offset += -offset % 8
        x, y, _, qx, qy, qz, qw = struct.unpack_from("<7d", body, offset)
        linear_x, _, _, _, _, angular_z = struct.unpack_from("<6d", body, offset + 43 * 8)
        pose = (x, y, yaw_of_quaternion(qx, qy, qz, qw))
        return OdometrySample(sec + 1e-9 * nanosec, sec, nanosec, pose, (linear_x, angular_z))
    msg = data if isinstance(data, Odometry) else deserialize_message(data, Odometry)
    stamp, twist = msg.header.stamp, msg.twist.twist
    pose, seconds = pose2d_of(msg.pose.pose), stamp_to_seconds(stamp)
    return OdometrySample(seconds, stamp.sec, stamp.nanosec, pose, (twist.linear.x, twist.angular.z))


# rclpy's classes by their ROS names, for beams_common.interfaces.bearing_messages
RCLPY_BEARING_TYPES = {
    "builtin_interfaces/msg/Time": Time,
    "std_msgs/msg/Header": Header,
    "beams_msgs/msg/BeaconBearing": BeaconBearing,
    "beams_msgs/msg/BeaconBearingArray": BeaconBearingArray,
}


def bearing_array(start_ns: int, bearings: Iterable[BearingFields], **fields: Any) -> BeaconBearingArray:
    """rclpy's beams_msgs/BeaconBearingArray (bearing_messages.bearing_array_message: period_s,
    revolution, rejected_windows, frame_id)."""
    return bearing_array_message(RCLPY_BEARING_TYPES, start_ns, bearings, **fields)


def stamp_to_seconds(stamp: Time) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


def seconds_to_stamp(seconds: float) -> Time:
    """builtin_interfaces/Time from seconds, nanoseconds rounded."""
    nanoseconds = round(seconds * 1e9)
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def pose2d_of(pose: Pose) -> Pose2D:
    """(x, y, yaw) of a geometry_msgs/Pose."""
    q = pose.orientation
    return (pose.position.x, pose.position.y, yaw_of_quaternion(q.x, q.y, q.z, q.w))


def set_pose2d(pose: Pose, planar: Pose2D) -> None:
    """Write (x, y, yaw) into a geometry_msgs/Pose (z = 0, rotation about z only)."""
    pose.position.x, pose.position.y = float(planar[0]), float(planar[1])
    pose.orientation.z = math.sin(0.5 * planar[2])
    pose.orientation.w = math.cos(0.5 * planar[2])


def planar_tf_message(header: Header, child_frame_id: str, planar: Pose2D) -> TFMessage:
    """A /tf message of one transform header.frame_id -> child_frame_id: (x, y, yaw), z = 0, rotation
    about z only; `set_planar_tf` moves it (a message built once, published at every estimate)."""
    message = TFMessage(transforms=[TransformStamped(header=header, child_frame_id=child_frame_id)])
    set_planar_tf(message, planar)
    return message


def set_planar_tf(message: TFMessage, planar: Pose2D) -> None:
    transform = message.transforms[0].transform
    transform.translation.x, transform.translation.y = float(planar[0]), float(planar[1])
    transform.rotation.z = math.sin(0.5 * planar[2])
    transform.rotation.w = math.cos(0.5 * planar[2])


def planar_covariance(covariance_6x6) -> np.ndarray:
    """The (x, y, yaw) 3x3 block of a row-major 6x6 ROS covariance."""
    full = np.asarray(covariance_6x6, dtype=float).reshape(6, 6)
    return full[np.ix_(PLANAR_INDICES, PLANAR_INDICES)]


def ros_covariance(planar: np.ndarray) -> np.ndarray:
    """Row-major 6x6 ROS covariance holding a (x, y, yaw) 3x3 block; z, roll, pitch marked unknown. A
    float64 array: rclpy takes it as it is (a list, it checks entry by entry)."""
    full = np.diag([0.0, 0.0, UNKNOWN_VARIANCE, UNKNOWN_VARIANCE, UNKNOWN_VARIANCE, 0.0])
    full[np.ix_(PLANAR_INDICES, PLANAR_INDICES)] = planar
    return full.ravel()
