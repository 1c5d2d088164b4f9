"""triangulation_node over DDS: exact poses from synthetic revolutions (message stamps only), the gate's
verdict on beams/pose and beams/pose_cov, bad input ignored with the node alive, motion compensation
with odometry, and a refused beacon map (exit 2)."""

import math
import signal

import numpy as np
import pytest

BEACONS = {1: (-0.062, -0.062), 2: (-0.062, 2.062), 3: (3.062, 1.0)}
OFFSET = (0.03, -0.02)
T0_S = 1000.0  # stamps that look like a real clock's
# synthetic stamps (T0_S), not on the node's clock: the stamp plausibility check off
PARAMS = {
    "turret_offset_m": list(OFFSET),
    "use_odometry": False,
    "max_stamp_age_s": 0.0,
    "max_stamp_lead_s": 0.0,
}
WAIT_S = 20.0
VARIANCE_RAD2 = float(np.deg2rad(0.1) ** 2)


def _time(seconds: float):
    from builtin_interfaces.msg import Time

    nanoseconds = round(seconds * 1e9)
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def _bearing(beacon_id: int, pose, offset=OFFSET) -> float:
    x, y, theta = pose
    turret_x = x + math.cos(theta) * offset[0] - math.sin(theta) * offset[1]
    turret_y = y + math.sin(theta) * offset[0] + math.cos(theta) * offset[1]
    bx, by = BEACONS[beacon_id]
    return math.remainder(math.atan2(by - turret_y, bx - turret_x) - theta, 2 * math.pi)


def _revolution(items, revolution=0):
    """items: (beacon_id, bearing, stamp_s) triples."""
    from beams_common.interfaces.bearing_messages import BearingFields, nanoseconds
    from beams_common.ros.messages import bearing_array

    fields = [
        BearingFields(nanoseconds(T0_S + s), beacon_id, bearing, VARIANCE_RAD2)
        for beacon_id, bearing, s in items
    ]
    start_ns = nanoseconds(T0_S + min(s for _, _, s in items) - 0.01)
    return bearing_array(start_ns, fields, period_s=0.1, revolution=revolution)


def _static_revolution(pose, stamp_s=0.0, ids=(1, 2, 3), revolution=0):
    return _revolution([(i, _bearing(i, pose), stamp_s + 0.03 * k) for k, i in enumerate(ids)], revolution)


def _yaw(orientation) -> float:
    return 2.0 * math.atan2(orientation.z, orientation.w)


def _probe(rclpy_node):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    from beams_msgs.msg import BeaconBearingArray, TriangulatedPose

    publisher = rclpy_node.node.create_publisher(BeaconBearingArray, "beams/bearings", 10)
    poses = rclpy_node.subscribe(TriangulatedPose, "beams/pose")
    covariances = rclpy_node.subscribe(PoseWithCovarianceStamped, "beams/pose_cov")
    return publisher, poses, covariances


