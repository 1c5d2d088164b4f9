"""The one BeaconBearingArray builder: every field set, stamps exact, the integer fields kept in range."""

from types import SimpleNamespace

from beams_common.interfaces.bearing_messages import (
    NS_PER_S,
    BearingFields,
    bearing_array_message,
    nanoseconds,
)

# any message classes taking keyword fields (rclpy's, a rosbags typestore's) serve the builder
TYPES = {
    name: (lambda **fields: SimpleNamespace(**fields))
    for name in (
        "builtin_interfaces/msg/Time",
        "std_msgs/msg/Header",
        "beams_msgs/msg/BeaconBearing",
        "beams_msgs/msg/BeaconBearingArray",
    )
}


def test_every_field_of_the_revolution_and_its_bearings_is_set():
    start_ns = 1_795_000_000 * NS_PER_S + 123_456_789  # an epoch stamp: exact to the nanosecond
    bearing = BearingFields(start_ns + 30_000_001, 2, -1.25, 3e-7, 0.07, 0.1, 0.2, codes_seen=4)
    message = bearing_array_message(
        TYPES, start_ns, [bearing], period_s=0.0998, revolution=77, frame_id="turret"
    )
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (1_795_000_000, 123_456_789)
    assert message.header.frame_id == "turret"
    assert (message.revolution, message.period, message.rejected_windows) == (77, 0.0998, 0)
    (item,) = message.bearings
    assert (item.header.stamp.sec, item.header.stamp.nanosec, item.header.frame_id) == (
        1_795_000_000,
        153_456_790,
        "turret",
    )
    assert (item.beacon_id, item.bearing, item.variance, item.codes_seen) == (2, -1.25, 3e-7, 4)
    assert (item.angular_window, item.rising_angle, item.falling_angle) == (0.07, 0.1, 0.2)


def test_revolution_wraps_to_uint32_and_rejected_windows_saturate_at_uint16():
    message = bearing_array_message(TYPES, 0, [], period_s=0.1, revolution=2**32 + 5, rejected_windows=70_000)
    assert (message.revolution, message.rejected_windows, message.bearings) == (5, 65_535, [])
    assert message.header.frame_id == "beams_sensor"


def test_nanoseconds_round_as_seconds_to_stamp_does():
    assert nanoseconds(1.0000000004) == 1_000_000_000
    assert nanoseconds(1.0000000006) == 1_000_000_001
    assert nanoseconds(-0.25) == -250_000_000
