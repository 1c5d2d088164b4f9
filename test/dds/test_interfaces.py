"""beams_msgs builds and every message and service round-trips between two processes over DDS (issue 2)."""

import math
import signal
import subprocess
import sys

import pytest

ROUND_TRIP_TIMEOUT_S = 20.0


def _sample_messages():
    import beams_msgs.msg as beams_msgs_msg
    from beams_common.interfaces.bearing_messages import NS_PER_S, BearingFields
    from beams_common.ros.messages import bearing_array

    stamp_ns = 12 * NS_PER_S + 345
    fields = [
        BearingFields(stamp_ns, i, -math.pi / 3 + i, 1.5e-7 * i, 0.07, 0.1, 0.2, codes_seen=4)
        for i in (1, 2, 3, 5)
    ]
    array = bearing_array(stamp_ns, fields[:3], period_s=0.0998, revolution=77, rejected_windows=2)
    lone_bearing = bearing_array(stamp_ns, fields[3:], period_s=0.1).bearings[0]
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
    status = beams_msgs_msg.LocalisationStatus(status=beams_msgs_msg.LocalisationStatus.DEGRADED)
    status.header.stamp.sec = 12
    status.message = "degraded: pose not yet confirmed by the bearings since operator pose (3 of 9)"
    return [lone_bearing, array, pose, status]


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
