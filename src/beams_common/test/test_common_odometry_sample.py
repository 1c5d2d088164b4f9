"""messages.odometry_sample reads a serialised nav_msgs/Odometry exactly as rclpy's deserialisation does:
every frame id length (the alignment before the pose), any double (NaN, infinities, -0.0, huge), the
stamp's whole range; a big-endian message goes through rclpy's deserialisation, a message object (a test
calling the callback) is read as it is."""

import math
import struct

from hypothesis import given
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message

from beams_common.ros.messages import OdometrySample, odometry_sample, pose2d_of, stamp_to_seconds

doubles = st.floats(allow_nan=True, allow_infinity=True, width=64)
frame_ids = st.text(alphabet="abcdefghij_/", max_size=19)


def message(sec, nanosec, frame_id, child_frame_id, pose7, twist6) -> Odometry:
    msg = Odometry(child_frame_id=child_frame_id)
    msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = sec, nanosec, frame_id
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z, q.x, q.y, q.z, q.w = pose7
    msg.pose.covariance = [float(i) for i in range(36)]
    v, w = msg.twist.twist.linear, msg.twist.twist.angular
    v.x, v.y, v.z, w.x, w.y, w.z = twist6
    msg.twist.covariance = [-float(i) for i in range(36)]
    return msg


def rclpy_sample(data: bytes) -> OdometrySample:
    """The sample read from rclpy's own deserialisation of the bytes."""
    msg = deserialize_message(data, Odometry)
    stamp, twist = msg.header.stamp, msg.twist.twist
    pose, seconds = pose2d_of(msg.pose.pose), stamp_to_seconds(stamp)
    return OdometrySample(seconds, stamp.sec, stamp.nanosec, pose, (twist.linear.x, twist.angular.z))


def bits(sample: OdometrySample) -> tuple:
    """The sample with each float as its bits: NaN equals NaN, -0.0 differs from 0.0."""
    floats = (sample.stamp_s, *sample.pose, *sample.twist)
    return sample.sec, sample.nanosec, struct.pack("<6d", *floats)


@given(
    st.integers(-(2**31), 2**31 - 1),
    st.integers(0, 2**32 - 1),
    frame_ids,
    frame_ids,
    st.tuples(*[doubles] * 7),
    st.tuples(*[doubles] * 6),
)
def test_the_sample_is_rclpys_deserialisation(sec, nanosec, frame_id, child, pose7, twist6):
    msg = message(sec, nanosec, frame_id, child, pose7, twist6)
    data = serialize_message(msg)
    assert data[:2] == b"\x00\x01"  # little-endian CDR: the fields read at their offsets
    assert bits(odometry_sample(data)) == bits(rclpy_sample(data)) == bits(odometry_sample(msg))


def test_the_stamp_in_seconds_is_stamp_to_seconds():
    data = serialize_message(message(1_795_000_000, 123_456_789, "odom", "base_link", [0.0] * 7, [0.0] * 6))
    assert odometry_sample(data).stamp_s == 1_795_000_000 + 1e-9 * 123_456_789


def test_a_big_endian_message_goes_through_rclpy():
    out = bytearray(b"\x00\x00\x00\x00")  # encapsulation: CDR, big endian

    def align(size: int) -> None:
        out.extend(b"\x00" * (-(len(out) - 4) % size))

    out += struct.pack(">iI", -5, 7)
    for text in ("odom", "base_link_x"):
        align(4)
        out += struct.pack(">I", len(text) + 1) + text.encode() + b"\x00"
    align(8)
    out += struct.pack(">7d", 1.0, 2.0, 3.0, 0.0, 0.0, 0.6, 0.8) + struct.pack(">36d", *[0.0] * 36)
    out += struct.pack(">6d", 4.0, 5.0, 6.0, 7.0, 8.0, 9.0) + struct.pack(">36d", *[0.0] * 36)
    sample = odometry_sample(bytes(out))
    assert bits(sample) == bits(rclpy_sample(bytes(out)))
    assert (sample.sec, sample.nanosec, sample.pose[:2], sample.twist) == (-5, 7, (1.0, 2.0), (4.0, 9.0))
    assert math.isclose(sample.pose[2], 2.0 * math.atan2(0.6, 0.8))