def test_exact_pose_with_covariance_stamped_with_the_bearings(start_node, rclpy_node):
    from visualization_msgs.msg import Marker, MarkerArray

    node = start_node("beams_triangulation", "triangulation_node", PARAMS)
    publisher, poses, covariances = _probe(rclpy_node)
    markers = rclpy_node.subscribe(MarkerArray, "beams/markers")
    pose = (1.3, 0.7, 2.4)
    assert rclpy_node.publish_until(
        publisher, _static_revolution(pose), lambda: bool(covariances) and bool(markers), WAIT_S
    ), node.log()
    # the beacons, the pose's arrow and its 2-sigma ellipse, in the pose's frame and at its stamp
    kinds = [m.type for m in markers[-1].markers]
    assert kinds == [Marker.SPHERE] * 3 + [Marker.ARROW, Marker.CYLINDER], kinds
    arrow = markers[-1].markers[3]
    assert (arrow.pose.position.x, arrow.pose.position.y) == pytest.approx(pose[:2], abs=1e-9)
    assert all(
        m.header.frame_id == "map" and m.header.stamp == poses[-1].header.stamp for m in markers[-1].markers
    )
    message = poses[-1]
    assert message.accepted and message.reason == ""
    assert message.header.frame_id == "map"
    # Stamped with the mean instant of the three bearings (0, 0.03, 0.06 s after T0).
    assert message.header.stamp.sec == 1000 and abs(message.header.stamp.nanosec - 30_000_000) < 10
    p = message.pose.pose
    assert (p.position.x, p.position.y, _yaw(p.orientation)) == pytest.approx(pose, abs=1e-9)
    covariance = np.array(message.pose.covariance).reshape(6, 6)
    assert 0.0 < covariance[0, 0] < 1e-3 and 0.0 < covariance[5, 5] < 1e-3
    assert covariance[0, 5] == pytest.approx(covariance[5, 0])
    assert list(message.beacon_ids) == [1, 2, 3]
    assert 0.0 < message.inverse_abs_d < 2.0
    np.testing.assert_array_equal(covariances[-1].pose.covariance, message.pose.covariance)
    node.assert_clean_exit(signal.SIGTERM)


def test_markers_are_built_only_while_something_subscribes(rclpy_context):
    """A robot's run has no marker reader: the array (more work than the pose's two messages) is not built
    for nobody; RViz (or a bag) subscribing gets them from the next pose on."""
    import time

    from visualization_msgs.msg import MarkerArray

    from beams_triangulation.gating import PoseEstimate
    from beams_triangulation.triangulation_node import TriangulationNode

    node = TriangulationNode()
    listener = rclpy_context.create_node("marker_listener")
    try:
        built = []
        build = node._markers
        node._markers = lambda *args: built.append(args) or build(*args)
        covariance = np.diag([1e-6, 2e-6, 1e-6])
        estimate = PoseEstimate(1.3, 0.7, 2.4, covariance, 0.5, (1, 2, 3), True, "")
        node._publish(estimate, T0_S, False)
        assert built == []
        listener.create_subscription(MarkerArray, "beams/markers", lambda _msg: None, 10)
        deadline = time.monotonic() + WAIT_S
        while node.marker_publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        node._publish(estimate, T0_S + 0.1, False)
        assert len(built) == 1
        node.publish_markers = False  # the parameter still switches them off
        node._publish(estimate, T0_S + 0.2, False)
        assert len(built) == 1
    finally:
        listener.destroy_node()
        node.destroy_node()


def test_bad_input_is_logged_and_ignored_then_good_input_works(start_node, rclpy_node):
    node = start_node("beams_triangulation", "triangulation_node", PARAMS)
    publisher, poses, _ = _probe(rclpy_node)
    assert rclpy_node.spin_until(lambda: publisher.get_subscription_count() > 0, WAIT_S)
    bad = [
        _revolution([(1, 0.1, 0.0), (2, 0.5, 0.03), (9, 1.0, 0.06)]),  # unknown id
        _revolution([(1, 0.1, 0.0), (2, math.nan, 0.03), (3, 1.0, 0.06)]),  # NaN bearing
        _revolution([(1, 0.1, 0.0), (1, 0.5, 0.03), (3, 1.0, 0.06)]),  # duplicated beacon
        _revolution([(1, 0.1, 0.0), (2, 0.5, 0.03)]),  # two beacons only
    ]

    def bad_input_logged():
        for message in bad:  # best effort: sent again until the node has seen them
            publisher.publish(message)
        rclpy_node.spin_for(0.2)
        return "bad input" in node.log()

    assert rclpy_node.spin_until(bad_input_logged, WAIT_S), node.log()
    assert not poses
    pose = (2.0, 1.5, -0.5)
    assert rclpy_node.publish_until(publisher, _static_revolution(pose), lambda: bool(poses), WAIT_S)
    assert poses[-1].pose.pose.position.x == pytest.approx(2.0, abs=1e-9)
    assert node.process.poll() is None
    assert "Traceback" not in node.log()


