"""beams_msgs builds and every message and service round-trips between two processes over DDS (issue 2)."""

import math
import signal
import subprocess
import sys

import pytest

ROUND_TRIP_TIMEOUT_S = 20.0


def _bearing(beams_msgs_msg, beacon_id: int):
    bearing = beams_msgs_msg.BeaconBearing()
    bearing.header.frame_id = "beams_sensor"
    bearing.header.stamp.sec = 12
    bearing.header.stamp.nanosec = 345
    bearing.beacon_id = beacon_id
    bearing.bearing = -math.pi / 3 + beacon_id
    bearing.variance = 1.5e-7 * beacon_id
    bearing.angular_window = 0.07
    bearing.rising_angle = 0.1
    bearing.falling_angle = 0.2
    bearing.codes_seen = 4
    return bearing


def _sample_messages():
    import beams_msgs.msg as beams_msgs_msg

    array = beams_msgs_msg.BeaconBearingArray()
    array.header.frame_id = "beams_sensor"
    array.revolution = 77
    array.period = 0.0998
    array.bearings = [_bearing(beams_msgs_msg, i) for i in (1, 2, 3)]
    array.rejected_windows = 2
    pose = beams_msgs_msg.TriangulatedPose()
    pose.header.frame_id = "map"
    pose.pose.pose.position.x = 1.25
    pose.pose.pose.orientation.z = math.sin(0.2)
    pose.pose.pose.orientation.w = math.cos(0.2)
    pose.pose.covariance = [float(i) for i in range(36)]
    pose.inverse_abs_d = 0.5
    pose.beacon_ids = [3, 1, 2]
    pose.accepted = False
    pose.reason = "1/|D| above the gate"
    return [_bearing(beams_msgs_msg, 5), array, pose]


@pytest.fixture
def echo_process(ros_env):
    script = __file__.replace("test_interfaces.py", "interface_echo.py")
    process = subprocess.Popen(
        [sys.executable, script], env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    yield process
    process.send_signal(signal.SIGINT)
    output, _ = process.communicate(timeout=15)
    assert process.returncode == 0, output
    assert "Traceback" not in output, output


def test_every_message_round_trips_between_processes(rclpy_node, echo_process):
    for message in _sample_messages():
        name = type(message).__name__
        received = rclpy_node.subscribe(type(message), f"echo_out/{name}")
        publisher = rclpy_node.node.create_publisher(type(message), f"echo_in/{name}", 10)
        arrived = rclpy_node.publish_until(publisher, message, received.__len__, ROUND_TRIP_TIMEOUT_S)
        assert arrived, f"{name} did not come back within {ROUND_TRIP_TIMEOUT_S} s"
        assert received[0] == message, f"{name} changed on the way: {received[0]} != {message}"


def test_every_service_round_trips_between_processes(rclpy_node, echo_process):
    from beams_msgs.srv import Calibrate, CaptureReference, ListConfigurations

    capture = rclpy_node.call(
        CaptureReference,
        "echo/capture_reference",
        CaptureReference.Request(x=1.5, y=0.25, theta=-1.0, revolutions=100),
        ROUND_TRIP_TIMEOUT_S,
    )
    assert capture.success and capture.message == "1.5 0.25 -1.0" and capture.configurations == 101

    calibrate = rclpy_node.call(
        Calibrate, "echo/calibrate", Calibrate.Request(dry_run=True), ROUND_TRIP_TIMEOUT_S
    )
    assert not calibrate.success and calibrate.calibration_file == ""
    assert calibrate.position_rms_before == pytest.approx(0.009)

    listing = rclpy_node.call(
        ListConfigurations, "echo/list_configurations", ListConfigurations.Request(), ROUND_TRIP_TIMEOUT_S
    )
    assert listing.configurations == 2 and list(listing.summaries) == ["0: a", "1: b"]