def test_pose_near_the_critical_circle_is_published_rejected_without_pose_cov(start_node, rclpy_node):
    start_node("beams_triangulation", "triangulation_node", PARAMS)
    publisher, poses, covariances = _probe(rclpy_node)
    # The circle through the three beacons: centre (cx, 1.0), through (-0.062, -0.062) and (3.062, 1.0).
    cx = (3.062**2 - 0.062**2 - 1.062**2) / (2 * (3.062 + 0.062))
    radius = 3.062 - cx
    angle = math.radians(-70.0)
    pose = (cx + (radius - 0.003) * math.cos(angle), 1.0 + (radius - 0.003) * math.sin(angle), 0.0)
    assert rclpy_node.publish_until(publisher, _static_revolution(pose), lambda: bool(poses), WAIT_S)
    assert not poses[-1].accepted
    assert "1/|D|" in poses[-1].reason
    assert not covariances


def test_odometry_brings_the_bearings_to_one_instant(start_node, rclpy_node):
    from nav_msgs.msg import Odometry

    node = start_node("beams_triangulation", "triangulation_node", {**PARAMS, "use_odometry": True})
    publisher, poses, _ = _probe(rclpy_node)
    odometry_publisher = rclpy_node.node.create_publisher(Odometry, "odom", 10)

    def truth(t):  # 0.5 m/s on a circle, 2 rad/s: 11 deg per revolution
        heading = 0.3 + 2.0 * t
        return (1.5 + 0.25 * math.sin(heading), 1.0 - 0.25 * math.cos(heading), heading)

    def odometry(t):  # the odometry frame is the start pose; odometry is perfect here
        x0, y0, h0 = truth(0.0)
        x, y, h = truth(t)
        c, s = math.cos(h0), math.sin(h0)
        message = Odometry()
        message.header.stamp = _time(T0_S + t)
        message.pose.pose.position.x = c * (x - x0) + s * (y - y0)
        message.pose.pose.position.y = -s * (x - x0) + c * (y - y0)
        orientation = message.pose.pose.orientation
        orientation.z, orientation.w = math.sin((h - h0) / 2), math.cos((h - h0) / 2)
        message.twist.twist.linear.x, message.twist.twist.angular.z = 0.5, 2.0
        return message

    stamps = (0.05, 0.09, 0.14)
    revolution = _revolution([(i, _bearing(i, truth(t)), t) for i, t in zip((1, 2, 3), stamps, strict=True)])
    x, y, heading = truth(sum(stamps) / 3)

    def errors(message):
        p = message.pose.pose
        return (
            math.hypot(p.position.x - x, p.position.y - y),
            abs(math.remainder(_yaw(p.orientation) - heading, 2 * math.pi)),
        )

    assert rclpy_node.spin_until(lambda: odometry_publisher.get_subscription_count() > 0, WAIT_S)
    rclpy_node.spin_for(0.5)  # discovery both ways

    def compensated_pose_arrived():
        for k in range(0, 11):  # a 50 Hz odometry stream covering the revolution, one message at a time
            odometry_publisher.publish(odometry(0.02 * k))
            rclpy_node.spin_for(0.01)
        publisher.publish(revolution)
        # Until the odometry arrived, poses are uncompensated: centimetres off (11 deg per revolution).
        return bool(poses) and errors(poses[-1])[0] < 1e-3

    assert rclpy_node.spin_until(compensated_pose_arrived, WAIT_S), node.log()
    position_error, heading_error = errors(poses[-1])
    assert position_error < 1e-4 and heading_error < 1e-4


def test_collinear_beacon_map_is_refused_with_exit_status_2(start_node):
    node = start_node(
        "beams_triangulation",
        "triangulation_node",
        {"beacon_x": [0.0, 1.0, 2.0], "beacon_y": [0.0, 0.0, 0.0]},
    )
    assert node.wait_exit(WAIT_S) == 2
    assert "all beacons lie on one line" in node.log()
    assert "Traceback" not in node.log()
